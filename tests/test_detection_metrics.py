"""Detection metrics: hand-checked matching/AP cases and ultralytics' coco8 val numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from privslam_jax.metrics.detection import (
    ImageEval,
    compute_ap,
    detection_metrics,
    evaluate_yolo_folder,
    match_predictions,
)


def test_match_is_one_to_one_and_class_aware():
    # one ground truth, two same-class predictions: one TP per threshold; class 2 never matches
    iou = np.array([[0.6, 0.9, 0.95]])
    tp = match_predictions(np.array([1, 1, 2]), np.array([1]), iou, np.array([0.5, 0.75]))
    assert tp.sum(0).tolist() == [1, 1] and not tp[2].any()
    assert tp[1, 1]  # at 0.75 only the 0.9 prediction qualifies
    # ultralytics quirk (kept on purpose): after de-duplicating by prediction the rows are ordered
    # by prediction index, so the ground truth keeps its lowest-index candidate, here the IoU-0.6 one
    assert tp[0, 0] and not tp[1, 0]
    # two ground truths, two predictions: both matched at 0.5
    tp = match_predictions(np.array([1, 1]), np.array([1, 1]), np.array([[0.6, 0.9], [0.7, 0.0]]), np.array([0.5]))
    assert tp[:, 0].tolist() == [True, True]


def test_compute_ap_closed_form():
    # envelope 1 on [0, 1) dropping to the sentinel 0 at recall 1: 101-point trapezoid = 1 - 0.01/2
    assert compute_ap(np.array([0.5, 1.0]), np.array([1.0, 1.0])) == pytest.approx(0.995)
    # precision 1 up to recall 0.5, then linear to 0 at recall 1: exact area 0.5 + 0.25
    assert compute_ap(np.array([0.5]), np.array([1.0])) == pytest.approx(0.75)


def test_perfect_and_empty_predictions():
    gt = np.array([[0, 0, 10, 10], [20, 20, 40, 40]], float)
    perfect = ImageEval(gt, np.array([0.9, 0.8]), np.array([0, 3]), gt, np.array([0, 3]))
    m = detection_metrics([perfect])
    assert m.map50 == pytest.approx(0.995) and m.map50_95 == pytest.approx(0.995)  # ultralytics' ceiling
    assert m.precision == pytest.approx(1.0) and m.recall == pytest.approx(1.0, abs=1e-6)
    empty = ImageEval(np.zeros((0, 4)), np.zeros(0), np.zeros(0, int), gt, np.array([0, 3]))
    assert detection_metrics([empty]).as_dict() == {"precision": 0.0, "recall": 0.0, "mAP50": 0.0, "mAP50-95": 0.0}
    # a box shifted to IoU 0.6 counts at 0.5 and 0.55 only: AP over thresholds = 2/10
    shifted = np.array([[0, 0, 10, 10], [20, 20, 40, 40]], float)
    shifted[1] = [20, 20, 40, 40 + 20 * (1 / 0.6 - 1)]  # IoU = 1/ (1 + extra) = 0.6
    m = detection_metrics([ImageEval(shifted[1:], np.array([0.9]), np.array([3]), gt[1:], np.array([3]))])
    assert m.map50 == pytest.approx(0.995) and m.map50_95 == pytest.approx(0.2 * 0.995)


@pytest.mark.shared
def test_coco8_matches_ultralytics_val(shared):
    from privslam_jax.detect import Detector, DetectorConfig

    ref = json.loads((shared / "reference" / "yolov8n_coco8_val.json").read_text())
    cfg = DetectorConfig(mode="square", conf=0.001, iou=0.7, multi_label=True, max_det=300)
    detector = Detector.from_weights(shared / "weights" / "yolov8n.pt", cfg)
    for split in ("val", "train"):
        got = evaluate_yolo_folder(detector, shared / "data" / "coco8", split).as_dict()
        for key, value in got.items():
            assert abs(value - ref[split][key]) <= 0.02, (split, key, value, ref[split][key])
