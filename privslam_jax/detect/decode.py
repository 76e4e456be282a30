"""YOLOv8 output decoding (DFL), letterbox geometry and NMS with ultralytics semantics.

Sources: ultralytics ``nn/modules/head.py`` (``Detect._inference``), ``nn/modules/block.py``
(``DFL``), ``utils/tal.py`` (``make_anchors``, ``dist2bbox``), ``utils/nms.py``
(``non_max_suppression``) and ``utils/ops.py`` (``scale_boxes``).

* Anchors: the centre of every cell of every level, ``(x + 0.5, y + 0.5)`` in grid units, levels
  P3, P4, P5 in order, cells row-major.
* DFL: for each box side the 16 logits ``z_k`` give ``d = Σ_k k · softmax(z)_k`` (grid units).
  Channel ``4·16`` is ordered side-major (``l, t, r, b``) then bin, as torch's
  ``view(b, 4, 16, a)``.
* ``dist2bbox``: ``x1y1 = a − (l, t)``, ``x2y2 = a + (r, b)``; centre ``(x1y1 + x2y2)/2`` and size
  ``x2y2 − x1y1``, times the stride → input pixels. Classes: sigmoid of the logits.
* NMS (host side, numpy): keep candidates whose best class probability exceeds ``conf``; with
  ``multi_label`` every (box, class) pair above ``conf``, else the arg-max class; optional class
  filter; at most ``max_nms`` by score; class-aware by offsetting boxes by ``class · 7680``;
  greedy suppression of boxes with IoU **>** ``iou`` against a kept higher-scoring box (ties in
  the score keep the lower index first, as a stable sort); the first ``max_det`` kept.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["make_anchors", "decode_head", "nms", "non_max_suppression", "scale_boxes", "box_iou"]

MAX_WH = 7680
"""Class offset of ultralytics' class-aware NMS (boxes of different classes never overlap)."""


def make_anchors(
    shapes: tuple[tuple[int, int], ...], strides: tuple[int, ...], offset: float = 0.5
) -> tuple[Float[Array, "A 2"], Float[Array, "A 1"]]:
    """Anchor points (grid units, ``(x, y)``) and their strides for feature maps ``(H_l, W_l)``."""
    points, strides_out = [], []
    for (h, w), s in zip(shapes, strides):
        sy, sx = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32) + offset,
                              jnp.arange(w, dtype=jnp.float32) + offset, indexing="ij")
        points.append(jnp.stack([sx, sy], axis=-1).reshape(-1, 2))
        strides_out.append(jnp.full((h * w, 1), float(s), jnp.float32))
    return jnp.concatenate(points, axis=0), jnp.concatenate(strides_out, axis=0)


def dfl(box_logits: Float[Array, "*batch A F"], reg_max: int = 16) -> Float[Array, "*batch A 4"]:
    """Distribution focal loss decoding: softmax expectation over ``reg_max`` bins per side."""
    shape = box_logits.shape[:-1] + (4, reg_max)
    prob = jax.nn.softmax(box_logits.reshape(shape), axis=-1)
    return prob @ jnp.arange(reg_max, dtype=box_logits.dtype)


