"""Detection metrics as ultralytics computes them: P, R, mAP50, mAP50-95.

Source: ultralytics ``utils/metrics.py`` (``ap_per_class``, ``compute_ap``, ``smooth``) and
``engine/validator.py::match_predictions`` / ``models/yolo/detect/val.py``.

* Matching (per image, per IoU threshold ``t ∈ {0.50, 0.55, …, 0.95}``): IoU of every
  (ground truth, prediction) pair of the **same class**; candidate pairs with IoU ≥ t sorted by
  IoU descending, then greedily made one-to-one (first by prediction, then by ground truth, with
  ``np.unique(..., return_index=True)``); matched predictions are true positives at ``t``.
  As in ultralytics, the second de-duplication sees rows re-ordered by prediction index, so a
  ground truth keeps its lowest-index candidate rather than its best-IoU one (kept for parity).
* ``ap_per_class``: predictions sorted by confidence descending; per class present in the ground
  truth, cumulative TP/FP give recall ``TP/(n_gt + 1e-16)`` and precision ``TP/(TP+FP)``; AP is the
  area under the monotone precision envelope (``mpre = max.accumulate`` from the right, sentinels
  ``(0, 1)`` and ``(1, 0)``) by the trapezoidal rule on **101 points** ``r ∈ {0, 0.01, …, 1}``
  (so a perfect detector scores 0.995, as in ultralytics).
  P and R are read from the per-class curves interpolated on 1000 confidences, at the confidence
  maximising the box-filtered (``f = 0.1``) mean F1 over classes.
* Reported: ``mean P``, ``mean R``, ``mAP50 = mean AP@0.5``, ``mAP50-95 = mean over classes and
  the 10 thresholds``. Classes without ground truth are ignored; a dataset without true
  positives gives zeros, as ultralytics does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

__all__ = [
    "IOU_THRESHOLDS",
    "DetectionMetrics",
    "ImageEval",
    "match_predictions",
    "compute_ap",
    "ap_per_class",
    "detection_metrics",
    "evaluate_yolo_folder",
    "RecallCounts",
    "privacy_recall",
]

IOU_THRESHOLDS = np.linspace(0.5, 0.95, 10)
"""COCO IoU thresholds 0.50:0.05:0.95."""


@dataclasses.dataclass(frozen=True)
class DetectionMetrics:
    """Dataset-level detection metrics (ultralytics ``DetMetrics.mean_results``)."""

    precision: float
    """Mean precision over classes at the max-F1 confidence."""
    recall: float
    """Mean recall over classes at the max-F1 confidence."""
    map50: float
    """Mean AP at IoU 0.5."""
    map50_95: float
    """Mean AP over IoU 0.50:0.05:0.95."""
    ap: np.ndarray
    """``(C, 10)`` AP per ground-truth class and IoU threshold."""
    classes: np.ndarray
    """``(C,)`` the ground-truth classes, rows of ``ap``."""

    def as_dict(self) -> dict[str, float]:
        """``{"precision", "recall", "mAP50", "mAP50-95"}`` (the keys of the reference JSON)."""
        return {"precision": self.precision, "recall": self.recall, "mAP50": self.map50, "mAP50-95": self.map50_95}


@dataclasses.dataclass(frozen=True)
class ImageEval:
    """Predictions and ground truth of one image (pixels, any consistent frame)."""

    pred_boxes: np.ndarray
    """``(N, 4)`` predicted ``xyxy``."""
    pred_scores: np.ndarray
    """``(N,)`` confidences."""
    pred_classes: np.ndarray
    """``(N,)`` predicted class ids."""
    gt_boxes: np.ndarray
    """``(M, 4)`` ground-truth ``xyxy``."""
    gt_classes: np.ndarray
    """``(M,)`` ground-truth class ids."""


def _iou(a: np.ndarray, b: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area_a = (a[:, 2:] - a[:, :2]).prod(-1)
    area_b = (b[:, 2:] - b[:, :2]).prod(-1)
    return inter / (area_a[:, None] + area_b[None, :] - inter + eps)


def match_predictions(
    pred_classes: np.ndarray, gt_classes: np.ndarray, iou: np.ndarray, thresholds: np.ndarray = IOU_THRESHOLDS
) -> np.ndarray:
    """``(N, T)`` boolean TP matrix from the ``(M, N)`` ground-truth × prediction IoU matrix."""
    iou = np.asarray(iou, np.float64) * (np.asarray(gt_classes)[:, None] == np.asarray(pred_classes)[None, :])
    correct = np.zeros((iou.shape[1], len(thresholds)), bool)
    for t, thr in enumerate(thresholds):
        matches = np.argwhere(iou >= thr)  # (gt, pred) pairs, row-major like np.nonzero
        if matches.shape[0]:
            if matches.shape[0] > 1:
                matches = matches[iou[matches[:, 0], matches[:, 1]].argsort()[::-1]]
                matches = matches[np.unique(matches[:, 1], return_index=True)[1]]
                matches = matches[np.unique(matches[:, 0], return_index=True)[1]]
            correct[matches[:, 1], t] = True
    return correct


def compute_ap(recall: np.ndarray, precision: np.ndarray) -> float:
    """Area under the precision envelope, 101-point trapezoidal interpolation (COCO style)."""
    mrec = np.concatenate(([0.0], recall, [1.0]))
    mpre = np.concatenate(([1.0], precision, [0.0]))
    mpre = np.flip(np.maximum.accumulate(np.flip(mpre)))
    x = np.linspace(0, 1, 101)
    return float(np.trapezoid(np.interp(x, mrec, mpre), x))


def _smooth(y: np.ndarray, f: float = 0.05) -> np.ndarray:
    nf = round(len(y) * f * 2) // 2 + 1  # odd number of filter elements
    p = np.ones(nf // 2)
    yp = np.concatenate((p * y[0], y, p * y[-1]), 0)
    return np.convolve(yp, np.ones(nf) / nf, mode="valid")


def ap_per_class(
    tp: np.ndarray, conf: np.ndarray, pred_cls: np.ndarray, target_cls: np.ndarray, eps: float = 1e-16
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(p, r, ap (C, T), classes)`` per ground-truth class, as ultralytics ``ap_per_class``."""
    order = np.argsort(-conf, kind="stable")
    tp, conf, pred_cls = tp[order], conf[order], pred_cls[order]
    classes, nt = np.unique(target_cls, return_counts=True)
    x = np.linspace(0, 1, 1000)
    ap = np.zeros((len(classes), tp.shape[1]))
    p_curve, r_curve = np.zeros((len(classes), 1000)), np.zeros((len(classes), 1000))
    for ci, c in enumerate(classes):
        i = pred_cls == c
        if i.sum() == 0 or nt[ci] == 0:
            continue
        fpc = (1 - tp[i]).cumsum(0)
        tpc = tp[i].cumsum(0)
        recall = tpc / (nt[ci] + eps)
        precision = tpc / (tpc + fpc)
        r_curve[ci] = np.interp(-x, -conf[i], recall[:, 0], left=0)
        p_curve[ci] = np.interp(-x, -conf[i], precision[:, 0], left=1)
        for j in range(tp.shape[1]):
            ap[ci, j] = compute_ap(recall[:, j], precision[:, j])
    f1 = 2 * p_curve * r_curve / (p_curve + r_curve + eps)
    best = _smooth(f1.mean(0), 0.1).argmax() if len(classes) else 0
    return p_curve[:, best], r_curve[:, best], ap, classes


