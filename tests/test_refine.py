"""Pose-only refinement against scipy.optimize.least_squares, χ² inliers, buckets and bad input."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy.optimize import least_squares

from privslam_jax.slam.refine import (
    RefineConfig,
    bucket_size,
    pad_to_bucket,
    refine_pose,
)
from privslam_jax.types import Camera

CAM = Camera(fx=700.0, fy=700.0, cx=610.0, cy=185.0, width=1226, height=370, baseline=0.54)
TIGHT = dict(rounds=1, max_iterations=100, function_tolerance=1e-15, step_tolerance=1e-14)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def _problem(n: int, seed: int, n_out: int = 0, noise: float = 1.0):
    rng = np.random.default_rng(seed)
    p_c = np.stack([rng.uniform(-8, 8, n), rng.uniform(-3, 3, n), rng.uniform(4, 40, n)], 1)
    T_true = jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [0.3, 0.3, 0.3, 0.05, 0.05, 0.05])))
    M = np.asarray(T_true.as_matrix())
    p_w = (p_c - M[:3, 3]) @ M[:3, :3]
    uv = p_c[:, :2] / p_c[:, 2:] * CAM.fx + np.array([CAM.cx, CAM.cy]) + rng.normal(0, noise, (n, 2))
    u_r = uv[:, 0] - CAM.fx * 0.54 / p_c[:, 2] + rng.normal(0, noise, n)
    uv[:n_out] += rng.uniform(20, 60, (n_out, 2)) * rng.choice([-1, 1], (n_out, 2))
    T0 = jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [0.05, 0.05, 0.05, 0.01, 0.01, 0.01]))) @ T_true
    return T0, p_w, uv, u_r


def _scipy_solve(T0, p_w, obs, inv_sigma2, delta, stereo):
    """Independent reference: scipy TRF on the 6-vector tangent, Jacobian by jax.jacfwd."""

    def per_obs(xi):
        T = jaxlie.SE3.exp(xi) @ T0
        p_c = jnp.asarray(p_w) @ T.rotation().as_matrix().T + T.translation()[None, :]
        u = CAM.fx * p_c[:, 0] / p_c[:, 2] + CAM.cx
        v = CAM.fy * p_c[:, 1] / p_c[:, 2] + CAM.cy
        cols = [u, v] + ([u - CAM.fx * 0.54 / p_c[:, 2]] if stereo else [])
        return (jnp.stack(cols, 1) - jnp.asarray(obs)) * jnp.sqrt(jnp.asarray(inv_sigma2))[:, None]

    if delta is None:  # squared loss: plain stacked residuals
        fun = jax.jit(lambda xi: per_obs(xi).reshape(-1))
        kw = {}
    else:  # Huber on ‖e_i‖ (the whitened χ² of the whole observation), as the solver
        fun = jax.jit(lambda xi: jnp.sqrt(jnp.sum(per_obs(xi) ** 2, axis=1)))
        kw = dict(loss="huber", f_scale=delta)
    jac = jax.jit(jax.jacfwd(fun))
    sol = least_squares(
        lambda x: np.asarray(fun(jnp.asarray(x))),
        np.zeros(6),
        jac=lambda x: np.asarray(jac(jnp.asarray(x))),
        ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=500, **kw,
    )
    return sol.cost, jaxlie.SE3.exp(jnp.asarray(sol.x)) @ T0


def test_squared_loss_matches_scipy(x64):
    T0, p_w, uv, _ = _problem(150, seed=0)
    isg = np.random.default_rng(1).uniform(0.3, 1.0, 150)
    res = refine_pose(T0, p_w, uv, None, CAM, RefineConfig(robust=False, **TIGHT), inv_sigma2=isg)
    ref_cost, T_ref = _scipy_solve(T0, p_w, uv, isg, None, stereo=False)
    assert float(res.cost) == pytest.approx(ref_cost, rel=1e-6)
    assert float(res.cost) < float(res.initial_cost)
    np.testing.assert_allclose((T_ref.inverse() @ res.T_c_w).log(), np.zeros(6), atol=1e-7)


def test_huber_loss_with_outliers_matches_scipy(x64):
    T0, p_w, uv, _ = _problem(200, seed=2, n_out=20)
    cfg = RefineConfig(**TIGHT)
    res = refine_pose(T0, p_w, uv, None, CAM, cfg)
    ref_cost, T_ref = _scipy_solve(T0, p_w, uv, np.ones(200), math.sqrt(5.991), stereo=False)
    assert float(res.cost) == pytest.approx(ref_cost, rel=1e-6)
    np.testing.assert_allclose((T_ref.inverse() @ res.T_c_w).log(), np.zeros(6), atol=1e-7)
    # inliers: an independent numpy χ² test at the refined pose
    M = np.asarray(res.T_c_w.as_matrix())
    p_c = p_w @ M[:3, :3].T + M[:3, 3]
    e = p_c[:, :2] / p_c[:, 2:] * CAM.fx + np.array([CAM.cx, CAM.cy]) - uv
    np.testing.assert_array_equal(np.asarray(res.inliers), np.sum(e**2, 1) < 5.991)
    assert not np.asarray(res.inliers)[:20].any()


def test_stereo_huber_matches_scipy(x64):
    T0, p_w, uv, u_r = _problem(160, seed=3, n_out=5)
    keep = u_r >= 0  # u_r < 0 marks a monocular observation
    T0, p_w, uv, u_r = T0, p_w[keep], uv[keep], u_r[keep]
    res = refine_pose(T0, p_w, uv, None, CAM, RefineConfig(**TIGHT), u_right=u_r)
    obs = np.concatenate([uv, u_r[:, None]], 1)
    ref_cost, _ = _scipy_solve(T0, p_w, obs, np.ones(len(u_r)), math.sqrt(7.815), stereo=True)
    assert float(res.cost) == pytest.approx(ref_cost, rel=1e-6)
    # mixed mono/stereo: marking every match monocular gives the monocular problem
    mono = refine_pose(T0, p_w, uv, None, CAM, RefineConfig(**TIGHT), u_right=np.full(len(u_r), -1.0))
    ref_mono, _ = _scipy_solve(T0, p_w, uv, np.ones(len(u_r)), math.sqrt(5.991), stereo=False)
    assert float(mono.cost) == pytest.approx(ref_mono, rel=1e-6)


def test_padding_and_valid_mask_do_not_change_the_solution(x64):
    T0, p_w, uv, _ = _problem(90, seed=4, n_out=5)
    valid = np.ones(90, bool)
    valid[::7] = False
    cfg = RefineConfig(rounds=2, max_iterations=30)
    a = refine_pose(T0, p_w, uv, valid, CAM, cfg)
    b = refine_pose(T0, p_w[valid], uv[valid], None, CAM, cfg, buckets=(256,))
    np.testing.assert_allclose(a.T_c_w.wxyz_xyz, b.T_c_w.wxyz_xyz, atol=1e-10)
    assert float(a.cost) == pytest.approx(float(b.cost), rel=1e-10)
    assert a.inliers.shape == (90,) and not np.asarray(a.inliers)[~valid].any()
    np.testing.assert_array_equal(np.asarray(a.inliers)[valid], np.asarray(b.inliers))


def test_successive_frames_in_a_bucket_do_not_recompile(count_compiles):
    cfg = RefineConfig(rounds=2, max_iterations=5)
    T0, p_w, uv, _ = _problem(300, seed=5)
    refine_pose(T0, p_w[:300], uv[:300], None, CAM, cfg)
    with count_compiles() as names:
        for n in (260, 290, 299, 300):
            res = refine_pose(T0, p_w[:n], uv[:n], None, CAM, cfg)
            assert res.inliers.shape == res.active.shape == (n,)
    assert names == []  # nothing at all: no solver program and no per-size copy or slice
    assert bucket_size(300) == bucket_size(260) == 512 and bucket_size(513) == 1024
    assert bucket_size(20000) % 8192 == 0 and bucket_size(20000) >= 20000


def test_pad_to_bucket_layout():
    p, z, v, ur, isg = pad_to_bucket(np.ones((3, 3)), np.zeros((3, 2)), u_right=np.array([1.0, -1, 2]))
    assert p.shape == (64, 3) and v.sum() == 3 and np.all(p[3:, 2] == 1.0)
    assert ur is not None and np.all(ur[3:] == -1) and np.all(isg == 1)


def test_bad_input_raises_clear_errors():
    T0, p_w, uv, _ = _problem(10, seed=6)
    with pytest.raises(ValueError, match="uv must have shape"):
        refine_pose(T0, p_w, uv[:9], None, CAM)
    with pytest.raises(ValueError, match="points_w must have shape"):
        refine_pose(T0, p_w[:, :2], uv, None, CAM)
    bad = p_w.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        refine_pose(T0, bad, uv, None, CAM)
    valid = np.ones(10, bool)
    valid[3] = False  # NaN in an invalid (padded) row is fine
    assert np.isfinite(float(refine_pose(T0, bad, uv, valid, CAM).cost))
    with pytest.raises(ValueError, match="baseline"):
        refine_pose(T0, p_w, uv, None, CAM.replace(baseline=None), u_right=uv[:, 0])
    with pytest.raises(ValueError, match="bool"):
        refine_pose(T0, p_w, uv, np.ones(10), CAM)


def _se3_exp_numpy(xi: np.ndarray) -> np.ndarray:
    """``exp`` of a twist ``(ρ, ω)`` as a 4×4 matrix: ``scipy.linalg.expm`` of ``[[ω×, ρ], [0, 0]]``."""
    from scipy.linalg import expm

    rho, w = xi[:3], xi[3:]
    A = np.zeros((4, 4))
    A[:3, :3] = [[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]
    A[:3, 3] = rho
    return expm(A)


def test_single_damped_step_matches_dense_numpy_solve(x64):
    """One LM step (squared loss) against numpy: ``J`` by central differences of the whitened residuals
    at ``expm(ξ)·T₀`` (left perturbation, as documented), ``(JᵀJ + λ·diag(clip(diag JᵀJ))) ξ = −Jᵀr``
    by ``numpy.linalg.solve``, pose ``expm(ξ)·T₀``. A step applied on the other side (``T₀·exp(ξ)``)
    with these Jacobians lands elsewhere (or is rejected)."""
    T0, p_w, uv, _ = _problem(60, seed=7)
    isg = np.random.default_rng(8).uniform(0.5, 1.0, 60)
    lam = 1e-2
    cfg = RefineConfig(rounds=1, max_iterations=1, robust=False, initial_damping=lam)
    res = refine_pose(T0, p_w, uv, None, CAM, cfg, inv_sigma2=isg)
    assert int(res.iterations) == 1
    assert float(res.cost) < float(res.initial_cost)  # accepted: the step is in the result

    M0 = np.asarray(T0.as_matrix(), np.float64)

    def residuals(M: np.ndarray) -> np.ndarray:
        p_c = p_w @ M[:3, :3].T + M[:3, 3]
        pred = p_c[:, :2] / p_c[:, 2:] * [CAM.fx, CAM.fy] + [CAM.cx, CAM.cy]
        return ((pred - uv) * np.sqrt(isg)[:, None]).reshape(-1)

    h = 1e-6
    J = np.stack([(residuals(_se3_exp_numpy(h * e) @ M0) - residuals(_se3_exp_numpy(-h * e) @ M0)) / (2 * h)
                  for e in np.eye(6)], 1)
    r = residuals(M0)
    H, g = J.T @ J, J.T @ r
    xi = np.linalg.solve(H + lam * np.diag(np.clip(np.diag(H), 1e-6, 1e32)), -g)
    assert np.abs(xi).max() > 1e-3  # a real step
    assert float(res.initial_cost) == pytest.approx(0.5 * r @ r, rel=1e-12)
    np.testing.assert_allclose(np.asarray(res.T_c_w.as_matrix()), _se3_exp_numpy(xi) @ M0, rtol=0, atol=1e-8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_iterations_on_the_noise_free_problem_are_few(seed):
    """Noise-free matches, default tolerances, float64: the left update converges in 4–5 LM
    iterations (seeds 0–2); the right update ``T·exp(ξ)`` with the Jacobians of the left
    perturbation still converges, but in 11–12."""
    with jax.enable_x64(True):
        T0, p_w, uv, _ = _problem(100, seed=seed, noise=0.0)
        res = refine_pose(T0, p_w, uv, None, CAM, RefineConfig(rounds=1, max_iterations=100, robust=False))
    assert float(res.cost) < 1e-12 * float(res.initial_cost)
    assert int(res.iterations) <= 7, int(res.iterations)
