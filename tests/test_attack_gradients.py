"""Issue 17 item 5: ``jax.jit(jax.grad(...))`` through the lift and the attacks, against central
finite differences in float64; the host boundary of the attacks (checks, ``throw``).

Reference: central differences ``(f(x + εv) − f(x − εv)) / 2ε`` along random directions ``v``,
compared with ``⟨∇f, v⟩``; relative error ≤ 1e-4 (observed ~1e-8).

* Lifts and Line2Point: differences of the jitted forward function itself, ε = 1e-7 (explicit
  rational functions: rounding error ~1e-16·|f|/ε). Line2Point's discrete choices (neighbour
  sets, Kuiper intervals) are constants of the gradient; they are not exposed, but a switch
  within ±1e-7 would show as a mismatch of orders of magnitude, not as a small error.
* Gradient attack: optimistix's NonlinearCG stops where its Armijo line search can no longer
  resolve a decrease of ``E`` (‖∇E‖ ≈ 1e-8), so differences of its output carry that solver noise
  divided by ε, and ε large enough to hide it moves the neighbour graph. The reference is
  therefore the derivative of the *exact* minimiser that the implicit adjoint differentiates:
  central differences (ε = 1e-6) of ``t*(lines)`` solved to machine precision by a plain numpy
  Newton iteration on ``E`` (hand-written gradient and Hessian) with the core's neighbour graph.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.attacks.gradient import (
    GradientAttackConfig,
    GradientAttackResult,
    gradient_attack,
    gradient_attack_core,
    line_neighbours,
)
from privslam_jax.attacks.line2point import (
    Line2PointConfig,
    line2point,
    line2point_core,
    line2point_offsets,
)
from privslam_jax.geometry.plucker import line_line_distance, point_line_distance
from privslam_jax.privacy.lift import (
    fixed_key,
    paired_lift,
    paired_lift_core,
    random_lift,
    random_lift_core,
    ray_anchors,
    ray_lift,
    ray_lift_core,
    axial_lift,
    axial_lift_core,
    sphere_lift,
    sphere_lift_core,
)
from privslam_jax.types import LineCloud

sys.path.insert(0, str(Path(__file__).parent))
from test_line2point import street_points

RTOL = 1e-4
# module-level jitted cores: one compilation per (shape, config), shared between the tests
ga_core = jax.jit(gradient_attack_core, static_argnames="config")
l2p_core = jax.jit(line2point_core, static_argnames="config")
l2p_offsets = jax.jit(line2point_offsets, static_argnames="config")


def _check_fd(f, x, grad, rng, eps, directions=3):
    """``⟨grad, v⟩`` against central differences of ``f`` along ``directions`` random ``v``."""
    leaves, tree = jax.tree.flatten(x)
    g = jax.tree.leaves(grad)
    assert len(g) == len(leaves)
    for _ in range(directions):
        v = [rng.normal(size=np.shape(leaf)) for leaf in leaves]
        plus = jax.tree.unflatten(tree, [leaf + eps * vi for leaf, vi in zip(leaves, v)])
        minus = jax.tree.unflatten(tree, [leaf - eps * vi for leaf, vi in zip(leaves, v)])
        fd = (float(f(plus)) - float(f(minus))) / (2 * eps)
        an = sum(float(np.sum(np.asarray(gi) * vi)) for gi, vi in zip(g, v))
        assert np.isfinite(an) and abs(an - fd) <= RTOL * abs(an), (an, fd)


def _clustered_lines(rng, centres=8, per=4, noise=0.05):
    """``per`` random lines through each of ``centres`` points (± noise): every line's 3
    nearest lines are its siblings, and the attack's minimiser is a smooth function of them."""
    c = rng.uniform(-5, 5, (centres, 3))
    p = np.repeat(c, per, axis=0) + rng.normal(0, noise, (centres * per, 3))
    u = rng.normal(size=p.shape)
    d = u / np.linalg.norm(u, axis=1, keepdims=True)
    return p, LineCloud(directions=jnp.asarray(d), moments=jnp.asarray(np.cross(p, d)))


def _graph(lines, k=3):
    """The gradient attack's neighbour sets."""
    d = jnp.asarray(lines.directions)
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    return np.asarray(line_neighbours(jnp.cross(d, jnp.asarray(lines.moments)), d, k=k))


