"""Batched YOLOv8 inference: letterbox → jitted forward + decode → host NMS → original pixels.

Preprocessing follows ultralytics (``data/augment.py::LetterBox``, ``data/base.py::load_image``):

* ``"rect"`` (``predict``): ``r = min(S/h0, S/w0)`` (never larger than 1 without ``scaleup``),
  resize to ``(round(w0·r), round(h0·r))`` with ``cv2.INTER_LINEAR``, pad with grey 114 up to the
  next multiple of 32 on each axis, centred (``top = round(dh − 0.1)``, ``bottom = round(dh + 0.1)``);
  boxes go back by removing the pad ``(left, top)`` and dividing by the per-axis gains
  ``(new_w/w0, new_h/h0)`` — what the ultralytics 8.4 reference outputs show (the older
  ``scale_boxes`` used one gain ``min(h1/h0, w1/w0)``, off by up to 0.08 % on one axis).
* ``"square"`` (``val``, ``rect=False``): resize the long side to ``S`` (``ceil``), then letterbox to
  ``S×S`` without upscaling; boxes go back with that ``(ratio, pad)``, per axis as well.

uint8 images are resized as uint8 (what ultralytics does with ``cv2.imread`` output), then /255;
float images in ``[0, 1]`` are resized as float32. Grey images are repeated to three channels.

Images with the same letterboxed shape are stacked; batches are padded to a power of two (≤
``max_batch``) so a repeated shape never recompiles. The forward pass is one ``jax.jit`` of
network + DFL decode; NMS runs on the host (:func:`privslam_jax.detect.decode.non_max_suppression`),
exact ultralytics/torchvision semantics.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from privslam_jax.data.images import check_unit_image
from privslam_jax.detect.decode import decode_head, non_max_suppression
from privslam_jax.detect.yolov8 import STRIDES, YOLOv8, fuse_batchnorm
from privslam_jax.types import Detections

__all__ = ["DetectorConfig", "Detector", "Letterboxed", "letterbox", "PRIVACY_CLASSES", "PRIVACY_PRESET",
           "EMBEDDED_WEIGHTS", "EMBEDDED_REAL_WEIGHTS"]

PRIVACY_CLASSES: tuple[int, ...] = (0, 1, 2, 3, 5, 7)
"""COCO ids of the privacy-sensitive classes: person, bicycle, car, motorcycle, bus, truck."""


@dataclasses.dataclass(frozen=True)
class DetectorConfig:
    """Inference settings (ultralytics ``predict`` defaults unless noted)."""

    imgsz: int = 640
    """Letterbox size ``S`` (long side in ``"rect"`` mode, square side in ``"square"`` mode)."""
    conf: float = 0.25
    """Confidence threshold (strictly greater keeps a box)."""
    iou: float = 0.7
    """NMS IoU threshold (a box with IoU > iou to a kept box of its class is dropped)."""
    max_det: int = 300
    """Maximum detections per image."""
    classes: tuple[int, ...] | None = None
    """Keep only these class ids (``None``: all)."""
    mode: str = "rect"
    """``"rect"``: minimal rectangle, multiple of 32 (``predict``); ``"square"``: S×S (``val``)."""
    multi_label: bool = False
    """One detection per (box, class) above ``conf`` (ultralytics ``val``) instead of the best class."""
    max_batch: int = 8
    """Largest batch sent to the network at once (batches are padded to powers of two)."""

    def __post_init__(self) -> None:
        if self.imgsz <= 0 or self.imgsz % 32:
            raise ValueError(f"imgsz must be a positive multiple of 32, got {self.imgsz}")
        if not (0 <= self.conf <= 1 and 0 <= self.iou <= 1):
            raise ValueError(f"conf and iou must lie in [0, 1], got {self.conf}, {self.iou}")
        if self.mode not in ("rect", "square"):
            raise ValueError(f"mode must be 'rect' or 'square', got {self.mode!r}")


PRIVACY_PRESET = DetectorConfig(conf=0.4, classes=PRIVACY_CLASSES)
"""The paper's privacy filter: person, bicycle, car, motorcycle, bus, truck at confidence 0.4."""

EMBEDDED_WEIGHTS = Path(__file__).resolve().parents[1] / "assets" / "detector_yolov8n_privacy.npz"
"""The embedded synthetic-world detector (:meth:`Detector.embedded`; model card: docs/model_card_detector.md)."""

EMBEDDED_REAL_WEIGHTS = Path(__file__).resolve().parents[1] / "assets" / "detector_yolov8n_real.npz"
"""The embedded real-frame detector (``Detector.embedded(domain="real")``; docs/model_card_detector.md)."""


