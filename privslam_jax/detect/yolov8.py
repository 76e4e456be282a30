"""YOLOv8 detection network in Flax NNX (NHWC, float32), as ultralytics ``yolov8.yaml``.

Architecture (Jocher et al., ultralytics ``cfg/models/v8/yolov8.yaml``; module definitions in
``ultralytics/nn/modules/{conv,block,head}.py``):

* ``Conv`` = Conv2d (no bias, padding ``k // 2``, ``g`` groups) → BatchNorm (eps 1e-3, torch
  momentum 0.03) → SiLU (or no activation, ``act=False``); ``DWConv`` = Conv with ``gcd(c1, c2)``
  groups (depthwise).
* ``C2f(c1, c2, n, shortcut)``: ``cv1`` 1×1 to ``2c`` (``c = c2 / 2``), split in two halves
  ``y0, y1``; ``n`` Bottlenecks (two 3×3 Convs, residual when ``shortcut`` and ``c_in == c_out``)
  applied in a chain to the last half, every intermediate kept; ``cv2`` 1×1 over the
  concatenation of the ``2 + n`` pieces.
* ``SPPF(k=5)``: ``cv1`` 1×1 to ``c1 / 2``, three chained 5×5 stride-1 max pools (padding 2,
  −∞ fill), ``cv2`` 1×1 over the four maps.
* Backbone: Conv 3×3/2 (P1), Conv 3×3/2 (P2), C2f×3, Conv/2 (P3), C2f×6, Conv/2 (P4), C2f×6,
  Conv/2 (P5), C2f×3, SPPF. Neck (PAN): upsample ×2 (nearest) ⊕ P4 → C2f; upsample ⊕ P3 → C2f
  (out P3); Conv/2 ⊕ → C2f (out P4); Conv/2 ⊕ SPPF → C2f (out P5); neck C2f have no shortcut.
* Decoupled anchor-free ``Detect`` head on P3/P4/P5 (strides 8/16/32): per level a box branch
  (Conv 3×3 → Conv 3×3 → Conv2d 1×1 to ``4·reg_max``, with bias) and a class branch (same with
  ``nc`` outputs), ``c2 = max(16, ch_P3 / 4, 4·reg_max)``, ``c3 = max(ch_P3, min(nc, 100))``.
  DFL (``reg_max = 16``) is a fixed softmax expectation, see :mod:`privslam_jax.detect.decode`.
  ``legacy=False`` (YOLO11, :mod:`privslam_jax.detect.yolo11`): the class branch is
  ``[DWConv 3×3, Conv 1×1 → c3]``, ``[DWConv 3×3, Conv 1×1]``, Conv2d 1×1 to ``nc``.
* Scales ``(depth, width, max_channels)``: n (0.33, 0.25, 1024), s (0.33, 0.50, 1024),
  m (0.67, 0.75, 768), l (1.0, 1.0, 512), x (1.0, 1.25, 512); channels
  ``ceil(min(c, max_ch)·width / 8)·8``, repeats ``max(round(n·depth), 1)``.

The network returns the three raw head maps ``(B, H_l, W_l, 4·reg_max + nc)`` (box DFL logits,
then class logits, as torch's ``cat(cv2, cv3)`` along channels). Attribute names follow the
ultralytics ``state_dict`` inside each block (``cv1``, ``cv2``, ``m``, ``conv``, ``bn``); the
top-level layer index of the torch model maps to the names in :data:`TORCH_LAYER_NAMES`.

Departures: BatchNorm in training uses the biased batch variance for the running average (torch
uses the unbiased one); weights are initialised like torch's defaults (kaiming-uniform
``a = √5``) plus ultralytics' ``Detect.bias_init``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float

from privslam_jax.detect.rgb_stem import rgb_stem

__all__ = ["YOLOv8", "YOLOv8Config", "SCALES", "TORCH_LAYER_NAMES", "count_parameters", "init_yolov8", "abstract_yolov8",
           "abstract_model", "fuse_batchnorm", "Conv", "DWConv", "Bottleneck", "C2f", "SPPF", "Detect"]

SCALES: dict[str, tuple[float, float, int]] = {
    "n": (0.33, 0.25, 1024),
    "s": (0.33, 0.50, 1024),
    "m": (0.67, 0.75, 768),
    "l": (1.00, 1.00, 512),
    "x": (1.00, 1.25, 512),
    "tiny": (0.33, 0.0625, 1024),
}
"""``scale -> (depth multiple, width multiple, max channels)`` from ``yolov8.yaml``; ``tiny`` (not in
the yaml: 8-64 channels) is a test-only variant for fast training tests."""

TORCH_LAYER_NAMES: dict[int, str] = {
    0: "stem", 1: "down1", 2: "c2f1", 3: "down2", 4: "c2f2", 5: "down3", 6: "c2f3", 7: "down4",
    8: "c2f4", 9: "sppf", 12: "neck4", 15: "neck3", 16: "pan_down3", 18: "pan4", 19: "pan_down4",
    21: "pan5", 22: "detect",
}
"""Index ``i`` of ultralytics ``model.model[i]`` → attribute of :class:`YOLOv8` (10, 13 are
Upsample, 11, 14, 17, 20 Concat: no parameters)."""

STRIDES: tuple[int, int, int] = (8, 16, 32)

# torch's default Conv2d init: kaiming_uniform(a=sqrt(5)) = U(±1/sqrt(fan_in)).
_torch_kernel_init = nnx.initializers.variance_scaling(1.0 / 3.0, "fan_in", "uniform")


@dataclasses.dataclass(frozen=True)
class YOLOv8Config:
    """Network hyper-parameters."""

    scales: ClassVar[dict[str, tuple[float, float, int]]] = SCALES
    """The family's ``scale -> (depth, width, max channels)`` table."""
    arch: ClassVar[str] = "yolov8"
    """Architecture name recorded in checkpoints."""

    num_classes: int = 80
    """Number of object classes ``nc`` (COCO: 80)."""
    scale: str = "n"
    """Model scale, one of ``n s m l x`` (depth/width multiples from ``yolov8.yaml``) or ``tiny`` (tests)."""
    reg_max: int = 16
    """DFL bins per box side."""

    def __post_init__(self) -> None:
        if self.scale not in self.scales:
            raise ValueError(f"unknown {self.arch} scale {self.scale!r}; choose one of {sorted(self.scales)}")
        if self.num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {self.num_classes}")

    def channels(self, c: int) -> int:
        """Scaled channel count ``ceil(min(c, max_ch)·width / 8)·8``."""
        _, width, max_ch = self.scales[self.scale]
        return int(math.ceil(min(c, max_ch) * width / 8) * 8)

    def depth(self, n: int) -> int:
        """Scaled repeat count ``max(round(n·depth), 1)``."""
        return max(round(n * self.scales[self.scale][0]), 1) if n > 1 else n


