"""Detector training: augmentation geometry and the optimiser (resume after a kill: tests/test_resume_training.py)."""

from __future__ import annotations

import jax
import numpy as np

from privslam_jax.detect.train import TrainConfig, augment


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


def test_augment_rect_canvas_moves_boxes_with_pixels():
    img = np.zeros((48, 160, 3), np.float32)
    img[10:30, 100:130] = 1.0  # white box, xyxy (100, 10, 130, 30)
    cfg = TrainConfig(data="-", num_classes=1, imgsz=320, imgh=96, hsv=(0.0, 0.0, 0.0), fliplr=0.5)
    assert cfg.canvas == (96, 320)
    for seed in range(6):
        out, boxes, keep = augment(img, np.array([[100.0, 10.0, 130.0, 30.0]]), cfg, np.random.default_rng(seed))
        assert out.shape == (96, 320, 3)
        if not len(keep):
            continue
        ys, xs = np.nonzero(out[..., 0] > 0.5)  # bilinear upscaling: the 0.5 level crossing is the edge
        np.testing.assert_allclose([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1], boxes[0], atol=1.0)


def test_rect_config_rejects_bad_sizes():
    import pytest

    with pytest.raises(ValueError, match="imgh"):
        TrainConfig(data="-", num_classes=1, imgsz=320, imgh=100)
    with pytest.raises(ValueError, match="imgh"):
        TrainConfig(data="-", num_classes=1, imgsz=320, imgh=352)
    with pytest.raises(ValueError, match="optimizer"):
        TrainConfig(data="-", num_classes=1, optimizer="lion")


def test_adamw_groups_match_torch_adamw_formula():
    """Three steps of the AdamW groups against a numpy transcription of torch.optim.AdamW."""
    import jax.numpy as jnp
    import optax

    from privslam_jax.detect.train import _make_tx, _set_hparams

    rng = np.random.default_rng(0)
    params = {"conv": {"kernel": rng.normal(size=(3, 3)).astype(np.float32)},
              "bn": {"scale": rng.normal(size=3).astype(np.float32), "bias": rng.normal(size=3).astype(np.float32)}}
    wd, lr, b1, b2, eps = 0.01, 0.05, 0.85, 0.999, 1e-8
    tx = _make_tx(params, wd, "adamw")
    p = jax.tree.map(jnp.asarray, params)
    opt = _set_hparams(tx.init(p), {"decay": lr, "no_decay": lr, "bias": lr}, b1)
    ref = jax.tree.map(lambda x: x.astype(np.float64), params)
    m = jax.tree.map(np.zeros_like, ref)
    v = jax.tree.map(np.zeros_like, ref)
    for t in range(1, 4):
        g = jax.tree.map(lambda x: rng.normal(size=x.shape), ref)
        upd, opt = tx.update(jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), g), opt, p)
        p = optax.apply_updates(p, upd)
        for path in (("conv", "kernel"), ("bn", "scale"), ("bn", "bias")):
            decay = wd if path[1] == "kernel" else 0.0
            x, gg = ref[path[0]][path[1]], g[path[0]][path[1]]
            x = x * (1 - lr * decay)  # torch AdamW: decoupled decay first
            m[path[0]][path[1]] = b1 * m[path[0]][path[1]] + (1 - b1) * gg
            v[path[0]][path[1]] = b2 * v[path[0]][path[1]] + (1 - b2) * gg**2
            mh, vh = m[path[0]][path[1]] / (1 - b1**t), v[path[0]][path[1]] / (1 - b2**t)
            ref[path[0]][path[1]] = x - lr * mh / (np.sqrt(vh) + eps)
    for a, b in zip(jax.tree.leaves(jax.tree.map(np.asarray, p)), jax.tree.leaves(ref)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
