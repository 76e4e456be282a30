r"""Umeyama alignment of two point sets: SE(3) (rotation + translation) and Sim(3) (+ scale).

Umeyama, "Least-squares estimation of transformation parameters between two point patterns",
IEEE TPAMI 13(4), 1991.  Given corresponding points :math:`x_i` (source, e.g. estimated camera
centres) and :math:`y_i` (target, e.g. ground truth), :math:`i = 1..n`, find :math:`c, R, t`
minimising :math:`\frac1n\sum_i \lVert y_i - (c R x_i + t)\rVert^2`:

* means (eqs. 34, 35): :math:`\mu_x = \frac1n\sum x_i`, :math:`\mu_y = \frac1n\sum y_i`;
* source variance (eq. 36): :math:`\sigma_x^2 = \frac1n\sum\lVert x_i - \mu_x\rVert^2`;
* covariance (eq. 38): :math:`\Sigma_{xy} = \frac1n\sum (y_i - \mu_y)(x_i - \mu_x)^\top = U D V^\top` (SVD);
* :math:`S = I`, or :math:`S = \mathrm{diag}(1, 1, -1)` when :math:`\det U \det V < 0` (eq. 43;
  the determinant test of the SVD factors, as evo and Eigen do, also covers rank-2 covariances);
* rotation (eq. 40): :math:`R = U S V^\top`;
* scale (eq. 42): :math:`c = \mathrm{tr}(D S) / \sigma_x^2` (Sim(3)); :math:`c = 1` for SE(3);
* translation (eq. 41): :math:`t = \mu_y - c R \mu_x`.

The maths is written once over an array namespace: :func:`umeyama` is the jitted JAX version
(JAX default precision, differentiable where the SVD is), :func:`umeyama_np` the float64 numpy
version used by the trajectory metrics (where agreement with evo to 1e-6 needs float64).

Collinear point sets (a straight drive: rank-1 covariance) are accepted, unlike evo, which raises.
The rotation about the line is then not determined, but every optimal :math:`R` of the family
(the SVD one among them) gives the same residuals :math:`\lVert y_i - (cRx_i + t)\rVert`: rotating
about the line through :math:`\mu_y` moves no point that lies on it, and for points off it keeps
their distance to it.  So ATE and the scale :math:`c` are well defined; only the aligned
orientations are arbitrary about the line.  Identical points (rank 0) are rejected.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

__all__ = ["umeyama", "umeyama_np", "apply_similarity"]


def _umeyama(xp: Any, src: Any, dst: Any, with_scale: bool) -> tuple[Any, Any, Any, Any]:
    """Eqs. 34-43 of Umeyama (1991) over the array namespace ``xp`` (numpy or jax.numpy)."""
    n = src.shape[0]
    mu_x = src.mean(axis=0)
    mu_y = dst.mean(axis=0)
    xc = src - mu_x[None, :]
    yc = dst - mu_y[None, :]
    sigma_x2 = (xc * xc).sum() / n
    cov = yc.T @ xc / n
    u, d, vt = xp.linalg.svd(cov)
    sign = xp.where(xp.linalg.det(u) * xp.linalg.det(vt) < 0.0, -1.0, 1.0)
    s_diag = xp.stack([xp.ones_like(sign), xp.ones_like(sign), sign])
    R = (u * s_diag[None, :]) @ vt
    c = (d * s_diag).sum() / sigma_x2 if with_scale else xp.ones_like(sigma_x2)
    t = mu_y - c * (R @ mu_x)
    return R, t, c, d


@partial(jax.jit, static_argnames=("with_scale",))
def umeyama(
    src: Float[Array, "N 3"], dst: Float[Array, "N 3"], with_scale: bool = False
) -> tuple[Float[Array, "3 3"], Float[Array, " 3"], Float[Array, ""]]:
    """Jitted Umeyama alignment ``dst ≈ c·R·src + t``; returns ``(R, t, c)`` (``c = 1`` unless ``with_scale``).

    No degeneracy check inside ``jit``: collinear inputs give an arbitrary rotation about the line.
    """
    R, t, c, _ = _umeyama(jnp, jnp.asarray(src), jnp.asarray(dst), with_scale)
    return R, t, c


def umeyama_np(
    src: Float[np.ndarray, "N 3"], dst: Float[np.ndarray, "M 3"], with_scale: bool = False
) -> tuple[Float[np.ndarray, "3 3"], Float[np.ndarray, " 3"], float]:
    """Float64 numpy Umeyama alignment ``dst ≈ c·R·src + t``; returns ``(R, t, c)``.

    Raises ``ValueError`` for mismatched shapes, fewer than 3 points or a zero covariance (all
    points identical).  Collinear points are accepted (see the module docstring).
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"umeyama needs two (N, 3) arrays of equal shape, got {x.shape} and {y.shape}")
    if x.shape[0] < 3:
        raise ValueError(f"umeyama needs at least 3 point pairs, got {x.shape[0]}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("umeyama: NaN or inf in the points")
    R, t, c, d = _umeyama(np, x, y, with_scale)
    if not d[0] > 0.0:
        raise ValueError("umeyama: degenerate point sets (zero covariance, e.g. all points identical)")
    return R, t, float(c)


def apply_similarity(
    R: Float[ArrayLike, "3 3"], t: Float[ArrayLike, " 3"], c: float | Float[ArrayLike, ""], T: Float[np.ndarray, "N 4 4"]
) -> Float[np.ndarray, "N 4 4"]:
    """Apply ``x ↦ c·R·x + t`` to camera-to-world poses (float64 numpy): ``R_w ← R·R_w``, ``t_w ← c·R·t_w + t``.

    This is what evo's ``PosePath3D.align`` / ``scale`` + ``transform`` do to the estimate.
    """
    R = np.asarray(R, np.float64)
    out = np.array(T, dtype=np.float64, copy=True)
    out[:, :3, :3] = R[None] @ out[:, :3, :3]
    out[:, :3, 3] = float(c) * out[:, :3, 3] @ R.T + np.asarray(t, np.float64)[None, :]
    return out
