"""YOLO11 detection network in Flax NNX (NHWC, float32), as ultralytics ``yolo11.yaml``.

Sources: ultralytics ``cfg/models/11/yolo11.yaml``, ``nn/modules/block.py`` (``C3k2``, ``C3k``,
``C3``, ``C2PSA``, ``PSABlock``, ``Attention``), ``nn/modules/head.py`` (``Detect`` with
``legacy=False``) and ``nn/tasks.py::parse_model`` (scaling, the ``c3k`` override). ``Conv``,
``Bottleneck``, ``C2f``, ``SPPF`` and ``Detect`` are those of :mod:`privslam_jax.detect.yolov8`.

* ``C3k2(c1, c2, n, c3k, e)``: a :class:`~privslam_jax.detect.yolov8.C2f` with hidden width
  ``c = int(c2·e)`` whose ``n`` inner blocks are ``C3k(c, c, 2)`` when ``c3k`` else
  ``Bottleneck(c, c, e=0.5)`` (hidden ``int(c/2)``); residuals on (``shortcut=True``).
* ``C3k(c1, c2, n=2)`` (a ``C3`` with 3×3 bottlenecks): ``c_ = int(c2/2)``;
  ``cv3([m(cv1(x)), cv2(x)])`` with ``cv1, cv2`` 1×1 to ``c_``, ``m`` = ``n`` ``Bottleneck(c_, c_, e=1)``.
* ``C2PSA(c1, c1, n)``: ``c = c1/2``; ``cv1`` 1×1 to ``2c``, split ``a, b``; ``b`` through ``n``
  ``PSABlock(c)``; ``cv2`` 1×1 over ``[a, b]``. ``PSABlock``: ``x + Attention(x)``, then
  ``x + ffn(x)`` with ``ffn`` = Conv 1×1 to ``2c`` (SiLU), Conv 1×1 to ``c`` (no activation).
* ``Attention(dim, h = max(dim // 64, 1) heads)``: head width ``d = dim/h``, key width
  ``k = d/2``; ``qkv`` = Conv 1×1 (no activation) to ``dim + 2hk`` channels, laid out per head as
  ``[q (k), key (k), v (d)]``; per head ``A = softmax_j(k^{-1/2} q_i · key_j)`` over the ``H·W``
  positions, ``o_i = Σ_j A_ij v_j``; output ``proj(o + pe(v))`` with ``pe`` a depthwise 3×3 Conv
  and ``proj`` a 1×1 Conv, both without activation.
* Backbone: Conv 3×3/2, Conv 3×3/2, C3k2(256, e=¼), Conv/2, C3k2(512, e=¼) (P3), Conv/2,
  C3k2(512, c3k) (P4), Conv/2, C3k2(1024, c3k), SPPF, C2PSA (P5). Neck (PAN) as YOLOv8 with
  C3k2 (the P5 one with c3k); the P3 input of the neck has ``ch(512)`` channels. ``parse_model``
  sets ``c3k=True`` in every C3k2 for scales m, l, x.
* Scales ``(depth, width, max_channels)``: n (0.50, 0.25, 1024), s (0.50, 0.50, 1024),
  m (0.50, 1.00, 512), l (1.00, 1.00, 512), x (1.00, 1.50, 512); channel and repeat rounding as
  YOLOv8.

The output is the YOLOv8 format (raw maps ``(B, H/s, W/s, 4·reg_max + nc)`` for strides 8/16/32),
so decoding, :class:`~privslam_jax.detect.predict.Detector`, :func:`fuse_batchnorm` and the
importer serve both. :class:`YOLO11` subclasses :class:`~privslam_jax.detect.yolov8.YOLOv8` for
that shared contract only (it builds its own layers).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

from privslam_jax.detect.yolov8 import (
    SPPF,
    C2f,
    Bottleneck,
    Conv,
    Detect,
    YOLOv8,
    YOLOv8Config,
    _upsample2,
    abstract_model,
    host_init,
)

__all__ = ["YOLO11", "YOLO11Config", "YOLO11_SCALES", "YOLO11_LAYER_NAMES", "abstract_yolo11", "init_yolo11",
           "C3k2", "C3k", "C2PSA", "PSABlock", "Attention"]

YOLO11_SCALES: dict[str, tuple[float, float, int]] = {
    "n": (0.50, 0.25, 1024),
    "s": (0.50, 0.50, 1024),
    "m": (0.50, 1.00, 512),
    "l": (1.00, 1.00, 512),
    "x": (1.00, 1.50, 512),
    "tiny": (0.50, 0.0625, 1024),
}
"""``scale -> (depth, width, max channels)`` from ``yolo11.yaml``; ``tiny`` is a test-only variant."""

YOLO11_LAYER_NAMES: dict[int, str] = {
    0: "stem", 1: "down1", 2: "c3k2_1", 3: "down2", 4: "c3k2_2", 5: "down3", 6: "c3k2_3", 7: "down4",
    8: "c3k2_4", 9: "sppf", 10: "c2psa", 13: "neck4", 16: "neck3", 17: "pan_down3", 19: "pan4",
    20: "pan_down4", 22: "pan5", 23: "detect",
}
"""Index ``i`` of ultralytics ``model.model[i]`` → attribute of :class:`YOLO11` (11, 14 are
Upsample, 12, 15, 18, 21 Concat)."""


@dataclasses.dataclass(frozen=True)
class YOLO11Config(YOLOv8Config):
    """YOLO11 hyper-parameters (fields as :class:`~privslam_jax.detect.yolov8.YOLOv8Config`)."""

    scales: ClassVar[dict[str, tuple[float, float, int]]] = YOLO11_SCALES
    arch: ClassVar[str] = "yolo11"

    @property
    def c3k(self) -> bool:
        """``parse_model`` forces ``c3k=True`` in every C3k2 of scales m, l, x."""
        return self.scale in ("m", "l", "x")


class C3k(nnx.Module):
    """CSP bottleneck with three convolutions and ``n`` 3×3 bottlenecks (ultralytics ``C3k``)."""

    def __init__(self, c1: int, c2: int, n: int = 2, *, rngs: nnx.Rngs):
        c_ = int(c2 * 0.5)
        self.cv1 = Conv(c1, c_, 1, rngs=rngs)
        self.cv2 = Conv(c1, c_, 1, rngs=rngs)
        self.cv3 = Conv(2 * c_, c2, 1, rngs=rngs)
        self.m = nnx.List([Bottleneck(c_, c_, True, 1.0, rngs=rngs) for _ in range(n)])

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W D"]:
        y = self.cv1(x)
        for block in self.m:
            y = block(y)
        return self.cv3(jnp.concatenate([y, self.cv2(x)], axis=-1))


class C3k2(C2f):
    """:class:`~privslam_jax.detect.yolov8.C2f` whose inner blocks are C3k (``c3k``) or e=0.5 Bottlenecks."""

    def __init__(self, c1: int, c2: int, n: int, c3k: bool, e: float = 0.5, *, rngs: nnx.Rngs):
        super().__init__(c1, c2, n, True, e, rngs=rngs)
        self.m = nnx.List([C3k(self.c, self.c, 2, rngs=rngs) if c3k else Bottleneck(self.c, self.c, True, 0.5, rngs=rngs)
                           for _ in range(n)])


class Attention(nnx.Module):
    """Multi-head self-attention over all positions with a depthwise positional term (ultralytics ``Attention``)."""

    def __init__(self, dim: int, num_heads: int, attn_ratio: float = 0.5, *, rngs: nnx.Rngs):
        self.num_heads = num_heads
        self.head_dim = dim // num_heads
        self.key_dim = int(self.head_dim * attn_ratio)
        self.qkv = Conv(dim, dim + 2 * self.key_dim * num_heads, 1, act=False, rngs=rngs)
        self.proj = Conv(dim, dim, 1, act=False, rngs=rngs)
        self.pe = Conv(dim, dim, 3, g=dim, act=False, rngs=rngs)

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W C"]:
        b, h, w, c = x.shape
        kd = self.key_dim
        qkv = self.qkv(x).reshape(b, h * w, self.num_heads, 2 * kd + self.head_dim)
        q, k, v = qkv[..., :kd], qkv[..., kd : 2 * kd], qkv[..., 2 * kd :]
        attn = jax.nn.softmax(jnp.einsum("bihd,bjhd->bhij", q * kd**-0.5, k), axis=-1)
        out = jnp.einsum("bhij,bjhc->bihc", attn, v).reshape(b, h, w, c)
        return self.proj(out + self.pe(v.reshape(b, h, w, c)))


class PSABlock(nnx.Module):
    """Attention then a 1×1 feed-forward pair, each with a residual connection."""

    def __init__(self, c: int, num_heads: int, *, rngs: nnx.Rngs):
        self.attn = Attention(c, num_heads, 0.5, rngs=rngs)
        self.ffn = nnx.List([Conv(c, 2 * c, 1, rngs=rngs), Conv(2 * c, c, 1, act=False, rngs=rngs)])

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W C"]:
        x = x + self.attn(x)
        return x + self.ffn[1](self.ffn[0](x))


class C2PSA(nnx.Module):
    """Split in two halves; ``n`` PSABlocks on the second; 1×1 conv over both (ultralytics ``C2PSA``)."""

    def __init__(self, c1: int, n: int, *, rngs: nnx.Rngs):
        self.c = int(c1 * 0.5)
        self.cv1 = Conv(c1, 2 * self.c, 1, rngs=rngs)
        self.cv2 = Conv(2 * self.c, c1, 1, rngs=rngs)
        self.m = nnx.List([PSABlock(self.c, max(self.c // 64, 1), rngs=rngs) for _ in range(n)])

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W C"]:
        y = self.cv1(x)
        a, b = y[..., : self.c], y[..., self.c :]
        for block in self.m:
            b = block(b)
        return self.cv2(jnp.concatenate([a, b], axis=-1))


class YOLO11(YOLOv8):
    """YOLO11 detector (``yolo11.yaml``); input NHWC RGB in ``[0, 1]``, H and W multiples of 32.

    Same call contract as :class:`~privslam_jax.detect.yolov8.YOLOv8`: raw head maps for strides
    8/16/32, ``model.eval()`` / ``model.train()`` switch BatchNorm.
    """

    torch_layer_names: ClassVar[dict[int, str]] = YOLO11_LAYER_NAMES

    def __init__(self, config: YOLO11Config = YOLO11Config(), *, rngs: nnx.Rngs):
        if not isinstance(config, YOLO11Config):
            raise TypeError(f"YOLO11 needs a YOLO11Config, got {type(config).__name__}")
        self.config = config
        ch, d, c3k = config.channels, config.depth, config.c3k
        c64, c128, c256, c512, c1024 = ch(64), ch(128), ch(256), ch(512), ch(1024)
        self.stem = Conv(3, c64, 3, 2, rngs=rngs)
        self.down1 = Conv(c64, c128, 3, 2, rngs=rngs)
        self.c3k2_1 = C3k2(c128, c256, d(2), c3k, 0.25, rngs=rngs)
        self.down2 = Conv(c256, c256, 3, 2, rngs=rngs)
        self.c3k2_2 = C3k2(c256, c512, d(2), c3k, 0.25, rngs=rngs)
        self.down3 = Conv(c512, c512, 3, 2, rngs=rngs)
        self.c3k2_3 = C3k2(c512, c512, d(2), True, rngs=rngs)
        self.down4 = Conv(c512, c1024, 3, 2, rngs=rngs)
        self.c3k2_4 = C3k2(c1024, c1024, d(2), True, rngs=rngs)
        self.sppf = SPPF(c1024, c1024, 5, rngs=rngs)
        self.c2psa = C2PSA(c1024, d(2), rngs=rngs)
        self.neck4 = C3k2(c1024 + c512, c512, d(2), c3k, rngs=rngs)
        self.neck3 = C3k2(c512 + c512, c256, d(2), c3k, rngs=rngs)
        self.pan_down3 = Conv(c256, c256, 3, 2, rngs=rngs)
        self.pan4 = C3k2(c256 + c512, c512, d(2), c3k, rngs=rngs)
        self.pan_down4 = Conv(c512, c512, 3, 2, rngs=rngs)
        self.pan5 = C3k2(c512 + c1024, c1024, d(2), True, rngs=rngs)
        self.detect = Detect(config.num_classes, (c256, c512, c1024), config.reg_max, legacy=False, rngs=rngs)

    def __call__(self, x: Float[Array, "B H W 3"]) -> list[Array]:
        if x.ndim != 4 or x.shape[-1] != 3 or x.shape[1] % 32 or x.shape[2] % 32:
            raise ValueError(f"YOLO11 expects (B, H, W, 3) with H, W multiples of 32, got {x.shape}")
        x = self.c3k2_1(self.down1(self.stem(x)))
        p3 = self.c3k2_2(self.down2(x))
        p4 = self.c3k2_3(self.down3(p3))
        p5 = self.c2psa(self.sppf(self.c3k2_4(self.down4(p4))))
        h4 = self.neck4(jnp.concatenate([_upsample2(p5), p4], axis=-1))
        o3 = self.neck3(jnp.concatenate([_upsample2(h4), p3], axis=-1))
        o4 = self.pan4(jnp.concatenate([self.pan_down3(o3), h4], axis=-1))
        o5 = self.pan5(jnp.concatenate([self.pan_down4(o4), p5], axis=-1))
        return self.detect([o3, o4, o5])


def abstract_yolo11(config: YOLO11Config = YOLO11Config()) -> YOLO11:
    """A :class:`YOLO11` whose variables are shape placeholders (no computation); fill before use."""
    return abstract_model(YOLO11, config)


def init_yolo11(config: YOLO11Config = YOLO11Config(), seed: int = 0) -> YOLO11:
    """A randomly initialised :class:`YOLO11` (torch-default init on the host, see ``host_init``)."""
    return host_init(abstract_yolo11(config), seed)
