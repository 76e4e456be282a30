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
