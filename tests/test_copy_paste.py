"""Copy-paste augmentation (``privslam_jax.detect.copy_paste``) against plain numpy / OpenCV references."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from privslam_jax.detect.copy_paste import PasteConfig, cut_instance, object_groups, paste_instances, synthetic_instances


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


def _synth_frame():
    """A rendered-frame stand-in: instance 1 a person, 2 a car beside it, 3 a person touching the border,
    4 a person with a car (instance 5) inside its box, 6 a bicycle too short to cut."""
    from types import SimpleNamespace
    img = np.random.default_rng(5).random((100, 200, 3)).astype(np.float32)
    ids = np.zeros((100, 200), np.int32)
    ids[20:70, 30:44] = 1
    ids[50:80, 44:90] = 2
    ids[10:60, 0:10] = 3
    ids[30:90, 120:140] = 4
    ids[60:80, 125:135] = 5
    ids[80:95, 160:180] = 6
    boxes = np.array([[30, 20, 44, 70], [44, 50, 90, 80], [0, 10, 10, 60], [120, 30, 140, 90], [125, 60, 135, 80],
                      [160, 80, 180, 95]], np.float32)
    return SimpleNamespace(image=img, instance_ids=ids, boxes=boxes, class_ids=np.array([0, 2, 0, 0, 2, 1], np.int32),
                           instance_of_box=np.array([1, 2, 3, 4, 5, 6], np.int32))


def test_synthetic_instances_cut_whole_unmixed_objects_by_their_masks():
    f = _synth_frame()
    out = synthetic_instances(f, np.random.default_rng(0), feather=0.0)
    assert len(out) == 1  # 2: not a cut class; 3: touches the border; 4: 1/6 of its box is instance 5; 6: too short
    inst = out[0]
    np.testing.assert_array_equal(inst.rgb, np.clip(np.rint(f.image[20:70, 30:44] * 255), 0, 255).astype(np.uint8))
    np.testing.assert_array_equal(inst.alpha, np.ones((50, 14), np.float32))
    np.testing.assert_array_equal(inst.boxes, [[0, 0, 14, 50]])
    assert list(inst.class_ids) == [0] and inst.bottom_row == 70 and inst.source_height == 100
    assert inst.horizon == pytest.approx(0.495)  # the world's level camera: cy = (H - 1) / 2
    # a looser share of other objects admits instance 4; lower min_height admits the bicycle
    more = synthetic_instances(f, np.random.default_rng(0), max_other=0.2, min_height=12, feather=0.0)
    assert [int(i.class_ids[0]) for i in more] == [0, 0, 1]
    np.testing.assert_array_equal(more[1].alpha, (f.instance_ids[30:90, 120:140] == 4).astype(np.float32))


def test_paste_matches_light_towards_the_covered_region():
    src = np.full((120, 400, 3), 200, np.uint8)
    matte = np.zeros(src.shape[:2], np.uint8)
    matte[60:100, 200:220] = 255
    inst = cut_instance(src, np.array([[200.0, 60.0, 220.0, 100.0]]), np.array([0]), matte, feather=0.0)
    tgt = np.full_like(src, 50)
    for seed in range(10):
        out, boxes, _ = paste_instances(tgt, np.zeros((0, 4)), np.zeros(0, np.int32), [inst], np.random.default_rng(seed),
                                        PasteConfig(horizon=0.4, match_light=1.0))
        x0, y0, x1, y1 = (int(v) for v in boxes[0])
        # gain = clip(50 / 200, 1/3, 3) ** U(0.5, 1) in [1/3, 1/sqrt(3)]
        v = out[y0:y1, x0:x1].astype(float)
        assert v.min() == v.max() and 200 / 3 - 1 <= v.min() <= 200 / np.sqrt(3) + 1
    plain, boxes, _ = paste_instances(tgt, np.zeros((0, 4)), np.zeros(0, np.int32), [inst], np.random.default_rng(0),
                                      PasteConfig(horizon=0.4))
    x0, y0, x1, y1 = (int(v) for v in boxes[0])
    assert (plain[y0:y1, x0:x1] == 200).all()


def test_synthetic_instances_skip_partly_hidden_people_and_take_real_textures():
    f = _synth_frame()
    f.instance_ids[20:70, 30:44] = 0
    f.instance_ids[40:70, 30:50] = 1  # the person now shows only its upper part: 20 wide, 30 tall
    f.boxes[0] = [30, 40, 50, 70]
    assert synthetic_instances(f, np.random.default_rng(0)) == []
    assert len(synthetic_instances(f, np.random.default_rng(0), min_person_aspect=1.0)) == 1
    # retexture: a flat grey render keeps shade 1, so every pixel is (1 - m) * texture + m * render, 0 <= m <= 0.4
    f = _synth_frame()
    f.image[20:70, 30:44] = 0.5
    tex = np.full((100, 200, 3), [200, 40, 90], np.uint8)
    for seed in range(5):
        inst = synthetic_instances(f, np.random.default_rng(seed), feather=0.0, textures=[tex], retexture=1.0)[0]
        t, r = tex[0, 0] / 255, 0.5
        m = (inst.rgb / 255 - t) / (r - t)
        assert np.ptp(m) < 0.02 and -0.01 <= m.mean() <= 0.41
    plain = synthetic_instances(f, np.random.default_rng(0), feather=0.0, textures=[tex], retexture=0.0)[0]
    assert (plain.rgb == 128).all()


def test_synthetic_instances_refuse_inputs_they_do_not_understand():
    f = _synth_frame()
    f.instance_ids = f.instance_ids[:, :-1]
    with pytest.raises(ValueError, match="instance_ids"):
        synthetic_instances(f, np.random.default_rng(0))
    f = _synth_frame()
    f.class_ids = f.class_ids[:-1]
    with pytest.raises(ValueError, match="differ in length"):
        synthetic_instances(f, np.random.default_rng(0))
    with pytest.raises(ValueError, match="retexture"):
        synthetic_instances(_synth_frame(), np.random.default_rng(0), retexture=1.5)
    with pytest.raises(ValueError, match="uint8"):
        synthetic_instances(_synth_frame(), np.random.default_rng(0), textures=[np.zeros((10, 10, 3), np.float32)],
                            retexture=1.0)