class Conv(nnx.Module):
    """Conv2d (no bias, padding ``k//2``, ``g`` groups) → BatchNorm(eps 1e-3) → SiLU (if ``act``).

    Once BatchNorm is folded (:func:`fuse_batchnorm`), the 3×3/2 convolution of a 3-channel image
    (the stem) runs :func:`privslam_jax.detect.rgb_stem.rgb_stem`, a native CPU kernel 3× faster than
    XLA's convolution there, differentiable through the XLA formulation.
    """

    def __init__(self, c1: int, c2: int, k: int = 1, s: int = 1, g: int = 1, act: bool = True, *, rngs: nnx.Rngs):
        p = k // 2
        self.act = act
        self.conv = nnx.Conv(c1, c2, (k, k), (s, s), padding=((p, p), (p, p)), use_bias=False,
                             feature_group_count=g, kernel_init=_torch_kernel_init, rngs=rngs)
        # flax momentum m: ra <- m·ra + (1-m)·batch; torch momentum 0.03 -> m = 0.97.
        self.bn = nnx.BatchNorm(c2, epsilon=1e-3, momentum=0.97, rngs=rngs)

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B h w D"]:
        if (self.bn is None and self.act and x.shape[-1] == 3 and self.conv.kernel_size == (3, 3)
                and self.conv.strides == (2, 2) and self.conv.feature_group_count == 1):
            return rgb_stem(x, self.conv.kernel[...], self.conv.bias[...])  # folded stem: native CPU kernel
        y = self.conv(x)
        y = y if self.bn is None else self.bn(y)  # bn is None once folded
        return jax.nn.silu(y) if self.act else y


def DWConv(c1: int, c2: int, k: int = 1, s: int = 1, act: bool = True, *, rngs: nnx.Rngs) -> Conv:  # noqa: N802
    """Depthwise :class:`Conv` (ultralytics ``DWConv``): ``gcd(c1, c2)`` groups."""
    return Conv(c1, c2, k, s, math.gcd(c1, c2), act, rngs=rngs)


