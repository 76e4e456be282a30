r"""Similarity transforms Sim(3), in the manner of ``jaxlie``: an immutable pytree, batch axes in front.

An element :math:`S = (s, R, t)` acts on points as :math:`S x = s R x + t` (as a matrix
:math:`\begin{bmatrix} sR & t \\ 0 & 1\end{bmatrix}`); composition and inverse follow from that:

* :math:`S_1 S_2 = (s_1 s_2,\; R_1 R_2,\; s_1 R_1 t_2 + t_1)`;
* :math:`S^{-1} = (1/s,\; R^\top,\; -R^\top t / s)`.

The scale is stored as :math:`\log s` so that every real value is a valid element.  Monocular SLAM
poses live here (the map's scale is unobservable and drifts); SE(3) is the subgroup :math:`s = 1`
(:meth:`Sim3.from_se3`, :meth:`Sim3.to_se3`).

Tangent chart used by the pose graph (:mod:`privslam_jax.slam.pose_graph`):
:meth:`Sim3.log_chart` maps :math:`S` to :math:`(\log_{SO(3)} R,\; t,\; \log s) \in \mathbb R^7`
— zero exactly at the identity, smooth near it — and :meth:`Sim3.retract` updates
:math:`(R, t, \log s) \leftarrow (\exp(\omega) R,\; t + v,\; \log s + \sigma)`.  This is a chart of
the product manifold :math:`SO(3)\times\mathbb R^3\times\mathbb R`, not the group logarithm of
Sim(3) (Strasdat et al., *Scale drift-aware large scale monocular SLAM*, RSS 2010, use the latter);
both vanish only at the identity, so a pose graph whose edges are all consistent has the same
minimiser either way, and near it the two differ at second order.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from jaxtyping import Array, Float

__all__ = ["Sim3"]


def _batched(fn: Callable[..., Any], *args: Any, ndim: int | None = None) -> Any:
    """``fn`` on unbatched ``jaxlie`` groups / vectors, mapped over the leading batch axes of ``args[0]``.

    ``jaxlie`` 1.5's group products broadcast with implicit rank promotion, which this project turns
    into an error; mapping keeps every operation at its documented rank.
    """
    if ndim is None:
        first = args[0]
        ndim = first.wxyz.ndim - 1 if isinstance(first, jaxlie.SO3) else first.ndim - 1
    for _ in range(ndim):
        fn = jax.vmap(fn)
    return fn(*args)


@struct.dataclass
class Sim3:
    """``x ↦ exp(log_scale)·R x + t`` with batch axes ``*b`` in front of every field."""

    rotation: jaxlie.SO3
    translation: Float[Array, "*b 3"]
    log_scale: Float[Array, "*b"]

    @staticmethod
    def identity(batch_shape: tuple[int, ...] = (), dtype: jnp.dtype | type = jnp.float32) -> "Sim3":
        """The identity, broadcast to ``batch_shape``."""
        wxyz = jnp.broadcast_to(jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype), (*batch_shape, 4))
        return Sim3(jaxlie.SO3(wxyz), jnp.zeros((*batch_shape, 3), dtype), jnp.zeros(batch_shape, dtype))

    @staticmethod
    def from_se3(T: jaxlie.SE3, log_scale: Float[Array, "*b"] | float = 0.0) -> "Sim3":
        """The rigid transform ``T`` with scale ``exp(log_scale)`` (``0``: ``T`` itself)."""
        t = T.translation()
        return Sim3(T.rotation(), t, jnp.broadcast_to(jnp.asarray(log_scale, t.dtype), t.shape[:-1]))

    @staticmethod
    def from_matrix(M: Float[Array, "*b 4 4"] | np.ndarray) -> "Sim3":
        """From ``[[sR, t], [0, 1]]`` (``s = cbrt(det(sR))``, ``R = sR / s``)."""
        M = jnp.asarray(M)
        sR = M[..., :3, :3]
        s = jnp.cbrt(jnp.linalg.det(sR))
        R = sR / s[..., None, None]
        return Sim3(_batched(jaxlie.SO3.from_matrix, R, ndim=R.ndim - 2), M[..., :3, 3], jnp.log(s))

    def scale(self) -> Float[Array, "*b"]:
        return jnp.exp(self.log_scale)

    def to_se3(self) -> jaxlie.SE3:
        """The rigid part ``(R, t)`` (the scale dropped)."""
        return jaxlie.SE3.from_rotation_and_translation(self.rotation, self.translation)

    def as_matrix(self) -> Float[Array, "*b 4 4"]:
        """``[[sR, t], [0, 1]]``."""
        sR = _batched(lambda R: R.as_matrix(), self.rotation) * self.scale()[..., None, None]
        top = jnp.concatenate([sR, self.translation[..., :, None]], axis=-1)
        bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], sR.dtype), (*sR.shape[:-2], 1, 4))
        return jnp.concatenate([top, bottom], axis=-2)

    def apply(self, x: Float[Array, "*b 3"]) -> Float[Array, "*b 3"]:
        """``s R x + t``."""
        return self.scale()[..., None] * _batched(lambda R, p: R.apply(p), self.rotation, x) + self.translation

    def __matmul__(self, other: "Sim3") -> "Sim3":
        """Composition ``self ∘ other`` (apply ``other`` first)."""
        return Sim3(
            _batched(lambda a, b: a @ b, self.rotation, other.rotation),
            self.apply(other.translation),
            self.log_scale + other.log_scale,
        )

    def inverse(self) -> "Sim3":
        R_inv = _batched(lambda R: R.inverse(), self.rotation)
        t = _batched(lambda R, x: R.apply(x), R_inv, self.translation)
        return Sim3(R_inv, -jnp.exp(-self.log_scale)[..., None] * t, -self.log_scale)

    def log_chart(self) -> Float[Array, "*b 7"]:
        """``(log R, t, log s)``: the residual chart of the pose graph (see the module docstring)."""
        log_R = _batched(lambda R: R.log(), self.rotation)
        return jnp.concatenate([log_R, self.translation, self.log_scale[..., None]], axis=-1)

    def retract(self, delta: Float[Array, "*b 7"]) -> "Sim3":
        """``(exp(ω) R, t + v, log s + σ)`` for ``delta = (ω, v, σ)``."""
        return Sim3(
            _batched(lambda w, R: jaxlie.SO3.exp(w) @ R, delta[..., :3], self.rotation),
            self.translation + delta[..., 3:6],
            self.log_scale + delta[..., 6],
        )

    def __getitem__(self, index) -> "Sim3":
        """Index the batch axes (``S[i]``, ``S[idx_array]``)."""
        return jax.tree.map(lambda a: a[index], self)
