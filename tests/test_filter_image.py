"""The differentiable privacy filter (issue 17 item 4): ``filter_image`` and the detector's input gradient.

References, all independent of ``privslam_jax/inpaint/differentiable.py``:

* values: :func:`filter_frame` (OpenCV crops and resizes, one jitted forward per crop, float64
  blend) on the synthetic test frame ``tests/data/synth_frame_320x96.npz`` with both embedded
  checkpoints, and on a tiny random model for grey frames, overlapping masks and frames smaller
  than the model size; the resize matrices against ``cv2.resize`` (``crops._resize``);
* privacy: random hidden pixels must leave the output bit-identical;
* gradients: central finite differences in float64 along random directions (relative error
  ≤ 1e-3), with the edges and prefill held fixed (they are constants of the forward pass).
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from privslam_jax.inpaint.crops import _resize, crop_box, extract
from privslam_jax.inpaint.differentiable import (
    FilterConstants,
    FilterModel,
    apply_filter,
    filter_constants,
    filter_geometry,
    filter_image,
    resize_matrices,
)
from privslam_jax.inpaint.filter import (
    EMBEDDED_INPAINTER,
    EMBEDDED_REAL_INPAINTER,
    EMBEDDED_TRADEOFF_INPAINTER,
    Inpainter,
    InpainterConfig,
    filter_frame,
)

DATA = os.path.join(os.path.dirname(__file__), "data", "synth_frame_320x96.npz")
TINY = InpainterConfig(width=4, num_residual_blocks=1)
"""Width 4, one residual block, model size 64 (at size 32 the edge hole, grown by 3σ + 2 = 8 px,
covers whole crops: the edge generator then sees a constant image and its instance norms amplify
float rounding)."""
FD_RTOL = 1e-3  # float64 central differences


def _synth():
    d = np.load(DATA)
    return d["image"].astype(np.float32) / np.float32(255), d["masks"]


def _tiny_case():
    """The left 96×128 of the synthetic frame (five masks, two cut by the border, some overlapping),
    mapped into (0.05, 0.95) so that no resampled pixel sits on the ``clip(·, 0, 1)`` kinks."""
    img, masks = _synth()
    img, masks = img[:, :128], masks[:, :, :128]
    masks = masks[masks.any(axis=(1, 2))]
    return (np.float32(0.05) + np.float32(0.9) * img).astype(np.float32), masks


def test_resize_matrices_equal_opencv():
    """``R_v x R_uᵀ`` = the resize of crops.py for shrinking, growing and mixed (one side shrinks,
    the other grows: another OpenCV code path) size pairs."""
    rng = np.random.default_rng(0)
    pairs = [(100, 100, 64, 64), (40, 40, 64, 64), (64, 64, 45, 45), (64, 64, 100, 100), (96, 120, 64, 64),
             (24, 40, 32, 32), (32, 32, 24, 40), (20, 200, 32, 32), (64, 64, 64, 64)]
    pairs += [(*map(int, rng.integers(12, 200, 2)), 64, 64) for _ in range(12)]
    for hi, wi, ho, wo in pairs:
        x = rng.random((hi, wi, 3)).astype(np.float32)
        rv, ru = resize_matrices(hi, wi, ho, wo)
        got = np.einsum("iv,vuc,ju->ijc", rv.astype(np.float64), x, ru.astype(np.float64), optimize=True)
        np.testing.assert_allclose(got, _resize(x, wo, ho), atol=1e-6, err_msg=str((hi, wi, ho, wo)))


@pytest.fixture(scope="module", params=["synthetic", "real", "tradeoff"])
def embedded(request):
    """``(inpainter, params, jitted filter_image on the synthetic frame's masks)`` for one shipped checkpoint."""
    path = {"synthetic": EMBEDDED_INPAINTER, "real": EMBEDDED_REAL_INPAINTER,
            "tradeoff": EMBEDDED_TRADEOFF_INPAINTER}[request.param]
    if not path.is_file():
        pytest.skip(f"{path.name} is not shipped in this checkout")
    inp = Inpainter.embedded(request.param)
    model, params = FilterModel.split(inp)
    _, masks = _synth()
    return inp, params, jax.jit(lambda p, x: filter_image(p, x, masks, model))


def test_equals_filter_frame_and_keeps_the_outside_bit_identical(embedded):
    """Parity on the 10-object synthetic frame: 3.0e-7 / 1.5e-7 / 1.8e-7 measured for the synthetic /
    real / trade-off checkpoints (acceptance: 2/255); outside the union of the masks the output is
    the input, bit for bit."""
    inp, params, run = embedded
    img, masks = _synth()
    hidden = masks.any(axis=0)
    ref = filter_frame(img, masks, "edgeconnect", inpainter=inp)
    out = np.asarray(run(params, img))
    assert out.dtype == np.float32 and out.shape == img.shape
    err = np.abs(out - ref)[hidden].max()
    assert err <= 1e-5 < 2 / 255, err
    assert np.array_equal(out[~hidden], img[~hidden])
    assert np.abs(out - img)[hidden].mean() > 0.02  # the objects were replaced


def test_output_does_not_depend_on_the_hidden_pixels(embedded):
    """Leak-freedom: any values under the masks give the same output, bit for bit."""
    _, params, run = embedded
    img, masks = _synth()
    hidden = masks.any(axis=0)
    out = np.asarray(run(params, img))
    rng = np.random.default_rng(1)
    for fill in (rng.random(img.shape), np.zeros(img.shape), np.ones(img.shape)):
        other = np.where(hidden[..., None], fill, img).astype(np.float32)
        assert np.array_equal(np.asarray(run(params, other)), out)


@pytest.fixture(scope="module")
def tiny():
    """``(inpainter, model, params, jitted filter_image on the tiny case's masks)``, random init."""
    inp = Inpainter.init(TINY, seed=3)
    model, params = FilterModel.split(inp)
    _, masks = _tiny_case()
    return inp, model, params, jax.jit(lambda p, x: filter_image(p, x, masks, model))


def test_grey_frames_overlaps_and_frames_smaller_than_the_model(tiny):
    """Tiny random model: overlapping masks (averaged), grey input (red channel of the RGB result,
    as ``privslam filter`` writes grey sequences) and a 40-px-high frame whose crop (40 × 90) grows
    along one side and shrinks along the other to the model's 64²."""
    inp, model, params, run = tiny
    img, masks = _tiny_case()
    hidden = masks.any(axis=0)
    assert (masks.sum(axis=0) > 1).any()  # objects overlap
    out = np.asarray(run(params, img))
    np.testing.assert_allclose(out, filter_frame(img, masks, inpainter=inp), atol=1e-5)
    assert np.array_equal(out[~hidden], img[~hidden])

    grey = img.mean(axis=-1)
    out = np.asarray(run(params, grey))
    assert out.shape == grey.shape and np.array_equal(out[~hidden], grey[~hidden])
    np.testing.assert_allclose(out, filter_frame(np.repeat(grey[..., None], 3, -1), masks, inpainter=inp)[..., 0],
                               atol=1e-5)

    small = img[30:70]
    m = np.zeros((1, 40, 128), bool)
    m[0, 15:25, 20:110] = True
    box = crop_box(m[0], TINY.crop_pad, TINY.min_crop)
    assert box.height < TINY.size < box.width
    np.testing.assert_allclose(filter_image(params, small, m, model), filter_frame(small, m, inpainter=inp), atol=1e-5)


def test_apply_filter_pads_rows_and_compiles_once_for_every_mask_set(tiny):
    """The fixed-shape form a training loop jits once: geometry and constants padded to 8 rows equal
    ``filter_frame`` for two different sets of masks (and for none), with a single trace."""
    inp, model, params, _ = tiny
    img, masks = _tiny_case()
    traces = []

    @jax.jit
    def run(p, x, geometry, constants):
        traces.append(1)
        return apply_filter(p, x, geometry, model, constants)

    def padded(m):
        c = filter_constants(img, m, TINY)
        k = len(c.edges)
        return filter_geometry(m, TINY, rows=8), FilterConstants(np.pad(c.edges, ((0, 8 - k), (0, 0), (0, 0))),
                                                                  np.pad(c.fill, ((0, 8 - k), (0, 0), (0, 0), (0, 0))))

    for m in (masks, masks[1:3], np.zeros_like(masks[:1])):
        out = np.asarray(run(params, img, *padded(m)))
        np.testing.assert_allclose(out, filter_frame(img, m, inpainter=inp), atol=1e-5)
        assert np.array_equal(out[~m.any(axis=0)], img[~m.any(axis=0)])
    assert len(traces) == 1
    with pytest.raises(ValueError, match="do not fit"):
        filter_geometry(masks, TINY, rows=1)


def test_empty_masks_and_bad_arguments(tiny):
    _, model, params, _ = tiny
    img, masks = _tiny_case()
    assert np.array_equal(filter_image(params, img, np.zeros((2, 96, 128), bool), model), img)
    with_empty = np.concatenate([masks[:1], np.zeros_like(masks[:1]), masks[1:]])
    np.testing.assert_array_equal(filter_constants(img, with_empty, TINY).edges,
                                  filter_constants(img, masks, TINY).edges)
    with pytest.raises(ValueError, match="image must be"):
        filter_image(params, img[..., :2], masks, model)
    with pytest.raises(ValueError, match="constants are for other masks"):
        filter_image(params, img, masks, model, filter_constants(img, masks[:2], TINY))
    with pytest.raises(TypeError, match="masks"):  # concrete masks only (jaxtyping refuses a tracer first)
        jax.jit(lambda m: filter_image(params, img, m, model))(masks)


def _to64(tree):
    return jax.tree.map(lambda x: jnp.asarray(np.asarray(x, np.float64)), tree)  # via numpy: no eager XLA ops


def _param_direction(params, rng):
    """Random normal on every ``nnx.Param``; zero on the spectral-norm vectors (not parameters:
    their gradient is stopped, as in torch)."""
    flat = [(k, v.replace(jnp.asarray(rng.standard_normal(v[...].shape) if isinstance(v, nnx.Param)
                                      else np.zeros(v[...].shape))))
            for k, v in nnx.to_flat_state(params)]
    return nnx.from_flat_state(flat)


def _dot(a, b) -> float:
    return float(sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)))