def _newton_minimiser(directions, moments, nb, sigma, t0):
    """numpy reference: ``argmin_t Σ_i Σ_{j∈nb[i]} σ² log(1 + ‖x_i − x_j‖²/σ²)``, ``x = a + t d``, by
    Newton's method from ``t0`` with the exact gradient and Hessian (``s = ‖x_i − x_j‖²``:
    ``∂s/∂t_i = 2 r·d_i``, ``∂s/∂t_j = −2 r·d_j``, ``∂²s = 2[[1, −d_i·d_j], [−d_i·d_j, 1]]``;
    ``ρ' = 1/(1 + s/σ²)``, ``ρ'' = −ρ'²/σ²``). Returns ``(a, d, t)``."""
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    a = np.cross(d, np.asarray(moments, np.float64))
    n, k = nb.shape
    i, j = np.repeat(np.arange(n), k), np.asarray(nb).ravel()
    t = np.array(t0, np.float64)
    dij = np.sum(d[i] * d[j], axis=1)
    for _ in range(50):
        x = a + t[:, None] * d
        r = x[i] - x[j]
        s = np.sum(r * r, axis=1)
        r1 = 1.0 / (1.0 + s / sigma**2)
        r2 = -(r1**2) / sigma**2
        gi, gj = 2 * np.sum(r * d[i], axis=1), -2 * np.sum(r * d[j], axis=1)
        grad = np.zeros(n)
        np.add.at(grad, i, r1 * gi)
        np.add.at(grad, j, r1 * gj)
        H = np.zeros((n, n))
        np.add.at(H, (i, i), r2 * gi * gi + 2 * r1)
        np.add.at(H, (j, j), r2 * gj * gj + 2 * r1)
        np.add.at(H, (i, j), r2 * gi * gj - 2 * r1 * dij)
        np.add.at(H, (j, i), r2 * gi * gj - 2 * r1 * dij)
        step = np.linalg.solve(H, grad)
        t = t - step
        if np.max(np.abs(step)) < 1e-14 * (1 + np.max(np.abs(t))):
            break
    assert np.max(np.abs(grad)) < 1e-9 and np.all(np.linalg.eigvalsh(H) > 0)  # a strict minimum
    return a, d, t


def _ray_core(pts, key):
    """``ray_lift_core`` with the 4 anchors ``ray_lift(pts, key, 4)`` picks, held constant."""
    anchors = jnp.asarray(ray_anchors(np.asarray(pts), 4, jax.random.split(key, 3)[0]))
    return lambda p: ray_lift_core(p, anchors, key)


@pytest.mark.parametrize("bind, host", [
    (lambda pts, key: lambda p: random_lift_core(p, key), random_lift),
    (lambda pts, key: lambda p: paired_lift_core(p, key), paired_lift),
    (_ray_core, lambda p, key: ray_lift(p, key, num_anchors=4)),
    (lambda pts, key: lambda p: sphere_lift_core(p, key), sphere_lift),
    (lambda pts, key: lambda p: axial_lift_core(p, jnp.asarray([0.3, -1.0, 0.2]), key),
     lambda p, key: axial_lift(p, (0.3, -1.0, 0.2), key)),
], ids=["random", "paired", "ray", "sphere", "axial"])
def test_lift_core_gradient_and_host_equality(bind, host):
    """Gradients of a scalar of the core's lines in the points against central differences; the core
    equals the host lift for distinct points.  The ray cloud's anchors (k-means, on the host) are held
    at their value for the unperturbed points; the sphere cloud's centroid moves with the points."""
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        pts = jnp.asarray(rng.uniform(-10, 10, (41, 3)))  # odd: the paired lift has an odd one out
        key = fixed_key(3)
        core = bind(pts, key)
        wd, wm = (jnp.asarray(w) for w in rng.normal(size=(2, 41, 3)))

        def f(p):
            lines = core(p)
            return jnp.sum(wd * lines.directions) + jnp.sum(jnp.sin(wm * lines.moments))

        grad = jax.jit(jax.grad(f))(pts)
        _check_fd(jax.jit(f), pts, grad, rng, 1e-7)
        # the core is the host lift (distinct points) up to rounding
        a, b = core(pts), host(np.asarray(pts), key)
        np.testing.assert_allclose(np.asarray(a.directions), np.asarray(b.directions), rtol=0, atol=1e-13)
        np.testing.assert_allclose(np.asarray(a.moments), np.asarray(b.moments), rtol=0, atol=1e-12)


