"""Copy-paste augmentation (``privslam_jax.detect.copy_paste``) against plain numpy / OpenCV references."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from privslam_jax.detect.copy_paste import PasteConfig, cut_instance, object_groups, paste_instances


def _frame(h: int = 120, w: int = 400, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3)).astype(np.uint8)


def test_object_groups_joins_riders_only():
    boxes = np.array([[10, 10, 30, 60], [12, 35, 32, 70],   # person on a bicycle
                      [100, 10, 120, 60],                     # a pedestrian alone
                      [200, 30, 260, 70],                     # a car
                      [300, 10, 320, 60], [330, 35, 350, 70]])  # person next to a bicycle, no overlap
    cls = np.array([0, 1, 0, 2, 0, 1])
    assert object_groups(boxes, cls) == [[0, 1], [2], [3], [4], [5]]
    assert object_groups(boxes, cls, skip=(2,)) == [[0, 1], [2], [4], [5]]


def test_cut_instance_uses_the_matte_or_an_ellipse():
    img = _frame()
    matte = np.zeros(img.shape[:2], np.uint8)
    matte[40:80, 50:60] = 255
    boxes = np.array([[48.0, 38.0, 63.0, 82.0]])
    inst = cut_instance(img, boxes, np.array([0]), matte, feather=0.0)
    np.testing.assert_array_equal(inst.rgb, img[38:82, 48:63])
    np.testing.assert_array_equal(inst.alpha, (matte[38:82, 48:63] > 0).astype(np.float32))
    np.testing.assert_allclose(inst.boxes, [[0, 0, 15, 44]])
    assert inst.bottom_row == 82 and inst.source_height == 120
    # a matte covering < 15 % of the box is ignored: the soft ellipse is 1 at the centre, 0 in the corners
    ell = cut_instance(img, boxes, np.array([0]), np.zeros_like(matte))
    assert ell.alpha[22, 7] == 1.0 and ell.alpha[0, 0] == 0.0 and ell.alpha[-1, -1] == 0.0
    np.testing.assert_allclose(ell.alpha, ell.alpha[::-1, ::-1])
    # objects cut by the frame border are not cut out
    assert cut_instance(img, np.array([[0.0, 38.0, 20.0, 82.0]]), np.array([0])) is None
    with pytest.raises((ValueError, TypeError), match="(?i)uint8"):  # TypeError: jaxtyping, when it checks
        cut_instance(img.astype(np.float32), boxes, np.array([0]))


def test_paste_blends_inside_the_new_box_on_the_ground_plane():
    src = _frame(seed=1)
    matte = np.zeros(src.shape[:2], np.uint8)
    matte[60:100, 200:220] = 255   # a solid object: alpha 1 everywhere in its box
    inst = cut_instance(src, np.array([[200.0, 60.0, 220.0, 100.0]]), np.array([0]), matte, feather=0.0)
    cfg = PasteConfig(horizon=0.4, max_cover=0.4)
    tgt = _frame(seed=2)
    existing = np.array([[0.0, 50.0, 60.0, 110.0]])
    for seed in range(20):
        out, boxes, cls = paste_instances(tgt, existing, np.array([2]), [inst], np.random.default_rng(seed), cfg)
        assert len(boxes) == 2 and list(cls) == [2, 0]
        np.testing.assert_array_equal(boxes[0], existing[0])
        x0, y0, x1, y1 = boxes[1]
        assert x0 == int(x0) and y0 == int(y0) and x1 == int(x1) and y1 == int(y1)
        x0, y0, x1, y1 = int(x0), int(y0), int(x1), int(y1)
        # flat ground: the distance of the bottom edge to the horizon scales with the object's height
        s = (y1 - y0) / 40
        assert abs((y1 - 0.4 * 120) - s * (100 - 0.4 * 120)) <= 1.0 + s
        # nothing outside the new box changed; inside it is the resized patch (possibly flipped)
        outside = np.ones(tgt.shape[:2], bool)
        outside[y0:y1, x0:x1] = False
        np.testing.assert_array_equal(out[outside], tgt[outside])
        patch = cv2.resize(inst.rgb, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        got = out[y0:y1, x0:x1].astype(int)
        assert min(np.abs(got - patch).max(), np.abs(got - patch[:, ::-1]).max()) <= 1
        # the existing box is covered at most by max_cover
        iw = max(0, min(x1, 60) - max(x0, 0))
        ih = max(0, min(y1, 110) - max(y0, 50))
        assert iw * ih / (60 * 60) <= 0.4 + 1e-9


def test_paste_keeps_rider_boxes_and_grey_frames():
    src = _frame(seed=3)
    boxes = np.array([[100.0, 40.0, 120.0, 90.0], [98.0, 65.0, 124.0, 100.0]])
    inst = cut_instance(src, boxes, np.array([0, 1]))
    grey = np.repeat(_frame(seed=4)[..., :1], 3, -1)
    out, pb, pc = paste_instances(grey, np.zeros((0, 4)), np.zeros(0, np.int32), [inst], np.random.default_rng(0),
                                  PasteConfig(horizon=0.4))
    assert list(pc) == [0, 1]
    assert np.array_equal(out[..., 0], out[..., 1]) and np.array_equal(out[..., 1], out[..., 2])
    # the members keep their layout: same relative offsets, scaled (or mirrored) with the patch
    s = (pb[0, 3] - pb[0, 1]) / 50
    union = np.r_[pb[:, :2].min(0), pb[:, 2:].max(0)]
    rel = (pb - np.r_[union[:2], union[:2]]) / s
    ref = boxes - [98, 40, 98, 40]
    mirrored = np.stack([26 - ref[:, 2], ref[:, 1], 26 - ref[:, 0], ref[:, 3]], 1)
    assert min(np.abs(rel - ref).max(), np.abs(rel - mirrored).max()) < 1.5
