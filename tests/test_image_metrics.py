"""Image metrics against plain numpy / scipy re-implementations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from privslam_jax.metrics.image import edge_precision_recall, l1, psnr, ssim


def _ssim_reference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Wang et al. 2004 with scipy's Gaussian filter (σ 1.5, radius 5), valid window centres."""
    def f(x):
        return ndimage.gaussian_filter(x, 1.5, mode="constant", truncate=5 / 1.5)[5:-5, 5:-5]
    a = a.astype(np.float64)
    b = b.astype(np.float64)
    c1, c2 = 0.01**2, 0.03**2
    ma, mb = f(a), f(b)
    saa, sbb, sab = f(a * a) - ma**2, f(b * b) - mb**2, f(a * b) - ma * mb
    return ((2 * ma * mb + c1) * (2 * sab + c2)) / ((ma**2 + mb**2 + c1) * (saa + sbb + c2))


def test_ssim_matches_numpy_reference():
    rng = np.random.default_rng(0)
    a = ndimage.uniform_filter(rng.random((40, 52, 3)), (3, 3, 1)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1).astype(np.float32)
    maps = np.stack([_ssim_reference(a[..., c], b[..., c]) for c in range(3)], -1)
    np.testing.assert_allclose(float(ssim(a, b)), maps.mean(), rtol=1e-4)
    mask = np.zeros((40, 52), bool)
    mask[10:30, 20:45] = True
    np.testing.assert_allclose(float(ssim(a, b, mask)), maps[mask[5:-5, 5:-5]].mean(), rtol=1e-4)
    assert abs(float(ssim(a, a)) - 1.0) < 1e-5


def test_psnr_and_l1_closed_form():
    a = np.zeros((8, 10, 3), np.float32)
    b = a.copy()
    mask = np.zeros((8, 10), bool)
    mask[:4] = True
    b[mask] = 0.1  # error 0.1 on the masked half only
    np.testing.assert_allclose(float(psnr(a, b, mask)), 20.0, rtol=1e-5)  # 10·log10(1/0.01)
    np.testing.assert_allclose(float(psnr(a, b)), 10 * np.log10(1 / 0.005), rtol=1e-5)
    np.testing.assert_allclose(float(l1(a, b, mask)), 0.1, rtol=1e-6)
    np.testing.assert_allclose(float(l1(a, b)), 0.05, rtol=1e-6)
    assert np.isinf(float(psnr(a, a)))


def test_edge_precision_recall():
    t = np.zeros((6, 6), np.float32)
    p = np.zeros((6, 6), np.float32)
    t[1, :4] = 1  # 4 true edge pixels
    p[1, 2:6] = 0.9  # 4 predicted, 2 correct
    prec, rec = edge_precision_recall(p, t)
    assert float(prec) == 0.5 and float(rec) == 0.5
    mask = np.zeros((6, 6), bool)
    mask[:, :3] = True  # inside: true at cols 0..2 (3), predicted at col 2 (1, correct)
    prec, rec = edge_precision_recall(p, t, mask)
    assert float(prec) == 1.0 and abs(float(rec) - 1 / 3) < 1e-7


def test_bad_shapes():
    with pytest.raises(ValueError, match="equal"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match="at least 11"):
        ssim(np.zeros((8, 8)), np.zeros((8, 8)))
    with pytest.raises(ValueError, match="mask"):
        l1(np.zeros((4, 4, 3)), np.zeros((4, 4, 3)), np.zeros((4, 4)))
