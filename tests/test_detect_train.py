"""Detector training: augmentation geometry, and resume after a kill gives the same weights."""

from __future__ import annotations

import dataclasses

import cv2
import jax
import numpy as np

from privslam_jax.detect.train import TrainConfig, augment, train


def _make_dataset(root, n=4, size=64, seed=0):
    rng = np.random.default_rng(seed)
    (root / "images" / "train").mkdir(parents=True)
    (root / "labels" / "train").mkdir(parents=True)
    for i in range(n):
        img = np.full((size, size, 3), 60, np.uint8)
        lines = []
        for _ in range(2):
            c = int(rng.integers(0, 2))
            w, h = (int(v) for v in rng.integers(12, 30, 2))
            x, y = int(rng.integers(0, size - w)), int(rng.integers(0, size - h))
            img[y : y + h, x : x + w] = (220, 40, 40) if c == 0 else (40, 220, 40)
            lines.append(f"{c} {(x + w / 2) / size:.6f} {(y + h / 2) / size:.6f} {w / size:.6f} {h / size:.6f}")
        cv2.imwrite(str(root / "images" / "train" / f"{i:03d}.png"), img[..., ::-1])
        (root / "labels" / "train" / f"{i:03d}.txt").write_text("\n".join(lines) + "\n")


def test_augment_moves_boxes_with_pixels():
    img = np.zeros((40, 80, 3), np.float32)
    img[10:20, 5:25] = 1.0  # white box, xyxy (5, 10, 25, 20)
    cfg = TrainConfig(data="-", num_classes=1, imgsz=64, hsv=(0.0, 0.0, 0.0))
    for seed in range(5):
        out, boxes, keep = augment(img, np.array([[5.0, 10.0, 25.0, 20.0]]), cfg, np.random.default_rng(seed))
        assert out.shape == (64, 64, 3) and keep.tolist() == [0]
        x1, y1, x2, y2 = boxes[0]
        inner = out[int(np.ceil(y1)) + 1 : int(y2) - 1, int(np.ceil(x1)) + 1 : int(x2) - 1]
        assert inner.size and inner.min() > 0.9  # the box still covers white pixels
        mask = out[..., 0] > 0.9
        ys, xs = np.nonzero(mask)
        np.testing.assert_allclose([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], boxes[0], atol=1.5)


def test_resume_after_kill_matches_uninterrupted_run(tmp_path):
    _make_dataset(tmp_path / "ds")
    cfg = TrainConfig(data=str(tmp_path / "ds"), num_classes=2, scale="tiny", imgsz=64, batch_size=2, epochs=2,
                      warmup_epochs=0.0, ckpt_every=1)
    full = train(cfg, progress=False)
    assert full.step == 4 and np.isfinite(full.losses).all()
    killed = train(dataclasses.replace(cfg, ckpt_dir=str(tmp_path / "ck"), max_steps=3), progress=False)
    assert killed.step == 3
    resumed = train(dataclasses.replace(cfg, ckpt_dir=str(tmp_path / "ck")), progress=False)
    assert resumed.step == 4 and len(resumed.losses) == 1  # only step 4 ran
    np.testing.assert_allclose(resumed.losses[0], full.losses[3], rtol=1e-6)
    a = jax.tree.leaves(jax.tree.map(np.asarray, __import__("flax").nnx.state(full.model)))
    b = jax.tree.leaves(jax.tree.map(np.asarray, __import__("flax").nnx.state(resumed.model)))
    assert len(a) == len(b) > 100
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-7)
    # and training actually changed the weights
    c = jax.tree.leaves(jax.tree.map(np.asarray, __import__("flax").nnx.state(killed.model)))
    assert any(not np.allclose(x, y) for x, y in zip(a, c))