def _check_fd(f, x, grad, direction, eps):
    """Central difference of ``f`` at ``x`` along ``direction`` against ``<grad, direction>``."""
    step = lambda s: jax.tree.map(lambda a, d: a + s * d, x, direction)  # noqa: E731
    fd = (float(f(step(eps))) - float(f(step(-eps)))) / (2 * eps)
    an = _dot(grad, direction)
    assert abs(fd - an) <= FD_RTOL * abs(an), (fd, an)


def test_gradients_match_finite_differences():
    """d(loss)/d(params) and d(loss)/d(image) in float64, ``loss = Σ w·output`` over the hidden
    pixels, two overlapping objects, the real checkpoint's options (Telea prefill, residual output).

    The gradient is taken with the default constants (pure callback on the stop-gradient image) and
    compared with central differences along 2 random directions each (relative error ≤ 1e-3;
    measured ≤ 1e-8): for the parameters through the same function (the constants do not depend on
    them), for the image with the constants held fixed (they are piecewise constant in the pixels:
    8-bit Telea, thresholded Canny). Steps 1e-8 (params) and 1e-7 (image): the generators are ReLU
    networks, and a random direction crosses a kink within ~1e-6. Hidden pixels: gradient exactly 0."""
    config = dataclasses.replace(TINY, prefill="telea", residual=True)
    model, params = FilterModel.split(Inpainter.init(config, seed=5))
    img, masks = _tiny_case()
    masks = masks[:2]
    hidden = masks.any(axis=0)
    assert (masks[0] & masks[1]).any()
    consts = filter_constants(img, masks, config)
    rng = np.random.default_rng(7)
    w = rng.standard_normal(img.shape) * hidden[..., None]
    with jax.enable_x64(True):
        p64, x64, w64 = _to64(params), jnp.asarray(img, jnp.float64), jnp.asarray(w)
        value_and_grad = jax.jit(jax.value_and_grad(
            lambda p, x: jnp.sum(w64 * filter_image(p, x, masks, model)), argnums=(0, 1)))
        fixed = jax.jit(lambda x: jnp.sum(w64 * filter_image(p64, x, masks, model, consts)))
        _, (gp, gx) = value_and_grad(p64, x64)
        assert np.all(np.asarray(gx)[hidden] == 0) and np.abs(np.asarray(gx)).max() > 0
        for _ in range(2):
            _check_fd(lambda p: value_and_grad(p, x64)[0], p64, gp, _param_direction(params, rng), 1e-8)
            _check_fd(fixed, x64, gx, jnp.asarray(rng.standard_normal(img.shape)), 1e-7)


