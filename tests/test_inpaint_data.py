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
