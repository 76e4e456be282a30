"""YOLO labels and dataset folders, against plain numpy parsing and OpenCV decoding."""

import cv2
import numpy as np
import pytest

from privslam_jax.data.yolo import (
    YoloDataset,
    cxcywhn_to_xyxy,
    read_yolo_labels,
    write_yolo_labels,
    xyxy_to_cxcywhn,
)


def test_box_conversions_inverse_and_closed_form():
    b = np.array([[10.0, 20.0, 50.0, 80.0], [0.0, 0.0, 640.0, 192.0]])
    n = xyxy_to_cxcywhn(b, 640, 192)
    np.testing.assert_allclose(n[0], [30 / 640, 50 / 192, 40 / 640, 60 / 192])
    np.testing.assert_allclose(n[1], [0.5, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(cxcywhn_to_xyxy(n, 640, 192), b, atol=1e-12)


def test_write_read_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 300, size=(6, 2))
    b = np.concatenate([lo, lo + rng.uniform(1, 100, size=(6, 2))], axis=1)
    cls = np.array([0, 2, 2, 7, 1, 5], np.int32)
    write_yolo_labels(tmp_path / "l.txt", cls, b, 640, 480)
    rows = np.loadtxt(tmp_path / "l.txt")
    assert rows.shape == (6, 5)
    c2, n2 = read_yolo_labels(tmp_path / "l.txt")
    np.testing.assert_array_equal(c2, cls)
    np.testing.assert_allclose(cxcywhn_to_xyxy(n2, 640, 480), b, atol=1e-3)  # %.6f of the normalised value
    write_yolo_labels(tmp_path / "e.txt", np.zeros(0, np.int32), np.zeros((0, 4)), 10, 10)
    c3, n3 = read_yolo_labels(tmp_path / "e.txt")
    assert c3.shape == (0,) and n3.shape == (0, 4)


def test_polygon_lines_become_bounding_boxes(tmp_path):
    (tmp_path / "p.txt").write_text("3 0.1 0.2 0.5 0.25 0.3 0.6\n")
    c, n = read_yolo_labels(tmp_path / "p.txt")
    assert c.tolist() == [3]
    np.testing.assert_allclose(n[0], [0.3, 0.4, 0.4, 0.4])


def test_coco8_dataset(shared):
    root = shared / "data/coco8"
    for split in ("train", "val"):
        ds = YoloDataset(root, split)
        assert len(ds) == 4
        for s in ds:
            ref = cv2.imread(str(s.image_path))[:, :, ::-1].astype(np.float32) / 255.0
            np.testing.assert_array_equal(s.image, ref)
            rows = np.loadtxt(root / "labels" / split / (s.image_path.stem + ".txt"), ndmin=2)
            h, w = ref.shape[:2]
            np.testing.assert_array_equal(s.class_ids, rows[:, 0].astype(int))
            cx, cy, bw, bh = rows[:, 1] * w, rows[:, 2] * h, rows[:, 3] * w, rows[:, 4] * h
            np.testing.assert_allclose(s.boxes, np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1))


def test_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        read_yolo_labels(tmp_path / "nope.txt")
    c, _ = read_yolo_labels(tmp_path / "nope.txt", missing_ok=True)
    assert c.size == 0
    (tmp_path / "b.txt").write_text("0 0.5 0.5 0.1 0.1\n1 0.5 0.5 0.1\n")
    with pytest.raises(ValueError, match=r"b\.txt:2: expected"):
        read_yolo_labels(tmp_path / "b.txt")
    (tmp_path / "c.txt").write_text("car 0.5 0.5 0.1 0.1\n")
    with pytest.raises(ValueError, match=r"c\.txt:1: not a number"):
        read_yolo_labels(tmp_path / "c.txt")
    (tmp_path / "d.txt").write_text("1.5 0.5 0.5 0.1 0.1\n")
    with pytest.raises(ValueError, match=r"d\.txt:1: class id"):
        read_yolo_labels(tmp_path / "d.txt")
    with pytest.raises(FileNotFoundError, match="images"):
        YoloDataset(tmp_path, "train")
    with pytest.raises(ValueError, match="class ids"):
        write_yolo_labels(tmp_path / "x.txt", np.zeros(2, np.int32), np.zeros((1, 4)), 10, 10)


def test_synthetic_label_rule_against_plain_numpy():
    from types import SimpleNamespace

    from privslam_jax.data.yolo import SynthLabelRule, synthetic_labels

    rng = np.random.default_rng(3)
    inst = np.zeros((40, 120), np.int32)
    specs = {}  # instance -> (x1, y1, x2, y2) of a filled rectangle
    for k, (x, y, w, h) in enumerate([(2, 2, 20, 30), (30, 5, 5, 12), (40, 5, 10, 9), (60, 1, 8, 13), (80, 3, 30, 30)], 1):
        inst[y : y + h, x : x + w] = k
        specs[k] = (x, y, x + w, y + h)
    blk = inst[3:33, 80:110]
    blk[rng.random(blk.shape) < 0.97] = 0  # instance 5: big box, few visible pixels
    boxes = np.array([specs[k] for k in (1, 2, 3, 4, 5)], np.float32)
    frame = SimpleNamespace(boxes=boxes, class_ids=np.array([0, 2, 7, 1, 5], np.int32),
                            instance_of_box=np.array([1, 2, 3, 4, 5], np.int32), instance_ids=inst)
    rule = SynthLabelRule(min_width=6.0, min_height=12.0, min_visible_px=60)
    cls, kept = synthetic_labels(frame, rule)
    expect = [k for k in (1, 2, 3, 4, 5)
              if boxes[k - 1, 2] - boxes[k - 1, 0] >= 6 and boxes[k - 1, 3] - boxes[k - 1, 1] >= 12
              and (inst == k).sum() >= 60]
    assert expect == [1, 4]  # 2 too narrow, 3 too short, 5 mostly hidden
    np.testing.assert_array_equal(kept, boxes[np.array(expect) - 1])
    np.testing.assert_array_equal(cls, frame.class_ids[np.array(expect) - 1])
    empty = SimpleNamespace(boxes=np.zeros((0, 4), np.float32), class_ids=np.zeros(0, np.int32),
                            instance_of_box=np.zeros(0, np.int32), instance_ids=np.zeros((4, 4), np.int32))
    c0, b0 = synthetic_labels(empty)
    assert c0.shape == (0,) and b0.shape == (0, 4)


def test_link_mixed_split_oversamples_and_keeps_labels(tmp_path):
    from privslam_jax.data.yolo import YoloDataset, link_mixed_split, write_yolo_labels

    for split, n in (("a", 3), ("b", 2)):
        (tmp_path / "images" / split).mkdir(parents=True)
        for i in range(n):
            cv2.imwrite(str(tmp_path / "images" / split / f"{split}{i}.png"), np.full((8, 8, 3), 10 * i, np.uint8))
            write_yolo_labels(tmp_path / "labels" / split / f"{split}{i}.txt", np.array([i]), np.array([[1.0, 1, 5, 5]]), 8, 8)
    assert link_mixed_split(tmp_path, "mix", [(tmp_path / "a", 1), (tmp_path / "b", 3)]) == 3 + 2 * 3
    ds = YoloDataset(tmp_path, "mix")
    assert len(ds) == 9
    names = [p.name for p in ds.image_paths]
    assert names.count("r0_b1.png") == 1 and "r2_b1.png" in names and "a0.png" in names
    sample = ds[names.index("r2_b1.png")]
    assert sample.class_ids.tolist() == [1] and np.allclose(sample.boxes, [[1, 1, 5, 5]], atol=1e-3)
