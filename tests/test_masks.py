"""Masks and leak-free edges: hidden pixels never influence the edge map."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from privslam_jax.inpaint.masks import (
    boxes_to_masks,
    dilate,
    edge_band,
    instance_masks,
    random_box_mask,
    random_irregular_mask,
    safe_canny,
    to_grey,
)


def _scene(rng: np.random.Generator, h: int = 48, w: int = 64) -> np.ndarray:
    """Blocks and a gradient: enough structure for Canny to find edges everywhere."""
    img = np.zeros((h, w, 3), np.float32)
    img += np.linspace(0, 0.3, w, dtype=np.float32)[None, :, None]
    for _ in range(6):
        v0, u0 = rng.integers(0, h - 8), rng.integers(0, w - 8)
        img[v0:v0 + rng.integers(4, 20), u0:u0 + rng.integers(4, 20)] = rng.random(3)
    return np.clip(img, 0, 1)


def test_boxes_to_masks_pixel_cover_and_dilation():
    m = boxes_to_masks(np.array([[2.0, 3.0, 5.0, 4.0]]), 10, 12, dilation=0)
    want = np.zeros((10, 12), bool)
    want[3:5, 2:6] = True  # pixels 2..5 overlap [2,5) shifted by ½, rows 3..4
    np.testing.assert_array_equal(m[0], want)
    d = boxes_to_masks(np.array([[2.0, 3.0, 5.0, 4.0]]), 10, 12, dilation=2)[0]
    # a disc dilation is the set of pixels within distance 2 of the box (scipy EDT reference)
    dist = ndimage.distance_transform_edt(~want)
    np.testing.assert_array_equal(d, dist <= 2.0)
    assert boxes_to_masks(np.zeros((0, 4)), 10, 12).shape == (0, 10, 12)
    with pytest.raises(ValueError, match="NaN"):
        boxes_to_masks(np.array([[np.nan, 0, 1, 1]]), 4, 4)


def test_instance_masks_and_errors():
    ids = np.zeros((8, 8), np.int32)
    ids[1:3, 1:3] = 4
    ids[5:7, 5:8] = 9
    m = instance_masks(ids, dilation=0)
    assert m.shape == (2, 8, 8)
    np.testing.assert_array_equal(m[0], ids == 4)
    np.testing.assert_array_equal(m[1], ids == 9)
    with pytest.raises(ValueError):
        dilate(m[0], -1)
    with pytest.raises(ValueError, match="instance_ids"):
        instance_masks(np.zeros((2, 2, 2), np.int32))


def test_safe_canny_is_bit_identical_for_any_hidden_pixels():
    rng = np.random.default_rng(0)
    for trial in range(12):
        img = _scene(rng)
        mask = random_box_mask(rng, 48, 64) if trial % 2 else random_irregular_mask(rng, 48, 64)
        grey = to_grey(img)
        edges, hole = safe_canny(grey, mask)
        assert edges.sum() > 0  # structure outside is found
        for _ in range(3):
            other = img.copy()
            other[mask] = rng.random((int(mask.sum()), 3))
            e2, h2 = safe_canny(to_grey(other), mask)
            assert np.array_equal(edges, e2) and np.array_equal(hole, h2)


def test_paper_algorithm1_leaks_and_ours_does_not():
    """Canny on the original then masking (paper) changes outside the mask with the object."""
    rng = np.random.default_rng(1)
    img = np.full((48, 64, 3), 0.4, np.float32)
    mask = np.zeros((48, 64), bool)
    mask[16:32, 20:40] = True
    obj = img.copy()
    obj[mask] = 1.0  # a bright object touching the mask border
    leaked = []
    for x in (img, obj):
        e_paper, _ = safe_canny(to_grey(x), np.zeros_like(mask), band=0)  # no hole: plain Canny
        leaked.append(np.where(mask, 0, e_paper))
    assert not np.array_equal(leaked[0], leaked[1])  # paper: edges outside reveal the object
    ours = [safe_canny(to_grey(x), mask)[0] for x in (img, obj)]
    assert np.array_equal(ours[0], ours[1])
    del rng


def test_canny_matches_numpy_reference_threshold_semantics():
    """A vertical step of height s smoothed by σ=2 has slope s/(√(2π)·2) at the step; the 3×3
    Sobel is 8× the slope: s = 1 → 1.6 > 0.2 gives one edge column per row; s = 0.03 → 0.048 <
    0.1 gives none (the skimage threshold convention)."""
    h, w = 32, 40
    for height, expect in ((1.0, True), (0.03, False)):
        grey = np.zeros((h, w), np.float32)
        grey[:, w // 2:] = height
        edges, _ = safe_canny(grey, np.zeros((h, w), bool))
        inner = edges[4:-4]
        if expect:
            cols = np.nonzero(inner.any(axis=0))[0]
            assert set(cols) <= {w // 2 - 1, w // 2} and inner.sum(axis=1).min() == 1
        else:
            assert inner.sum() == 0
    assert edge_band(2.0) == 8
    with pytest.raises(ValueError, match="mask"):
        safe_canny(np.zeros((4, 4), np.float32), np.zeros((4, 5), bool))
