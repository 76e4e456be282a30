"""The embedded default detector: shipped in the package, COCO ids/names, finds the synthetic world's objects.

Reference: the synthetic renderer's ground truth (tight boxes around visible instance masks, kept
by the documented label rule) on a frame of a seed never used in training.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from privslam_jax.cli import main
from privslam_jax.commands import detect as detect_cmd
from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.data.yolo import synthetic_labels
from privslam_jax.detect import EMBEDDED_WEIGHTS, PRIVACY_PRESET, Detector
from privslam_jax.metrics.detection import _iou

COCO = {0: "person", 1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}


@pytest.fixture(scope="module")
def frames():
    seq = make_sequence(SynthConfig(seed=424242, num_frames=25))
    return [seq[0], seq[24]]


def test_embedded_weights_are_shipped_small_and_coco_named():
    assert EMBEDDED_WEIGHTS == detect_cmd.EMBEDDED_WEIGHTS
    assert EMBEDDED_WEIGHTS.is_file(), "the embedded detector must ship in privslam_jax/assets"
    assert EMBEDDED_WEIGHTS.stat().st_size <= 15 * 2**20
    det = Detector.embedded()
    assert det.config == PRIVACY_PRESET
    assert det.model.config.num_classes == 8
    for k, v in COCO.items():
        assert det.names[k] == v


def test_embedded_detector_finds_ground_truth_objects(frames):
    det = Detector.embedded()
    found = total = false_pos = 0
    for f in frames:
        gt_cls, gt_boxes = synthetic_labels(f)
        d = det.detect([f.image])[0]
        boxes, cls = np.asarray(d.boxes, np.float64), np.asarray(d.class_ids)
        assert set(cls.tolist()) <= set(COCO)
        iou = _iou(gt_boxes, boxes) if len(boxes) and len(gt_boxes) else np.zeros((len(gt_boxes), len(boxes)))
        same = gt_cls[:, None] == cls[None, :]
        found += int(((iou >= 0.5) & same).any(1).sum())
        total += len(gt_boxes)
        false_pos += int((~((iou >= 0.3)).any(0)).sum()) if len(gt_boxes) else len(boxes)
    assert total >= 5
    assert found / total >= 0.8, f"found {found} of {total} ground-truth objects"
    assert false_pos <= max(2, total // 5), f"{false_pos} detections far from every ground-truth object"


def test_cli_uses_the_embedded_synthetic_detector(frames, tmp_path):
    f = frames[0]
    img = tmp_path / "frame.png"
    cv2.imwrite(str(img), cv2.cvtColor(np.round(f.image * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    out = tmp_path / "out"
    assert main(["detect", str(img), "--classes", "privacy", "--embedded", "synthetic", "--out", str(out)]) == 0
    data = json.loads((out / "detections.json").read_text())
    dets = data["images"][0]["detections"]
    gt_cls, gt_boxes = synthetic_labels(f)
    assert len(dets) >= len(gt_boxes) // 2 > 0
    for d in dets:
        assert d["class_name"] == COCO[d["class_id"]] and d["conf"] > 0.4
    boxes = np.array([d["xyxy"] for d in dets])
    assert (_iou(gt_boxes, boxes) >= 0.5).any(1).mean() >= 0.7
