"""EdgeConnect networks in Flax NNX (NHWC).

Source: Nazeri et al., "EdgeConnect: Generative Image Inpainting with Adversarial Edge
Learning", ICCVW 2019, and the official code ``knazeri/edge-connect`` ``src/networks.py``
(re-implemented here, not copied). Topology, at ``width = w`` (official ``w = 64``):

* generators: ReflPad3 → Conv7×7/w → IN → ReLU → Conv4×4 s2 p1 /2w → IN → ReLU →
  Conv4×4 s2 p1 /4w → IN → ReLU → ``num_residual_blocks`` × ResnetBlock(4w, dilation 2) →
  ConvT4×4 s2 p1 /2w → IN → ReLU → ConvT4×4 s2 p1 /w → IN → ReLU → ReflPad3 → Conv7×7 →
  ``sigmoid`` (edge, 1 channel) or ``(tanh + 1) / 2`` (image, 3 channels).
  IN = instance norm without affine parameters (eps 1e-5, biased variance).
* ResnetBlock: ReflPad(d) → Conv3×3 dilation d → IN → ReLU → ReflPad1 → Conv3×3 → IN, plus
  the identity (no ReLU after the sum). Its convs carry a bias only without spectral norm.
* EdgeGenerator: spectral norm on every conv except the last 7×7 (the encoder/decoder convs
  keep their bias, the residual convs have none). InpaintGenerator: no spectral norm.
* Discriminator (PatchGAN): Conv4×4 s2 p1 /w, /2w, /4w, then s1 /8w, s1 /1, LeakyReLU 0.2
  after all but the last, spectral norm and no bias; returns ``(out, [f1..f5])`` where ``out``
  is ``sigmoid(f5)`` for the edge discriminator and ``f5`` for the inpaint one.

Spectral norm (Miyato et al. 2018; torch ``nn.utils.spectral_norm``): the applied kernel is
``W / σ`` with ``σ = uᵀ W v`` and ``W`` the torch-layout weight reshaped to ``(out, −1)``
(transposed convs normalise dim 1, i.e. their *output* channels). In training mode one power
iteration ``v ← normalise(Wᵀu), u ← normalise(W v)`` updates the ``SpectralState``
variables first (no gradient through ``u, v``); in eval mode (``module.eval()``, which sets
``use_running_average=True``) the stored ``u, v`` are used, as torch does in ``eval()``.

Full-width parameter counts (trainable, equal to the official torch counts):
EdgeGenerator 10,761,089; InpaintGenerator 10,774,595; edge discriminator (2 ch) 2,762,752;
inpaint discriminator (3 ch) 2,763,776.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float

__all__ = [
    "CPU_WIDTH",
    "Conv",
    "Discriminator",
    "EdgeGenerator",
    "InpaintGenerator",
    "ResnetBlock",
    "SpectralState",
    "count_params",
    "instance_norm",
]

CPU_WIDTH = 16
"""Width of the CPU preset (official EdgeConnect: 64)."""

_INIT_STD = 0.02  # official init_weights('normal', gain=0.02), biases zero


class SpectralState(nnx.Variable):
    """Power-iteration vectors ``u`` (out) and ``v`` (in·kh·kw) of spectral norm; not trained."""


def _host_normal(key: jax.Array, shape: tuple[int, ...], std: float = 1.0) -> jax.Array:
    """N(0, std²) drawn on the host by a numpy generator seeded from ``key``.

    Deterministic for the key, and it avoids compiling one XLA random kernel per weight shape
    (which dominated model construction time on CPU).
    """
    seed = np.asarray(jax.random.key_data(key)).astype(np.uint32).ravel()
    return jnp.asarray(np.random.default_rng(seed).normal(0.0, std, shape).astype(np.float32))


def _normalise(x: Float[Array, " n"], eps: float = 1e-12) -> Float[Array, " n"]:
    return x / jnp.maximum(jnp.linalg.norm(x), eps)


def instance_norm(x: Float[Array, "B H W C"], eps: float = 1e-5) -> Float[Array, "B H W C"]:
    """``InstanceNorm2d(affine=False, track_running_stats=False)``: per sample and channel."""
    mean = jnp.mean(x, axis=(1, 2), keepdims=True)
    var = jnp.mean(jnp.square(x - mean), axis=(1, 2), keepdims=True)
    return (x - mean) * jax.lax.rsqrt(var + eps)


def _reflect(x: Float[Array, "B H W C"], p: int) -> Float[Array, "B H2 W2 C"]:
    return jnp.pad(x, ((0, 0), (p, p), (p, p), (0, 0)), mode="reflect")


class Conv(nnx.Module):
    """2-D (transposed) convolution, NHWC, kernel stored HWIO, optional spectral norm.

    For ``transpose=True`` this is torch ``ConvTranspose2d(in, out, k, stride, padding)``:
    output size ``(n − 1)·stride − 2·padding + k``, computed as an input-dilated convolution
    with the spatially flipped kernel and padding ``k − 1 − padding``.
    """

    def __init__(
        self,
        in_features: int,
        out_features: int,
        kernel_size: int,
        *,
        stride: int = 1,
        padding: int = 0,
        dilation: int = 1,
        use_bias: bool = True,
        spectral_norm: bool = False,
        transpose: bool = False,
        rngs: nnx.Rngs,
    ):
        self.in_features = in_features
        self.out_features = out_features
        self.kernel_size = kernel_size
        self.stride = stride
        self.padding = padding
        self.dilation = dilation
        self.transpose = transpose
        self.spectral_norm = spectral_norm
        self.use_running_average = False
        k = kernel_size
        self.kernel = nnx.Param(
            _host_normal(rngs.params(), (k, k, in_features, out_features), _INIT_STD)
        )
        self.bias = nnx.Param(jnp.asarray(np.zeros((out_features,), np.float32))) if use_bias else None
        if spectral_norm:
            u = np.asarray(_host_normal(rngs.params(), (out_features,)))
            v = np.asarray(_host_normal(rngs.params(), (in_features * k * k,)))
            self.u = SpectralState(jnp.asarray(u / np.linalg.norm(u)))
            self.v = SpectralState(jnp.asarray(v / np.linalg.norm(v)))
        else:
            self.u = None
            self.v = None

    def weight_matrix(self) -> Float[Array, "O K"]:
        """Kernel in torch layout reshaped to ``(out, in·kh·kw)`` (the matrix σ is taken of)."""
        return jnp.transpose(self.kernel[...], (3, 2, 0, 1)).reshape(self.out_features, -1)

    def sigma(self) -> Float[Array, ""]:
        """``σ = uᵀ W v`` with the stored ``u, v`` (torch's eval-mode value)."""
        if self.u is None or self.v is None:
            raise ValueError("sigma() needs spectral_norm=True")
        w = self.weight_matrix()
        u = jax.lax.stop_gradient(self.u[...])
        v = jax.lax.stop_gradient(self.v[...])
        return jnp.dot(u, w @ v)

    def __call__(self, x: Float[Array, "B H W Ci"]) -> Float[Array, "B H2 W2 Co"]:
        kernel = self.kernel[...]
        if self.spectral_norm:
            assert self.u is not None and self.v is not None
            if not self.use_running_average:
                w = jax.lax.stop_gradient(self.weight_matrix())
                v = _normalise(w.T @ self.u[...])
                u = _normalise(w @ v)
                self.v[...] = v
                self.u[...] = u
            kernel = kernel / self.sigma()
        dn = ("NHWC", "HWIO", "NHWC")
        if self.transpose:
            q = self.kernel_size - 1 - self.padding
            y = jax.lax.conv_general_dilated(
                x,
                jnp.flip(kernel, (0, 1)),
                window_strides=(1, 1),
                padding=((q, q), (q, q)),
                lhs_dilation=(self.stride, self.stride),
                dimension_numbers=dn,
            )
        else:
            p = self.padding
            y = jax.lax.conv_general_dilated(
                x,
                kernel,
                window_strides=(self.stride, self.stride),
                padding=((p, p), (p, p)),
                rhs_dilation=(self.dilation, self.dilation),
                dimension_numbers=dn,
            )
        if self.bias is not None:
            y = y + self.bias[...][None, None, None, :]
        return y


class ResnetBlock(nnx.Module):
    """``x + IN(Conv3×3(pad1(ReLU(IN(Conv3×3_d(pad_d(x)))))))`` (official ResnetBlock)."""

    def __init__(self, dim: int, dilation: int = 2, *, spectral_norm: bool, rngs: nnx.Rngs):
        self.dilation = dilation
        kw = dict(use_bias=not spectral_norm, spectral_norm=spectral_norm, rngs=rngs)
        self.conv1 = Conv(dim, dim, 3, dilation=dilation, **kw)
        self.conv2 = Conv(dim, dim, 3, **kw)

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W C"]:
        y = jax.nn.relu(instance_norm(self.conv1(_reflect(x, self.dilation))))
        y = instance_norm(self.conv2(_reflect(y, 1)))
        return x + y


class _Generator(nnx.Module):
    """Shared encoder / residual middle / decoder of both EdgeConnect generators."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        *,
        num_residual_blocks: int,
        width: int,
        spectral_norm: bool,
        rngs: nnx.Rngs,
    ):
        if num_residual_blocks < 0 or width < 1:
            raise ValueError(f"need num_residual_blocks >= 0 and width >= 1, got {num_residual_blocks}, {width}")
        w, sn = width, spectral_norm
        self.width = width
        self.num_residual_blocks = num_residual_blocks
        self.enc1 = Conv(in_channels, w, 7, spectral_norm=sn, rngs=rngs)
        self.enc2 = Conv(w, 2 * w, 4, stride=2, padding=1, spectral_norm=sn, rngs=rngs)
        self.enc3 = Conv(2 * w, 4 * w, 4, stride=2, padding=1, spectral_norm=sn, rngs=rngs)
        self.middle = nnx.List(
            [ResnetBlock(4 * w, 2, spectral_norm=sn, rngs=rngs) for _ in range(num_residual_blocks)]
        )
        self.dec1 = Conv(4 * w, 2 * w, 4, stride=2, padding=1, spectral_norm=sn, transpose=True, rngs=rngs)
        self.dec2 = Conv(2 * w, w, 4, stride=2, padding=1, spectral_norm=sn, transpose=True, rngs=rngs)
        self.dec3 = Conv(w, out_channels, 7, rngs=rngs)  # never spectral-normalised

    def logits(self, x: Float[Array, "B H W Ci"]) -> Float[Array, "B H W Co"]:
        h, w = x.shape[1], x.shape[2]
        y = jax.nn.relu(instance_norm(self.enc1(_reflect(x, 3))))
        y = jax.nn.relu(instance_norm(self.enc2(y)))
        y = jax.nn.relu(instance_norm(self.enc3(y)))
        for block in self.middle:
            y = block(y)
        y = jax.nn.relu(instance_norm(self.dec1(y)))
        y = jax.nn.relu(instance_norm(self.dec2(y)))
        y = self.dec3(_reflect(y, 3))
        # official output_align: replicate-pad when H or W is not a multiple of 4
        return jnp.pad(y, ((0, 0), (0, h - y.shape[1]), (0, w - y.shape[2]), (0, 0)), mode="edge")


class EdgeGenerator(_Generator):
    """Edge generator: input ``(grey_masked, edges_masked, mask)``, output edge probability."""

    def __init__(
        self,
        *,
        num_residual_blocks: int = 8,
        width: int = 64,
        spectral_norm: bool = True,
        rngs: nnx.Rngs,
    ):
        super().__init__(
            3, 1, num_residual_blocks=num_residual_blocks, width=width, spectral_norm=spectral_norm, rngs=rngs
        )

    def __call__(self, x: Float[Array, "B H W 3"]) -> Float[Array, "B H W 1"]:
        return jax.nn.sigmoid(self.logits(x))


class InpaintGenerator(_Generator):
    """Image generator: input ``(rgb_masked, edges)``, output RGB in [0, 1]."""

    def __init__(self, *, num_residual_blocks: int = 8, width: int = 64, rngs: nnx.Rngs):
        super().__init__(
            4, 3, num_residual_blocks=num_residual_blocks, width=width, spectral_norm=False, rngs=rngs
        )

    def __call__(self, x: Float[Array, "B H W 4"]) -> Float[Array, "B H W 3"]:
        return (jnp.tanh(self.logits(x)) + 1.0) / 2.0


class Discriminator(nnx.Module):
    """PatchGAN discriminator returning ``(output, [features1..features5])``."""

    def __init__(
        self,
        in_channels: int,
        *,
        use_sigmoid: bool,
        width: int = 64,
        spectral_norm: bool = True,
        rngs: nnx.Rngs,
    ):
        w, sn = width, spectral_norm
        self.use_sigmoid = use_sigmoid
        chans = [in_channels, w, 2 * w, 4 * w, 8 * w, 1]
        strides = [2, 2, 2, 1, 1]
        self.convs = nnx.List(
            [
                Conv(chans[i], chans[i + 1], 4, stride=strides[i], padding=1, use_bias=not sn, spectral_norm=sn, rngs=rngs)
                for i in range(5)
            ]
        )

    def __call__(
        self, x: Float[Array, "B H W C"]
    ) -> tuple[Float[Array, "B h w 1"], list[Float[Array, "B _ _ _"]]]:
        feats = []
        y = x
        for i, conv in enumerate(self.convs):
            y = conv(y)
            if i < 4:
                y = jax.nn.leaky_relu(y, 0.2)
            feats.append(y)
        out = jax.nn.sigmoid(y) if self.use_sigmoid else y
        return out, feats


def count_params(module: nnx.Module) -> int:
    """Number of trainable scalars (``nnx.Param``), as torch's ``sum(p.numel())``."""
    return int(sum(x.size for x in jax.tree.leaves(nnx.state(module, nnx.Param))))
