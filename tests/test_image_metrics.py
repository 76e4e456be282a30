"""Image metrics against plain numpy / scipy re-implementations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from privslam_jax.metrics.image import edge_precision_recall, l1, psnr, ssim


def _ssim_reference(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> np.ndarray:
    """Wang et al. 2004 with scipy's Gaussian filter (σ 1.5, radius 5), valid window centres,
    ``C1 = (0.01 R)²``, ``C2 = (0.03 R)²``."""
    def f(x):
        return ndimage.gaussian_filter(x, 1.5, mode="constant", truncate=5 / 1.5)[5:-5, 5:-5]
    a = a.astype(np.float64)
    b = b.astype(np.float64)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
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


def test_psnr_and_ssim_at_data_range_255_match_numpy():
    """0–255 images (float and uint8) with ``data_range=255``. Reference: plain numpy,
    PSNR = 10·log10(255² / MSE) and the SSIM of :func:`_ssim_reference` with C1, C2 scaled by 255."""
    rng = np.random.default_rng(5)
    a8 = ndimage.uniform_filter(rng.integers(0, 256, (40, 52, 3)).astype(np.float64), (3, 3, 1)).astype(np.uint8)
    b8 = np.clip(a8 + rng.normal(0, 12, a8.shape), 0, 255).astype(np.uint8)
    a, b = a8.astype(np.float64), b8.astype(np.float64)
    mask = np.zeros((40, 52), bool)
    mask[8:30, 5:40] = True
    ref_psnr = 10 * np.log10(255.0**2 / np.mean((a - b) ** 2))
    ref_psnr_mask = 10 * np.log10(255.0**2 / np.mean((a[mask] - b[mask]) ** 2))
    maps = np.stack([_ssim_reference(a[..., c], b[..., c], 255.0) for c in range(3)], -1)
    for x, y in ((a.astype(np.float32), b.astype(np.float32)), (a8, b8)):
        np.testing.assert_allclose(float(psnr(x, y, data_range=255.0)), ref_psnr, rtol=1e-5)
        np.testing.assert_allclose(float(psnr(x, y, mask, data_range=255.0)), ref_psnr_mask, rtol=1e-5)
        np.testing.assert_allclose(float(ssim(x, y, data_range=255.0)), maps.mean(), rtol=1e-4)
        np.testing.assert_allclose(float(ssim(x, y, mask, data_range=255.0)), maps[mask[5:-5, 5:-5]].mean(), rtol=1e-4)
    # the same pictures scaled to [0, 1] with data_range 1 give the same numbers (scale invariance)
    np.testing.assert_allclose(float(psnr(a / 255, b / 255)), ref_psnr, rtol=1e-5)
    np.testing.assert_allclose(float(ssim((a / 255).astype(np.float32), (b / 255).astype(np.float32))), maps.mean(), rtol=1e-4)


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
