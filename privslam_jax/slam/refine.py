"""Pose-only refinement: jitted Huber-robust Levenberg–Marquardt on SE(3) (ORB-SLAM ``PoseOptimization``).

Problem.  Given map points ``p_i`` (world), their observations ``z_i`` (pixels, optionally with the
right-image ``u_r`` of a rectified stereo pair) and per-observation information ``Ω_i = σ_i⁻² I``,
find the world-to-camera pose minimising

    F(T) = ½ Σ_i ρ(s_i),   s_i = Ω_i ‖π(T p_i) − z_i‖²,

with the Huber loss on the whitened squared error ``s`` (scipy's ``loss="huber"`` with
``f_scale = δ`` applied to ``‖e_i‖``; g2o's ``RobustKernelHuber``):

    ρ(s) = s               if s ≤ δ²
           2δ√s − δ²       otherwise,          ρ'(s) = min(1, δ/√s).

Step.  Linearise at the current pose with a left perturbation ``T ← exp(ξ) T`` (jaxlie tangent
``ξ = (ρ, ω)``), analytic 2×6 (stereo 3×6) Jacobians ``J_i`` (:mod:`privslam_jax.geometry.projection`),
and build the 6×6 normal equations with the IRLS weights ``w_i = ρ'(s_i)``
(Triggs et al., *Bundle Adjustment — A Modern Synthesis*, §4.3; the gradient is exact):

    H = Σ w_i Ω_i J_iᵀ J_i,   g = Σ w_i Ω_i J_iᵀ e_i,   (H + λ D) ξ = −g,   D = diag(H) clamped to [1e-6, 1e32].

The damped system is solved by Cholesky (:mod:`privslam_jax.solvers.linear`) inside the shared
Levenberg–Marquardt loop (:mod:`privslam_jax.solvers.lm`, Nielsen's damping rule); why the last round
stopped is ``RefineResult.summary``.
Measured (DESIGN §5.3): optimistix's default LM (QR on the tall Jacobian) took 170–280 ms for 2,000
matches, this hand-written 6×6 normal-equation solve a few ms (``benchmarks/bench_refine.py``).

Outliers.  As ORB-SLAM, ``config.rounds`` rounds of at most ``config.max_iterations`` LM iterations;
after each round every valid observation is re-classified with the χ² test (2 dof: 5.991, 3 dof: 7.815)
and the next round uses only the inliers.  Observations whose point lies behind the camera
(``z ≤ min_depth``) get no gradient and a constant penalty ``ρ(behind_chi2)`` so that a step cannot
lower the cost by pushing points behind the camera; they are outliers.

Derivatives.  :func:`refine_pose_padded` is differentiable (``jax.grad``, ``jacfwd``, ``jacrev``, under
``jit`` and ``vmap``) in the points, observations, information, ``u_right`` and intrinsics by the
implicit-function theorem on the last round's cost (:mod:`privslam_jax.solvers.implicit`); the
re-classification between rounds is piecewise constant and has no derivative.  When the last round did
not converge the derivative is NaN.

Shapes.  The jitted core takes padded arrays and a ``valid`` mask; :func:`refine_pose` pads on the
host to a size bucket (:func:`bucket_size`) so that successive frames with different match counts
reuse the compiled program.
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
    world_to_camera,
)
from privslam_jax.solvers.implicit import implicit_argmin
from privslam_jax.solvers.linear import DenseSystem, dense_damped_solve
from privslam_jax.solvers.lm import LMParams, SolveSummary, levenberg_marquardt
from privslam_jax.solvers.robust import huber_rho, huber_weight
from privslam_jax.types import Camera

__all__ = [
    "RefineConfig",
    "RefineResult",
    "DEFAULT_BUCKETS",
    "bucket_size",
    "pad_to_bucket",
    "refine_pose",
    "refine_pose_padded",
    "camera_params",
]

DEFAULT_BUCKETS: tuple[int, ...] = (64, 128, 256, 512, 1024, 2048, 4096, 8192)
"""Padded sizes used by :func:`pad_to_bucket`; larger inputs round up to a multiple of the last one."""


@dataclasses.dataclass(frozen=True)
class RefineConfig:
    """Settings of :func:`refine_pose` (all static: changing one recompiles)."""

    max_iterations: int = 10
    """LM iterations per round (ORB-SLAM: 10)."""
    rounds: int = 4
    """Outlier re-classification rounds (ORB-SLAM: 4). Use 1 to solve one fixed robust problem."""
    robust: bool = True
    """Huber loss on the whitened χ² (``False``: squared loss)."""
    huber_mono: float = math.sqrt(5.991)
    """Huber threshold δ (whitened pixels) for monocular observations (ORB-SLAM: √5.991)."""
    huber_stereo: float = math.sqrt(7.815)
    """Huber threshold δ for stereo observations (ORB-SLAM: √7.815)."""
    chi2_mono: float = 5.991
    """χ² inlier threshold, 2 dof, 95 % (ORB-SLAM)."""
    chi2_stereo: float = 7.815
    """χ² inlier threshold, 3 dof, 95 % (ORB-SLAM)."""
    initial_damping: float = 1e-4
    """Initial LM λ (relative to ``diag(H)``; Ceres' default trust radius 1e4 ⇒ 1e-4)."""
    function_tolerance: float = 1e-6
    """Stop a round when an accepted step lowers the cost by less than this fraction."""
    step_tolerance: float = 1e-10
    """Stop a round when ``‖ξ‖`` falls below this."""
    min_depth: float = 1e-3
    """Points with camera-frame ``z`` at or below this are treated as behind the camera (metres)."""
    behind_chi2: float = 1e6
    """Whitened χ² charged for a point behind the camera (a constant, see the module docstring)."""


@struct.dataclass
class RefineResult:
    """Output of :func:`refine_pose`."""

    T_c_w: jaxlie.SE3
    """Refined world-to-camera pose."""
    cost: Float[Array, ""]
    """Final cost ``½ Σ ρ(s_i)`` over the last round's active observations."""
    initial_cost: Float[Array, ""]
    """The same cost at the initial pose over all valid observations (first round)."""
    inliers: Bool[Array, " N"]
    """Valid observations in front of the camera passing the χ² test at the final pose."""
    iterations: Int[Array, ""]
    """LM iterations run in total (over all rounds)."""
    active: Bool[Array, " N"]
    """The observations the last round minimised over (its cost is ``cost``)."""
    summary: SolveSummary
    """Why the last round stopped (:class:`~privslam_jax.solvers.lm.SolveSummary`; its ``iterations``
    count that round only)."""


def camera_params(camera: Camera, dtype: jnp.dtype | type | None = None) -> Float[Array, " 5"]:
    """``(fx, fy, cx, cy, baseline)`` of a :class:`Camera` as one array (baseline 0 when absent)."""
    b = 0.0 if camera.baseline is None else camera.baseline
    return jnp.asarray([camera.fx, camera.fy, camera.cx, camera.cy, b], dtype=dtype)


def bucket_size(n: int, buckets: tuple[int, ...] = DEFAULT_BUCKETS) -> int:
    """The smallest bucket ``≥ n`` (multiples of the largest bucket beyond it)."""
    if n < 0:
        raise ValueError(f"size must be non-negative, got {n}")
    for b in buckets:
        if n <= b:
            return b
    last = buckets[-1]
    return int(-(-n // last) * last)


def pad_to_bucket(
    points_w: ArrayLike,
    uv: ArrayLike,
    valid: ArrayLike | None = None,
    u_right: ArrayLike | None = None,
    inv_sigma2: ArrayLike | None = None,
    buckets: tuple[int, ...] = DEFAULT_BUCKETS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Host-side padding to :func:`bucket_size` rows.

    Returns ``(points_w, uv, valid, u_right, inv_sigma2)`` as numpy arrays with ``B`` rows; padded rows
    hold a harmless point at ``z = 1`` in front of an identity camera, ``valid = False``, ``u_right = −1``
    and ``inv_sigma2 = 1``.  ``u_right`` stays ``None`` when not given.
    """
    points_w = np.asarray(points_w)
    uv = np.asarray(uv)
    n = points_w.shape[0]
    b = bucket_size(n, buckets)
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    inv_sigma2 = np.ones(n, points_w.dtype) if inv_sigma2 is None else np.asarray(inv_sigma2, points_w.dtype)

    def pad(a: np.ndarray, fill: float | bool) -> np.ndarray:
        out = np.full((b,) + a.shape[1:], fill, dtype=a.dtype)
        out[:n] = a
        return out

    pts = pad(points_w, 0.0)
    pts[n:, 2] = 1.0
    return (
        pts,
        pad(uv, 0.0),
        pad(valid, False),
        None if u_right is None else pad(np.asarray(u_right, points_w.dtype), -1.0),
        pad(inv_sigma2, 1.0),
    )


def _check_inputs(
    points_w: np.ndarray,
    uv: np.ndarray,
    valid: np.ndarray,
    u_right: np.ndarray | None,
    inv_sigma2: np.ndarray | None,
    camera: Camera,
) -> None:
    n = points_w.shape[0] if points_w.ndim >= 1 else -1
    if points_w.ndim != 2 or points_w.shape[1] != 3:
        raise ValueError(f"points_w must have shape (N, 3), got {points_w.shape}")
    if uv.shape != (n, 2):
        raise ValueError(f"uv must have shape ({n}, 2) to match points_w, got {uv.shape}")
    if valid.shape != (n,):
        raise ValueError(f"valid must have shape ({n},), got {valid.shape}")
    for name, a in (("u_right", u_right), ("inv_sigma2", inv_sigma2)):
        if a is not None and a.shape != (n,):
            raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if u_right is not None and camera.baseline is None:
        raise ValueError("stereo observations (u_right) need camera.baseline")
    bad = ~np.all(np.isfinite(points_w), axis=1) | ~np.all(np.isfinite(uv), axis=1)
    if u_right is not None:
        bad |= ~np.isfinite(u_right)
    if inv_sigma2 is not None:
        bad |= ~np.isfinite(inv_sigma2) | (inv_sigma2 <= 0)
    if np.any(bad & valid):
        raise ValueError(f"{int(np.sum(bad & valid))} valid observations contain NaN/inf (or non-positive inv_sigma2)")


def _residuals(
    T_c_w: jaxlie.SE3,
    points_w: Float[Array, "N 3"],
    obs: Float[Array, "N K"],
    intrinsics: Float[Array, " 5"],
    stereo: Bool[Array, " N"] | None,
) -> tuple[Float[Array, "N 3"], Float[Array, "N K"]]:
    p_c = world_to_camera(T_c_w, points_w)
    fx, fy, cx, cy, b = (intrinsics[k] for k in range(5))
    if stereo is None:
        pred = pinhole(p_c, fx, fy, cx, cy)
        return p_c, pred - obs
    pred = pinhole_stereo(p_c, fx, fy, cx, cy, fx * b)
    e = pred - obs
    return p_c, e.at[:, 2].multiply(stereo.astype(e.dtype))


def _obs_cost(
    p_c: Float[Array, "N 3"],
    e: Float[Array, "N K"],
    mask: Bool[Array, " N"],
    inv_sigma2: Float[Array, " N"],
    delta: Float[Array, " N"],
    params: "_RefineParams",
) -> tuple[Float[Array, " N"], Float[Array, " N"], Bool[Array, " N"]]:
    """Per-observation cost contribution, whitened χ² and in-front flag (``δ = +inf``: squared loss)."""
    front = p_c[:, 2] > params.min_depth
    s = inv_sigma2 * jnp.sum(e * e, axis=1)
    c = jnp.where(front, huber_rho(s, delta), huber_rho(jnp.full_like(s, params.behind_chi2), delta))
    return jnp.where(mask, c, 0.0), s, front


def _cost(
    T: jaxlie.SE3,
    points_w: Float[Array, "N 3"],
    obs: Float[Array, "N K"],
    intrinsics: Float[Array, " 5"],
    stereo: Bool[Array, " N"] | None,
    mask: Bool[Array, " N"],
    inv_sigma2: Float[Array, " N"],
    delta: Float[Array, " N"],
    config: "_RefineParams",
) -> tuple[Float[Array, ""], Float[Array, " N"], Bool[Array, " N"]]:
    """``F(T) = ½ Σ_{mask} ρ(s_i)``, with each whitened χ² ``s_i`` and in-front flag."""
    p_c, e = _residuals(T, points_w, obs, intrinsics, stereo)
    c, s, front = _obs_cost(p_c, e, mask, inv_sigma2, delta, config)
    return 0.5 * jnp.sum(c), s, front


class _RefineParams(struct.PyTreeNode):
    """Numeric :class:`RefineConfig` fields as traced values (changing them does not recompile)."""

    lm: LMParams
    huber_mono: Array
    huber_stereo: Array
    chi2_mono: Array
    chi2_stereo: Array
    min_depth: Array
    behind_chi2: Array

    @staticmethod
    def of(config: RefineConfig, dtype: jnp.dtype) -> "_RefineParams":
        f = lambda v: jnp.asarray(v, dtype)  # noqa: E731
        inf = jnp.inf
        return _RefineParams(
            lm=LMParams.of(dtype, config.max_iterations, config.initial_damping, config.function_tolerance,
                           step_tolerance=config.step_tolerance),
            huber_mono=f(config.huber_mono if config.robust else inf),
            huber_stereo=f(config.huber_stereo if config.robust else inf),
            chi2_mono=f(config.chi2_mono),
            chi2_stereo=f(config.chi2_stereo),
            min_depth=f(config.min_depth),
            behind_chi2=f(config.behind_chi2),
        )


def refine_pose_padded(
    T_c_w: jaxlie.SE3,
    points_w: Float[Array, "N 3"],
    uv: Float[Array, "N 2"],
    valid: Bool[Array, " N"],
    inv_sigma2: Float[Array, " N"],
    u_right: Float[Array, " N"] | None,
    intrinsics: Float[Array, " 5"],
    config: RefineConfig,
) -> RefineResult:
    """Core of :func:`refine_pose` on already padded arrays (no host checks; jit-able, differentiable).

    ``intrinsics = (fx, fy, cx, cy, baseline)`` from :func:`camera_params` (a plain array, so that
    the camera is a traced value).  ``u_right`` entries ``< 0`` mark monocular observations
    (ORB-SLAM's convention); pass ``None`` for a purely monocular problem (2-row residuals, cheaper).
    Only ``config.rounds``, the shapes and ``u_right is None`` select the compiled program.
    """
    params = _RefineParams.of(config, points_w.dtype)
    theta = (points_w, uv, inv_sigma2, u_right, intrinsics)
    T_f, result = _differentiable_refine(config.rounds)(T_c_w, theta, (valid, params))
    return result.replace(T_c_w=T_f)


@functools.cache
def _differentiable_refine(rounds: int) -> Callable[..., tuple[jaxlie.SE3, RefineResult]]:
    """:func:`_refine_jit` with implicit derivatives in ``θ = (points_w, uv, inv_sigma2, u_right, intrinsics)``."""

    def solve(T0: jaxlie.SE3, theta: tuple, const: tuple) -> tuple[jaxlie.SE3, RefineResult]:
        points_w, uv, inv_sigma2, u_right, intrinsics = theta
        valid, params = const
        out = _refine_jit(T0, points_w, uv, valid, inv_sigma2, u_right, intrinsics, params, rounds)
        return out.T_c_w, out

    def objective(T: jaxlie.SE3, theta: tuple, const: tuple, out: RefineResult) -> Float[Array, ""]:
        points_w, uv, inv_sigma2, u_right, intrinsics = theta
        params = const[1]
        dtype = points_w.dtype
        obs, stereo, delta, _ = observation_rows(uv, u_right, (params.huber_mono, params.chi2_mono),
                                                (params.huber_stereo, params.chi2_stereo), dtype)
        return _cost(T, points_w, obs, intrinsics.astype(dtype), stereo, out.active, inv_sigma2, delta, params)[0]

    return implicit_argmin(
        solve, objective,
        retract=lambda T, xi, const: jaxlie.SE3.exp(xi) @ T,
        zero_tangent=lambda T: jnp.zeros(6, T.wxyz_xyz.dtype),
        converged=lambda out: out.summary.converged,
    )


@partial(jax.jit, static_argnames=("rounds",))
def _refine_jit(
    T_c_w: jaxlie.SE3,
    points_w: Float[Array, "N 3"],
    uv: Float[Array, "N 2"],
    valid: Bool[Array, " N"],
    inv_sigma2: Float[Array, " N"],
    u_right: Float[Array, " N"] | None,
    intrinsics: Float[Array, " 5"],
    config: _RefineParams,
    rounds: int,
) -> RefineResult:
    dtype = points_w.dtype
    intrinsics = intrinsics.astype(dtype)
    T_c_w = jax.tree.map(lambda a: jnp.asarray(a, dtype), T_c_w)
    obs, stereo, delta, chi2 = observation_rows(uv, u_right, (config.huber_mono, config.chi2_mono),
                                                (config.huber_stereo, config.chi2_stereo), dtype)

    def cost_at(T: jaxlie.SE3, mask: Bool[Array, " N"]) -> tuple[Float[Array, ""], Float[Array, " N"], Bool[Array, " N"]]:
        return _cost(T, points_w, obs, intrinsics, stereo, mask, inv_sigma2, delta, config)

    def linearise(T: jaxlie.SE3, mask: Bool[Array, " N"]) -> DenseSystem:
        p_c, e = _residuals(T, points_w, obs, intrinsics, stereo)
        c, s, front = _obs_cost(p_c, e, mask, inv_sigma2, delta, config)
        fx, fy, bf = intrinsics[0], intrinsics[1], intrinsics[0] * intrinsics[4]
        R = T.rotation().as_matrix()
        if stereo is None:
            J, _ = reprojection_jacobians(p_c, R, fx, fy)
        else:
            J, _ = stereo_jacobians(p_c, R, fx, fy, bf)
            J = J.at[:, 2].multiply(stereo.astype(dtype)[:, None])
        w = jnp.where(mask & front, huber_weight(s, delta) * inv_sigma2, 0.0)
        H = jnp.einsum("n,nki,nkj->ij", w, J, J)
        g = jnp.einsum("n,nki,nk->i", w, J, e)
        return DenseSystem(H=H, g=g, cost=0.5 * jnp.sum(c))

    def run_round(T: jaxlie.SE3, mask: Bool[Array, " N"]) -> tuple[jaxlie.SE3, SolveSummary]:
        T_f, _, summary = levenberg_marquardt(
            T,
            linearise=lambda T: linearise(T, mask),
            solve=dense_damped_solve,
            cost=lambda T: cost_at(T, mask)[0],
            retract=lambda T, xi: jaxlie.SE3.exp(xi) @ T,
            params=config.lm,
        )
        return T_f, summary

    def classify(T: jaxlie.SE3) -> Bool[Array, " N"]:
        _, s, front = cost_at(T, valid)
        return valid & front & (s < chi2)

    initial_cost, _, _ = cost_at(T_c_w, valid)

    def round_step(carry, _):
        T, mask, _, iters, _ = carry
        T, summary = run_round(T, mask)
        return (T, classify(T), mask, iters + summary.iterations, summary), None

    summary0 = SolveSummary(status=jnp.asarray(0), iterations=jnp.asarray(0), initial_cost=initial_cost, cost=initial_cost)
    carry0 = (T_c_w, valid, valid, jnp.asarray(0), summary0)
    (T_f, inl, active, iters, summary), _ = jax.lax.scan(round_step, carry0, None, length=rounds)
    return RefineResult(T_c_w=T_f, cost=summary.cost, initial_cost=initial_cost, inliers=inl, iterations=iters,
                        active=active, summary=summary)


def refine_pose(
    T_c_w: jaxlie.SE3,
    points_w: ArrayLike,
    uv: ArrayLike,
    valid: ArrayLike | None,
    camera: Camera,
    config: RefineConfig = RefineConfig(),
    *,
    u_right: ArrayLike | None = None,
    inv_sigma2: ArrayLike | None = None,
    buckets: tuple[int, ...] = DEFAULT_BUCKETS,
) -> RefineResult:
    """Refine a world-to-camera pose from 2D–3D matches (host entry point).

    Args:
      T_c_w: initial world-to-camera pose (unbatched ``jaxlie.SE3``).
      points_w: ``(N, 3)`` map points in the world frame.
      uv: ``(N, 2)`` observed pixels in the left image.
      valid: ``(N,)`` bool mask of real matches, or ``None`` (all real).
      camera: pinhole intrinsics (``baseline`` needed for stereo).
      config: solver settings (static).
      u_right: optional ``(N,)`` right-image ``u`` of stereo matches; ``< 0`` marks a monocular match.
      inv_sigma2: optional ``(N,)`` information ``1/σ²`` (ORB-SLAM: ``1/scale_factor^(2·octave)``).
      buckets: padded sizes (see :func:`pad_to_bucket`).

    Inputs are checked (shapes, NaN/inf in valid rows → ``ValueError``) and padded to a size bucket, so
    calls with ``N`` in the same bucket reuse one compiled program.  ``inliers`` and ``active`` are
    returned unpadded (``N`` entries).  Inside ``jit`` call :func:`refine_pose_padded` directly.
    """
    p = np.asarray(points_w)
    z = np.asarray(uv)
    n = p.shape[0] if p.ndim >= 1 else 0
    v = np.ones(n, bool) if valid is None else np.asarray(valid)
    if v.dtype != np.bool_:
        raise ValueError(f"valid must be a bool array, got dtype {v.dtype}")
    ur = None if u_right is None else np.asarray(u_right)
    isg = None if inv_sigma2 is None else np.asarray(inv_sigma2)
    _check_inputs(p, z, v, ur, isg, camera)
    if not np.all(np.isfinite(np.asarray(T_c_w.wxyz_xyz))):
        raise ValueError("T_c_w contains NaN/inf")
    # the dtype JAX would give these points, found on the host: an eager ``jnp.asarray`` of an (N, 3)
    # host array compiles a copy program for every new N (jax 0.10; once per tracked frame in SLAM)
    dtype = jax.dtypes.canonicalize_dtype(p.dtype if np.issubdtype(p.dtype, np.floating) else np.float64)
    p = p.astype(dtype)
    z = z.astype(dtype)
    pts, uvp, vp, urp, isgp = pad_to_bucket(p, z, v, ur, isg, buckets)
    out = refine_pose_padded(
        T_c_w,
        jnp.asarray(pts),
        jnp.asarray(uvp),
        jnp.asarray(vp),
        jnp.asarray(isgp),
        None if urp is None else jnp.asarray(urp),
        camera_params(camera, dtype),
        config,
    )
    # unpadded on the host and transferred back: an eager slice of a device array, like ``jnp.asarray``
    # of a host array, compiles a program for every new N (jax 0.10)
    return out.replace(inliers=jax.device_put(np.asarray(out.inliers)[:n]),
                       active=jax.device_put(np.asarray(out.active)[:n]))