def decode_head(
    feats: list[Array], strides: tuple[int, ...] = (8, 16, 32), reg_max: int = 16
) -> Float[Array, "B A C"]:
    """Raw head maps ``(B, H_l, W_l, 4·reg_max + nc)`` → ``(B, A, 4 + nc)``.

    Rows are ``cx, cy, w, h`` in input pixels then the class probabilities — ultralytics'
    inference output transposed (it is ``(B, 4 + nc, A)``).
    """
    b = feats[0].shape[0]
    flat = jnp.concatenate([f.reshape(b, -1, f.shape[-1]) for f in feats], axis=1)
    anchors, stride = make_anchors(tuple((f.shape[1], f.shape[2]) for f in feats), strides)
    dist = dfl(flat[..., : 4 * reg_max], reg_max)
    x1y1 = anchors[None] - dist[..., :2]
    x2y2 = anchors[None] + dist[..., 2:]
    xywh = jnp.concatenate([(x1y1 + x2y2) / 2, x2y2 - x1y1], axis=-1) * stride[None]
    return jnp.concatenate([xywh, jax.nn.sigmoid(flat[..., 4 * reg_max :])], axis=-1)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU ``(N, M)`` of ``xyxy`` boxes (numpy, as ultralytics ``box_iou``, eps 1e-7)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area_a = (a[:, 2:] - a[:, :2]).prod(-1)
    area_b = (b[:, 2:] - b[:, :2]).prod(-1)
    return inter / (area_a[:, None] + area_b[None, :] - inter + 1e-7)


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy NMS as ``torchvision.ops.nms``: indices kept, by decreasing score.

    A box is dropped when its IoU with an already kept box is ``> iou_threshold``.
    """
    boxes = np.asarray(boxes, np.float32)
    order = np.argsort(-np.asarray(scores), kind="stable")
    x1, y1, x2, y2 = boxes.T
    areas = (x2 - x1) * (y2 - y1)
    keep = []
    while order.size:
        i = order[0]
        keep.append(i)
        rest = order[1:]
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        iou = inter / (areas[i] + areas[rest] - inter)
        order = rest[~(iou > iou_threshold)]
    return np.asarray(keep, dtype=np.int64)


def non_max_suppression(
    pred: np.ndarray,
    conf: float = 0.25,
    iou: float = 0.7,
    classes: tuple[int, ...] | None = None,
    max_det: int = 300,
    multi_label: bool = False,
    agnostic: bool = False,
    max_nms: int = 30000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ultralytics NMS for one image: ``pred (A, 4 + nc)`` (xywh, probs) → ``(xyxy, conf, cls)``."""
    if not (0.0 <= conf <= 1.0 and 0.0 <= iou <= 1.0):
        raise ValueError(f"conf and iou must lie in [0, 1], got conf={conf}, iou={iou}")
    pred = np.asarray(pred, np.float32)
    if pred.ndim != 2 or pred.shape[1] < 5:
        raise ValueError(f"pred must have shape (A, 4 + nc), got {pred.shape}")
    probs = pred[:, 4:]
    x = pred[probs.max(1) > conf]
    empty = (np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))
    if not len(x):
        return empty
    cx, cy, w, h = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    box = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    p = x[:, 4:]
    if multi_label and p.shape[1] > 1:
        i, j = np.nonzero(p > conf)
        box, score, cls = box[i], p[i, j], j
    else:
        cls = p.argmax(1)
        score = p[np.arange(len(p)), cls]
        keep = score > conf
        box, score, cls = box[keep], score[keep], cls[keep]
    if classes is not None:
        keep = np.isin(cls, np.asarray(classes))
        box, score, cls = box[keep], score[keep], cls[keep]
    if not len(score):
        return empty
    if len(score) > max_nms:
        top = np.argsort(-score, kind="stable")[:max_nms]
        box, score, cls = box[top], score[top], cls[top]
    offset = 0.0 if agnostic else cls[:, None].astype(np.float32) * MAX_WH
    keep = nms(box + offset, score, iou)[:max_det]
    return box[keep], score[keep], cls[keep].astype(np.int64)


def scale_boxes(
    boxes: np.ndarray, input_hw: tuple[int, int], orig_hw: tuple[int, int]
) -> np.ndarray:
    """Letterboxed-input ``xyxy`` boxes → original pixels (ultralytics ``scale_boxes``), clipped.

    ``gain = min(h1/h0, w1/w0)``, ``pad = round((s1 − s0·gain)/2 − 0.1)`` per axis.
    """
    (h1, w1), (h0, w0) = input_hw, orig_hw
    gain = min(h1 / h0, w1 / w0)
    pad_x = round((w1 - w0 * gain) / 2 - 0.1)
    pad_y = round((h1 - h0 * gain) / 2 - 0.1)
    out = np.array(boxes, np.float32, copy=True).reshape(-1, 4)
    out[:, [0, 2]] -= pad_x
    out[:, [1, 3]] -= pad_y
    out /= gain
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, w0)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, h0)
    return out