class Bottleneck(nnx.Module):
    """Two 3×3 Convs (hidden width ``int(c2·e)``) with an optional residual connection."""

    def __init__(self, c1: int, c2: int, shortcut: bool, e: float = 1.0, *, rngs: nnx.Rngs):
        c_ = int(c2 * e)  # e = 1.0 inside C2f and C3k, 0.5 inside C3k2
        self.cv1 = Conv(c1, c_, 3, rngs=rngs)
        self.cv2 = Conv(c_, c2, 3, rngs=rngs)
        self.add = shortcut and c1 == c2

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W C"]:
        y = self.cv2(self.cv1(x))
        return x + y if self.add else y


class C2f(nnx.Module):
    """CSP bottleneck with two convolutions, keeping every intermediate (hidden ``c = int(c2·e)``)."""

    def __init__(self, c1: int, c2: int, n: int, shortcut: bool, e: float = 0.5, *, rngs: nnx.Rngs):
        self.c = int(c2 * e)
        self.cv1 = Conv(c1, 2 * self.c, 1, rngs=rngs)
        self.cv2 = Conv((2 + n) * self.c, c2, 1, rngs=rngs)
        self.m = nnx.List([Bottleneck(self.c, self.c, shortcut, rngs=rngs) for _ in range(n)])

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W D"]:
        y = self.cv1(x)
        ys = [y[..., : self.c], y[..., self.c :]]
        for block in self.m:
            ys.append(block(ys[-1]))
        return self.cv2(jnp.concatenate(ys, axis=-1))


def _maxpool_same(x: Float[Array, "B H W C"], k: int) -> Float[Array, "B H W C"]:
    p = k // 2
    return jax.lax.reduce_window(x, -jnp.inf, jax.lax.max, (1, k, k, 1), (1, 1, 1, 1),
                                 ((0, 0), (p, p), (p, p), (0, 0)))


class SPPF(nnx.Module):
    """Spatial pyramid pooling, fast: three chained ``k×k`` max pools."""

    def __init__(self, c1: int, c2: int, k: int = 5, *, rngs: nnx.Rngs):
        c_ = c1 // 2
        self.k = k
        self.cv1 = Conv(c1, c_, 1, rngs=rngs)
        self.cv2 = Conv(4 * c_, c2, 1, rngs=rngs)

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W D"]:
        ys = [self.cv1(x)]
        for _ in range(3):
            ys.append(_maxpool_same(ys[-1], self.k))
        return self.cv2(jnp.concatenate(ys, axis=-1))


def _run(layers: Iterable, x: Array) -> Array:
    """Apply a (possibly nested) list of layers in order, like a torch ``nn.Sequential``."""
    for layer in layers:
        x = _run(layer, x) if isinstance(layer, nnx.List) else layer(x)
    return x


class Detect(nnx.Module):
    """Decoupled head: per level a box (DFL logits) and a class branch, concatenated.

    ``legacy`` (YOLOv8) class branch: two 3×3 Convs; otherwise (YOLO11) two
    ``[DWConv 3×3, Conv 1×1]`` pairs; both end in a 1×1 Conv2d with bias.
    """

    def __init__(self, nc: int, ch: tuple[int, ...], reg_max: int, legacy: bool = True, *, rngs: nnx.Rngs):
        self.nc, self.reg_max = nc, reg_max
        c2 = max(16, ch[0] // 4, reg_max * 4)
        c3 = max(ch[0], min(nc, 100))

        def branch(c_in: int, c_mid: int, c_out: int, bias: float, dw: bool = False):
            last = nnx.Conv(c_mid, c_out, (1, 1), kernel_init=_torch_kernel_init,
                            bias_init=nnx.initializers.constant(bias), rngs=rngs)
            if dw:
                return nnx.List([nnx.List([DWConv(c_in, c_in, 3, rngs=rngs), Conv(c_in, c_mid, 1, rngs=rngs)]),
                                 nnx.List([DWConv(c_mid, c_mid, 3, rngs=rngs), Conv(c_mid, c_mid, 1, rngs=rngs)]), last])
            return nnx.List([Conv(c_in, c_mid, 3, rngs=rngs), Conv(c_mid, c_mid, 3, rngs=rngs), last])

        # ultralytics Detect.bias_init: box bias 1.0, class bias log(5 / nc / (640 / s)^2).
        self.cv2 = nnx.List([branch(c, c2, 4 * reg_max, 1.0) for c in ch])
        self.cv3 = nnx.List([branch(c, c3, nc, math.log(5 / nc / (640 / s) ** 2), not legacy)
                             for c, s in zip(ch, STRIDES)])

    def __call__(self, feats: list[Array]) -> list[Array]:
        return [jnp.concatenate([_run(box, x), _run(cls, x)], axis=-1) for x, box, cls in zip(feats, self.cv2, self.cv3)]


def _upsample2(x: Float[Array, "B H W C"]) -> Float[Array, "B h w C"]:
    return jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)


