"""Gradient attack: closed-form pair problem, exact intersections, gradient vs finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.attacks.gradient import GradientAttackConfig, consistency_energy, gradient_attack
from privslam_jax.geometry.plucker import closest_approach
from privslam_jax.types import LineCloud


def _lines(p, d):
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return LineCloud(directions=jnp.asarray(d), moments=jnp.asarray(np.cross(p, d)))


def test_pair_of_lines_goes_to_closest_approach():
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        p = rng.normal(size=(2, 3)) * 3
        d = rng.normal(size=(2, 3))
        lines = _lines(p, d)
        dd = np.asarray(lines.directions)
        a = np.cross(dd, np.asarray(lines.moments))
        cfg = GradientAttackConfig(num_neighbours=1, sigma=1e4, rtol=1e-10, atol=1e-10, max_steps=500)
        t = gradient_attack(lines, cfg, t0=jnp.zeros(2)).offsets
        t1, t2 = closest_approach(jnp.asarray(a[0]), jnp.asarray(dd[0]), jnp.asarray(a[1]), jnp.asarray(dd[1]))
    np.testing.assert_allclose(np.asarray(t), [float(t1), float(t2)], atol=1e-5)


def test_recovers_exact_intersections():
    # 30 points, 4 lines through each: every line's neighbours include its 3 siblings
    rng = np.random.default_rng(1)
    centres = rng.uniform(-20, 20, (30, 3))
    p = np.repeat(centres, 4, axis=0)
    with jax.enable_x64(True):
        lines = _lines(p, rng.normal(size=(120, 3)))
        rec = gradient_attack(lines, GradientAttackConfig(num_neighbours=3, sigma=0.5, max_steps=1000, rtol=1e-9, atol=1e-9)).points
    err = np.linalg.norm(np.asarray(rec) - p, axis=1)
    assert np.median(err) < 1e-3 and np.mean(err < 1e-2) > 0.9


def test_energy_gradient_matches_finite_differences():
    rng = np.random.default_rng(2)
    with jax.enable_x64(True):
        a = jnp.asarray(rng.normal(size=(12, 3)))
        d = jnp.asarray(rng.normal(size=(12, 3)))
        nb = jnp.asarray(rng.integers(0, 12, (12, 4)))
        t = jnp.asarray(rng.normal(size=12))
        g = np.asarray(jax.grad(consistency_energy)(t, a, d, nb, 0.7))
        eps = 1e-6
        fd = [(float(consistency_energy(t.at[i].add(eps), a, d, nb, 0.7)) - float(consistency_energy(t.at[i].add(-eps), a, d, nb, 0.7))) / (2 * eps) for i in range(12)]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-6)


def test_too_few_lines():
    with pytest.raises(ValueError, match="more than 16"):
        gradient_attack(_lines(np.zeros((5, 3)), np.ones((5, 3))))


@pytest.mark.parametrize("sigma", [0.3, 2.5])
def test_energy_value_matches_closed_form(sigma):
    """``E(t) = Σ_i Σ_{j∈𝒩(i)} σ²·log(1 + ‖x_i − x_j‖²/σ²)`` with ``x_i = a_i + t_i d_i``, evaluated by
    plain numpy loops at σ ≠ 1 (where σ and σ² inside the log differ)."""
    rng = np.random.default_rng(4)
    a, d = rng.normal(size=(9, 3)) * 2, rng.normal(size=(9, 3))
    nb = rng.integers(0, 9, (9, 3))
    t = rng.normal(size=9)
    x = a + t[:, None] * d
    expected = sum(sigma**2 * np.log(1.0 + np.sum((x[i] - x[j]) ** 2) / sigma**2) for i in range(9) for j in nb[i])
    with jax.enable_x64(True):
        got = float(consistency_energy(jnp.asarray(t), jnp.asarray(a), jnp.asarray(d), jnp.asarray(nb), sigma))
    assert got == pytest.approx(expected, rel=1e-12)
