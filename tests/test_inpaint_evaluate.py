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
