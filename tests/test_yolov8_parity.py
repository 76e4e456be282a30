"""Parity with ultralytics 8.4 + torch (reference outputs in ../shared/reference/yolov8n_reference.npz)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from privslam_jax.detect import box_iou
from privslam_jax.detect.predict import Detector, DetectorConfig

pytestmark = pytest.mark.shared


@pytest.fixture(scope="module")
def setup(shared):
    detector = Detector.from_weights(shared / "weights" / "yolov8n.pt", DetectorConfig(conf=0.25, iou=0.7))
    return shared, detector, np.load(shared / "reference" / "yolov8n_reference.npz")


def test_raw_head_output_matches(setup):
    _, detector, ref = setup
    names = ["rand_192x640", "kitti00_0_192x640"]
    x = np.concatenate([ref[f"{n}_input_nchw_rgb01"] for n in names]).transpose(0, 2, 3, 1)
    out = detector.forward(x).transpose(0, 2, 1)  # (B, 84, 2520) like torch
    for i, n in enumerate(names):
        expected = ref[f"{n}_raw_output"][0]
        assert out[i].shape == expected.shape
        assert np.abs(out[i, :4] - expected[:4]).max() <= 0.05, n  # cx, cy, w, h in pixels
        assert np.abs(out[i, 4:] - expected[4:]).max() <= 1e-3, n  # class probabilities


def test_end_to_end_detections_match(setup):
    shared, detector, ref = setup
    files = [str(f) for f in ref["pred_files"]]
    assert len(files) == 24
    images = [cv2.cvtColor(cv2.imread(str(shared / f)), cv2.COLOR_BGR2RGB) for f in files]
    results = detector.detect(images)
    n_ref = 0
    for i, (f, det) in enumerate(zip(files, results)):
        rb, rc, rk = ref[f"pred{i}_xyxy"], ref[f"pred{i}_conf"], ref[f"pred{i}_cls"]
        b, c, k = np.asarray(det.boxes), np.asarray(det.scores), np.asarray(det.class_ids)
        n_ref += len(rb)
        iou = box_iou(rb, b) if len(rb) and len(b) else np.zeros((len(rb), len(b)))
        iou = np.where(rk[:, None] == k[None, :], iou, 0.0)  # same class only
        matched = set()
        for j in range(len(rb)):
            m = int(np.argmax(iou[j])) if len(b) else -1
            assert m >= 0 and iou[j, m] >= 0.98, f"{f}: reference box {j} unmatched (IoU {iou[j].max(initial=0):.4f})"
            assert abs(c[m] - rc[j]) <= 0.01, f"{f}: conf {c[m]:.4f} vs {rc[j]:.4f}"
            matched.add(m)
        extra = [c[m] for m in range(len(b)) if m not in matched]
        assert all(e <= 0.3 for e in extra), f"{f}: unmatched detections {extra}"
    assert n_ref > 40  # the reference really has boxes to match
