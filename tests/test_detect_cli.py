"""``privslam detect`` CLI: JSON layout, annotated PNGs, class filter, clear errors."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from privslam_jax.cli import main
from privslam_jax.commands import detect as detect_cmd


def _run(argv):
    return main(argv)


@pytest.mark.shared
def test_detect_folder_writes_json_and_pngs(shared, tmp_path):
    src = tmp_path / "seq"
    (src / "image_0").mkdir(parents=True)
    for name in ("000000.png", "000001.png"):
        shutil.copy(shared / "data/kitti_odometry/sequences/00/image_0" / name, src / "image_0" / name)
    out = tmp_path / "out"
    weights = shared / "weights" / "yolov8n.pt"
    assert _run(["detect", str(src), "--weights", str(weights), "--classes", "privacy", "--out", str(out)]) == 0
    data = json.loads((out / "detections.json").read_text())
    assert [im["file"] for im in data["images"]] == ["image_0/000000.png", "image_0/000001.png"]
    dets = [d for im in data["images"] for d in im["detections"]]
    assert dets, "parked cars are expected in KITTI 00"
    for d in dets:
        assert set(d) == {"xyxy", "conf", "class_id", "class_name"}
        assert d["class_id"] in (0, 1, 2, 3, 5, 7) and d["conf"] > 0.4
        x1, y1, x2, y2 = d["xyxy"]
        assert 0 <= x1 < x2 <= 1241 and 0 <= y1 < y2 <= 376  # original KITTI pixels
    assert {d["class_name"] for d in dets} <= {"person", "bicycle", "car", "motorcycle", "bus", "truck"}
    png = cv2.imread(str(out / "image_0__000000.png"))
    assert png is not None and png.shape[:2] == (376, 1241)


def test_cli_boxes_are_detector_detect(tmp_path):
    """The JSON holds exactly what ``Detector.detect`` returns on the same files (read back from
    the PNGs), with the settings the CLI documents for ``--classes privacy`` (PRIVACY_CLASSES at
    conf 0.4, NMS IoU 0.7, imgsz 640). Reference: ``Detector.embedded(PRIVACY_PRESET).detect``
    called directly; runs without ../shared (synthetic frames, embedded synthetic-world detector)."""
    from privslam_jax.data.images import read_rgb8
    from privslam_jax.data.synthetic import SynthConfig, make_sequence
    from privslam_jax.detect.predict import PRIVACY_CLASSES, PRIVACY_PRESET, Detector, DetectorConfig

    seq = make_sequence(SynthConfig(seed=424242, num_frames=3))
    src = tmp_path / "seq"
    (src / "image_2").mkdir(parents=True)
    for i in (0, 2):
        rgb8 = np.round(seq[i].image * 255).astype(np.uint8)
        cv2.imwrite(str(src / "image_2" / f"{i:06d}.png"), cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR))
    out = tmp_path / "out"
    assert _run(["detect", str(src), "--embedded", "synthetic", "--classes", "privacy", "--out", str(out)]) == 0
    data = json.loads((out / "detections.json").read_text())
    files = sorted((src / "image_2").glob("*.png"))
    assert [im["file"] for im in data["images"]] == ["image_2/000000.png", "image_2/000002.png"]

    config = DetectorConfig(imgsz=640, conf=0.4, iou=0.7, classes=PRIVACY_CLASSES)
    assert config == PRIVACY_PRESET
    det = Detector.embedded(config, domain="synthetic")
    expected = det.detect([read_rgb8(p) for p in files])
    total = 0
    for im, ref in zip(data["images"], expected):
        got = im["detections"]
        assert len(got) == len(np.asarray(ref.scores)), im["file"]
        total += len(got)
        if not got:
            continue
        np.testing.assert_allclose(np.array([d["xyxy"] for d in got]), np.asarray(ref.boxes), rtol=0, atol=1e-3)
        np.testing.assert_allclose([d["conf"] for d in got], np.asarray(ref.scores), rtol=1e-5)
        assert [d["class_id"] for d in got] == np.asarray(ref.class_ids).tolist()
        assert [d["class_name"] for d in got] == [det.names[c] for c in np.asarray(ref.class_ids).tolist()]
        assert min(d["conf"] for d in got) > 0.4 and {d["class_id"] for d in got} <= set(PRIVACY_CLASSES)
    assert total >= 4  # the synthetic street has cars and people to find
    for name in ("image_2__000000.png", "image_2__000002.png"):
        png = cv2.imread(str(out / name))
        assert png is not None and png.shape == seq[0].image.shape


def test_missing_weights_and_source_errors(tmp_path, capsys):
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((32, 32, 3), np.uint8))
    if not detect_cmd.EMBEDDED_REAL_WEIGHTS.is_file():
        assert _run(["detect", str(img), "--out", str(tmp_path / "o")]) == 2
        assert "pass --weights" in capsys.readouterr().err
    assert _run(["detect", str(tmp_path / "nope"), "--weights", "x.pt", "--out", str(tmp_path / "o")]) == 2
    assert "source not found" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no images"):
        detect_cmd.list_images(tmp_path / "empty")