def _tiny_detector():
    """A random 8-class tiny YOLOv8 in eval mode (BatchNorm with its running statistics;
    ``Detector`` folds them into the convolutions, the same function), float64. The kernels are
    scaled ×√6 (He's variance 2/fan_in instead of torch's 1/(3·fan_in)): with torch's init the
    activations shrink ~3× per layer and the head hardly depends on the pixels."""
    from privslam_jax.detect.yolov8 import YOLOv8Config, init_yolov8

    model = init_yolov8(YOLOv8Config(num_classes=8, scale="tiny"), seed=0)
    for _, node in nnx.iter_graph(model):
        if isinstance(node, nnx.Conv):
            node.kernel.set_value(jnp.asarray(np.asarray(node.kernel.get_value()) * np.sqrt(6.0)))
    model.eval()
    graphdef, state = nnx.split(model)
    return graphdef, _to64(state)


def test_privacy_loss_of_the_detector_is_differentiable_in_its_input_pixels(tiny):
    """A privacy loss on the filtered image: the highest class probability of a tiny random YOLOv8
    (sigmoid of its raw class logits, over every anchor) on ``filter_image``'s output, differentiated
    w.r.t. that image and compared with central differences along 2 random directions (float64, step
    1e-6, relative error ≤ 1e-3; measured ≤ 3e-7). With the filter's own gradient (test above), the
    chain rule gives the loss's gradient w.r.t. the inpainter's parameters and the input frame.
    ``Detector`` runs the same network with BatchNorm folded and a native float32 stem kernel whose
    VJP is XLA's convolution (tests/test_rgb_stem.py)."""
    from privslam_jax.detect.decode import decode_head
    from privslam_jax.detect.yolov8 import STRIDES

    _, _, params, run = tiny
    img, masks = _tiny_case()
    filtered = np.asarray(run(params, img), np.float64)
    rng = np.random.default_rng(11)
    with jax.enable_x64(True):
        graphdef, det = _tiny_detector()
        y = jnp.asarray(filtered)

        def privacy_loss(y):
            return jnp.max(decode_head(nnx.merge(graphdef, det)(y[None]), STRIDES, 16)[0, :, 4:])

        value_and_grad = jax.jit(jax.value_and_grad(privacy_loss))
        _, g = value_and_grad(y)
        assert np.abs(np.asarray(g)[masks.any(axis=0)]).max() > 0  # the filled pixels matter
        for _ in range(2):
            _check_fd(lambda y: value_and_grad(y)[0], y, g, jnp.asarray(rng.standard_normal(img.shape)), 1e-6)


