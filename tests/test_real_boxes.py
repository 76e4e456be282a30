"""The developer-drawn real training boxes (``train/data/real_boxes*.json``): well-formed, and never on evaluation data."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted((ROOT / "train" / "data").glob("real_boxes*.json"))
EVALUATION_ONLY = ("kitti_object", "kitti_raw_b", "nuscenes_front")  # ../shared/README.md
SIZES = {"data/real/kitti_raw_a/": (1242, 375), "data/kitti_odometry/sequences/seq1/": (1241, 376),
         "data/kitti_odometry/sequences/00/": (1241, 376)}  # the frames' width, height


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_real_boxes_are_well_formed_and_only_on_training_frames(path):
    boxes = json.loads(path.read_text())["boxes"]
    assert len(FILES) >= 2 and boxes
    for frame, rows in boxes.items():
        assert not any(name in frame for name in EVALUATION_ONLY), frame
        (w, h), = [size for prefix, size in SIZES.items() if frame.startswith(prefix)]
        for x1, y1, x2, y2, cls in rows:
            assert 0 <= x1 < x2 <= w + 1 and 0 <= y1 < y2 <= h + 1, (frame, x1, y1, x2, y2)
            assert cls in (0, 1, 2, 3, 5, 7), (frame, cls)
        assert len({tuple(r) for r in rows}) == len(rows), f"duplicate box in {frame}"


def test_version_2_keeps_every_keyframe_of_version_1():
    v1, v2 = (json.loads((ROOT / "train" / "data" / n).read_text())["boxes"] for n in ("real_boxes.json", "real_boxes_v2.json"))
    assert v1.keys() == v2.keys()
    assert sum(map(len, v2.values())) > sum(map(len, v1.values()))
