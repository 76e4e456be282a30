"""One damped LM step of the bundle adjustment against a dense numpy solve, and the iteration count.

The Schur complement is exact algebra: the reduced camera system plus back-substitution must give
the same step as solving the full damped normal equations

    (H + λ·diag(clip(diag H, 1e-6, 1e32))) Δ = −g,   H = JᵀWJ,  g = JᵀWr,

over (tangents of the free cameras, points). Reference: ``J`` by ``jax.jacfwd`` of an independent
residual function (left update ``T ← exp(ξ) T``, jaxlie tangent ``(ρ, ω)``, as documented in
:mod:`privslam_jax.slam.ba`), ``W`` the IRLS weights ``ρ'(s)·Ω`` computed in numpy, the solve by
``numpy.linalg.solve`` on the dense matrix. A Schur complement missing a term (e.g. ``S_off = X``
instead of ``X + Xᵀ``) gives a different step; LM still converges with such a step, only slowly,
which the iteration bound catches.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from privslam_jax.slam.ba import BAConfig, bundle_adjust

sys.path.insert(0, str(Path(__file__).parent))
from test_ba import CAM, _problem  # cameras on a line, perturbed start (after the sys.path entry)


def _dense_step(T0, X0, oc, op, uv, fixed, isg, delta, lam):
    """``(ξ (M, 6), δ (P, 3))`` of one damped Gauss–Newton step, by a dense numpy solve."""
    n_c, n_p = T0.wxyz_xyz.shape[0], X0.shape[0]
    free = np.flatnonzero(~fixed)
    T0m = jnp.asarray(np.asarray(T0.as_matrix()))

    def residuals(x):
        xi = jnp.zeros((n_c, 6), x.dtype).at[free].set(x[: 6 * len(free)].reshape(-1, 6))
        X = x[6 * len(free):].reshape(n_p, 3)

        def one(c, p, z):
            q = jaxlie.SE3.exp(xi[c]) @ jaxlie.SE3.from_matrix(T0m[c]) @ X[p]
            return jnp.stack([CAM.fx * q[0] / q[2] + CAM.cx, CAM.fy * q[1] / q[2] + CAM.cy]) - z

        return jax.vmap(one)(jnp.asarray(oc), jnp.asarray(op), jnp.asarray(uv))  # (O, 2)

    x0 = jnp.concatenate([jnp.zeros(6 * len(free)), jnp.asarray(X0).reshape(-1)])
    r = np.asarray(jax.jit(residuals)(x0), np.float64)
    J = np.asarray(jax.jit(jax.jacfwd(residuals))(x0), np.float64)  # (O, 2, n)
    s = isg * np.sum(r * r, axis=1)
    w = isg * (np.ones_like(s) if delta is None else np.where(s <= delta**2, 1.0, delta / np.sqrt(s)))
    H = np.einsum("o,oki,okj->ij", w, J, J)
    g = np.einsum("o,oki,ok->i", w, J, r)
    A = H + lam * np.diag(np.clip(np.diag(H), 1e-6, 1e32))
    step = np.linalg.solve(A, -g)
    xi = np.zeros((n_c, 6))
    xi[free] = step[: 6 * len(free)].reshape(-1, 6)
    return xi, step[6 * len(free):].reshape(n_p, 3)


@pytest.mark.parametrize(
    ("delta", "n_out", "n_fixed"),
    [(None, 0, 1), (math.sqrt(5.991), 6, 2)],
    ids=["squared-loss-one-fixed", "huber-outliers-two-fixed"],
)
def test_single_damped_step_matches_dense_numpy_solve(delta, n_out, n_fixed):
    with jax.enable_x64(True):
        T0, X0, oc, op, uv = _problem(n_cams=5, n_pts=24, seed=3, n_out=n_out)
        fixed = np.zeros(5, bool)
        fixed[:n_fixed] = True
        isg = np.random.default_rng(7).uniform(0.5, 1.0, len(oc))
        lam = 1e-2
        cfg = BAConfig(max_iterations=1, huber_delta=delta, initial_damping=lam)
        res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, cfg, obs_inv_sigma2=isg)
        assert int(res.iterations) == 1
        assert float(res.cost) < float(res.initial_cost)  # the step was accepted, so it is in the result
        xi, dp = _dense_step(T0, X0, oc, op, uv, fixed, isg, delta, lam)
        expected_T = np.asarray(jax.vmap(lambda v, T: (jaxlie.SE3.exp(v) @ T).as_matrix())(jnp.asarray(xi), T0))
        got_T = np.asarray(res.T_c_w.as_matrix())
    assert np.abs(dp).max() > 1e-2 and np.abs(xi[n_fixed:]).max() > 1e-3  # a real step, not a no-op
    np.testing.assert_allclose(np.asarray(res.points), X0 + dp, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got_T, expected_T, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_iterations_on_the_clean_problem_are_few(seed):
    """Exact Schur steps converge in a handful of LM iterations on a noise-only problem (4–6 here,
    squared loss, default tolerances, float64); an inexact reduced system (still a descent
    direction) needs many more (36–200 with ``S_off = X`` instead of ``X + Xᵀ``)."""
    with jax.enable_x64(True):
        T0, X0, oc, op, uv = _problem(seed=seed)
        fixed = np.array([True, False, False, False])
        cfg = BAConfig(huber_delta=None, max_iterations=200)
        res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, cfg)
    assert float(res.cost) < 0.02 * float(res.initial_cost)
    assert int(res.iterations) <= 10, int(res.iterations)