def detection_metrics(images: Iterable[ImageEval], thresholds: np.ndarray = IOU_THRESHOLDS) -> DetectionMetrics:
    """P, R, mAP50, mAP50-95 over a dataset of images."""
    tps, confs, pcls, tcls = [], [], [], []
    for im in images:
        pb = np.asarray(im.pred_boxes, np.float64).reshape(-1, 4)
        gb = np.asarray(im.gt_boxes, np.float64).reshape(-1, 4)
        pc, gc = np.asarray(im.pred_classes).reshape(-1), np.asarray(im.gt_classes).reshape(-1)
        tp = np.zeros((len(pb), len(thresholds)), bool)
        if len(pb) and len(gb):
            tp = match_predictions(pc, gc, _iou(gb, pb), thresholds)
        tps.append(tp)
        confs.append(np.asarray(im.pred_scores, np.float64).reshape(-1))
        pcls.append(pc)
        tcls.append(gc)
    tp = np.concatenate(tps) if tps else np.zeros((0, len(thresholds)), bool)
    target = np.concatenate(tcls) if tcls else np.zeros(0)
    if not tp.any():
        classes = np.unique(target)
        return DetectionMetrics(0.0, 0.0, 0.0, 0.0, np.zeros((len(classes), len(thresholds))), classes)
    p, r, ap, classes = ap_per_class(tp.astype(np.float64), np.concatenate(confs), np.concatenate(pcls), target)
    return DetectionMetrics(float(p.mean()), float(r.mean()), float(ap[:, 0].mean()), float(ap.mean()), ap, classes)


def evaluate_yolo_folder(detector, root: str | Path, split: str = "val", class_map: Sequence[int] | None = None) -> DetectionMetrics:
    """Run ``detector.detect`` on a YOLO dataset split and compute the metrics (native pixels).

    Images are read with ``cv2.imread`` (uint8, BGR → RGB) as ultralytics does (through :func:`~privslam_jax.data.images.read_rgb8`, which refuses damaged files). ``class_map``
    optionally maps dataset class ids to detector class ids. For ultralytics ``val`` numbers use a
    detector configured with ``DetectorConfig(mode="square", conf=0.001, iou=0.7,
    multi_label=True)``.
    """

    from privslam_jax.data.images import read_rgb8
    from privslam_jax.data.yolo import YoloDataset, cxcywhn_to_xyxy

    ds = YoloDataset(root, split)
    images = [read_rgb8(path) for path in ds.image_paths]
    dets = detector.detect(images)
    evals = []
    for i, (img, det) in enumerate(zip(images, dets)):
        cls, boxes = ds.labels(i)
        if class_map is not None:
            cls = np.asarray([class_map[int(c)] for c in cls], np.int64)
        h, w = img.shape[:2]
        evals.append(ImageEval(np.asarray(det.boxes), np.asarray(det.scores), np.asarray(det.class_ids),
                               cxcywhn_to_xyxy(boxes, w, h), np.asarray(cls)))
    return detection_metrics(evals)


