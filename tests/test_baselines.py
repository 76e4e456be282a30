"""Baseline fills: outside untouched, privacy-safe ones independent of the hidden pixels."""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.inpaint.baselines import LEAKY_METHODS, METHODS, NOISE_STD, SAFE_METHODS, fill
from privslam_jax.inpaint.masks import random_irregular_mask


def _frame(seed: int = 0):
    rng = np.random.default_rng(seed)
    img = rng.random((40, 56, 3)).astype(np.float32)
    img = (img + np.roll(img, 1, 0) + np.roll(img, 1, 1)) / 3  # some spatial correlation
    mask = random_irregular_mask(rng, 40, 56)
    return img.astype(np.float32), mask, rng


@pytest.mark.parametrize("method", METHODS)
def test_outside_untouched_and_deterministic(method):
    img, mask, _ = _frame()
    out = fill(img, mask, method, seed=3)
    assert out.dtype == np.float32 and out.shape == img.shape
    assert np.array_equal(out[~mask], img[~mask])
    assert np.array_equal(out, fill(img, mask, method, seed=3))
    assert 0.0 <= out.min() and out.max() <= 1.0
    assert np.array_equal(fill(img, np.zeros_like(mask), method), img)


@pytest.mark.parametrize("method", SAFE_METHODS)
def test_safe_methods_bit_identical_for_any_hidden_pixels(method):
    img, mask, rng = _frame(1)
    ref = fill(img, mask, method, seed=7)
    for _ in range(4):
        other = img.copy()
        other[mask] = rng.random((int(mask.sum()), 3))
        assert np.array_equal(fill(other, mask, method, seed=7), ref)


@pytest.mark.parametrize("method", LEAKY_METHODS)
def test_leaky_methods_do_reveal_hidden_pixels(method):
    """Documents the leak of the paper's blur / pixelation (and additive noise)."""
    img, mask, rng = _frame(2)
    other = img.copy()
    other[mask] = rng.random((int(mask.sum()), 3))
    assert not np.array_equal(fill(img, mask, method, seed=7), fill(other, mask, method, seed=7))


def test_fill_values_follow_their_definitions():
    img, mask, _ = _frame(3)
    n = int(mask.sum())
    assert np.all(fill(img, mask, "black")[mask] == 0)
    assert np.all(fill(img, mask, "gray")[mask] == 0.5)
    assert np.all(fill(img, mask, "white")[mask] == 1)
    big = np.zeros((200, 200), bool)
    big[20:180, 20:180] = True
    g = fill(np.zeros((200, 200, 3), np.float32), big, "gaussian", seed=0)[big]
    # N(0, σ) clipped at 0: half the values are 0, the positive half has mean σ·√(2/π)
    assert abs((g == 0).mean() - 0.5) < 0.02
    assert abs(g[g > 0].mean() - NOISE_STD * np.sqrt(2 / np.pi)) < 0.05 * NOISE_STD
    for method, share in (("noise25", 0.25), ("noise50", 0.5)):
        v = fill(np.zeros((200, 200, 3), np.float32), big, method, seed=1)[big]
        grey = np.all(v == 0.5, axis=1)
        assert abs((1 - grey.mean()) - share) < 0.02
    del n


def test_bad_input():
    img, mask, _ = _frame()
    with pytest.raises(ValueError, match="unknown fill method"):
        fill(img, mask, "magic")
    with pytest.raises(ValueError, match="mask"):
        fill(img, mask.astype(np.uint8), "black")
    with pytest.raises(ValueError, match="RGB"):
        fill(img[..., 0], mask, "black")
