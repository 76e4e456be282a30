"""Damped normal equations solved densely (small problems, e.g. one pose).

``(H + λ D) δ = −g`` with ``D = diag(H)`` clamped to [1e-6, 1e32] (Marquardt's scaling; the clamp as
in Ceres), factorised by Cholesky.  The predicted decrease of the Gauss–Newton model
``m(δ) = F + gᵀδ + ½ δᵀHδ`` at that step is ``F − m(δ) = ½ δᵀ(λ D δ − g)`` (Madsen et al. 2004, eq. 3.14).
The Schur-complement form for bundle adjustment is :mod:`privslam_jax.solvers.schur`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from jaxtyping import Array, Float

__all__ = ["DenseSystem", "dense_damped_solve"]


@struct.dataclass
class DenseSystem:
    """Normal equations ``H δ = −g`` of a linearisation, with the cost at that point."""

    H: Float[Array, "n n"]
    g: Float[Array, " n"]
    cost: Float[Array, ""]


def dense_damped_solve(system: DenseSystem, lam: Float[Array, ""]) -> tuple[Float[Array, " n"], Float[Array, ""]]:
    """The Levenberg–Marquardt step and its predicted cost decrease (see the module docstring)."""
    d = jnp.clip(jnp.diagonal(system.H), 1e-6, 1e32)
    L = jnp.linalg.cholesky(system.H + jnp.diag(lam * d))
    step = jax.scipy.linalg.cho_solve((L, True), -system.g)
    return step, 0.5 * jnp.dot(step, lam * d * step - system.g)