@dataclasses.dataclass(frozen=True)
class Letterboxed:
    """A letterboxed image and how to map its boxes back."""

    image: np.ndarray
    """``(H, W, 3)`` float32 RGB in ``[0, 1]``, H and W multiples of 32."""
    orig_hw: tuple[int, int]
    """Original ``(h0, w0)``."""
    gains: tuple[float, float]
    """Scale factors ``(h_resized / h0, w_resized / w0)`` from original to letterboxed pixels."""
    pad: tuple[int, int]
    """Padding ``(left, top)`` in letterboxed pixels."""

    def boxes_to_original(self, boxes: np.ndarray) -> np.ndarray:
        """Letterboxed ``xyxy`` → original pixels: remove the pad, divide by the per-axis gain, clip."""
        out = np.array(boxes, np.float32, copy=True).reshape(-1, 4)
        (gy, gx), (left, top), (h0, w0) = self.gains, self.pad, self.orig_hw
        out[:, [0, 2]] = ((out[:, [0, 2]] - left) / gx).clip(0, w0)
        out[:, [1, 3]] = ((out[:, [1, 3]] - top) / gy).clip(0, h0)
        return out


def _as_hwc3(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[-1] == 1:
        img = img[..., 0]
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[-1] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"expected an image (H, W), (H, W, 1) or (H, W, 3), got shape {img.shape}")
    if img.dtype == np.uint8:
        return img
    if not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"images must be uint8 or float in [0, 1], got dtype {img.dtype}")
    return check_unit_image(img, "detector input image")


def letterbox(image: np.ndarray, imgsz: int = 640, mode: str = "rect") -> Letterboxed:
    """Resize and pad one RGB (or grey) image as ultralytics ``predict`` (rect) or ``val`` (square)."""
    img = _as_hwc3(image)
    h0, w0 = img.shape[:2]
    fill = 114 if img.dtype == np.uint8 else 114 / 255
    if mode == "rect":
        r = min(imgsz / h0, imgsz / w0)
        new_w, new_h = max(1, round(w0 * r)), max(1, round(h0 * r))  # a 1×20000 strip keeps one row
        dw, dh = (imgsz - new_w) % 32 / 2, (imgsz - new_h) % 32 / 2
        gains = (new_h / h0, new_w / w0)
    else:
        r0 = imgsz / max(h0, w0)  # load_image: long side to imgsz (ceil)
        if r0 != 1:
            w1, h1 = max(1, min(math.ceil(w0 * r0), imgsz)), max(1, min(math.ceil(h0 * r0), imgsz))
            img = cv2.resize(img, (w1, h1), interpolation=cv2.INTER_LINEAR)
        h1, w1 = img.shape[:2]
        gains = (h1 / h0, w1 / w0)
        r = min(min(imgsz / h1, imgsz / w1), 1.0)  # LetterBox(scaleup=False)
        new_w, new_h = max(1, round(w1 * r)), max(1, round(h1 * r))
        dw, dh = (imgsz - new_w) / 2, (imgsz - new_h) / 2
    if (img.shape[1], img.shape[0]) != (new_w, new_h):
        img = cv2.resize(img, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    top, bottom = round(dh - 0.1), round(dh + 0.1)
    left, right = round(dw - 0.1), round(dw + 0.1)
    img = cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT, value=(fill, fill, fill))
    out = img.astype(np.float32) / 255 if img.dtype == np.uint8 else img
    return Letterboxed(image=out, orig_hw=(h0, w0), gains=gains, pad=(left, top))


