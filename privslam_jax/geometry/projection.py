"""Rigid transforms, pinhole projection and reprojection residuals with analytic Jacobians.

Conventions (DESIGN §3): ``T_c_w`` maps world points into the camera frame (``p_c = T_c_w p_w``),
``T_w_c = T_c_w⁻¹`` is the camera pose.  The camera looks along ``+z``, ``x`` right, ``y`` down;
pixels ``(u, v)`` with ``v`` down (OpenCV).

The projection and its Jacobians are written once, here, elementwise over any batch shape
(``*b``), so one camera with ``N`` points, one camera per observation (bundle adjustment) and a single
point all use the same code; :func:`pinhole` also takes numpy arrays (the SLAM front end's host-side
map queries), where it computes in numpy.

Jacobians (used by :mod:`privslam_jax.slam.refine` and :mod:`privslam_jax.slam.ba`) are for the
**left** perturbation of the world-to-camera pose, ``T_c_w ← exp(δ) · T_c_w`` with jaxlie's tangent
order ``δ = (ρ, ω)`` (translation first).  To first order ``p_c(δ) = p_c + ρ + ω × p_c``, so

    ∂p_c/∂ρ = I₃,   ∂p_c/∂ω = −[p_c]ₓ,   ∂p_c/∂p_w = R_c_w,

and the pinhole ``u = fx·x/z + cx``, ``v = fy·y/z + cy`` (stereo: ``u_r = fx·(x − b)/z + cx``) has

    ∂(u, v)/∂p_c = [[fx/z, 0, −fx·x/z²], [0, fy/z, −fy·y/z²]],   ∂u_r/∂p_c = [fx/z, 0, −fx·(x − b)/z²].

This is the ``EdgeSE3ProjectXYZ`` Jacobian of ORB-SLAM (g2o), up to g2o's (ω, ρ) ordering and its
residual sign (g2o uses ``obs − proj``; here ``r = proj − obs``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from privslam_jax.types import Camera

__all__ = [
    "world_to_camera",
    "world_to_camera_from_pose",
    "pinhole",
    "pinhole_stereo",
    "project_points",
    "reprojection_residual",
    "reprojection_residuals",
    "reprojection_jacobians",
    "stereo_residual",
    "stereo_jacobians",
    "observation_rows",
    "skew",
]


def skew(v: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """The cross-product matrix ``[v]ₓ`` with ``[v]ₓ a = v × a``."""
    z = jnp.zeros_like(v[0])
    return jnp.stack(
        [jnp.stack([z, -v[2], v[1]]), jnp.stack([v[2], z, -v[0]]), jnp.stack([-v[1], v[0], z])]
    )


def world_to_camera(T_c_w: jaxlie.SE3, p_w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """``p_c = T_c_w · p_w`` (``T_c_w`` unbatched, points with any batch shape)."""
    t = T_c_w.translation()
    return p_w @ T_c_w.rotation().as_matrix().T + jnp.reshape(t, (1,) * (p_w.ndim - 1) + (3,))


def world_to_camera_from_pose(T_w_c: jaxlie.SE3, p_w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """``p_c = T_w_c⁻¹ · p_w = R_w_cᵀ (p_w − t_w_c)`` for a camera pose ``T_w_c`` (unbatched)."""
    t = T_w_c.translation()
    return (p_w - jnp.reshape(t, (1,) * (p_w.ndim - 1) + (3,))) @ T_w_c.rotation().as_matrix()


def _xp(a: Any) -> Any:
    return np if isinstance(a, np.ndarray) else jnp


def pinhole(
    p_c: Float[Array | np.ndarray, "*b 3"], fx: ArrayLike, fy: ArrayLike, cx: ArrayLike, cy: ArrayLike
) -> Float[Array | np.ndarray, "*b 2"]:
    """Pinhole projection of camera-frame points: ``(fx·x/z + cx, fy·y/z + cy)``."""
    inv_z = 1.0 / p_c[..., 2]
    return _xp(p_c).stack([fx * p_c[..., 0] * inv_z + cx, fy * p_c[..., 1] * inv_z + cy], axis=-1)


def pinhole_stereo(
    p_c: Float[Array | np.ndarray, "*b 3"], fx: ArrayLike, fy: ArrayLike, cx: ArrayLike, cy: ArrayLike, bf: ArrayLike
) -> Float[Array | np.ndarray, "*b 3"]:
    """Rectified stereo projection ``(u, v, u_r)`` with ``u_r = u − bf/z`` and ``bf = fx·baseline``."""
    inv_z = 1.0 / p_c[..., 2]
    u = fx * p_c[..., 0] * inv_z + cx
    return _xp(p_c).stack([u, fy * p_c[..., 1] * inv_z + cy, u - bf * inv_z], axis=-1)


def project_points(T_c_w: jaxlie.SE3, p_w: Float[Array, "N 3"], camera: Camera) -> Float[Array, "N 2"]:
    """Project world points into a camera with world-to-camera pose ``T_c_w``."""
    return camera.project(world_to_camera(T_c_w, p_w))


def reprojection_residual(
    T_c_w: jaxlie.SE3, p_w: Float[Array, "3"], uv: Float[Array, "2"], camera: Camera
) -> Float[Array, "2"]:
    """Residual of one observation: ``π(T_c_w p_w) − uv`` in pixels."""
    return pinhole(T_c_w @ p_w, camera.fx, camera.fy, camera.cx, camera.cy) - uv


def reprojection_residuals(
    T_c_w: jaxlie.SE3, p_w: Float[Array, "N 3"], uv: Float[Array, "N 2"], camera: Camera
) -> Float[Array, "N 2"]:
    """:func:`reprojection_residual` vmapped over observations of one camera."""
    return jax.vmap(reprojection_residual, in_axes=(None, 0, 0, None))(T_c_w, p_w, uv, camera)


def _d_uv_d_pc(p_c: Float[Array, "*b 3"], fx: ArrayLike, fy: ArrayLike) -> tuple[Float[Array, "*b 3"], Float[Array, "*b 3"]]:
    """The rows ``∂u/∂p_c`` and ``∂v/∂p_c``."""
    x, y, inv_z = p_c[..., 0], p_c[..., 1], 1.0 / p_c[..., 2]
    zero = jnp.zeros_like(inv_z)
    return (jnp.stack([fx * inv_z + zero, zero, -fx * x * inv_z * inv_z], -1),
            jnp.stack([zero, fy * inv_z + zero, -fy * y * inv_z * inv_z], -1))


def _chain(rows: list[Float[Array, "*b 3"]], p_c: Float[Array, "*b 3"], R_c_w: Float[Array, "*r 3 3"]
           ) -> tuple[Float[Array, "*b K 6"], Float[Array, "*b K 3"]]:
    """``∂r/∂(ρ, ω) = [P | P·(−[p_c]ₓ)]`` (row-wise ``(P_k, p_c × P_k)``) and ``∂r/∂p_w = P·R_c_w``."""
    J_pose = jnp.stack([jnp.concatenate([P, jnp.cross(p_c, P)], -1) for P in rows], -2)
    R = jnp.reshape(R_c_w, (1,) * (p_c.ndim + 1 - R_c_w.ndim) + R_c_w.shape)  # explicit rank promotion
    J_point = jnp.stack([jnp.sum(P[..., :, None] * R, -2) for P in rows], -2)
    return J_pose, J_point


def reprojection_jacobians(
    p_c: Float[Array, "*b 3"], R_c_w: Float[Array, "*r 3 3"], fx: ArrayLike, fy: ArrayLike
) -> tuple[Float[Array, "*b 2 6"], Float[Array, "*b 2 3"]]:
    """Jacobians of ``π(T_c_w p_w)`` w.r.t. the left pose perturbation ``(ρ, ω)`` and the point ``p_w``.

    ``p_c`` is the camera-frame point ``T_c_w p_w`` (already computed by the caller); ``R_c_w``,
    ``fx``, ``fy`` broadcast against its batch shape (one camera, or one per observation).
    """
    return _chain(list(_d_uv_d_pc(p_c, fx, fy)), p_c, R_c_w)


def stereo_residual(
    T_c_w: jaxlie.SE3, p_w: Float[Array, "3"], uvr: Float[Array, "3"], camera: Camera
) -> Float[Array, "3"]:
    """Stereo residual ``(u, v, u_r) − obs`` of one observation (needs ``camera.baseline``)."""
    if camera.baseline is None:
        raise ValueError("stereo residuals need camera.baseline")
    bf = camera.fx * camera.baseline
    return pinhole_stereo(T_c_w @ p_w, camera.fx, camera.fy, camera.cx, camera.cy, bf) - uvr


def stereo_jacobians(
    p_c: Float[Array, "*b 3"], R_c_w: Float[Array, "*r 3 3"], fx: ArrayLike, fy: ArrayLike, bf: ArrayLike
) -> tuple[Float[Array, "*b 3 6"], Float[Array, "*b 3 3"]]:
    """Jacobians of :func:`pinhole_stereo` ∘ ``T_c_w`` w.r.t. ``(ρ, ω)`` and ``p_w`` (batched as
    :func:`reprojection_jacobians`)."""
    Pu, Pv = _d_uv_d_pc(p_c, fx, fy)
    inv_z = 1.0 / p_c[..., 2]
    zero = jnp.zeros_like(inv_z)
    # u_r = u − bf/z  ⇒  ∂u_r/∂p_c = ∂u/∂p_c + (0, 0, bf/z²)
    return _chain([Pu, Pv, Pu + jnp.stack([zero, zero, bf * inv_z * inv_z], -1)], p_c, R_c_w)


def observation_rows(
    uv: Float[Array, "N 2"], u_right: Float[Array, " N"] | None, mono: tuple[ArrayLike, ArrayLike],
    stereo: tuple[ArrayLike, ArrayLike], dtype: Any,
) -> tuple[Float[Array, "N K"], Bool[Array, " N"] | None, Float[Array, " N"], Float[Array, " N"]]:
    """Observation rows of mixed monocular / stereo measurements, as ORB-SLAM lays them out.

    ``u_right < 0`` marks a monocular observation (ORB-SLAM's convention). Returns the rows
    ``(u, v)`` (``K = 2``, when ``u_right`` is ``None``) or ``(u, v, u_r)`` (``K = 3``, ``u_r = 0`` on
    monocular rows), the stereo flags (``None`` without ``u_right``) and each row's Huber δ and χ²
    threshold, taken from ``mono = (δ, χ²)`` or ``stereo = (δ, χ²)``.
    """
    n = uv.shape[0]
    if u_right is None:
        return (uv.astype(dtype), None, jnp.full((n,), mono[0], dtype), jnp.full((n,), mono[1], dtype))
    is_st = u_right >= 0
    rows = jnp.concatenate([uv.astype(dtype), jnp.where(is_st, u_right, 0.0).astype(dtype)[:, None]], axis=1)
    return (rows, is_st, jnp.where(is_st, stereo[0], mono[0]).astype(dtype),
            jnp.where(is_st, stereo[1], mono[1]).astype(dtype))