def test_constants_are_what_filter_frame_feeds_the_network():
    """``filter_constants`` = the edges and prefill ``Inpainter.inpaint_crop`` computes per crop
    (reference written out with extract/safe_canny/baselines.fill), and they ignore hidden pixels."""
    from privslam_jax.inpaint import baselines
    from privslam_jax.inpaint.masks import safe_canny, to_grey

    cfg = dataclasses.replace(TINY, prefill="telea")
    img, masks = _tiny_case()
    hidden = masks.any(axis=0)
    c = filter_constants(img, masks, cfg)
    assert isinstance(c, FilterConstants) and c.edges.shape == (len(masks), 64, 64)
    for k, m in enumerate(masks):
        rgb, hole = extract(img, hidden, crop_box(m, cfg.crop_pad, cfg.min_crop), 64)
        np.testing.assert_array_equal(c.edges[k], safe_canny(to_grey(rgb), hole, sigma=cfg.sigma)[0])
        np.testing.assert_array_equal(c.fill[k], baselines.fill(rgb, hole, "telea"))
    assert c.edges.sum() > 0
    other = np.where(hidden[..., None], np.random.default_rng(0).random(img.shape), img).astype(np.float32)
    d = filter_constants(other, masks, cfg)
    assert np.array_equal(d.edges, c.edges) and np.array_equal(d.fill, c.fill)
