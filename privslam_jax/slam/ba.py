"""Bundle adjustment: jitted Huber-robust Levenberg–Marquardt with the Schur complement on the points.

Problem.  Cameras ``T_c,w`` (world-to-camera, ``M`` of them, some fixed for the gauge) and points
``X_p`` (``P``), observations ``o = (c, p, z_o)`` with information ``Ω_o = σ_o⁻² I``:

    F = ½ Σ_o ρ_o(s_o),   s_o = Ω_o ‖π_c(T_c X_p) − z_o‖²,

with the Huber ``ρ`` of :mod:`privslam_jax.slam.refine` (``config.huber_delta = None``: squared loss).

Stereo / RGB-D observations (ORB-SLAM ``EdgeStereoSE3ProjectXYZ``).  An observation may carry the
right-image ``u_r`` of a rectified pair (RGB-D: a virtual one, ``u_r = u − bf/z_depth``); then
``z_o = (u, v, u_r)`` and ``π(p) = (f_x x/z + c_x, f_y y/z + c_y, f_x x/z + c_x − bf/z)`` with
``bf = f_x·baseline``, Huber threshold ``√7.815`` and χ² threshold 7.815 (3 dof) instead of
``√5.991``/5.991.  Pass ``obs_u_right`` with ``u_r < 0`` marking monocular observations (whose third
row is zero); without it the program has 2-row residuals (cheaper, e.g. the BAL benchmark).

Solver.  Cameras are updated on the left, ``T_c ← exp(ξ_c) T_c`` (jaxlie tangent ``(ρ, ω)``), points
additively.  With the IRLS weights ``w_o = ρ'(s_o) Ω_o`` and the analytic Jacobians
``A_o = ∂r_o/∂ξ_c`` (2×6 / 3×6), ``B_o = ∂r_o/∂X_p`` (2×3 / 3×3) the blocks of the normal equations
are solved by the Schur complement on the points (:mod:`privslam_jax.solvers.schur`) inside the
shared Levenberg–Marquardt loop (:mod:`privslam_jax.solvers.lm`: Nielsen's damping; stopping as
Ceres: relative cost decrease ``< function_tolerance``, ``‖Δx‖ ≤ parameter_tolerance·(‖x‖ +
parameter_tolerance)``, or ``cost ≤ target_cost``; why it stopped is ``BAResult.summary``).

Derivatives.  :func:`bundle_adjust_padded` is differentiable in the observations, their information,
the intrinsics and ``obs_u_right`` by the implicit-function theorem
(:mod:`privslam_jax.solvers.implicit`; dense Hessian, so for small problems; fixed cameras stay
fixed; NaN when the solve did not converge or a gauge is left free, e.g. monocular BA with one fixed
camera).

Sizes.  All arrays are padded to size buckets (cameras, points, observations, pairs); a new bucket
combination compiles once.  :func:`bundle_adjust` is the host entry point (checks, padding, unpadding).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from privslam_jax.geometry.projection import (
    observation_rows,
    pinhole,
    pinhole_stereo,
    reprojection_jacobians,
    stereo_jacobians,
)
from privslam_jax.solvers.implicit import implicit_argmin
from privslam_jax.solvers.lm import LMParams, SolveSummary, levenberg_marquardt
from privslam_jax.solvers.robust import huber_rho, huber_weight
from privslam_jax.solvers.schur import BlockSystem, SchurStructure, analyze, pow2_bucket, schur_damped_solve
from privslam_jax.types import Camera

__all__ = ["BAConfig", "BAResult", "BAStructure", "analyze", "bundle_adjust", "bundle_adjust_padded", "ba_bucket"]

BAStructure = SchurStructure
"""The Schur-complement sparsity of a BA problem (:class:`privslam_jax.solvers.schur.SchurStructure`)."""
ba_bucket = pow2_bucket
"""Padded sizes of BA problems (:func:`privslam_jax.solvers.schur.pow2_bucket`)."""


@dataclasses.dataclass(frozen=True)
class BAConfig:
    """Settings of :func:`bundle_adjust` (static: changing one recompiles)."""

    max_iterations: int = 50
    """Maximum LM iterations (accepted or rejected)."""
    huber_delta: float | None = math.sqrt(5.991)
    """Huber threshold δ on the whitened error (ORB-SLAM local BA: √5.991); ``None`` = squared loss
    (for the stereo observations too)."""
    chi2: float = 5.991
    """χ² threshold (2 dof, 95 %) for the returned inlier mask."""
    huber_delta_stereo: float = math.sqrt(7.815)
    """Huber threshold δ of stereo observations (3 rows; ORB-SLAM: √7.815)."""
    chi2_stereo: float = 7.815
    """χ² threshold (3 dof, 95 %) of stereo observations for the inlier mask."""
    initial_damping: float = 1e-4
    """Initial λ (Ceres' default initial trust-region radius 1e4 ⇒ 1e-4)."""
    function_tolerance: float = 1e-6
    """Stop when an accepted step lowers the cost by less than this fraction (Ceres' default)."""
    parameter_tolerance: float = 1e-8
    """Stop when ``‖Δx‖ ≤ tol·(‖x‖ + tol)`` (Ceres' default)."""
    target_cost: float = 0.0
    """Stop as soon as the cost is at or below this (benchmarks; 0 disables)."""
    min_depth: float = 1e-3
    """Camera-frame ``z`` at or below which a point counts as behind the camera (no gradient, penalty)."""
    behind_chi2: float = 1e6
    """Whitened χ² charged for an observation behind the camera."""
    chunk: int = 16
    """Pairs per dense chunk in the Schur assembly (see the module docstring)."""


@struct.dataclass
class BAResult:
    """Output of :func:`bundle_adjust`."""

    T_c_w: jaxlie.SE3
    """Optimised world-to-camera poses (batch ``M``)."""
    points: Float[Array, "P 3"]
    """Optimised world points."""
    cost: Float[Array, ""]
    """Final cost ``½ Σ ρ(s_o)``."""
    initial_cost: Float[Array, ""]
    """Cost at the start."""
    inliers: Bool[Array, " O"]
    """Valid observations in front of their camera with ``s_o < chi2`` at the solution."""
    iterations: Int[Array, ""]
    """LM iterations run."""
    summary: SolveSummary
    """Why the solve stopped (:class:`~privslam_jax.solvers.lm.SolveSummary`)."""


# ----------------------------------------------------------------------------------------------
# jitted core


def _project(
    R: Float[Array, "O 3 3"], t: Float[Array, "O 3"], X: Float[Array, "O 3"], K: Float[Array, "O 5"],
    stereo: bool = False,
) -> tuple[Float[Array, "O 3"], Float[Array, "O K"]]:
    """Camera-frame points and their projections ``(u, v)``, or ``(u, v, u_r)`` when ``stereo``."""
    p_c = jnp.sum(R * X[:, None, :], axis=2) + t
    if stereo:
        return p_c, pinhole_stereo(p_c, K[:, 0], K[:, 1], K[:, 2], K[:, 3], K[:, 0] * K[:, 4])
    return p_c, pinhole(p_c, K[:, 0], K[:, 1], K[:, 2], K[:, 3])


def _jacobians(
    p_c: Float[Array, "O 3"], R: Float[Array, "O 3 3"], K: Float[Array, "O 5"], stereo: bool = False
) -> tuple[Float[Array, "O K 6"], Float[Array, "O K 3"]]:
    """Per-observation Jacobians (:mod:`privslam_jax.geometry.projection`) w.r.t. the camera and the point."""
    if stereo:
        return stereo_jacobians(p_c, R, K[:, 0], K[:, 1], K[:, 0] * K[:, 4])
    return reprojection_jacobians(p_c, R, K[:, 0], K[:, 1])


class _Obs(struct.PyTreeNode):
    """Padded observations with per-observation intrinsics and weights."""

    cam: Array  # (O,) int32
    pt: Array  # (O,) int32
    uv: Array  # (O, K) observed (u, v) or (u, v, u_r); u_r = 0 on monocular rows
    stereo: Array | None  # (O,) 1.0 on stereo rows, 0.0 on monocular ones; None: no stereo rows at all
    delta: Array  # (O,) Huber threshold of each observation (+inf: squared loss)
    chi2: Array  # (O,) χ² inlier threshold of each observation
    isg: Array  # (O,) information, 0 for padded rows
    K: Array  # (O, 5) intrinsics of the observing camera
    valid: Array  # (O,) bool
    free: Array  # (O,) 1.0 when the observing camera is free, else 0.0


def _residuals(obs: _Obs, T: jaxlie.SE3, X: Array, config: _Params):
    Rm = T.rotation().as_matrix()[obs.cam]
    t = T.translation()[obs.cam]
    p_c, uv = _project(Rm, t, X[obs.pt], obs.K, stereo=obs.stereo is not None)
    e = uv - obs.uv
    if obs.stereo is not None:
        e = e.at[:, 2].multiply(obs.stereo)
    s = obs.isg * jnp.sum(e * e, axis=1)
    front = p_c[:, 2] > config.min_depth
    delta = obs.delta  # +inf for the squared loss
    rho, behind = huber_rho(s, delta), huber_rho(jnp.full_like(s, config.behind_chi2), delta)
    c = jnp.where(obs.valid, jnp.where(front, rho, behind), 0.0)
    return Rm, p_c, e, s, front, 0.5 * jnp.sum(c)


def _linearise(obs: _Obs, T: jaxlie.SE3, X: Array, n_cams: int, config: _Params) -> BlockSystem:
    Rm, p_c, e, s, front, cost = _residuals(obs, T, X, config)
    delta = obs.delta
    w = jnp.where(front, obs.isg * huber_weight(s, delta), 0.0)
    Jc, Jp = _jacobians(p_c, Rm, obs.K, stereo=obs.stereo is not None)
    if obs.stereo is not None:
        Jc = Jc.at[:, 2].multiply(obs.stereo[:, None])
        Jp = Jp.at[:, 2].multiply(obs.stereo[:, None])
    Jc = Jc * obs.free[:, None, None]
    wJc = Jc * w[:, None, None]
    wJp = Jp * w[:, None, None]
    U_o = jnp.sum(wJc[:, :, :, None] * Jc[:, :, None, :], axis=1)  # (O, 6, 6)
    V_o = jnp.sum(wJp[:, :, :, None] * Jp[:, :, None, :], axis=1)  # (O, 3, 3)
    W_o = jnp.sum(wJc[:, :, :, None] * Jp[:, :, None, :], axis=1)  # (O, 6, 3)
    gc_o = jnp.sum(wJc * e[:, :, None], axis=1)
    gp_o = jnp.sum(wJp * e[:, :, None], axis=1)
    P = X.shape[0]
    return BlockSystem(
        U=jax.ops.segment_sum(U_o, obs.cam, n_cams),
        V=jax.ops.segment_sum(V_o, obs.pt, P),
        W=W_o,
        gc=jax.ops.segment_sum(gc_o, obs.cam, n_cams),
        gp=jax.ops.segment_sum(gp_o, obs.pt, P),
        cost=cost,
    )


class _Params(struct.PyTreeNode):
    """The numeric fields of :class:`BAConfig` as traced values (changing them does not recompile)."""

    lm: LMParams
    huber_delta: Array
    chi2: Array
    huber_delta_stereo: Array
    chi2_stereo: Array
    min_depth: Array
    behind_chi2: Array

    @staticmethod
    def of(config: BAConfig, dtype: jnp.dtype) -> "_Params":
        f = lambda v: jnp.asarray(v, dtype)  # noqa: E731
        return _Params(
            lm=LMParams.of(dtype, config.max_iterations, config.initial_damping, config.function_tolerance,
                           parameter_tolerance=config.parameter_tolerance, target_cost=config.target_cost),
            huber_delta=f(jnp.inf if config.huber_delta is None else config.huber_delta),
            chi2=f(config.chi2),
            huber_delta_stereo=f(jnp.inf if config.huber_delta is None else config.huber_delta_stereo),
            chi2_stereo=f(config.chi2_stereo),
            min_depth=f(config.min_depth),
            behind_chi2=f(config.behind_chi2),
        )


def _observations(
    obs_cam: Int[Array, " O"],
    obs_pt: Int[Array, " O"],
    obs_uv: Float[Array, "O 2"],
    obs_valid: Bool[Array, " O"],
    obs_inv_sigma2: Float[Array, " O"],
    fixed_cams: Bool[Array, " M"],
    intrinsics: Float[Array, "M 5"],
    config: _Params,
    obs_u_right: Float[Array, " O"] | None,
    dtype: Any,
) -> _Obs:
    """The padded observations with per-row intrinsics, Huber δ, χ² threshold and information."""
    uv_obs, is_st, delta, chi2 = observation_rows(obs_uv, obs_u_right, (config.huber_delta, config.chi2),
                                                  (config.huber_delta_stereo, config.chi2_stereo), dtype)
    return _Obs(
        cam=obs_cam,
        pt=obs_pt,
        uv=uv_obs,
        stereo=None if is_st is None else is_st.astype(dtype),
        delta=delta,
        chi2=chi2,
        isg=jnp.where(obs_valid, obs_inv_sigma2.astype(dtype), 0.0),
        K=intrinsics.astype(dtype)[obs_cam],
        valid=obs_valid,
        free=(~fixed_cams)[obs_cam].astype(dtype),
    )


def bundle_adjust_padded(
    T_c_w: jaxlie.SE3,
    points: Float[Array, "P 3"],
    obs_cam: Int[Array, " O"],
    obs_pt: Int[Array, " O"],
    obs_uv: Float[Array, "O 2"],
    obs_valid: Bool[Array, " O"],
    obs_inv_sigma2: Float[Array, " O"],
    fixed_cams: Bool[Array, " M"],
    intrinsics: Float[Array, "M 5"],
    structure: BAStructure,
    config: BAConfig,
    obs_u_right: Float[Array, " O"] | None = None,
) -> BAResult:
    """Core of :func:`bundle_adjust` on padded arrays and a precomputed :class:`BAStructure` (jit-friendly).

    ``obs_u_right``: right-image ``u`` of stereo observations, ``< 0`` on monocular ones (``None``:
    all monocular, 2-row residuals).  Only ``config.chunk``, the array shapes and ``obs_u_right is
    None`` select the compiled program; the other settings are passed as traced values, so changing
    them does not recompile.
    """
    params = _Params.of(config, points.dtype)
    theta = (obs_uv, obs_inv_sigma2, intrinsics, obs_u_right)
    const = (obs_cam, obs_pt, obs_valid, fixed_cams, structure, params)
    (T_f, X_f), result = _differentiable_ba(config.chunk)((T_c_w, points), theta, const)
    return result.replace(T_c_w=T_f, points=X_f)


@functools.cache
def _differentiable_ba(chunk: int) -> Callable[..., tuple[tuple[jaxlie.SE3, Array], BAResult]]:
    """:func:`_bundle_adjust_jit` with implicit derivatives of the poses and points in
    ``θ = (obs_uv, obs_inv_sigma2, intrinsics, obs_u_right)`` (fixed cameras stay fixed)."""

    def solve(x0: tuple, theta: tuple, const: tuple) -> tuple[tuple[jaxlie.SE3, Array], BAResult]:
        obs_uv, isg, intrinsics, u_right = theta
        cam, pt, valid, fixed, structure, params = const
        out = _bundle_adjust_jit(x0[0], x0[1], cam, pt, obs_uv, valid, isg, fixed, intrinsics, structure, params,
                                 u_right, chunk)
        return (out.T_c_w, out.points), out

    def objective(x: tuple, theta: tuple, const: tuple, out: BAResult) -> Float[Array, ""]:
        obs_uv, isg, intrinsics, u_right = theta
        cam, pt, valid, fixed, _, params = const
        obs = _observations(cam, pt, obs_uv, valid, isg, fixed, intrinsics, params, u_right, x[1].dtype)
        return _residuals(obs, x[0], x[1], params)[-1]

    def retract(x: tuple, step: tuple, const: tuple) -> tuple[jaxlie.SE3, Array]:
        free = (~const[3]).astype(x[1].dtype)[:, None]
        return jax.vmap(lambda v, T: jaxlie.SE3.exp(v) @ T)(step[0] * free, x[0]), x[1] + step[1]

    return implicit_argmin(
        solve, objective, retract,
        zero_tangent=lambda x: (jnp.zeros((x[0].wxyz_xyz.shape[0], 6), x[1].dtype), jnp.zeros_like(x[1])),
        converged=lambda out: out.summary.converged,
    )


@partial(jax.jit, static_argnames=("chunk",))
def _bundle_adjust_jit(
    T_c_w: jaxlie.SE3,
    points: Float[Array, "P 3"],
    obs_cam: Int[Array, " O"],
    obs_pt: Int[Array, " O"],
    obs_uv: Float[Array, "O 2"],
    obs_valid: Bool[Array, " O"],
    obs_inv_sigma2: Float[Array, " O"],
    fixed_cams: Bool[Array, " M"],
    intrinsics: Float[Array, "M 5"],
    structure: BAStructure,
    config: _Params,
    obs_u_right: Float[Array, " O"] | None,
    chunk: int,
) -> BAResult:
    dtype = points.dtype
    M = fixed_cams.shape[0]
    obs = _observations(obs_cam, obs_pt, obs_uv, obs_valid, obs_inv_sigma2, fixed_cams, intrinsics, config, obs_u_right, dtype)
    T0 = jax.tree.map(lambda a: jnp.asarray(a, dtype), T_c_w)

    def retract(x, step):
        (T, X), (xi, dp) = x, step
        return jax.vmap(lambda v, Tc: jaxlie.SE3.exp(v) @ Tc)(xi, T), X + dp

    (T_f, X_f), lin_f, summary = levenberg_marquardt(
        (T0, points),
        linearise=lambda x: _linearise(obs, x[0], x[1], M, config),
        solve=lambda lin, lam: _split(schur_damped_solve(lin, obs.cam, obs.pt, lam, fixed_cams, structure, chunk)),
        cost=lambda x: _residuals(obs, x[0], x[1], config)[-1],
        retract=retract,
        params=config.lm,
    )
    _, _, _, s, front, _ = _residuals(obs, T_f, X_f, config)
    inl = obs_valid & front & (s < obs.chi2)
    return BAResult(T_c_w=T_f, points=X_f, cost=lin_f.cost, initial_cost=summary.initial_cost, inliers=inl,
                    iterations=summary.iterations, summary=summary)


def _split(out: tuple[Array, Array, Array]) -> tuple[tuple[Array, Array], Array]:
    xi, dp, predicted = out
    return (xi, dp), predicted


def _check(name: str, a: np.ndarray, shape: tuple[int, ...]) -> None:
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")


def bundle_adjust(
    T_c_w: jaxlie.SE3,
    points: ArrayLike,
    obs_cam: ArrayLike,
    obs_pt: ArrayLike,
    obs_uv: ArrayLike,
    obs_valid: ArrayLike | None,
    fixed_cams: ArrayLike,
    camera: Camera | ArrayLike,
    config: BAConfig = BAConfig(),
    *,
    obs_inv_sigma2: ArrayLike | None = None,
    obs_u_right: ArrayLike | None = None,
    pad: bool = True,
) -> BAResult:
    """Bundle adjustment (host entry point): checks, pads to buckets, runs the jitted LM, unpads.

    Args:
      T_c_w: ``M`` world-to-camera poses (``jaxlie.SE3`` with batch axis ``M``).
      points: ``(P, 3)`` world points.
      obs_cam, obs_pt: ``(O,)`` integer camera and point index of each observation.
      obs_uv: ``(O, 2)`` observed pixels.
      obs_valid: ``(O,)`` bool mask of real observations, or ``None``.
      fixed_cams: ``(M,)`` bool, cameras held fixed (gauge: fix at least one; monocular: the scale is
        then still free and only damped).
      camera: one :class:`Camera` for all, or ``(M, 4|5)`` per-camera ``(fx, fy, cx, cy[, baseline])``.
      config: solver settings.
      obs_inv_sigma2: ``(O,)`` information ``1/σ²`` per observation (default 1).
      obs_u_right: ``(O,)`` right-image ``u`` of stereo (or RGB-D virtual-stereo) observations,
        ``< 0`` for monocular ones; needs a positive baseline for the cameras that have stereo rows.
      pad: pad sizes to buckets (``False``: exact sizes, e.g. for one large problem).

    Returns the unpadded :class:`BAResult` (``M`` poses, ``P`` points, ``O`` inliers).
    """
    pts = np.asarray(points)
    n_p = pts.shape[0] if pts.ndim == 2 else -1
    _check("points", pts, (n_p, 3))
    wxyz = np.asarray(T_c_w.wxyz_xyz)
    if wxyz.ndim != 2:
        raise ValueError(f"T_c_w must be a batch of poses (M,), got wxyz_xyz shape {wxyz.shape}")
    n_c = wxyz.shape[0]
    oc = np.asarray(obs_cam)
    op = np.asarray(obs_pt)
    n_o = oc.shape[0] if oc.ndim == 1 else -1
    _check("obs_cam", oc, (n_o,))
    _check("obs_pt", op, (n_o,))
    uv = np.asarray(obs_uv)
    _check("obs_uv", uv, (n_o, 2))
    valid = np.ones(n_o, bool) if obs_valid is None else np.asarray(obs_valid)
    _check("obs_valid", valid, (n_o,))
    fixed = np.asarray(fixed_cams)
    _check("fixed_cams", fixed, (n_c,))
    if valid.dtype != np.bool_ or fixed.dtype != np.bool_:
        raise ValueError("obs_valid and fixed_cams must be bool arrays")
    if not np.issubdtype(oc.dtype, np.integer) or not np.issubdtype(op.dtype, np.integer):
        raise ValueError("obs_cam and obs_pt must be integer arrays")
    isg = np.ones(n_o) if obs_inv_sigma2 is None else np.asarray(obs_inv_sigma2)
    _check("obs_inv_sigma2", isg, (n_o,))
    ur = None if obs_u_right is None else np.asarray(obs_u_right)
    if ur is not None:
        _check("obs_u_right", ur, (n_o,))
    if isinstance(camera, Camera):
        b = 0.0 if camera.baseline is None else camera.baseline
        intr = np.tile(np.array([camera.fx, camera.fy, camera.cx, camera.cy, b], np.float64), (n_c, 1))
    else:
        intr = np.asarray(camera, np.float64)
        if intr.shape not in ((n_c, 4), (n_c, 5)):
            raise ValueError(f"per-camera intrinsics must have shape ({n_c}, 4) or ({n_c}, 5), got {intr.shape}")
        if intr.shape[1] == 4:
            intr = np.concatenate([intr, np.zeros((n_c, 1))], 1)
    oc, op, uv, isg = oc[valid], op[valid], uv[valid], isg[valid]
    if ur is not None:
        ur = ur[valid]
        if not np.all(np.isfinite(ur)):
            raise ValueError("obs_u_right contains NaN/inf (mark monocular observations with a negative value)")
    if oc.size and (oc.min() < 0 or oc.max() >= n_c or op.min() < 0 or op.max() >= n_p):
        raise ValueError(f"observation indices out of range (cameras [0, {n_c}), points [0, {n_p}))")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(uv)) and np.all(np.isfinite(wxyz))):
        raise ValueError("points, obs_uv or T_c_w contain NaN/inf")
    if not np.all(np.isfinite(isg)) or np.any(isg <= 0):
        raise ValueError("obs_inv_sigma2 must be finite and positive")
    if not np.all(np.isfinite(intr)):
        raise ValueError("camera intrinsics contain NaN/inf")
    if not np.any(fixed):
        raise ValueError("fix at least one camera (gauge freedom)")
    if ur is not None and oc.size and np.any((ur >= 0) & ~(intr[oc, 4] > 0)):
        raise ValueError("stereo observations (obs_u_right >= 0) need a positive camera baseline")

    dtype = jax.dtypes.canonicalize_dtype(pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64)
    m_pad = ba_bucket(n_c) if pad else n_c
    p_pad = ba_bucket(n_p, minimum=8) if pad else n_p
    o_pad = ba_bucket(oc.size + 1, minimum=8) if pad else oc.size + 1
    n_v = oc.size

    def padded(a: np.ndarray, n: int, fill: float | int | bool) -> np.ndarray:
        out = np.full((n,) + a.shape[1:], fill, dtype=a.dtype)
        out[: a.shape[0]] = a
        return out

    wxyz_p = padded(wxyz, m_pad, 0.0)
    wxyz_p[n_c:, 0] = 1.0
    fixed_p = padded(fixed, m_pad, True)
    intr_p = padded(intr, m_pad, 1.0)
    pts_p = padded(pts, p_pad, 0.0)
    pts_p[n_p:, 2] = 1.0
    structure = analyze(oc, op, m_pad, o_pad, config.chunk, pad=pad)
    res = bundle_adjust_padded(
        jaxlie.SE3(jnp.asarray(wxyz_p, dtype)),
        jnp.asarray(pts_p, dtype),
        jnp.asarray(padded(oc.astype(np.int32), o_pad, 0)),
        jnp.asarray(padded(op.astype(np.int32), o_pad, 0)),
        jnp.asarray(padded(uv, o_pad, 0.0), dtype),
        jnp.asarray(padded(np.ones(n_v, bool), o_pad, False)),
        jnp.asarray(padded(isg, o_pad, 1.0), dtype),
        jnp.asarray(fixed_p),
        jnp.asarray(intr_p, dtype),
        structure,
        config,
        None if ur is None else jnp.asarray(padded(ur, o_pad, -1.0), dtype),
    )
    inl = np.zeros(n_o, bool)
    inl[valid] = np.asarray(res.inliers)[:n_v]
    return res.replace(
        # unpadded on the host and transferred back: an eager device slice, like ``jnp.asarray`` of a
        # host array, compiles a program for every new size (jax 0.10)
        T_c_w=jaxlie.SE3(jax.device_put(np.asarray(res.T_c_w.wxyz_xyz)[:n_c])),
        points=jax.device_put(np.asarray(res.points)[:n_p]), inliers=jax.device_put(inl)
    )
