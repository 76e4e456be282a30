"""The optimised lift (issue 19 item 5): its loss's gradient against central differences (the implicit
gradient through the gradient attack), and on a street-like cloud the lift beats the random lift it starts
from under the attack it was optimised against *and* under Line2Point, which took no part; the viewing-ray
term keeps lines off the viewing directions; points stay on their lines; bad input is refused."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.attacks.gradient import GradientAttackConfig, gradient_attack, gradient_attack_core
from privslam_jax.geometry.plucker import lines_from_points_directions
from privslam_jax.attacks.line2point import Line2PointConfig, line2point
from privslam_jax.metrics.privacy import point_recovery_metrics
from privslam_jax.privacy.lift import fixed_key, random_lift
from privslam_jax.privacy.optimised_lift import OptimisedLiftConfig, lift_loss, optimised_lift

pytestmark = pytest.mark.xla_optimized  # a long gradient-descent loop (tests/conftest.py)


def _street(n=900, seed=0):
    """Two 5 m high façades 8 m apart and the road between them, 16 m long: the surfaces attacks rely on."""
    rng = np.random.default_rng(seed)
    k = n // 3
    a = np.stack([rng.uniform(-8, 8, k), np.full(k, -4.0), rng.uniform(0, 5, k)], 1)
    b = np.stack([rng.uniform(-8, 8, k), np.full(k, 4.0), rng.uniform(0, 5, k)], 1)
    c = np.stack([rng.uniform(-8, 8, n - 2 * k), rng.uniform(-4, 4, n - 2 * k), np.zeros(n - 2 * k)], 1)
    return np.concatenate([a, b, c])


def _within(points, rec):
    return point_recovery_metrics(points, np.asarray(rec))["within_0.5"]


def test_loss_gradient_matches_central_differences():
    """``jit(grad)`` of the loss in the unnormalised directions (float64) against central differences of the same
    loss computed in numpy, the attack's minimiser polished by the exact Newton method of
    ``tests/test_attack_gradients.py`` (NonlinearCG's stopping noise, ~1e-7, would swamp the differences).

    Where the attack's minimiser is a smooth function of the lines: 8 clusters of 4 points 5 cm wide, 3
    neighbours (each line's siblings).  On a street-like cloud the loss is only piecewise smooth (the attack's
    start and neighbour graph change with the lines and its minimiser jumps), so differences are no reference there."""
    from test_attack_gradients import _check_fd, _graph, _newton_minimiser

    rng = np.random.default_rng(2)
    pts = np.repeat(rng.uniform(-5, 5, (8, 3)), 4, axis=0) + rng.normal(0, 0.05, (32, 3))
    cfg = OptimisedLiftConfig(cap=2.0, conditioning_weight=0.3,
                              attack=GradientAttackConfig(num_neighbours=3, max_steps=20000, rtol=1e-13, atol=1e-13))
    with jax.enable_x64(True):
        P = jnp.asarray(pts)
        theta = rng.normal(size=(32, 3))
        view = rng.normal(size=(32, 3))
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        d = theta / np.linalg.norm(theta, axis=1, keepdims=True)
        lines = lines_from_points_directions(P, jnp.asarray(d))
        res = gradient_attack_core(lines, cfg.attack)
        assert bool(res.successful) and int(res.num_steps) < cfg.attack.max_steps  # implicit gradients need a minimiser
        nb, t_core = _graph(lines), np.asarray(res.offsets)
        grad = np.asarray(jax.jit(jax.grad(lambda th: lift_loss(th, P, jnp.asarray(view), cfg)[0]))(jnp.asarray(theta)))

        def f_ref(th):
            dd = th / np.linalg.norm(th, axis=1, keepdims=True)
            a, dd, t = _newton_minimiser(dd, np.cross(pts, dd), nb, cfg.attack.sigma, t_core)
            err = np.linalg.norm(a + t[:, None] * dd - pts, axis=1)
            return -np.mean(cfg.cap * np.tanh(err / cfg.cap)) + cfg.conditioning_weight * np.mean(np.sum(dd * view, 1) ** 2)

        _check_fd(f_ref, theta, grad, rng, 1e-6)
        assert np.abs(grad).max() > 1e-3  # the attack's term moves the loss


def test_beats_the_random_lift_under_the_attack_it_was_made_against_and_under_line2point():
    pts = _street()
    key = fixed_key(0)
    cfg = OptimisedLiftConfig(passes=30.0)
    start = random_lift(pts, jax.random.split(key)[0])  # the draw it starts from
    opt = optimised_lift(pts, key, config=cfg)
    d, m = np.asarray(opt.directions, np.float64), np.asarray(opt.moments, np.float64)
    assert np.max(np.linalg.norm(np.cross(pts, d) - m, axis=1)) < 1e-9  # point i on line i (float64 in, out)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    results = {}
    for name, lines in (("random", start), ("optimised", opt)):
        g = gradient_attack(lines, throw=False).points
        r, _ = line2point(lines, Line2PointConfig(num_refine_iterations=1))
        results[name] = (_within(pts, g), _within(pts, r))
        if name == "optimised":
            # an attacker who knows the optimiser pushed the estimates away and moves them back by s metres
            # along the line, on the side an oracle tells: still below the random lift's exposure
            off = np.sum((np.asarray(g) - pts) * d, axis=1)
            shifted = [100 * np.mean(np.minimum(abs(off - s), abs(off + s)) < 0.5) for s in (1.0, 2.0, 3.0)]
    # measured: random 27.4 / 32.7 %, optimised 4.0 / 6.1 % (gradient / Line2Point within 0.5 m); shifted 10.8-12.0 %;
    # on an AVX-512 machine (2026-12-07) the optimisation ends elsewhere: optimised 1.9 / 6.3 %, shifted 9.7 / 12.9 / 17.6 %
    assert results["optimised"][0] < 0.5 * results["random"][0], results
    assert results["optimised"][1] < 0.5 * results["random"][1], results
    assert max(shifted) < 0.75 * min(results["random"]), (shifted, results)


def test_viewing_directions_keep_lines_off_the_viewing_rays():
    """With a camera path along the street, the mean ``(d·v)²`` falls well below the ⅓ of random directions
    when the term is weighted, and stays near ⅓ without viewing directions."""
    pts = _street(400)
    cams = np.stack([pts[:, 0], np.zeros(len(pts)), np.full(len(pts), 1.6)], 1)
    view = pts - cams
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    cfg = OptimisedLiftConfig(passes=10.0, conditioning_weight=5.0)
    with_term = optimised_lift(pts, fixed_key(3), viewing_directions=view, config=cfg)
    without = optimised_lift(pts, fixed_key(3), config=cfg)
    cos2 = lambda lines: float(np.mean(np.sum(np.asarray(lines.directions) * view, axis=1) ** 2))  # noqa: E731
    assert cos2(with_term) < 0.1 and cos2(without) > 0.2, (cos2(with_term), cos2(without))


def test_repeated_points_and_bad_input():
    pts = _street(300)
    rep = np.concatenate([pts, pts[:5]])
    lines = optimised_lift(rep, fixed_key(1), config=OptimisedLiftConfig(passes=2.0))
    np.testing.assert_array_equal(np.asarray(lines.directions)[-5:], np.asarray(lines.directions)[:5])
    with pytest.raises(ValueError, match="patch_size"):
        optimised_lift(pts[:100], fixed_key(0))
    with pytest.raises(ValueError, match="viewing directions"):
        optimised_lift(pts, fixed_key(0), viewing_directions=np.ones((10, 3)))
    with pytest.raises(ValueError, match="NaN"):
        optimised_lift(np.where(np.arange(300)[:, None] == 4, np.nan, pts), fixed_key(0))
    assert dataclasses.replace(OptimisedLiftConfig(), passes=1.0).passes == 1.0