class Detector:
    """YOLOv8 + config: ``detect(images) -> list[Detections]`` in original pixels.

    ``names`` maps class ids to names (from the checkpoint); ``meta`` is the checkpoint's record of
    what the network was trained on (``meta["domain"]``: ``"synthetic"``, ``"real"`` or
    ``"unknown"``) and what was measured on it (``meta["card"]``, e.g. its recall on real frames;
    :func:`privslam_jax.detect.weights.checkpoint_meta`). The forward pass is jitted once per
    ``(batch, H, W)``; ``compile_count`` reports how many programs were compiled so far.
    """

    def __init__(self, model: YOLOv8, config: DetectorConfig = DetectorConfig(),
                 names: Mapping[int, str] | None = None, meta: Mapping | None = None):
        model.eval()
        self.model, self.config = model, config
        self.names = dict(names) if names else {i: str(i) for i in range(model.config.num_classes)}
        self.meta = {"domain": "unknown", "card": {}, **dict(meta or {})}
        bad = [jax.tree_util.keystr(k) for k, v in jax.tree_util.tree_leaves_with_path(nnx.state(model))
               if jnp.issubdtype(v.dtype, jnp.floating) and not bool(jnp.isfinite(v).all())]
        if bad:  # NaN weights detect nothing: refuse instead of reporting an empty street
            raise ValueError(f"detector weights hold NaN or infinite values in {len(bad)} arrays, e.g. {bad[0]}")
        graphdef, state = nnx.split(fuse_batchnorm(model))  # inference: BatchNorm folded (as ultralytics)
        self._state = state
        reg_max = model.config.reg_max

        def forward(state, x: jax.Array) -> jax.Array:
            return decode_head(nnx.merge(graphdef, state)(x), STRIDES, reg_max)

        self._forward = jax.jit(forward)

    @classmethod
    def from_weights(cls, path: str | Path, config: DetectorConfig = DetectorConfig()) -> "Detector":
        """Load an ultralytics ``.pt`` (file or unzipped folder) or our ``.npz`` checkpoint."""
        from privslam_jax.detect.weights import checkpoint_meta, load_detector

        model, names = load_detector(path)
        meta = checkpoint_meta(path)
        return cls(model, config, names, {"domain": meta["domain"], "card": meta["card"], "path": str(path)})

    @classmethod
    def embedded(cls, config: DetectorConfig = PRIVACY_PRESET, domain: str = "synthetic") -> "Detector":
        """A detector shipped in the package (``privslam_jax/assets``, docs/model_card_detector.md).

        ``domain="synthetic"``: the YOLOv8n trained from scratch on the synthetic world (the
        default of ``privslam run``); ``domain="real"``: the same network fine-tuned for real street
        frames (synthetic frames with domain randomisation plus developer-labelled real frames).
        Both have an 8-class head whose ids are COCO ids 0-7 (only person 0, bicycle 1, car 2,
        motorcycle 3, bus 5, truck 7 were labelled) and want 640-wide "rect" letterboxing. Loaded
        from the package, never from the network.
        """
        paths = {"synthetic": EMBEDDED_WEIGHTS, "real": EMBEDDED_REAL_WEIGHTS}
        if domain not in paths:
            raise ValueError(f"domain must be one of {sorted(paths)}, got {domain!r}")
        if not paths[domain].is_file():
            raise FileNotFoundError(f"no embedded {domain} detector shipped at {paths[domain]}")
        return cls.from_weights(paths[domain], config)

    def with_config(self, config: DetectorConfig) -> "Detector":
        """The same network with other settings (shares the compiled forward)."""
        other = object.__new__(Detector)
        other.__dict__.update(self.__dict__)
        other.config = config
        return other

    @property
    def domain(self) -> str:
        """What the network was trained on: ``"synthetic"``, ``"real"`` or ``"unknown"``."""
        return str(self.meta["domain"])

    @property
    def compile_count(self) -> int:
        """Number of compiled forward programs (one per distinct input shape)."""
        return int(self._forward._cache_size())

    def forward(self, batch: np.ndarray) -> np.ndarray:
        """Letterboxed ``(B, H, W, 3)`` float32 batch → decoded ``(B, A, 4 + nc)`` (xywh px, probs)."""
        return np.asarray(self._forward(self._state, jnp.asarray(batch, jnp.float32)))

    def predict_raw(self, images: Sequence[np.ndarray]) -> list[tuple[Letterboxed, np.ndarray]]:
        """Letterbox, bucket by shape and run the network: ``(letterboxed, (A, 4 + nc))`` per image."""
        cfg = self.config
        boxed = [letterbox(im, cfg.imgsz, cfg.mode) for im in images]
        raw: list[np.ndarray | None] = [None] * len(boxed)
        buckets: dict[tuple[int, int], list[int]] = {}
        for i, lb in enumerate(boxed):
            buckets.setdefault(lb.image.shape[:2], []).append(i)
        for idx in buckets.values():
            for start in range(0, len(idx), cfg.max_batch):
                chunk = idx[start : start + cfg.max_batch]
                size = min(1 << (len(chunk) - 1).bit_length(), cfg.max_batch)
                batch = np.stack([boxed[i].image for i in chunk])
                if size > len(chunk):
                    batch = np.concatenate([batch, np.zeros((size - len(chunk),) + batch.shape[1:], np.float32)])
                out = self.forward(batch)
                for j, i in enumerate(chunk):
                    raw[i] = out[j]
        return [(lb, r) for lb, r in zip(boxed, raw)]

    def detect(self, images: Sequence[np.ndarray] | np.ndarray) -> list[Detections]:
        """Detections for each image (uint8 or float [0, 1]; RGB or grey; any size)."""
        if isinstance(images, np.ndarray) and images.ndim != 4:
            raise ValueError(f"detect expects a list of images or a (B, H, W, C) array, got an array of shape "
                             f"{images.shape}; wrap a single image in a list")
        cfg = self.config
        results = []
        for lb, raw in self.predict_raw(list(images)):
            box, score, cls = non_max_suppression(raw, cfg.conf, cfg.iou, cfg.classes, cfg.max_det, cfg.multi_label)
            box = lb.boxes_to_original(box)
            results.append(Detections(boxes=jnp.asarray(box.reshape(-1, 4), jnp.float32),
                                      scores=jnp.asarray(score, jnp.float32),
                                      class_ids=jnp.asarray(cls, jnp.int32), valid=None))
        return results
