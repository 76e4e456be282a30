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
