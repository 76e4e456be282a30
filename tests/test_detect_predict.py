"""Detector API: letterbox geometry, shape buckets without recompiles, grey/RGB inputs, NMS semantics."""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.detect import (
    PRIVACY_CLASSES,
    PRIVACY_PRESET,
    Detector,
    DetectorConfig,
    YOLOv8Config,
    box_iou,
    letterbox,
    nms,
    non_max_suppression,
)
from privslam_jax.detect.yolov8 import init_yolov8


@pytest.fixture(scope="module")
def detector():
    return Detector(init_yolov8(YOLOv8Config(num_classes=80), seed=0), DetectorConfig(imgsz=64, conf=0.0))


def test_letterbox_geometry_like_ultralytics():
    # README: KITTI 1226x370 frames run at 224x640 (long side 640, short side padded to a multiple of 32)
    lb = letterbox(np.zeros((370, 1226), np.uint8), 640, "rect")
    assert lb.image.shape == (224, 640, 3) and lb.pad == (0, 15)
    col = lb.image[:, 320, 0]
    assert np.allclose(col[:15], 114 / 255) and np.allclose(col[15 + 193 :], 114 / 255) and np.allclose(col[15:208], 0)
    assert letterbox(np.zeros((480, 640, 3), np.uint8), 640, "rect").image.shape == (480, 640, 3)
    sq = letterbox(np.zeros((480, 640, 3), np.uint8), 640, "square")
    assert sq.image.shape == (640, 640, 3) and sq.pad == (0, 80)
    # boxes map back exactly: a box drawn in original pixels, scaled forward by hand
    b = np.array([[100.0, 50.0, 400.0, 300.0]])
    gy, gx = lb.gains
    fwd = np.array([[100 * gx, 50 * gy + 15, 400 * gx, 300 * gy + 15]])
    np.testing.assert_allclose(lb.boxes_to_original(fwd), b, rtol=1e-5)


def test_no_recompile_for_repeated_shapes(detector):
    rng = np.random.default_rng(0)
    detector.detect([rng.random((40, 64, 3), np.float32)])
    n = detector.compile_count
    detector.detect([rng.random((40, 64, 3), np.float32)])  # same shape
    detector.detect([rng.integers(0, 255, (80, 128), np.uint8)])  # other size, same letterbox shape (64x32)
    assert detector.compile_count == n
    detector.detect([rng.random((40, 64, 3), np.float32) for _ in range(3)])  # batch 3 -> padded to 4
    assert detector.compile_count == n + 1
    detector.detect([rng.random((40, 64, 3), np.float32) for _ in range(4)])
    assert detector.compile_count == n + 1


def test_grey_and_rgb_inputs_agree(detector):
    grey = np.random.default_rng(1).integers(0, 255, (50, 64), np.uint8)
    outs = detector.detect([grey, grey[..., None], np.repeat(grey[..., None], 3, -1)])
    assert len(outs[0]) > 0  # conf 0: raw candidates survive, so the comparison is not vacuous
    for o in outs[1:]:
        np.testing.assert_array_equal(np.asarray(o.boxes), np.asarray(outs[0].boxes))
        np.testing.assert_array_equal(np.asarray(o.class_ids), np.asarray(outs[0].class_ids))
    box = np.asarray(outs[0].boxes)
    assert box.min() >= 0 and box[:, [0, 2]].max() <= 64 and box[:, [1, 3]].max() <= 50


def test_bad_images_are_rejected(detector):
    with pytest.raises(ValueError, match="wrap a single image"):
        detector.detect(np.zeros((32, 32, 3), np.float32))
    with pytest.raises(ValueError, match="shape"):
        detector.detect([np.zeros((32, 32, 4), np.float32)])
    with pytest.raises(ValueError, match="shape"):
        detector.detect([np.zeros((0, 32, 3), np.float32)])
    with pytest.raises(ValueError, match="dtype"):
        detector.detect([np.zeros((32, 32, 3), np.int32)])
    with pytest.raises(ValueError, match="multiple of 32"):
        DetectorConfig(imgsz=100)