def test_gradient_attack_core_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    with jax.enable_x64(True):
        _, lines = _clustered_lines(rng)
        cfg = GradientAttackConfig(num_neighbours=3, sigma=0.5, max_steps=20000, rtol=1e-13, atol=1e-13)
        w = jnp.asarray(rng.normal(size=(32, 3)))

        def f(lines):
            return jnp.sum(w * gradient_attack_core(lines, cfg).points)

        res = ga_core(lines, cfg)
        assert bool(res.successful) and 0 < int(res.num_steps) < cfg.max_steps
        grad = jax.jit(jax.grad(f))(lines)
        assert isinstance(grad, LineCloud)
        nb, t_core = _graph(lines), np.asarray(res.offsets)
        _, _, t_ref = _newton_minimiser(lines.directions, lines.moments, nb, 0.5, t_core)
        np.testing.assert_allclose(t_core, t_ref, rtol=0, atol=1e-6)  # the solve found that minimum

        def f_ref(lines):
            a, d, t = _newton_minimiser(lines.directions, lines.moments, nb, 0.5, t_core)
            return np.sum(np.asarray(w) * (a + t[:, None] * d))

        _check_fd(f_ref, lines, grad, rng, 1e-6)


def test_lift_then_gradient_attack_is_differentiable_in_the_points():
    """``loss`` = random_lift_core → gradient_attack_core → scalar, ``jit(grad)`` w.r.t. the points;
    reference: the host lift (numpy) and the numpy Newton minimiser."""
    rng = np.random.default_rng(2)
    with jax.enable_x64(True):
        pts, _ = _clustered_lines(rng)
        key = fixed_key(5)
        cfg = GradientAttackConfig(num_neighbours=3, sigma=0.5, max_steps=20000, rtol=1e-13, atol=1e-13)
        w = rng.normal(size=(32, 3))

        def f(p):
            res = gradient_attack_core(random_lift_core(p, key), cfg)
            return jnp.sum(w * res.points) + jnp.sum(jnp.sin(res.offsets))

        grad = jax.jit(jax.grad(f))(jnp.asarray(pts))
        res = gradient_attack_core(random_lift_core(jnp.asarray(pts), key), cfg)
        assert bool(res.successful)
        nb, t_core = _graph(random_lift_core(jnp.asarray(pts), key)), np.asarray(res.offsets)

        def f_ref(p):
            lines = random_lift(np.asarray(p), key)
            a, d, t = _newton_minimiser(lines.directions, lines.moments, nb, 0.5, t_core)
            return np.sum(w * (a + t[:, None] * d)) + np.sum(np.sin(t))

        _check_fd(f_ref, pts, grad, rng, 1e-6)


def test_line2point_core_gradient_and_public_equality():
    rng = np.random.default_rng(3)
    cfg = Line2PointConfig(num_refine_iterations=1)
    with jax.enable_x64(True):
        lines = random_lift(jnp.asarray(street_points(120, 2)), fixed_key(4))
        _, t = l2p_core(lines, cfg)
        _, t_pub = line2point(lines, cfg)
        np.testing.assert_allclose(np.asarray(t), np.asarray(t_pub), rtol=0, atol=1e-9)  # the same attack
        w = rng.normal(size=(120, 3))
        grad = jax.jit(jax.grad(lambda lines: jnp.sum(w * line2point_core(lines, cfg)[0])))(lines)
        assert np.all(np.isfinite(np.asarray(grad.directions))) and np.all(np.isfinite(np.asarray(grad.moments)))
        _check_fd(lambda lines: np.sum(w * np.asarray(l2p_core(lines, cfg)[0])), lines, grad, rng, 1e-7)


def test_line2point_offsets_given_neighbours_gradient():
    """The continuous part alone: random neighbour sets with masks, the line itself among its
    neighbours (a zero cross product, where ``jnp.linalg.norm`` would make the gradient NaN)."""
    rng = np.random.default_rng(4)
    cfg = Line2PointConfig()
    with jax.enable_x64(True):
        lines = random_lift(jnp.asarray(street_points(90, 3)), fixed_key(6))
        nb = rng.integers(0, 90, (90, 24))
        nb[:, 0] = np.arange(90)
        nb, valid = jnp.asarray(nb), jnp.asarray(rng.random((90, 24)) < 0.8)
        w = rng.normal(size=90)
        grad = jax.jit(jax.grad(lambda lines: jnp.sum(w * line2point_offsets(lines, nb, valid, cfg))))(lines)
        _check_fd(lambda lines: np.sum(w * np.asarray(l2p_offsets(lines, nb, valid, cfg))), lines, grad, rng, 1e-7)