class YOLOv8(nnx.Module):
    """YOLOv8 detector (``yolov8.yaml``); input NHWC RGB in ``[0, 1]``, H and W multiples of 32.

    ``model(x)`` returns the raw head maps for strides 8/16/32, each
    ``(B, H/s, W/s, 4·reg_max + nc)``; decode them with
    :func:`privslam_jax.detect.decode.decode_head`. Call ``model.eval()`` for inference
    (BatchNorm running statistics) and ``model.train()`` for training.
    """

    torch_layer_names: ClassVar[dict[int, str]] = TORCH_LAYER_NAMES
    """ultralytics ``model.model[i]`` index → attribute (the importer's key map)."""

    def __init__(self, config: YOLOv8Config = YOLOv8Config(), *, rngs: nnx.Rngs):
        self.config = config
        ch, d = config.channels, config.depth
        c64, c128, c256, c512, c1024 = ch(64), ch(128), ch(256), ch(512), ch(1024)
        self.stem = Conv(3, c64, 3, 2, rngs=rngs)
        self.down1 = Conv(c64, c128, 3, 2, rngs=rngs)
        self.c2f1 = C2f(c128, c128, d(3), True, rngs=rngs)
        self.down2 = Conv(c128, c256, 3, 2, rngs=rngs)
        self.c2f2 = C2f(c256, c256, d(6), True, rngs=rngs)
        self.down3 = Conv(c256, c512, 3, 2, rngs=rngs)
        self.c2f3 = C2f(c512, c512, d(6), True, rngs=rngs)
        self.down4 = Conv(c512, c1024, 3, 2, rngs=rngs)
        self.c2f4 = C2f(c1024, c1024, d(3), True, rngs=rngs)
        self.sppf = SPPF(c1024, c1024, 5, rngs=rngs)
        self.neck4 = C2f(c1024 + c512, c512, d(3), False, rngs=rngs)
        self.neck3 = C2f(c512 + c256, c256, d(3), False, rngs=rngs)
        self.pan_down3 = Conv(c256, c256, 3, 2, rngs=rngs)
        self.pan4 = C2f(c256 + c512, c512, d(3), False, rngs=rngs)
        self.pan_down4 = Conv(c512, c512, 3, 2, rngs=rngs)
        self.pan5 = C2f(c512 + c1024, c1024, d(3), False, rngs=rngs)
        self.detect = Detect(config.num_classes, (c256, c512, c1024), config.reg_max, rngs=rngs)

    def __call__(self, x: Float[Array, "B H W 3"]) -> list[Array]:
        if x.ndim != 4 or x.shape[-1] != 3 or x.shape[1] % 32 or x.shape[2] % 32:
            raise ValueError(f"YOLOv8 expects (B, H, W, 3) with H, W multiples of 32, got {x.shape}")
        x = self.c2f1(self.down1(self.stem(x)))
        p3 = self.c2f2(self.down2(x))
        p4 = self.c2f3(self.down3(p3))
        p5 = self.sppf(self.c2f4(self.down4(p4)))
        h4 = self.neck4(jnp.concatenate([_upsample2(p5), p4], axis=-1))
        o3 = self.neck3(jnp.concatenate([_upsample2(h4), p3], axis=-1))
        o4 = self.pan4(jnp.concatenate([self.pan_down3(o3), h4], axis=-1))
        o5 = self.pan5(jnp.concatenate([self.pan_down4(o4), p5], axis=-1))
        return self.detect([o3, o4, o5])


def count_parameters(model: YOLOv8) -> int:
    """Parameters as ultralytics counts them (``sum(p.numel() for p in model.parameters())``).

    That is every conv kernel, head-conv bias and BatchNorm scale/bias (running statistics are
    buffers, not parameters) plus the fixed DFL ``1×1`` conv weight (``reg_max`` values, a
    parameter with ``requires_grad=False`` in torch; here a constant in the decoder).
    """
    params = nnx.state(model, nnx.Param)
    return int(sum(x.size for x in jax.tree.leaves(params))) + model.config.reg_max