def _greedy_reference(boxes, scores, thr):
    """Plain-Python greedy NMS (textbook definition) for cross-checking."""
    order = sorted(range(len(scores)), key=lambda i: -scores[i])
    keep = []
    for i in order:
        if all(box_iou(boxes[i : i + 1], boxes[k : k + 1])[0, 0] <= thr for k in keep):
            keep.append(i)
    return keep


def test_nms_matches_greedy_reference():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (200, 2))
    wh = rng.uniform(5, 40, (200, 2))
    boxes = np.concatenate([xy, xy + wh], 1).astype(np.float32)
    scores = rng.permutation(200).astype(np.float32) / 200  # distinct scores
    for thr in (0.3, 0.5, 0.7):
        assert list(nms(boxes, scores, thr)) == _greedy_reference(boxes, scores, thr)


def test_class_aware_nms_and_privacy_preset():
    # two identical boxes of different classes both survive; same class -> one; class filter applies
    nc = 80
    pred = np.zeros((3, 4 + nc), np.float32)
    pred[:, :4] = [50, 50, 20, 20]
    pred[0, 4 + 2] = 0.9  # car
    pred[1, 4 + 2] = 0.8  # car duplicate
    pred[2, 4 + 9] = 0.7  # traffic light
    box, score, cls = non_max_suppression(pred, conf=0.25, iou=0.7)
    assert sorted(cls.tolist()) == [2, 9] and np.allclose(box[0], [40, 40, 60, 60])
    _, _, cls = non_max_suppression(pred, conf=PRIVACY_PRESET.conf, iou=0.7, classes=PRIVACY_PRESET.classes)
    assert cls.tolist() == [2]
    assert PRIVACY_CLASSES == (0, 1, 2, 3, 5, 7) and PRIVACY_PRESET.conf == 0.4
    # multi-label keeps each (box, class) pair above conf
    pred[0, 4 + 0] = 0.5
    _, _, cls = non_max_suppression(pred, conf=0.25, iou=0.7, multi_label=True)
    assert sorted(cls.tolist()) == [0, 2, 9]


def test_detector_refuses_input_it_does_not_understand():
    """Issue 15 item 8: 0-255 floats, NaN/inf or negative pixels, NaN weights gave '0 detections' (a leak)."""
    import jax
    from flax import nnx

    from privslam_jax.detect import Detector, DetectorConfig
    from privslam_jax.detect.yolov8 import YOLOv8Config, init_yolov8

    model = init_yolov8(YOLOv8Config(num_classes=8, scale="tiny"))
    det = Detector(model, DetectorConfig(imgsz=64))
    ok = np.full((40, 64, 3), 0.5, np.float32)
    assert len(det.detect([ok])) == 1
    for bad, match in ((ok * 255, "divide by 255"), (np.where(ok > 0, np.nan, ok), "NaN"), (ok - 1, r"\[0, 1\]")):
        with pytest.raises(ValueError, match=match):
            det.detect([bad])
    params = nnx.state(model, nnx.Param)
    leaf = jax.tree.leaves(params)[0]
    nnx.update(model, jax.tree.map(lambda x: x * np.nan if x is leaf else x, params))
    with pytest.raises(ValueError, match="NaN or infinite"):
        Detector(model, DetectorConfig(imgsz=64))


@pytest.mark.parametrize("mode", ["rect", "square"])
@pytest.mark.parametrize("shape", [(1, 20000, 3), (20000, 1, 3), (3, 5000)])
def test_extreme_aspect_ratios_letterbox_instead_of_a_cv2_error(shape, mode):
    """Issue 15 item 9: a 1×20000 image made cv2.resize assert (0-pixel side) deep in the detector."""
    from privslam_jax.detect.predict import letterbox

    img = np.full(shape, 200, np.uint8)
    lb = letterbox(img, 640, mode)
    assert lb.image.shape[-1] == 3 and max(lb.image.shape[:2]) == 640 and min(lb.image.shape[:2]) >= 1
    # the image content survives (not only padding): some pixel is the image's, not the grey 114
    assert np.isclose(lb.image, 200 / 255, atol=1e-3).any()
