"""Function-preserving widening of an EdgeConnect generator (Net2WiderNet).

Source: Chen, Goodfellow & Shlens, "Net2Net: Accelerating Learning via Knowledge Transfer",
ICLR 2016, §2.1. A layer of width ``w`` becomes one of width ``w' > w`` by a map
``g: {0..w'−1} → {0..w−1}`` (``g(j) = j`` for ``j < w``, the new channels copy distinct random
old ones). Each conv's new kernel and bias are

    K'[:, :, a, b] = K[:, :, g_in(a), g_out(b)] · f(a),      bias'[b] = bias[g_out(b)],

where the split fractions ``f`` of the copies of one input channel sum to 1. Copies of a channel
then carry equal values through every per-channel operation of the generator (instance norm
without affine parameters, ReLU, the residual sum), so the next layer sees the old sum and the
output is unchanged. The residual stream (``enc3``, each block's ``conv2`` output and the skip)
uses one map for all blocks, so ``x + y`` adds matching channels.

Departures: Net2Net splits a copied unit's outgoing weights equally; here the two copies of a
channel get fractions ``(u, 1 − u)``, ``u ~ U(0.25, 0.75)``, and the copies' incoming weights get
a little noise (``noise`` × the kernel's standard deviation), because with equal splits and no
noise the copies receive proportional gradients, which Adam turns into identical updates, and
would never differ. ``noise=0`` preserves the function exactly (up to float rounding).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import nnx

from privslam_jax.inpaint.edgeconnect import Conv, InpaintGenerator

__all__ = ["widen_inpaint_generator"]


def _channel_map(old: int, new: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``(g, f)``: source channel and split fraction of each of ``new`` channels (``new ≤ 2·old``)."""
    extra = rng.choice(old, size=new - old, replace=False)
    g = np.concatenate([np.arange(old), extra])
    f = np.ones(new)
    u = rng.uniform(0.25, 0.75, size=new - old)
    f[extra], f[old:] = u, 1.0 - u
    return g, f


def _widen_conv(conv: Conv, g_in: np.ndarray, f_in: np.ndarray, g_out: np.ndarray, noise: float,
                rng: np.random.Generator) -> None:
    kernel = np.asarray(conv.kernel[...], np.float64)
    new = kernel[:, :, g_in][:, :, :, g_out] * f_in[None, None, :, None]
    copied = np.arange(len(g_out)) >= kernel.shape[3]  # output channels that are new copies
    if noise and copied.any():
        new[..., copied] += rng.normal(0.0, noise * kernel.std(), new[..., copied].shape)
    conv.kernel = nnx.Param(jnp.asarray(new, jnp.float32))
    conv.in_features, conv.out_features = len(g_in), len(g_out)
    if conv.bias is not None:
        conv.bias = nnx.Param(jnp.asarray(np.asarray(conv.bias[...])[g_out]))


def widen_inpaint_generator(gen: InpaintGenerator, width: int, *, seed: int = 0,
                            noise: float = 0.01) -> InpaintGenerator:
    """A copy of ``gen`` at channel width ``width`` (``gen.width ≤ width ≤ 2·gen.width``) computing
    the same function (exactly for ``noise=0``; module docstring). The stored ``width`` becomes ``width``."""
    w = gen.width
    if not w <= width <= 2 * w:
        raise ValueError(f"can widen a width-{w} generator to {w}..{2 * w} channels, not {width}")
    rng = np.random.default_rng(seed)
    out = nnx.clone(gen)
    ident = lambda n: (np.arange(n), np.ones(n))  # noqa: E731
    g1, f1 = _channel_map(w, width, rng)
    g2, f2 = _channel_map(2 * w, 2 * width, rng)
    g4, f4 = _channel_map(4 * w, 4 * width, rng)
    gi, fi = ident(out.enc1.in_features)
    _widen_conv(out.enc1, gi, fi, g1, noise, rng)
    _widen_conv(out.enc2, g1, f1, g2, noise, rng)
    _widen_conv(out.enc3, g2, f2, g4, noise, rng)
    for block in out.middle:  # the stream and each block's inner channels share the map g4
        _widen_conv(block.conv1, g4, f4, g4, noise, rng)
        _widen_conv(block.conv2, g4, f4, g4, noise, rng)
    _widen_conv(out.dec1, g4, f4, g2, noise, rng)
    _widen_conv(out.dec2, g2, f2, g1, noise, rng)
    _widen_conv(out.dec3, g1, f1, ident(out.dec3.out_features)[0], noise, rng)
    out.width = width
    return out
