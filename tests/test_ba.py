"""Bundle adjustment against scipy.optimize.least_squares, Jacobians, buckets, bad input, real BAL subset."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy.optimize import least_squares

from privslam_jax.geometry.projection import reprojection_jacobians, stereo_jacobians
from privslam_jax.slam.ba import (
    BAConfig,
    _jacobians,
    analyze,
    ba_bucket,
    bundle_adjust,
)
from privslam_jax.solvers.schur import sym3_inverse as _sym3_inverse
from privslam_jax.types import Camera

CAM = Camera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
BASELINE = 0.5
CAM_ST = Camera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480, baseline=BASELINE)
TIGHT = dict(max_iterations=200, function_tolerance=1e-14, parameter_tolerance=1e-14)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def _se3_from_vec(v: np.ndarray) -> jaxlie.SE3:
    return jaxlie.SE3.exp(jnp.asarray(v))


def _problem(n_cams: int = 4, n_pts: int = 30, seed: int = 0, n_out: int = 0, with_u_right: bool = False):
    """Cameras on a line looking along +z at a point cloud; perturbed start.

    ``with_u_right``: also return the right-image ``u`` (baseline ``BASELINE``, noisy) of every
    other observation, ``−1`` (monocular) on the rest."""
    rng = np.random.default_rng(seed)
    X = np.stack([rng.uniform(-4, 4, n_pts), rng.uniform(-2, 2, n_pts), rng.uniform(6, 14, n_pts)], 1)
    true = np.zeros((n_cams, 6))
    true[:, 0] = -np.linspace(0, 2, n_cams)  # T_c_w translation: camera centres move along +x
    true[:, 4] = rng.normal(0, 0.02, n_cams)
    rng_ur = np.random.default_rng(seed + 1000)  # own stream: the monocular problem stays unchanged
    cams, pts, uvs, urs = [], [], [], []
    for c in range(n_cams):
        T = _se3_from_vec(true[c])
        M = np.asarray(T.as_matrix())
        p_c = X @ M[:3, :3].T + M[:3, 3]
        uv = p_c[:, :2] / p_c[:, 2:] * CAM.fx + np.array([CAM.cx, CAM.cy])
        seen = rng.random(n_pts) < 0.8
        seen[:10] = True  # outliers go to camera 0's view of these well-observed points
        cams.append(np.full(seen.sum(), c))
        pts.append(np.flatnonzero(seen))
        uvs.append(uv[seen] + rng.normal(0, 0.5, (seen.sum(), 2)))
        ur = uv[seen, 0] - CAM.fx * BASELINE / p_c[seen, 2] + rng_ur.normal(0, 0.5, seen.sum())
        urs.append(np.where(np.arange(seen.sum()) % 2 == 0, ur, -1.0))
    obs_cam, obs_pt, obs_uv = np.concatenate(cams), np.concatenate(pts), np.concatenate(uvs)
    obs_ur = np.concatenate(urs)
    obs_uv[:n_out] += rng.uniform(15, 40, (n_out, 2))
    obs_ur[:n_out] = np.where(obs_ur[:n_out] >= 0, obs_ur[:n_out] + 30.0, -1.0)
    start = true + rng.normal(0, [0.02, 0.02, 0.02, 0.005, 0.005, 0.005], true.shape)
    start[0] = true[0]
    X0 = X + rng.normal(0, 0.05, X.shape)
    T0 = jaxlie.SE3(jnp.stack([_se3_from_vec(v).wxyz_xyz for v in start]))
    out = (T0, X0, obs_cam.astype(np.int32), obs_pt.astype(np.int32), obs_uv)
    return out + (obs_ur,) if with_u_right else out


def _scipy_ba(T0, X0, obs_cam, obs_pt, obs_uv, fixed, delta, isg=None, max_nfev=2000, ur=None, delta_st=None):
    """Reference: scipy (MINPACK LM) over (tangent of free cameras, points), Jacobian by jax.jacfwd.

    ``ur``: right-image ``u`` per observation (``< 0`` monocular): stereo rows get the third residual
    ``u − fx·b/z − u_r`` and the Huber threshold ``delta_st``."""
    n_c, n_p = T0.wxyz_xyz.shape[0], X0.shape[0]
    free = np.flatnonzero(~fixed)
    isg = np.ones(len(obs_cam)) if isg is None else isg
    T0m = np.asarray(T0.as_matrix())
    ur = np.full(len(obs_cam), -1.0) if ur is None else np.asarray(ur)
    st = jnp.asarray(ur >= 0)
    dl = jnp.where(st, delta_st if delta_st is not None else jnp.inf, delta if delta is not None else jnp.inf)

    def per_obs(xi_c, X, c, p, uv, w, u_r, is_st):
        T = jaxlie.SE3.exp(xi_c) @ jaxlie.SE3.from_matrix(jnp.asarray(T0m)[c])
        q = T @ X[p]
        u = CAM.fx * q[0] / q[2] + CAM.cx
        e = jnp.stack([u - uv[0], CAM.fy * q[1] / q[2] + CAM.cy - uv[1], jnp.where(is_st, u - CAM.fx * BASELINE / q[2] - u_r, 0.0)])
        return e * jnp.sqrt(w)

    def unpack(x):
        xi = jnp.zeros((n_c, 6)).at[free].set(x[: 6 * len(free)].reshape(-1, 6))
        return xi, x[6 * len(free) :].reshape(n_p, 3)

    def res(x):
        xi, X = unpack(x)
        e = jax.vmap(per_obs, in_axes=(0, None, 0, 0, 0, 0, 0, 0))(
            xi[obs_cam], X, obs_cam, obs_pt, obs_uv, isg, jnp.asarray(ur), st)
        if delta is None and delta_st is None:
            return e.reshape(-1)
        # Huber: the residual √ρ(s) with the squared loss has exactly the cost ½Σρ(s) (smooth for s > 0)
        s = jnp.sum(e * e, axis=1)
        return jnp.sqrt(jnp.where(s <= dl**2, s, 2 * dl * jnp.sqrt(s) - dl**2))

    f = jax.jit(res)
    jf = jax.jit(jax.jacfwd(res))
    x0 = np.concatenate([np.zeros(6 * len(free)), X0.reshape(-1)])
    sol = least_squares(
        lambda x: np.asarray(f(jnp.asarray(x))), x0, jac=lambda x: np.asarray(jf(jnp.asarray(x))),
        method="lm", ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=max_nfev,
    )
    return sol.cost


def test_squared_loss_matches_scipy(x64):
    T0, X0, oc, op, uv = _problem(seed=0)
    fixed = np.zeros(4, bool)
    fixed[:2] = True  # two fixed cameras: no gauge freedom left
    isg = np.random.default_rng(3).uniform(0.5, 1.0, len(oc))
    cfg = BAConfig(huber_delta=None, **TIGHT)
    res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, cfg, obs_inv_sigma2=isg)
    ref = _scipy_ba(T0, X0, oc, op, uv, fixed, None, isg)
    assert float(res.cost) == pytest.approx(ref, rel=1e-6)
    assert float(res.cost) < 0.2 * float(res.initial_cost)
    np.testing.assert_allclose(res.T_c_w.wxyz_xyz[:2], T0.wxyz_xyz[:2])  # fixed cameras stay


def test_huber_with_outliers_is_a_minimum_for_scipy_and_flags_them(x64):
    T0, X0, oc, op, uv = _problem(seed=1, n_out=6)
    fixed = np.zeros(4, bool)
    fixed[:2] = True
    cfg = BAConfig(huber_delta=math.sqrt(5.991), **TIGHT)
    res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, cfg)
    # IRLS-type solvers (this one, Ceres, scipy) converge only linearly on this Huber problem, so scipy
    # from the start stalls above the optimum; started at our solution it must not find a lower cost.
    ref = _scipy_ba(res.T_c_w, np.asarray(res.points), oc, op, uv, fixed, math.sqrt(5.991), max_nfev=300)
    assert float(res.cost) == pytest.approx(ref, rel=1e-6)
    assert float(res.cost) < float(res.initial_cost)
    assert not np.asarray(res.inliers)[:6].any() and np.asarray(res.inliers)[6:].mean() > 0.9


def test_stereo_squared_loss_matches_scipy(x64):
    T0, X0, oc, op, uv, ur = _problem(n_pts=20, seed=4, with_u_right=True)
    fixed = np.zeros(4, bool)
    fixed[0] = True  # one fixed camera: the stereo rows fix the scale
    isg = np.random.default_rng(5).uniform(0.5, 1.0, len(oc))
    cfg = BAConfig(huber_delta=None, **TIGHT)
    res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, cfg, obs_inv_sigma2=isg, obs_u_right=ur)
    ref = _scipy_ba(T0, X0, oc, op, uv, fixed, None, isg, ur=ur)
    assert float(res.cost) == pytest.approx(ref, rel=1e-6)
    assert float(res.cost) < 0.2 * float(res.initial_cost)
    # the stereo rows count: without them the optimum is different (lower: fewer residuals)
    mono = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, cfg, obs_inv_sigma2=isg)
    assert float(mono.cost) < 0.9 * float(res.cost)


def test_stereo_huber_with_outliers_matches_scipy_and_uses_3dof_threshold(x64):
    T0, X0, oc, op, uv, ur = _problem(n_cams=5, n_pts=24, seed=6, n_out=6, with_u_right=True)
    fixed = np.zeros(5, bool)
    fixed[0] = True  # the only unperturbed camera; the stereo rows fix the scale
    cfg = BAConfig(huber_delta=math.sqrt(5.991), huber_delta_stereo=math.sqrt(7.815), **TIGHT)
    res = bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, cfg, obs_u_right=ur)
    ref = _scipy_ba(res.T_c_w, np.asarray(res.points), oc, op, uv, fixed, math.sqrt(5.991), max_nfev=300,
                    ur=ur, delta_st=math.sqrt(7.815))
    assert float(res.cost) == pytest.approx(ref, rel=1e-6)
    assert not np.asarray(res.inliers)[:6].any() and np.asarray(res.inliers)[6:].mean() > 0.9
    # inlier mask: whitened χ² against 7.815 on stereo rows, 5.991 on monocular ones (numpy re-evaluation)
    T = np.asarray(res.T_c_w.as_matrix())
    X = np.asarray(res.points)
    p_c = np.einsum("oij,oj->oi", T[oc, :3, :3], X[op]) + T[oc, :3, 3]
    u = CAM.fx * p_c[:, 0] / p_c[:, 2] + CAM.cx
    v = CAM.fy * p_c[:, 1] / p_c[:, 2] + CAM.cy
    s = (u - uv[:, 0]) ** 2 + (v - uv[:, 1]) ** 2 + np.where(ur >= 0, (u - CAM.fx * BASELINE / p_c[:, 2] - ur) ** 2, 0)
    np.testing.assert_array_equal(np.asarray(res.inliers), s < np.where(ur >= 0, 7.815, 5.991))


def test_stereo_needs_a_baseline_and_finite_u_right():
    T0, X0, oc, op, uv, ur = _problem(n_cams=3, n_pts=10, seed=3, with_u_right=True)
    fixed = np.array([True, False, False])
    with pytest.raises(ValueError, match="baseline"):
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, obs_u_right=ur)
    bad = ur.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="obs_u_right"):
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, obs_u_right=bad)
    with pytest.raises(ValueError, match="obs_u_right must have shape"):
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, obs_u_right=ur[:-1])


def test_elementwise_stereo_jacobians_match_projection_module(x64):
    rng = np.random.default_rng(1)
    p_c = jnp.asarray(rng.normal(0, 1, (4, 3)) + [0, 0, 5])
    R = jnp.stack([jaxlie.SO3.exp(jnp.asarray(rng.normal(0, 0.5, 3))).as_matrix() for _ in range(4)])
    K = jnp.asarray(np.tile([500.0, 480.0, 320.0, 240.0, 0.3], (4, 1)))
    Jc, Jp = _jacobians(p_c, R, K, stereo=True)
    for i in range(4):
        a, b = stereo_jacobians(p_c[i], R[i], 500.0, 480.0, 500.0 * 0.3)  # checked against finite differences
        np.testing.assert_allclose(Jc[i], a, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Jp[i], b, rtol=1e-12, atol=1e-9)


def test_elementwise_jacobians_match_projection_module(x64):
    rng = np.random.default_rng(0)
    p_c = jnp.asarray(rng.normal(0, 1, (4, 3)) + [0, 0, 5])
    R = jnp.stack([jaxlie.SO3.exp(jnp.asarray(rng.normal(0, 0.5, 3))).as_matrix() for _ in range(4)])
    K = jnp.asarray(np.tile([500.0, 480.0, 320.0, 240.0, 0.0], (4, 1)))
    Jc, Jp = _jacobians(p_c, R, K)
    for i in range(4):
        a, b = reprojection_jacobians(p_c[i], R[i], 500.0, 480.0)  # checked against finite differences
        np.testing.assert_allclose(Jc[i], a, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Jp[i], b, rtol=1e-12, atol=1e-9)


def test_batched_3x3_inverse(x64):
    A = np.random.default_rng(1).normal(size=(7, 3, 3))
    A = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(3)
    np.testing.assert_allclose(_sym3_inverse(jnp.asarray(A)), np.linalg.inv(A), rtol=1e-9, atol=1e-9)


def test_schur_pairs_cover_every_pair_once():
    oc = np.array([0, 1, 2, 0, 2, 1, 1])
    op = np.array([0, 0, 0, 1, 1, 2, 2])  # point 2 seen twice by camera 1
    st = analyze(oc, op, 3, 8, chunk=4)
    a, b = np.asarray(st.pair_a), np.asarray(st.pair_b)
    real = a != 7
    got = sorted(zip(a[real].tolist(), b[real].tolist()))
    assert got == [(0, 1), (0, 2), (1, 2), (3, 4), (5, 6)]
    seg = np.repeat(np.asarray(st.chunk_seg), 4)
    np.testing.assert_array_equal(seg[real], oc[a[real]] * 3 + oc[b[real]])


def test_no_recompile_within_buckets(count_compiles):
    cfg = BAConfig(max_iterations=3)
    T0, X0, oc, op, uv = _problem(n_cams=5, n_pts=50, seed=2)
    fixed = np.zeros(5, bool)
    fixed[0] = True
    bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM, cfg)
    with count_compiles() as names:
        for n_pts, n_drop in ((48, 3), (45, 9)):  # fewer points and observations, same buckets
            keep = (op < n_pts) & (np.arange(len(op)) >= n_drop)
            out = bundle_adjust(T0, X0[:n_pts], oc[keep], op[keep], uv[keep], None, fixed, CAM, cfg)
            assert out.points.shape == (n_pts, 3) and out.inliers.shape == (int(keep.sum()),)
    assert names == []
    # stereo: one more program, then none for other stereo problems in the same buckets
    T0, X0, oc, op, uv, ur = _problem(n_cams=5, n_pts=50, seed=2, with_u_right=True)
    with count_compiles() as names:
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, cfg, obs_u_right=ur)
    assert names  # the counter sees compilations
    with count_compiles() as names:
        keep = (op < 46) & (np.arange(len(op)) >= 5)
        bundle_adjust(T0, X0[:46], oc[keep], op[keep], uv[keep], None, fixed, CAM_ST, cfg, obs_u_right=ur[keep])
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, CAM_ST, cfg, obs_u_right=np.full(len(oc), -1.0))
    assert names == []
    assert ba_bucket(5) == 8 and ba_bucket(49, minimum=8) == 64 and ba_bucket(3) == 4 and ba_bucket(64) == 64


def test_bad_input_raises_clear_errors():
    T0, X0, oc, op, uv = _problem(n_cams=3, n_pts=10, seed=3)
    fixed = np.array([True, False, False])
    with pytest.raises(ValueError, match="obs_uv must have shape"):
        bundle_adjust(T0, X0, oc, op, uv[:-1], None, fixed, CAM)
    with pytest.raises(ValueError, match="out of range"):
        bundle_adjust(T0, X0[:5], oc, op, uv, None, fixed, CAM)
    bad = X0.copy()
    bad[2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        bundle_adjust(T0, bad, oc, op, uv, None, fixed, CAM)
    with pytest.raises(ValueError, match="gauge"):
        bundle_adjust(T0, X0, oc, op, uv, None, np.zeros(3, bool), CAM)
    with pytest.raises(ValueError, match="fixed_cams must have shape"):
        bundle_adjust(T0, X0, oc, op, uv, None, fixed[:2], CAM)
    with pytest.raises(ValueError, match="intrinsics"):
        bundle_adjust(T0, X0, oc, op, uv, None, fixed, np.ones((2, 4)))


def test_inlier_mask_uses_3dof_threshold_on_stereo_rows_inside_the_chi2_band(x64):
    """Whitened χ² set by construction on both sides of and inside (5.991, 7.815), on stereo and
    monocular rows, at a fixed solution (``max_iterations=0``: the mask is evaluated at the start).

    Reference: the numpy χ² test ``s < 7.815`` (3 dof) on stereo rows, ``s < 5.991`` (2 dof) on
    monocular ones, ``s`` re-evaluated in numpy from the poses and points. Inside the band the two
    thresholds disagree: stereo rows there are inliers, monocular rows outliers."""
    rng = np.random.default_rng(11)
    targets = np.array([1.0, 5.5, 6.1, 6.5, 7.0, 7.5, 7.7, 8.2, 12.0])  # four inside (5.991, 7.815) and 6.1
    n_pts = 2 * len(targets)
    X = np.stack([rng.uniform(-1.5, 3, n_pts), rng.uniform(-2, 2, n_pts), rng.uniform(6, 12, n_pts)], 1)
    poses = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [-1.0, 0.1, 0.0, 0.01, -0.02, 0.0]])
    T = jaxlie.SE3(jnp.stack([_se3_from_vec(v).wxyz_xyz for v in poses]))
    Tm = np.asarray(T.as_matrix())
    oc = np.repeat(np.arange(2), n_pts).astype(np.int32)  # every point seen by both cameras
    op = np.tile(np.arange(n_pts), 2).astype(np.int32)
    n_o = len(oc)
    stereo = np.arange(n_o) % 2 == 0
    s_target = np.tile(targets, -(-n_o // len(targets)))[:n_o]
    isg = rng.uniform(0.5, 1.5, n_o)
    # an error of whitened squared norm s_target in a random direction (2-D mono, 3-D stereo)
    direction = rng.normal(size=(n_o, 3))
    direction[~stereo, 2] = 0.0
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    err = direction * np.sqrt(s_target / isg)[:, None]
    p_c = np.einsum("oij,oj->oi", Tm[oc, :3, :3], X[op]) + Tm[oc, :3, 3]
    u = CAM_ST.fx * p_c[:, 0] / p_c[:, 2] + CAM_ST.cx
    v = CAM_ST.fy * p_c[:, 1] / p_c[:, 2] + CAM_ST.cy
    u_r = u - CAM_ST.fx * BASELINE / p_c[:, 2]
    uv = np.stack([u, v], 1) - err[:, :2]
    ur = np.where(stereo, u_r - err[:, 2], -1.0)
    assert np.all(ur[stereo] >= 0)
    fixed = np.array([True, False])
    res = bundle_adjust(T, X, oc, op, uv, None, fixed, CAM_ST, BAConfig(max_iterations=0),
                        obs_inv_sigma2=isg, obs_u_right=ur)
    assert int(res.iterations) == 0
    np.testing.assert_array_equal(np.asarray(res.T_c_w.wxyz_xyz), np.asarray(T.wxyz_xyz))
    # independent numpy χ² at the (unchanged) solution
    s = isg * ((u - uv[:, 0]) ** 2 + (v - uv[:, 1]) ** 2 + np.where(stereo, (u_r - ur) ** 2, 0.0))
    np.testing.assert_allclose(s, s_target, rtol=1e-9)
    band = (s > 5.991 + 1e-3) & (s < 7.815 - 1e-3)
    assert band[stereo].sum() >= 4 and band[~stereo].sum() >= 4
    expected = s < np.where(stereo, 7.815, 5.991)
    assert expected[stereo & band].all() and not expected[~stereo & band].any()
    np.testing.assert_array_equal(np.asarray(res.inliers), expected)
