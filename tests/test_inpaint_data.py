"""Training data sources: pure functions of the step, correct targets and holes."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from privslam_jax.inpaint.data import CropBank, FolderData


def test_folder_data_deterministic_per_step(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i}.png"), (rng.random((50, 70, 3)) * 255).astype(np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    data = FolderData(tmp_path, 32, seed=1)
    imgs, holes = data(5, 4)
    assert imgs.shape == (4, 32, 32, 3) and imgs.dtype == np.float32 and holes.shape == (4, 32, 32)
    assert 0 <= imgs.min() and imgs.max() <= 1 and holes.any(axis=(1, 2)).all()
    again = FolderData(tmp_path, 32, seed=1)(5, 4)
    assert np.array_equal(again[0], imgs) and np.array_equal(again[1], holes)
    assert not np.array_equal(data(6, 4)[0], imgs)
    with pytest.raises(FileNotFoundError):
        FolderData(tmp_path / "missing", 32)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no images"):
        FolderData(tmp_path / "empty", 32)


def test_crop_bank_targets_are_object_free(tmp_path):
    bg = np.tile(np.linspace(0, 1, 96, dtype=np.float32)[None, :, None], (48, 1, 3))
    ids = np.zeros((48, 96), np.int32)
    ids[10:30, 20:40] = 1  # 400 px object
    ids[40:42, 80:82] = 2  # 4 px: below min_area, skipped
    frame = SimpleNamespace(background=bg, instance_ids=ids)
    bank = CropBank.from_frames([frame], 32, dilation=0, min_area=64)
    assert len(bank) == 1
    # crop = 20 px box ·(1 + 2·0.5) = 40 px square at v 0..40, u 10..50 (centred, shifted inside)
    want = cv2.resize(bg[0:40, 10:50], (32, 32), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(bank.images[0] / 255.0, want, atol=0.5 / 255 + 1e-6)
    hole = bank.holes[0]
    assert hole[8:24, 8:24].all() and not hole[:6].any() and not hole[:, 28:].any()
    imgs, holes = bank(3, 5)
    assert imgs.shape == (5, 32, 32, 3) and np.array_equal(bank(3, 5)[1], holes)
    bank.save(tmp_path / "b.npz")
    assert np.array_equal(CropBank.load(tmp_path / "b.npz").images, bank.images)
    with pytest.raises(ValueError, match="min_area"):
        CropBank.from_frames([SimpleNamespace(background=bg, instance_ids=np.zeros_like(ids))], 32)


def _mask_file(path, shape, boxes):
    m = np.zeros(shape, np.uint8)
    for v0, v1, u0, u1 in boxes:
        m[v0:v1, u0:u1] = 255
    cv2.imwrite(str(path), m)


def test_object_shapes_are_the_connected_components(tmp_path):
    from privslam_jax.inpaint.data import object_shapes

    _mask_file(tmp_path / "a.png", (100, 200), [(10, 30, 20, 60), (50, 90, 100, 120), (0, 5, 0, 5)])
    shapes = object_shapes([tmp_path / "a.png"], min_area=100)  # the 25 px blob is dropped
    got = sorted((s.mask.shape, int(s.mask.sum()), s.v_center, s.frame_width) for s in shapes)
    # cv2 centroids are pixel-centre means: rows 10..29 -> 19.5, rows 50..89 -> 69.5
    assert got == [((20, 40), 800, 19.5 / 100, 200), ((40, 20), 800, 69.5 / 100, 200)]
    _mask_file(tmp_path / "empty.png", (10, 10), [])
    with pytest.raises(ValueError, match="no object"):
        object_shapes([tmp_path / "empty.png"])


def test_place_shape_scales_by_frame_width_and_keeps_the_row():
    from privslam_jax.inpaint.data import ObjectShape, place_shape

    sil = np.zeros((20, 30), bool)
    sil[2:18, 5:25] = True  # 16 x 20 = 320 px
    shape = ObjectShape(sil, 0.5, 300)
    rng = np.random.default_rng(0)
    for _ in range(20):  # same camera width, unit scale: an exact translated copy
        m = place_shape(rng, shape, 120, 300, scale=(1.0, 1.0), v_jitter=0.0)
        vs, us = np.nonzero(m)
        assert m.sum() == 320 and vs.max() - vs.min() + 1 == 16 and us.max() - us.min() + 1 == 20
        assert vs.min() == 60 - 10 + 2  # the 20-row silhouette centred on row 0.5 * 120
    m = place_shape(rng, shape, 240, 600, scale=(1.0, 1.0), v_jitter=0.0)  # twice the width: twice the size
    assert m.sum() == 4 * 320
    tiny = place_shape(rng, ObjectShape(np.ones((200, 200), bool), 0.5, 100), 50, 60)  # never larger than the frame
    assert tiny.shape == (50, 60) and tiny.sum() <= (0.9 * 50) ** 2 + 1


def test_real_hole_data_crops_like_the_filter(tmp_path):
    from privslam_jax.inpaint.crops import crop_box
    from privslam_jax.inpaint.data import Mixture, ObjectShape, RealHoleData, image_paths, place_shape
    from privslam_jax.inpaint.masks import dilate

    img = np.tile(np.linspace(0, 255, 160).astype(np.uint8)[None, :, None], (80, 1, 3))
    img[..., 1] = 255 - img[..., 1]
    cv2.imwrite(str(tmp_path / "f.png"), img[..., ::-1])
    sil = np.ones((10, 16), bool)
    data = RealHoleData(image_paths(tmp_path), [ObjectShape(sil, 0.5, 160)], 32, seed=3, free_prob=0.0,
                        grey_prob=0.0)
    crop, hole = data.sample(np.random.default_rng(5))
    # independent replay of the same draws: frame index, grey coin, free coin, shape index, placement, flip
    rng = np.random.default_rng(5)
    rng.integers(1), rng.random(), rng.random()
    rng.integers(1)
    mask = dilate(place_shape(rng, data.shapes[0], 80, 160), 4)
    box = crop_box(mask, 0.5, 32)
    want = cv2.resize(img[box.v0:box.v1, box.u0:box.u1], (32, 32), interpolation=cv2.INTER_AREA) / 255.0
    want_hole = cv2.resize(mask[box.v0:box.v1, box.u0:box.u1].astype(np.float32), (32, 32),
                           interpolation=cv2.INTER_AREA) > 0
    if rng.random() < 0.5:
        want, want_hole = want[:, ::-1], want_hole[:, ::-1]
    np.testing.assert_allclose(crop, want, atol=1e-6)
    assert np.array_equal(hole, want_hole) and 0.05 < hole.mean() < 0.6
    a = data(7, 6)
    assert a[0].shape == (6, 32, 32, 3) and np.array_equal(data(7, 6)[0], a[0])  # pure in the step
    grey = RealHoleData(image_paths(tmp_path), data.shapes, 32, grey_prob=1.0, free_prob=0.5)(2, 4)[0]
    assert np.array_equal(grey[..., 0], grey[..., 1]) and grey.std() > 0.01
    # a mixture with weight 0 on the second source never asks it for samples
    never = lambda step, n: (_ for _ in ()).throw(AssertionError("asked"))  # noqa: E731
    mixed = Mixture([data, never], [1.0, 0.0])(7, 6)
    assert mixed[0].shape == (6, 32, 32, 3)
    half = Mixture([data, data], [1.0, 1.0], seed=1)
    assert np.array_equal(half(4, 8)[0], half(4, 8)[0])
    with pytest.raises(ValueError, match="weight"):
        Mixture([data], [1.0, 2.0])
    with pytest.raises(FileNotFoundError):
        image_paths(tmp_path / "missing")
