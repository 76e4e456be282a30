"""EdgeConnect losses (official ``src/loss.py`` / ``src/models.py`` semantics, in JAX).

* Non-saturating GAN ("nsgan", binary cross-entropy on logits):
  ``L_D = ½[BCE(D(real), 1) + BCE(D(fake), 0)]``, ``L_G,adv = BCE(D(fake), 1)``.
  The official discriminators apply ``sigmoid`` and ``nn.BCELoss``; using the pre-sigmoid
  logits (``features5``) with a log-sigmoid is the same loss, numerically stable.
* Feature matching (edge generator): ``Σ_i mean|D_i(real) − D_i(fake)|`` over the five
  discriminator feature maps, real features held constant.
* L1 (inpaint generator): ``mean|ŷ − y| / mean(M)`` over the whole image, ``M`` = hole mask.
* Perceptual (content): ``Σ_i w_i mean|φ_i(ŷ) − φ_i(y)|`` over feature maps of a frozen network φ.
* Style: ``Σ_j mean|G(φ_j(ŷ·M)) − G(φ_j(y·M))|`` with the Gram matrix
  ``G(F) = FᵀF / (H·W·C)`` of a ``(H, W, C)`` feature map (official: style on masked images).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Float

__all__ = [
    "discriminator_loss",
    "feature_matching_loss",
    "generator_adversarial_loss",
    "gram",
    "l1_hole_loss",
    "masked_hole_loss",
    "perceptual_loss",
    "style_loss",
]


def _bce_logits(logits: ArrayLike, target: float) -> Float[Array, ""]:
    """Mean binary cross-entropy of ``sigmoid(logits)`` against a constant label."""
    logits = jnp.asarray(logits)
    return -jnp.mean(target * jax.nn.log_sigmoid(logits) + (1.0 - target) * jax.nn.log_sigmoid(-logits))


def discriminator_loss(real_logits: ArrayLike, fake_logits: ArrayLike) -> Float[Array, ""]:
    """``½[BCE(real, 1) + BCE(fake, 0)]``."""
    return 0.5 * (_bce_logits(real_logits, 1.0) + _bce_logits(fake_logits, 0.0))


def generator_adversarial_loss(fake_logits: ArrayLike) -> Float[Array, ""]:
    """Non-saturating generator loss ``BCE(D(fake), 1) = −mean log σ(D(fake))``."""
    return _bce_logits(fake_logits, 1.0)


def feature_matching_loss(real_feats: Sequence[ArrayLike], fake_feats: Sequence[ArrayLike]) -> Float[Array, ""]:
    """``Σ_i mean|D_i(real) − D_i(fake)|`` with the real features as constants."""
    if len(real_feats) != len(fake_feats):
        raise ValueError("feature lists differ in length")
    return sum(
        (jnp.mean(jnp.abs(jax.lax.stop_gradient(jnp.asarray(r)) - jnp.asarray(f))) for r, f in zip(real_feats, fake_feats, strict=True)),
        jnp.zeros(()),
    )


def l1_hole_loss(output: ArrayLike, target: ArrayLike, hole: ArrayLike) -> Float[Array, ""]:
    """``mean|output − target| / mean(hole)`` (official; guards an empty hole)."""
    output, target, hole = jnp.asarray(output), jnp.asarray(target), jnp.asarray(hole)
    return jnp.mean(jnp.abs(output - target)) / jnp.maximum(jnp.mean(hole), 1e-6)


def masked_hole_loss(output: ArrayLike, target: ArrayLike, hole: ArrayLike, power: int = 2) -> Float[Array, ""]:
    """``Σ hole·|output − target|^power / Σ hole`` over pixels and channels: the error **inside** the
    hole only (the filter pastes nothing else). ``power=2`` is the MSE that PSNR measures, whose
    minimiser is the conditional mean; ``power=1`` the median."""
    output, target, hole = jnp.asarray(output), jnp.asarray(target), jnp.asarray(hole)
    err = jnp.abs(output - target) ** power * hole
    return jnp.sum(err) / jnp.maximum(jnp.sum(hole) * output.shape[-1], 1e-6)


def gram(f: ArrayLike) -> Float[Array, "B C C"]:
    """Gram matrix ``FᵀF / (H·W·C)`` per sample of ``(B, H, W, C)`` features."""
    f = jnp.asarray(f)
    b, h, w, c = f.shape
    x = f.reshape(b, h * w, c)
    return jnp.einsum("bnc,bnd->bcd", x, x) / (h * w * c)


def perceptual_loss(
    out_feats: Sequence[ArrayLike], target_feats: Sequence[ArrayLike], weights: Sequence[float] | None = None
) -> Float[Array, ""]:
    """``Σ_i w_i mean|φ_i(ŷ) − φ_i(y)|`` (official weights all 1)."""
    weights = [1.0] * len(out_feats) if weights is None else list(weights)
    return sum(
        (w * jnp.mean(jnp.abs(jnp.asarray(a) - jnp.asarray(b))) for w, a, b in zip(weights, out_feats, target_feats, strict=True)),
        jnp.zeros(()),
    )


def style_loss(out_feats: Sequence[ArrayLike], target_feats: Sequence[ArrayLike]) -> Float[Array, ""]:
    """``Σ_j mean|G(φ_j(ŷ)) − G(φ_j(y))|``."""
    return sum(
        (jnp.mean(jnp.abs(gram(a) - gram(b))) for a, b in zip(out_feats, target_feats, strict=True)),
        jnp.zeros(()),
    )
