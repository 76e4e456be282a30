"""Method comparison inside the privacy masks against the object-free render."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from privslam_jax.inpaint.evaluate import evaluate_frames, markdown_table
from privslam_jax.inpaint.masks import dilate


def test_evaluate_frames_black_psnr_closed_form():
    rng = np.random.default_rng(0)
    frames = []
    for k in range(3):
        bg = rng.random((32, 48, 3)).astype(np.float32)
        ids = np.zeros((32, 48), np.int32)
        if k != 1:
            ids[8:20, 10:30] = 3
        img = bg.copy()
        img[ids > 0] = 1.0
        frames.append(SimpleNamespace(image=img, background=bg, instance_ids=ids))
    res = evaluate_frames(frames, ["black", "white"], dilation=2, progress=False)
    assert len(res["black"]["psnr"]) == 2  # the frame without objects is skipped
    hidden = dilate(frames[0].instance_ids > 0, 2)
    mse = np.mean(frames[0].background[hidden] ** 2)
    np.testing.assert_allclose(res["black"]["psnr"][0], 10 * np.log10(1 / mse), rtol=1e-5)
    np.testing.assert_allclose(res["black"]["l1"][0], np.mean(frames[0].background[hidden]), rtol=1e-5)
    table = markdown_table(res)
    assert table.count("\n") == 3 and "| black | 2 |" in table


def test_markdown_table_paired_difference_to_telea():
    res = {"telea": {"psnr": np.array([10.0, 12.0, 20.0]), "ssim": np.ones(3), "l1": np.ones(3)},
           "ours": {"psnr": np.array([13.0, 12.5, 21.0]), "ssim": np.ones(3), "l1": np.ones(3)}}
    rows = {r.split("|")[1].strip(): r for r in markdown_table(res).splitlines()[2:]}
    d = res["ours"]["psnr"] - res["telea"]["psnr"]
    assert f"{d.mean():+.2f} [{np.percentile(d, 25):+.2f}, {np.percentile(d, 75):+.2f}]" in rows["ours"]
    assert "+0.00 [+0.00, +0.00]" in rows["telea"]


def test_score_fill_against_numpy_and_perfect_edges():
    from privslam_jax.inpaint.evaluate import score_fill

    rng = np.random.default_rng(1)
    target = np.zeros((40, 60, 3), np.float32)
    target[:, 30:] = 1.0  # one vertical edge
    hole = np.zeros((40, 60), bool)
    hole[10:30, 20:40] = True
    s = score_fill(target, target, hole)
    assert s["edge_p"] == s["edge_r"] == s["edge_f1"] == 1.0 and s["l1"] == 0.0
    flat = target.copy()
    flat[hole] = 0.5  # the edge gone inside (only the hole's own border can coincide with it)
    s = score_fill(flat, target, hole)
    assert s["edge_r"] <= 0.2 and s["edge_f1"] <= 0.2
    noisy = np.clip(target + rng.normal(0, 0.1, target.shape), 0, 1).astype(np.float32)
    mse = np.mean((noisy[hole] - target[hole]) ** 2)
    np.testing.assert_allclose(score_fill(noisy, target, hole)["psnr"], 10 * np.log10(1 / mse), rtol=1e-5)


def test_real_hole_cases_deterministic_and_inside(tmp_path):
    import cv2

    from privslam_jax.inpaint.data import ObjectShape
    from privslam_jax.inpaint.evaluate import evaluate_cases, real_hole_cases

    for i in range(2):
        cv2.imwrite(str(tmp_path / f"{i}.png"), (np.random.default_rng(i).random((60, 120, 3)) * 255).astype(np.uint8))
    paths = sorted(tmp_path.glob("*.png"))
    shapes = [ObjectShape(np.ones((8, 12), bool), 0.6, 120)]
    a = list(real_hole_cases(paths, shapes, objects=2, repeats=2))
    b = list(real_hole_cases(paths, shapes, objects=2, repeats=2))
    assert len(a) == 4 and all(np.array_equal(x[2], y[2]) for x, y in zip(a, b, strict=True))
    assert all(c[2].shape == (2, 60, 120) and c[2].any(axis=(1, 2)).all() for c in a)
    assert not np.array_equal(a[0][2], a[2][2])  # the second placement differs
    res = evaluate_cases(iter(a), ["black"], progress=False)
    img, target, masks = a[0]
    hidden = masks.any(axis=0)
    np.testing.assert_allclose(res["black"]["l1"][0], np.mean(target[hidden]), rtol=1e-5)