@dataclasses.dataclass(frozen=True)
class RecallCounts:
    """Object-level recall and false positives of a privacy detector over a set of images."""

    found: int
    """Required objects matched by a detection of an accepted class at IoU ≥ ``iou``."""
    total: int
    """Required objects."""
    false_positives: int
    """Detections on no labelled object (see :func:`privacy_recall`)."""
    images: int
    """Images evaluated."""
    per_type: dict[str, tuple[int, int]]
    """``type -> (found, total)`` per ground-truth type (e.g. KITTI ``Car``, ``Pedestrian``)."""

    @property
    def recall(self) -> float:
        """``found / total`` (``nan`` without required objects)."""
        return self.found / self.total if self.total else float("nan")

    @property
    def fp_per_image(self) -> float:
        """False positives per image."""
        return self.false_positives / self.images if self.images else float("nan")

    def __add__(self, other: "RecallCounts") -> "RecallCounts":
        per_type = dict(self.per_type)
        for k, (f, t) in other.per_type.items():
            f0, t0 = per_type.get(k, (0, 0))
            per_type[k] = (f0 + f, t0 + t)
        return RecallCounts(self.found + other.found, self.total + other.total,
                            self.false_positives + other.false_positives, self.images + other.images, per_type)


def privacy_recall(pred_boxes: np.ndarray, pred_scores: np.ndarray, pred_classes: np.ndarray,
                   gt_boxes: np.ndarray, gt_accepted: Sequence[Sequence[int]], gt_types: Sequence[str] = (),
                   ignored_boxes: np.ndarray | None = None, iou: float = 0.5) -> RecallCounts:
    """Object recall and false positives of one image's detections (a privacy filter's view).

    Detections are taken in descending confidence; each is matched to the unmatched required
    object of highest IoU ≥ ``iou`` whose accepted classes contain the detection's class
    (``gt_accepted[j]``, e.g. a KITTI Cyclist accepts person or bicycle). An unmatched detection
    is a false positive unless it lies on a labelled object: IoU ≥ ``iou`` with any required
    object (a duplicate or a class confusion still covers a real object) or with an
    ``ignored_boxes`` entry, or at least half of its area inside an ignored box (KITTI DontCare
    regions hold crowds of small objects).
    """
    pb = np.asarray(pred_boxes, np.float64).reshape(-1, 4)
    ps = np.asarray(pred_scores, np.float64).reshape(-1)
    pc = np.asarray(pred_classes).reshape(-1)
    gb = np.asarray(gt_boxes, np.float64).reshape(-1, 4)
    ib = np.zeros((0, 4)) if ignored_boxes is None else np.asarray(ignored_boxes, np.float64).reshape(-1, 4)
    if not (len(pb) == len(ps) == len(pc)):
        raise ValueError(f"prediction arrays differ in length: {len(pb)}, {len(ps)}, {len(pc)}")
    if len(gt_accepted) != len(gb) or (gt_types and len(gt_types) != len(gb)):
        raise ValueError("gt_accepted (and gt_types) need one entry per ground-truth box")
    iou_g = _iou(pb, gb) if len(gb) else np.zeros((len(pb), 0))
    iou_i = _iou(pb, ib) if len(ib) else np.zeros((len(pb), 0))
    if len(ib):
        lt = np.maximum(pb[:, None, :2], ib[None, :, :2])
        rb = np.minimum(pb[:, None, 2:], ib[None, :, 2:])
        inside = np.clip(rb - lt, 0, None).prod(-1) / np.maximum((pb[:, 2:] - pb[:, :2]).prod(-1), 1e-9)[:, None]
    else:
        inside = iou_i
    matched = np.zeros(len(gb), bool)
    fp = 0
    for d in np.argsort(-ps, kind="stable"):
        ok = np.array([int(pc[d]) in gt_accepted[j] for j in range(len(gb))], bool)
        cand = np.where(ok & ~matched & (iou_g[d] >= iou), iou_g[d], -1.0)
        if len(gb) and cand.max() >= iou:
            matched[int(cand.argmax())] = True
        elif not ((iou_g[d] >= iou).any() or (iou_i[d] >= iou).any() or (inside[d] >= 0.5).any()):
            fp += 1
    per_type: dict[str, tuple[int, int]] = {}
    for j, t in enumerate(gt_types):
        f0, t0 = per_type.get(t, (0, 0))
        per_type[t] = (f0 + int(matched[j]), t0 + 1)
    return RecallCounts(int(matched.sum()), len(gb), fp, 1, per_type)
