"""Re-detection: how many privacy objects a detector still finds after a privacy filter.

The source paper's Table 2 measure (DESIGN.md §5.6): the objects of a frame are a detector's
detections on the **original** frame; an object is *re-detected* when the same detector, on the
**filtered** frame, returns a detection of the same class whose box overlaps it with

    IoU(b_o, b_f) = |b_o ∩ b_f| / |b_o ∪ b_f| ≥ 0.5

(``xyxy`` pixel boxes, :func:`privslam_jax.detect.decode.box_iou`, ultralytics' ``box_iou`` with
eps 1e-7 in the denominator).  Several objects may be matched by the same filtered detection (no
one-to-one assignment: any surviving evidence of an object counts).  The re-detection rate of a
filter is ``Σ re-detected / Σ objects`` over the frames.

The detector setting is the paper's privacy filter: the privacy classes (person, bicycle, car,
motorcycle, bus, truck — looked up by name in the checkpoint, COCO ids when it has no names),
confidence 0.4, NMS IoU 0.7 (:func:`privacy_config`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from jaxtyping import Int, Real

from privslam_jax.detect.decode import box_iou
from privslam_jax.detect.predict import PRIVACY_CLASSES, DetectorConfig

__all__ = ["IOU", "PRIVACY_NAMES", "count_refound", "detection_arrays", "privacy_config", "refound"]

PRIVACY_NAMES: frozenset[str] = frozenset({"person", "bicycle", "car", "motorcycle", "bus", "truck"})
"""Class names of the privacy objects."""

IOU = 0.5
"""An object counts as re-detected at ``IoU ≥ IOU`` with a same-class detection of the filtered frame."""


def privacy_config(detector: Any) -> DetectorConfig:
    """The paper's preset (conf 0.4, NMS IoU 0.7) restricted to ``detector``'s privacy classes (by name in
    ``detector.names``; the COCO ids :data:`~privslam_jax.detect.predict.PRIVACY_CLASSES` when none is named)."""
    ids = tuple(sorted(i for i, n in detector.names.items() if n in PRIVACY_NAMES))
    if not ids:  # unnamed classes: assume COCO ids
        ids = PRIVACY_CLASSES
    return DetectorConfig(conf=0.4, iou=0.7, classes=ids)


def detection_arrays(detections: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(boxes (N, 4) float64 xyxy, class ids (N,) int64)`` of a
    :class:`~privslam_jax.types.Detections` (or anything with ``boxes`` and ``class_ids``)."""
    boxes = np.asarray(detections.boxes, np.float64).reshape(-1, 4)
    classes = np.asarray(detections.class_ids, np.int64).reshape(-1)
    return boxes, classes


def count_refound(boxes_orig: Real[np.ndarray, "N 4"], classes_orig: Int[np.ndarray, " N"],
                  boxes_filt: Real[np.ndarray, "M 4"], classes_filt: Int[np.ndarray, " M"],
                  iou: float = IOU) -> int:
    """Number of the ``N`` original objects matched by a filtered detection of the same class with
    ``IoU ≥ iou``: ``#{i : ∃ j, c_f[j] = c_o[i] ∧ IoU(b_o[i], b_f[j]) ≥ iou}``."""
    bo = np.asarray(boxes_orig, np.float64).reshape(-1, 4)
    bf = np.asarray(boxes_filt, np.float64).reshape(-1, 4)
    co = np.asarray(classes_orig).reshape(-1)
    cf = np.asarray(classes_filt).reshape(-1)
    if len(co) != len(bo) or len(cf) != len(bf):
        raise ValueError(f"boxes and classes differ in length: {len(bo)} vs {len(co)}, {len(bf)} vs {len(cf)}")
    if len(bo) == 0 or len(bf) == 0:
        return 0
    same = co[:, None] == cf[None, :]
    return int(np.any((box_iou(bo, bf) >= iou) & same, axis=1).sum())


def refound(orig: Any, filt: Any, iou: float = IOU) -> int:
    """:func:`count_refound` of two :class:`~privslam_jax.types.Detections`: the detections of the original
    frame (the objects) and of the filtered frame."""
    (bo, co), (bf, cf) = detection_arrays(orig), detection_arrays(filt)
    return count_refound(bo, co, bf, cf, iou)
