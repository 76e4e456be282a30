"""Inference settings of an inpainter checkpoint: ``InpainterConfig.flip_average``, ``prefill_blend``,
``prefill_blend_distance`` and ``prefill_blend_unit``.

References: mirror equivariance (a property the plain network lacks), the public
``filter_frame`` of the same weights without the setting combined with
:func:`privslam_jax.inpaint.baselines.fill` of the whole frame (and a brute-force nearest visible
pixel and crop sizes worked out by hand for the distance-dependent share), and the differentiable ``filter_image`` against
``filter_frame`` (as ``tests/test_filter_image.py`` does for the defaults).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.errors import InputError
from privslam_jax.inpaint import baselines
from privslam_jax.inpaint.differentiable import FilterModel, filter_constants, filter_image
from privslam_jax.inpaint.filter import (Inpainter, InpainterConfig, blend_distance, filter_frame, hole_distance, inpaint_inference,
                                         network_share)

TINY = InpainterConfig(width=4, num_residual_blocks=1, prefill="telea", residual=True)


def _frame(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random 96×160 float frame in (0.05, 0.95) and two overlapping object masks."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:96, 0:160] / 40.0
    img = np.stack([0.5 + 0.4 * np.sin(xx * rng.uniform(1, 3) + yy * rng.uniform(0, 2) + rng.uniform(0, 6))
                    for _ in range(3)], -1).astype(np.float32)
    masks = np.zeros((2, 96, 160), bool)
    masks[0, 30:70, 40:75] = True
    masks[1, 50:90, 65:120] = True
    return img, masks


def _with(inp: Inpainter, **settings) -> Inpainter:
    return Inpainter(*inp.modules, dataclasses.replace(inp.config, **settings))


def test_flip_average_is_mirror_equivariant_and_keeps_the_outside():
    """With ``flip_average`` the crop's fill of the mirrored inputs is the mirrored fill (to float
    rounding); the plain network is not mirror-symmetric (so the test can fail); outside the hole
    the output is the input, bit for bit."""
    inp = Inpainter.init(TINY, seed=2)
    eg, ig = inp.modules
    rng = np.random.default_rng(0)
    s = TINY.size
    rgb = jnp.asarray(rng.random((2, s, s, 3)), jnp.float32)
    hole = jnp.zeros((2, s, s, 1)).at[:, 20:44, 10:40].set(1.0)
    edge_hole = jnp.zeros((2, s, s, 1)).at[:, 12:52, 2:48].set(1.0)
    rgb = rgb * (1 - hole)
    grey = rgb.mean(-1, keepdims=True)
    edges = jnp.asarray(rng.random((2, s, s, 1)) > 0.8, jnp.float32) * (1 - edge_hole)
    fill = jnp.asarray(rng.random((2, s, s, 3)), jnp.float32)
    args = (rgb, grey, edges, hole, edge_hole)
    m = lambda x: x[:, :, ::-1]  # noqa: E731

    def run(flip: bool, mirrored: bool):
        cfg = dataclasses.replace(TINY, flip_average=flip)
        xs = [m(a) for a in args] if mirrored else list(args)
        return np.asarray(inpaint_inference(eg, ig, *xs, cfg, True, m(fill) if mirrored else fill))

    plain, plain_m = run(False, False), run(False, True)
    assert np.abs(m(plain_m) - plain).max() > 1e-3
    both, both_m = run(True, False), run(True, True)
    np.testing.assert_allclose(m(both_m), both, atol=1e-6)
    outside = np.asarray(hole[..., 0]) == 0
    assert np.array_equal(both[outside], np.asarray(rgb)[outside])
    assert np.abs(both - plain).max() > 1e-3  # it changed the fill


@pytest.mark.parametrize("blend", [0.0, 0.8])
def test_prefill_blend_mixes_with_the_full_resolution_prefill(blend):
    """``filter_frame`` with ``prefill_blend = a`` = ``a ·`` the same weights' fill without it ``+ (1 − a) ·``
    OpenCV Telea of the whole frame, inside the hidden pixels; the input elsewhere; and no hidden
    pixel changes the output."""
    inp = Inpainter.init(TINY, seed=2)
    img, masks = _frame()
    hidden = masks.any(axis=0)
    plain = filter_frame(img, masks, inpainter=inp)
    got = filter_frame(img, masks, inpainter=_with(inp, prefill_blend=blend))
    want = blend * plain + (1 - blend) * baselines.fill(img, hidden, "telea")
    np.testing.assert_allclose(got[hidden], want[hidden], atol=2e-6)
    assert np.array_equal(got[~hidden], img[~hidden])
    other = np.where(hidden[..., None], np.random.default_rng(1).random(img.shape), img).astype(np.float32)
    assert np.array_equal(filter_frame(other, masks, inpainter=_with(inp, prefill_blend=blend)), got)


def test_distance_blend_follows_the_distance_to_the_visible_pixels():
    """With ``prefill_blend_distance = τ`` the network's share of a hidden pixel is ``a · (1 − exp(−d/τ))``,
    ``d`` its Euclidean distance to the nearest visible pixel (brute force): ``filter_frame``
    = that share of the same weights' fill plus the rest of OpenCV Telea of the whole frame; the
    share is 0 on no hidden pixel, tends to ``a`` deep inside; the output ignores every hidden pixel."""
    inp = Inpainter.init(TINY, seed=2)
    img, masks = _frame()
    hidden = masks.any(axis=0)
    a, tau = 0.85, 5.0
    cfg = dataclasses.replace(TINY, prefill_blend=a, prefill_blend_distance=tau)
    share = network_share(masks, cfg)
    vis, hid = np.argwhere(~hidden), np.argwhere(hidden)  # brute force: the nearest visible pixel of each
    d = np.zeros(hidden.shape)
    d[hidden] = [np.sqrt(((vis - q) ** 2).sum(axis=1).min()) for q in hid]
    np.testing.assert_allclose(hole_distance(hidden), d, rtol=1e-6)
    np.testing.assert_allclose(share, a * (1 - np.exp(-d / tau)), rtol=1e-5, atol=1e-6)
    assert np.all(share[~hidden] == 0) and 0 < share[hidden].min() < 0.2 * a and share.max() > 0.95 * a
    assert network_share(masks, TINY) == 1.0 and network_share(masks, dataclasses.replace(TINY, prefill_blend=a)) == a
    plain = filter_frame(img, masks, inpainter=inp)
    got = filter_frame(img, masks, inpainter=_with(inp, prefill_blend=a, prefill_blend_distance=tau))
    w = (a * (1 - np.exp(-d / tau)))[..., None]
    want = w * plain + (1 - w) * baselines.fill(img, hidden, "telea")
    np.testing.assert_allclose(got[hidden], want[hidden], atol=2e-6)
    assert np.array_equal(got[~hidden], img[~hidden])
    assert np.abs(got - filter_frame(img, masks, inpainter=_with(inp, prefill_blend=a))).max() > 1e-3  # not the constant share
    other = np.where(hidden[..., None], np.random.default_rng(1).random(img.shape), img).astype(np.float32)
    assert np.array_equal(filter_frame(other, masks, inpainter=_with(inp, prefill_blend=a, prefill_blend_distance=tau)), got)


def test_distance_in_model_pixels_divides_by_each_crops_resize_factor():
    """``prefill_blend_unit="model"``: the distance is divided by the resize factor of the pixel's crop,
    worked out by hand for ``_frame``'s masks (``crop_pad`` 0.5, ``min_crop`` 32, 96×160 frame): mask 0
    (40×35 px) gets an 80-px square crop, factor 80/64; mask 1 (40×55 px) a crop of 110 px shrunk to
    the frame's 96, factor 96/64; where they overlap, the mean 1.375, as their fills are averaged.
    The share follows it, and ``filter_constants`` hands the differentiable filter the same share."""
    img, masks = _frame()
    hidden = masks.any(axis=0)
    cfg = dataclasses.replace(TINY, prefill_blend=0.9, prefill_blend_distance=3.0, prefill_blend_unit="model")
    factor = np.ones(hidden.shape)
    factor[masks[0]] = 80 / 64
    factor[masks[1]] = 96 / 64
    factor[masks[0] & masks[1]] = (80 / 64 + 96 / 64) / 2
    d = hole_distance(hidden) / factor
    np.testing.assert_allclose(blend_distance(masks, cfg), d, rtol=1e-6)
    np.testing.assert_array_equal(blend_distance(masks, dataclasses.replace(cfg, prefill_blend_unit="frame")),
                                  hole_distance(hidden))
    share = network_share(masks, cfg)
    np.testing.assert_allclose(share, 0.9 * (1 - np.exp(-d / 3.0)), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(filter_constants(img, masks, cfg).frame_share, share)
    with pytest.raises(ValueError, match="prefill_blend_unit"):
        dataclasses.replace(cfg, prefill_blend_unit="metres")


def test_distance_in_model_pixels_of_a_non_square_crop_uses_its_longer_side():
    """A mask longer than the frame is tall (20×120 px in 96×160) gets a crop that cannot stay square:
    2 × 120 = 240 px wanted, 96 rows available, so 96 rows × 120 columns (the mask's own width), resized to
    64² — by hand, its resize factor is the longer side, 120 / 64, not the shorter 96 / 64."""
    masks = np.zeros((1, 96, 160), bool)
    masks[0, 40:60, 20:140] = True
    cfg = dataclasses.replace(TINY, prefill_blend_distance=3.0, prefill_blend_unit="model")
    np.testing.assert_allclose(blend_distance(masks, cfg), hole_distance(masks[0]) / (120 / 64), rtol=1e-6)


def test_distance_share_edge_cases_and_constants_it_needs():
    """A frame hidden everywhere has no visible pixel: every distance is infinite and the share is
    ``a``; a hole of one pixel is 1 px from the visible ones. Constants made for a constant blend
    (no ``frame_share``) are refused by a distance-blend model instead of being blended wrongly."""
    cfg = dataclasses.replace(TINY, prefill_blend=0.85, prefill_blend_distance=5.0)
    everywhere = np.ones((4, 6), bool)
    assert np.all(np.isinf(hole_distance(everywhere))) and np.all(network_share(everywhere[None], cfg) == np.float32(0.85))
    one = np.zeros((5, 5), bool)
    one[2, 2] = True
    assert hole_distance(one)[2, 2] == 1.0 and hole_distance(one).sum() == 1.0
    inp = _with(Inpainter.init(TINY, seed=2), prefill_blend=0.85, prefill_blend_distance=5.0)
    model, params = FilterModel.split(inp)
    img, masks = _frame()
    constant = filter_constants(img, masks, dataclasses.replace(cfg, prefill_blend_distance=0.0))
    assert constant.frame_share is None and constant.frame_fill is not None
    with pytest.raises(ValueError, match="frame_share"):
        filter_image(params, img, masks, model, constants=constant)


@pytest.mark.parametrize("distance", [0.0, 5.0])
def test_filter_image_equals_filter_frame_with_both_settings(distance):
    """The differentiable filter runs the same inference: parity with ``filter_frame`` (overlapping
    masks, flip and blend on, the blend constant or by distance), the outside bit-identical, no
    dependence on hidden pixels, and a finite gradient in the parameters."""
    inp = _with(Inpainter.init(TINY, seed=2), flip_average=True, prefill_blend=0.7, prefill_blend_distance=distance)
    model, params = FilterModel.split(inp)
    img, masks = _frame()
    hidden = masks.any(axis=0)
    run = jax.jit(lambda p, x: filter_image(p, x, masks, model))
    out = np.asarray(run(params, img))
    np.testing.assert_allclose(out, filter_frame(img, masks, inpainter=inp), atol=1e-5)
    assert np.array_equal(out[~hidden], img[~hidden])
    other = np.where(hidden[..., None], 0.0, img).astype(np.float32)
    assert np.array_equal(np.asarray(run(params, other)), out)
    g = jax.grad(lambda p: jnp.sum(filter_image(p, img, masks, model) ** 2))(params)
    leaves = jax.tree.leaves(g)
    assert all(np.all(np.isfinite(x)) for x in leaves) and any(np.any(np.asarray(x) != 0) for x in leaves)


def test_settings_are_checked_and_saved(tmp_path):
    with pytest.raises(ValueError, match="prefill_blend must lie"):
        InpainterConfig(prefill="telea", prefill_blend=1.5)
    with pytest.raises(ValueError, match="not white"):
        InpainterConfig(prefill_blend=0.5)
    with pytest.raises(ValueError, match="not white"):
        InpainterConfig(prefill_blend_distance=5.0)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=">= 0 pixels and finite"):
            InpainterConfig(prefill="telea", prefill_blend_distance=bad)
    inp = _with(Inpainter.init(TINY, seed=2), flip_average=True, prefill_blend=0.8, prefill_blend_distance=5.0,
                prefill_blend_unit="model")
    inp.save(tmp_path / "m.npz")
    back = Inpainter.load(tmp_path / "m.npz")
    assert back.config == inp.config
    img, masks = _frame()
    np.testing.assert_array_equal(filter_frame(img, masks, inpainter=back), filter_frame(img, masks, inpainter=inp))
    arrays = dict(np.load(tmp_path / "m.npz"))  # a checkpoint whose distance is negative is refused, naming the file
    arrays["config/prefill_blend_distance"] = np.asarray(-5.0, arrays["config/prefill_blend_distance"].dtype)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match="bad.npz"):
        Inpainter.load(tmp_path / "bad.npz")
    for unit in (np.asarray("metres"), np.asarray(3.0)):  # a unit it does not know, or not a string
        arrays = dict(np.load(tmp_path / "m.npz"))
        arrays["config/prefill_blend_unit"] = unit
        np.savez(tmp_path / "unit.npz", **arrays)
        with pytest.raises(InputError, match="unit.npz"):
            Inpainter.load(tmp_path / "unit.npz")
