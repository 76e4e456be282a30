"""Robust losses of a whitened squared error (one copy for every solver).

For a residual ``e`` with information ``Ω`` the whitened squared error is ``s = Ω‖e‖²`` and a robust
cost is ``ρ(s)``.  The Huber loss (g2o's ``RobustKernelHuber``; scipy's ``loss="huber"`` with
``f_scale = δ`` applied to ``‖e‖``) is

    ρ(s) = s               if s ≤ δ²
           2δ√s − δ²       otherwise,          ρ'(s) = min(1, δ/√s),

and ``δ = +inf`` gives the squared loss.  Iteratively reweighted least squares uses the weight
``ρ'(s)`` (Triggs et al., *Bundle Adjustment — A Modern Synthesis*, §4.3): with it the Gauss–Newton
gradient ``Σ ρ' Ω Jᵀe`` is the exact gradient of ``½ Σ ρ(s)``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["huber_rho", "huber_weight"]


def huber_rho(s: Float[Array, "*b"], delta: Array | float) -> Float[Array, "*b"]:
    """Huber loss of a squared (whitened) error: ``s`` if ``s ≤ δ²`` else ``2δ√s − δ²``."""
    safe = jnp.maximum(s, delta * delta)
    return jnp.where(s <= delta * delta, s, 2.0 * delta * jnp.sqrt(safe) - delta * delta)


def huber_weight(s: Float[Array, "*b"], delta: Array | float) -> Float[Array, "*b"]:
    """The IRLS weight ``ρ'(s) = min(1, δ/√s)`` of :func:`huber_rho`."""
    safe = jnp.maximum(s, delta * delta)
    return jnp.where(s <= delta * delta, 1.0, delta / jnp.sqrt(safe))