def test_plucker_distances_have_finite_gradients_at_zero():
    """A point on its line / two identical lines: distance exactly 0, gradient 0 (not NaN)."""
    with jax.enable_x64(True):
        d = jnp.asarray([0.0, 0.0, 1.0])
        x = jnp.asarray([1.0, 2.0, 5.0])
        m = jnp.asarray([2.0, -1.0, 0.0])  # x × d, exactly
        assert float(point_line_distance(x, d, m)) == 0.0
        np.testing.assert_array_equal(np.asarray(jax.jit(jax.grad(point_line_distance))(x, d, m)), 0.0)
        g = jax.jit(jax.grad(line_line_distance, argnums=(0, 1, 2, 3)))(d, m, d, m)
        assert all(np.all(np.isfinite(np.asarray(gi))) for gi in g)
        # away from zero the usual gradient: ∂‖x × d − m‖/∂x = d × r/‖r‖ with r = x × d − m
        x1 = x + jnp.asarray([0.3, -0.1, 0.2])
        r = jnp.cross(x1, d) - m
        np.testing.assert_allclose(np.asarray(jax.grad(point_line_distance)(x1, d, m)),
                                   np.asarray(jnp.cross(d, r) / jnp.linalg.norm(r)), atol=1e-15)


def test_throw_at_the_api_boundary_and_step_count():
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        _, lines = _clustered_lines(rng)
        one_step = GradientAttackConfig(num_neighbours=3, max_steps=1)
        with pytest.raises(RuntimeError, match="did not succeed after 1 of max_steps=1"):
            gradient_attack(lines, one_step)  # throw=True is the default
        res = gradient_attack(lines, one_step, throw=False)
        assert not bool(res.successful) and int(res.num_steps) == 1
        assert "maximum number of steps" in res.message()
        # the core never raises: the caller reads the result code, also under jit
        core = ga_core(lines, one_step)
        assert not bool(core.successful) and int(core.num_steps) == 1
        ok_cfg = GradientAttackConfig(num_neighbours=3, max_steps=2000, rtol=1e-9, atol=1e-9)
        res = gradient_attack(lines, ok_cfg)
        assert isinstance(res, GradientAttackResult)
        assert bool(res.successful) and res.message() == "" and 1 < int(res.num_steps) < ok_cfg.max_steps
        # the boundary and the core run the same computation
        same = gradient_attack_core(lines, ok_cfg)
        np.testing.assert_array_equal(np.asarray(same.offsets), np.asarray(res.offsets))
        assert int(same.num_steps) == int(res.num_steps)


def test_nan_inputs_are_refused_at_the_host_boundary():
    rng = np.random.default_rng(6)
    with jax.enable_x64(True):
        _, lines = _clustered_lines(rng)
        bad = LineCloud(directions=lines.directions, moments=lines.moments.at[3, 1].set(jnp.nan))
        with pytest.raises(ValueError, match="NaN"):
            gradient_attack(bad, GradientAttackConfig(num_neighbours=3))
        with pytest.raises(ValueError, match="NaN"):
            line2point(bad, Line2PointConfig(num_refine_iterations=0))
        with pytest.raises(ValueError, match="t0 contains NaN"):
            gradient_attack(lines, GradientAttackConfig(num_neighbours=3), t0=jnp.full(32, jnp.nan))
        with pytest.raises(ValueError, match=r"t0 must have shape \(32,\)"):
            gradient_attack(lines, GradientAttackConfig(num_neighbours=3), t0=jnp.zeros(31))
        pts = np.asarray(rng.normal(size=(10, 3)))
        pts[2, 0] = np.nan
        for lift in (random_lift, paired_lift):
            with pytest.raises(ValueError, match="NaN"):
                lift(pts, fixed_key(0))
        # the core does not check (it runs under jit): NaN in, NaN out, no exception
        res = ga_core(bad, GradientAttackConfig(num_neighbours=3, max_steps=1))
        assert np.isnan(np.asarray(res.points)[3]).any()