def fuse_batchnorm(model: YOLOv8) -> YOLOv8:
    """An inference copy of ``model`` with every BatchNorm folded into its convolution.

    ultralytics ``fuse_conv_and_bn``: with ``s = γ / √(σ² + ε)`` per output channel,
    ``BN(W * x) = (s·W) * x + (β − μ·s)``, so the kernel is scaled and the conv gains a bias.  Uses
    the running statistics (eval mode); the same function up to float rounding, one fewer
    elementwise pass per layer (≈ 10 % of the CPU forward).  ``model`` is left unchanged; the copy
    is for inference only (it has no BatchNorm to train).
    """
    model = nnx.clone(model)
    convs = [node for _, node in nnx.iter_graph(model) if isinstance(node, Conv) and node.bn is not None]
    for node in convs:
        bn, conv = node.bn, node.conv
        s = bn.scale[...] / jnp.sqrt(bn.var[...] + bn.epsilon)
        conv.kernel.set_value(conv.kernel[...] * s[None, None, None, :])  # HWIO: per output channel
        conv.bias = nnx.Param(bn.bias[...] - bn.mean[...] * s)
        conv.use_bias = True
        node.bn = None
    return model


def abstract_model(cls: type[YOLOv8], config: YOLOv8Config) -> YOLOv8:
    """``cls(config)`` with shape placeholders as variables (``nnx.eval_shape``: no computation).

    The key counter of the ``Rngs`` is a host (numpy) array: a traced counter is written back
    through ``Variable.set_value`` at every key draw, which reads the tracer's ``sharding``, and
    the error message behind that walks the whole jaxpr traced so far, so construction was
    quadratic in the layer count (YOLO11x 5.9 s → 1.0 s, YOLOv8n 0.6 → 0.3 s, on this machine).
    Only the shapes are used, so the keys' values do not matter.
    """

    def build() -> YOLOv8:
        rngs = nnx.Rngs(0)
        rngs.default.count.set_value(np.zeros((), np.uint32))
        return cls(config, rngs=rngs)

    return nnx.eval_shape(build)


def abstract_yolov8(config: YOLOv8Config = YOLOv8Config()) -> YOLOv8:
    """A :class:`YOLOv8` whose variables are shape placeholders (no computation); fill before use."""
    return abstract_model(YOLOv8, config)


def init_yolov8(config: YOLOv8Config = YOLOv8Config(), seed: int = 0) -> YOLOv8:
    """A randomly initialised :class:`YOLOv8`, initialised on the host with numpy (:func:`host_init`)."""
    return host_init(abstract_yolov8(config), seed)


def host_init(model: YOLOv8, seed: int = 0) -> YOLOv8:
    """Fill the variables of an abstract ``model`` (YOLOv8 or YOLO11) with a random init, on the host.

    Same distributions as the module constructor (torch defaults: kernels and biases
    ``U(±1/√fan_in)``, BatchNorm ``γ = 1, β = 0``, running mean 0 and variance 1) plus
    ultralytics' ``Detect.bias_init`` (box bias 1, class bias ``log(5 / nc / (640 / s)²)``).
    Eager NNX initialisation dispatches one small XLA program per layer shape (tens of seconds on
    a busy 2-core CPU); this takes well under a second.
    """
    config = model.config
    rng = np.random.default_rng(seed)

    def put(var: nnx.Variable, value: np.ndarray) -> None:
        var.set_value(jnp.asarray(np.asarray(value, np.float32)))

    for _, node in nnx.iter_graph(model):
        if isinstance(node, nnx.Conv):
            shape = node.kernel.get_value().shape
            bound = 1.0 / math.sqrt(shape[0] * shape[1] * shape[2])
            put(node.kernel, rng.uniform(-bound, bound, shape))
            if node.bias is not None:
                put(node.bias, np.zeros(node.bias.get_value().shape))
        elif isinstance(node, nnx.BatchNorm):
            c = node.scale.get_value().shape
            put(node.scale, np.ones(c))
            put(node.bias, np.zeros(c))
            put(node.mean, np.zeros(c))
            put(node.var, np.ones(c))
    for box, cls, s in zip(model.detect.cv2, model.detect.cv3, STRIDES):
        put(box[-1].bias, np.ones(box[-1].bias.get_value().shape))
        put(cls[-1].bias, np.full(cls[-1].bias.get_value().shape, math.log(5 / config.num_classes / (640 / s) ** 2)))
    return model
