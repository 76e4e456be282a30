"""KITTI object labels and the privacy-recall metric, against a plain re-implementation and the real labels."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from privslam_jax.data.kitti_object import read_kitti_object_labels
from privslam_jax.metrics.detection import RecallCounts, privacy_recall

LABELS = """\
Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57
Pedestrian 0.00 1 0.21 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01
Cyclist 0.70 0 -1.2 0.00 150.00 60.00 300.00 1.8 0.6 1.7 -8 1.6 9 -1.5
Van 0.10 2 1.2 500.00 150.00 600.00 250.00 2.0 1.9 4.5 1 1.7 15 1.1
Truck 0.00 0 1.2 800.00 100.00 1000.00 260.00 3.0 2.5 9.0 5 1.7 25 1.1
DontCare -1 -1 -10 1000.00 160.00 1100.00 200.00 -1 -1 -1 -1000 -1000 -1000 -10
"""


def test_read_labels_applies_the_protocol(tmp_path):
    p = tmp_path / "000000.txt"
    p.write_text(LABELS)
    lab = read_kitti_object_labels(p)
    # Car is 21.6 px tall (< 25), Cyclist truncated 0.7 (> 0.5), Van occluded 2 (> 1), DontCare: ignored.
    assert lab.types == ("Pedestrian", "Truck")
    assert lab.accepted == ((0,), (7, 2))
    np.testing.assert_allclose(lab.boxes, [[712.40, 143.00, 810.73, 307.92], [800, 100, 1000, 260]])
    assert lab.ignored.shape == (4, 4)


@pytest.mark.parametrize("bad", ["Car 0 0", "Bird 0 0 0 1 2 3 4", "Car x 0 0 1 2 3 4", "Car 0 0 0 10 10 5 20"])
def test_read_labels_rejects_bad_lines(tmp_path, bad):
    p = tmp_path / "x.txt"
    p.write_text(bad + "\n")
    with pytest.raises(ValueError, match="x.txt:1"):
        read_kitti_object_labels(p)
    with pytest.raises(FileNotFoundError):
        read_kitti_object_labels(tmp_path / "missing.txt")


def _iou(a, b):
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def _reference(pb, ps, pc, gb, acc, ib, thr=0.5):
    """Loop-by-loop re-implementation of the documented rule."""
    matched = [False] * len(gb)
    fp = 0
    for d in sorted(range(len(pb)), key=lambda i: -ps[i]):
        best, best_iou = None, thr
        for j in range(len(gb)):
            v = _iou(pb[d], gb[j])
            if not matched[j] and pc[d] in acc[j] and v >= best_iou:
                if best is None or v > best_iou:
                    best, best_iou = j, v
        if best is not None:
            matched[best] = True
            continue
        on_object = any(_iou(pb[d], g) >= thr for g in gb) or any(_iou(pb[d], g) >= thr for g in ib)
        area = (pb[d][2] - pb[d][0]) * (pb[d][3] - pb[d][1])
        for g in ib:
            ix = max(0.0, min(pb[d][2], g[2]) - max(pb[d][0], g[0]))
            iy = max(0.0, min(pb[d][3], g[3]) - max(pb[d][1], g[1]))
            on_object |= ix * iy / area >= 0.5
        fp += not on_object
    return sum(matched), fp


def _boxes(rng, n):
    xy = rng.uniform(0, 80, (n, 2))
    wh = rng.uniform(8, 40, (n, 2))
    return np.concatenate([xy, xy + wh], 1)


@pytest.mark.parametrize("seed", range(40))
def test_privacy_recall_matches_reference(seed):
    rng = np.random.default_rng(seed)
    gb = _boxes(rng, rng.integers(0, 6))
    acc = [tuple(rng.choice([0, 1, 2, 7], rng.integers(1, 3), replace=False).tolist()) for _ in gb]
    # predictions: jittered copies of some ground truths plus random boxes
    pb = np.concatenate([gb[rng.random(len(gb)) < 0.7] + rng.normal(0, 3, (1, 4)), _boxes(rng, rng.integers(0, 5))])
    pb[:, 2:] = np.maximum(pb[:, 2:], pb[:, :2] + 1)
    ps = rng.uniform(0, 1, len(pb))
    pc = rng.choice([0, 1, 2, 7], len(pb))
    ib = _boxes(rng, rng.integers(0, 3))
    r = privacy_recall(pb, ps, pc, gb, acc, ignored_boxes=ib)
    found, fp = _reference(pb.tolist(), ps.tolist(), pc.tolist(), gb.tolist(), acc, ib.tolist())
    assert (r.found, r.false_positives, r.total) == (found, fp, len(gb))


def test_privacy_recall_counts_and_sum():
    gb = np.array([[0, 0, 10, 20], [50, 50, 70, 90.0]])
    r = privacy_recall(np.array([[0, 0, 10, 20], [0, 1, 10, 20], [200, 200, 210, 210.0]]), np.array([0.9, 0.8, 0.5]),
                       np.array([2, 2, 2]), gb, [(2,), (0,)], ("Car", "Pedestrian"))
    # the duplicate covers the matched car: not a false positive; the far box is one
    assert (r.found, r.total, r.false_positives) == (1, 2, 1)
    assert r.per_type == {"Car": (1, 1), "Pedestrian": (0, 1)}
    s = r + r
    assert (s.found, s.total, s.images, s.recall, s.fp_per_image) == (2, 4, 2, 0.5, 1.0)
    assert np.isnan(RecallCounts(0, 0, 0, 0, {}).recall)
    with pytest.raises(ValueError):
        privacy_recall(np.zeros((2, 4)), np.zeros(1), np.zeros(2), gb, [(2,), (0,)])
    with pytest.raises(ValueError):
        privacy_recall(np.zeros((0, 4)), np.zeros(0), np.zeros(0), gb, [(2,)])


@pytest.mark.shared
def test_kitti_object_set_has_the_issue_counts(shared):
    """The 31 labelled real frames hold the 56 required objects that issue 13 counted independently."""
    paths = sorted((shared / "data" / "real" / "kitti_object" / "label_2").glob("*.txt"))
    assert len(paths) == 31
    types = list(itertools.chain.from_iterable(read_kitti_object_labels(p).types for p in paths))
    assert len(types) == 56
