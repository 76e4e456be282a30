"""The EdgeConnect privacy filter as one differentiable JAX function.

``filter_image(params, image, masks, model)`` computes what
:func:`~privslam_jax.inpaint.filter.filter_frame` computes with ``method="edgeconnect"``, written
as JAX operations so that ``jax.grad`` / ``jax.jit`` / ``jax.vjp`` go through it:

1. hide: the pixels of the union of ``masks`` are set to zero (``jnp.where``);
2. crop: each object's square crop (:func:`~privslam_jax.inpaint.crops.crop_box`) is a static slice;
3. resize to the model size: ``R_v · crop · R_uᵀ`` per channel, then clipped to ``[0, 1]`` and the
   crop's hole zeroed, as :func:`~privslam_jax.inpaint.crops.extract` does;
4. the EdgeConnect forward (:func:`~privslam_jax.inpaint.filter.edgeconnect_forward`), all
   objects in one batch;
5. resize back (``P_v · out · P_uᵀ``), paste under each object's own mask, average where masks
   overlap, and keep the input everywhere outside the union of the masks (``jnp.where``).

Resampling. ``crops.py`` resizes with OpenCV (``INTER_AREA`` when shrinking, ``INTER_LINEAR``
otherwise). Both are linear maps along each axis, so ``R_v``/``R_u`` are read off OpenCV itself
(the resize of an identity matrix; :func:`resize_matrices`) and the resize is a matrix product in
JAX. ``jax.image.resize`` is not used: its antialiased down-sampling is a triangle filter, not
OpenCV's box average (``INTER_AREA``), so the network sees other pixels than in ``filter_frame``
(with it the filtered frames differ by up to 6.4/255; its ``linear`` up-sampling does equal
``INTER_LINEAR`` up to rounding).

What is differentiated and what is a constant. The Canny edges (:func:`~privslam_jax.inpaint.masks.safe_canny`)
and the prefill of the hole (``InpainterConfig.prefill``, e.g. OpenCV Telea for the real-frame
checkpoint) are host-side, piecewise-constant or OpenCV computations. They are computed from the
crop's pixels *outside* the hole only (as in ``filter_frame``) and enter the forward pass as
constants (:class:`FilterConstants`): either passed in, or computed by a ``jax.pure_callback`` on
``jax.lax.stop_gradient(image)``. The gradient with respect to the image therefore flows through
the network's inputs (masked RGB and its grey level) and through the paste/blend of the context
pixels; with respect to ``params`` through both generators. It is the derivative with the edges
and the prefill held fixed: finite differences of ``filter_image`` with fixed ``constants`` equal
it (``tests/test_filter_image.py``). As both constants are piecewise constant in the pixels
(thresholded edges; the Telea and NS prefills are 8-bit; white, grey and black are constant), this
is also the derivative of ``filter_frame`` itself wherever that exists (almost everywhere). The
gradient with respect to every hidden pixel is exactly zero and the output does not depend on
them, bit for bit.

Shapes: ``masks`` must be concrete (numpy): the crop boxes, holes and resize matrices are computed
from them on the host and are static under ``jax.jit`` (close over them:
``jax.jit(lambda p, x: filter_image(p, x, masks, model))``; one compilation per set of boxes).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, PyTree

from privslam_jax.data.images import as_unit_image
from privslam_jax.inpaint import baselines
from privslam_jax.inpaint.crops import CropBox, crop_box, extract
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig, edgeconnect_forward
from privslam_jax.inpaint.masks import GREY_WEIGHTS, dilate, edge_band, safe_canny, to_grey

__all__ = ["FilterConstants", "FilterModel", "filter_constants", "filter_image", "resize_matrices"]


@dataclasses.dataclass(frozen=True)
class FilterModel:
    """The static half of the differentiable filter: the generators' graph (in eval mode) and the
    inference settings. The parameters are the other half (``params``, an ``nnx.State``)."""

    graphdef: Any
    """``nnx.split`` graph of ``(EdgeGenerator, InpaintGenerator)`` in eval mode."""
    config: InpainterConfig
    """Model size, crop context, Canny σ, prefill and residual settings."""
    use_edge_model: bool = True
    """``False``: the edge-generator ablation of :meth:`Inpainter.without_edge_model`."""

    @classmethod
    def split(cls, inpainter: Inpainter) -> tuple[FilterModel, PyTree]:
        """``(model, params)`` of an :class:`~privslam_jax.inpaint.filter.Inpainter`; ``params``
        is its state (kernels, biases and the spectral-norm vectors)."""
        return cls(inpainter.graphdef, inpainter.config, inpainter.use_edge_model), inpainter.state


class FilterConstants(NamedTuple):
    """The non-differentiable inputs of the networks, one row per non-empty mask (in order).

    Both are functions of the pixels outside the union of the masks and of the masks only."""

    edges: Float[np.ndarray | Array, "K S S"]
    """Leak-free Canny edges of each crop at the model size (zero on the grown hole)."""
    fill: Float[np.ndarray | Array, "K S S 3"]
    """What the image generator sees inside each crop's hole (``InpainterConfig.prefill``)."""


@dataclasses.dataclass(frozen=True)
class _Crop:
    box: CropBox
    hole: np.ndarray  # (S, S) bool
    edge_hole: np.ndarray  # (S, S) bool
    down: tuple[np.ndarray, np.ndarray]  # (S, h), (S, w)
    up: tuple[np.ndarray, np.ndarray]  # (h, S), (w, S)
    own: np.ndarray  # (h, w) bool


@functools.lru_cache(maxsize=512)
def resize_matrices(h_in: int, w_in: int, h_out: int, w_out: int) -> tuple[np.ndarray, np.ndarray]:
    """``(R_v (h_out, h_in), R_u (w_out, w_in))`` float32 with ``R_v · x · R_uᵀ`` equal (to float
    rounding) to the OpenCV resize of ``crops.py`` of any ``(h_in, w_in)`` image ``x`` to
    ``(h_out, w_out)``: ``INTER_AREA`` if either side shrinks, else ``INTER_LINEAR``.

    Read off OpenCV: the resize of an identity matrix along one axis. When one side shrinks and
    the other grows, OpenCV's ``INTER_AREA`` takes another code path than for one axis alone, so
    the matrices are then probed with images of the full size (four columns of the identity per call).
    """
    shrink = w_out < w_in or h_out < h_in
    interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    if not (shrink and (w_out > w_in or h_out > h_in)):
        rv = cv2.resize(np.eye(h_in, dtype=np.float32), (h_in, h_out), interpolation=interp)
        ru = cv2.resize(np.eye(w_in, dtype=np.float32), (w_in, w_out), interpolation=interp)
        return rv.reshape(h_out, h_in), ru.reshape(w_out, w_in)

    def probe(n: int, axis: int) -> np.ndarray:
        cols = []
        for j0 in range(0, n, 4):
            js = np.arange(j0, min(j0 + 4, n))
            x = np.zeros((h_in, w_in, 4), np.float32)
            if axis == 0:
                x[js, :, np.arange(len(js))] = 1.0
            else:
                x[:, js, np.arange(len(js))] = 1.0
            out = cv2.resize(x, (w_out, h_out), interpolation=interp).reshape(h_out, w_out, 4)
            cols.append(out[:, 0, : len(js)] if axis == 0 else out[0, :, : len(js)])
        return np.concatenate(cols, axis=1)

    return probe(h_in, 0), probe(w_in, 1)


def _check_masks(masks, h: int, w: int) -> np.ndarray:
    if isinstance(masks, jax.core.Tracer):
        raise TypeError("masks must be concrete (numpy): the crop boxes are computed from them on the host")
    masks = np.asarray(masks)
    if masks.dtype != np.bool_ or masks.ndim != 3 or masks.shape[1:] != (h, w):
        raise ValueError(f"masks must be bool (K, {h}, {w}), got {masks.dtype} {masks.shape}")
    return masks[masks.any(axis=(1, 2))]


def _image_shape(shape: tuple[int, ...]) -> tuple[int, int]:
    if not (len(shape) == 2 or (len(shape) == 3 and shape[2] == 3)):
        raise ValueError(f"image must be (H, W) grey or (H, W, 3) RGB, got shape {shape}")
    return shape[0], shape[1]


def _crops(masks: np.ndarray, config: InpainterConfig) -> list[_Crop]:
    """Host-side geometry of every object (depends on the masks only)."""
    h, w = masks.shape[1:]
    hidden = masks.any(axis=0)
    size = config.size
    band = edge_band(config.sigma)
    out = []
    for m in masks:
        box = crop_box(m, config.crop_pad, config.min_crop)
        _, hole = extract(np.zeros((h, w, 3), np.float32), hidden, box, size)
        out.append(_Crop(box, hole, dilate(hole, band), resize_matrices(box.height, box.width, size, size),
                         resize_matrices(size, size, box.height, box.width),
                         m[box.v0:box.v1, box.u0:box.u1]))
    return out


def filter_constants(
    image: Float[np.ndarray, "H W *C"], masks: Bool[np.ndarray, "K H W"], config: InpainterConfig
) -> FilterConstants:
    """Edges and prefill of every crop, on the host, exactly as ``filter_frame`` computes them
    (:func:`~privslam_jax.inpaint.crops.extract` with the union hidden, then
    :func:`~privslam_jax.inpaint.masks.safe_canny` and the prefill). ``image`` float in ``[0, 1]``,
    grey ``(H, W)`` (repeated to RGB) or ``(H, W, 3)``; empty masks are dropped, as in
    :func:`filter_image`."""
    h, w = _image_shape(np.shape(image))
    masks = _check_masks(masks, h, w)
    rgb = as_unit_image(np.asarray(image, np.float32), "filter_constants image")
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=-1)
    hidden = masks.any(axis=0)
    s = config.size
    edges = np.zeros((len(masks), s, s), np.float32)
    fill = np.zeros((len(masks), s, s, 3), np.float32)
    for k, m in enumerate(masks):
        rgb_s, hole_s = extract(rgb, hidden, crop_box(m, config.crop_pad, config.min_crop), s)
        edges[k] = safe_canny(to_grey(rgb_s), hole_s, sigma=config.sigma)[0]
        fill[k] = baselines.fill(rgb_s, hole_s, config.prefill)
    return FilterConstants(edges, fill)


def filter_image(
    params: PyTree,
    image: Float[Array | np.ndarray, "H W *C"],
    masks: Bool[np.ndarray, "K H W"],
    model: FilterModel,
    constants: FilterConstants | None = None,
) -> Float[Array, "H W *C"]:
    """Hide every object of ``masks`` in ``image`` with the EdgeConnect inpainter, differentiably.

    ``params``: the generators' state (:meth:`FilterModel.split`; any float dtype, e.g. cast to
    float64 for gradient checks). ``image``: float in ``[0, 1]``, grey ``(H, W)`` or RGB
    ``(H, W, 3)``; the result has its shape and dtype. A grey image is repeated to RGB and the
    result's red channel returned (what ``privslam filter`` writes for grey sequences).
    ``masks``: concrete bool ``(K, H, W)``, one already-dilated mask per object (empty ones are
    ignored; none at all returns ``image``). ``constants``: the edges and prefill
    (:func:`filter_constants`); by default computed from ``stop_gradient(image)`` through a
    ``jax.pure_callback``. Pass them to hold them fixed, e.g. for finite differences.

    Equals ``filter_frame(image, masks, "edgeconnect", inpainter=...)`` up to float rounding inside
    the masks and is the input, bit for bit, outside them (see the module docstring for what the
    gradient is).
    """
    image = jnp.asarray(image)
    h, w = _image_shape(image.shape)
    masks = _check_masks(masks, h, w)
    if len(masks) == 0:
        return image
    cfg = model.config
    dtype = image.dtype
    rgb = jnp.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image
    crops = _crops(masks, cfg)
    k, s = len(crops), cfg.size
    if constants is None:
        shapes = FilterConstants(jax.ShapeDtypeStruct((k, s, s), jnp.float32),
                                 jax.ShapeDtypeStruct((k, s, s, 3), jnp.float32))
        constants = jax.pure_callback(lambda x: filter_constants(np.asarray(x), masks, cfg), shapes,
                                      jax.lax.stop_gradient(rgb), vmap_method="sequential")
    edges = jax.lax.stop_gradient(jnp.asarray(constants.edges, dtype))
    fill = jax.lax.stop_gradient(jnp.asarray(constants.fill, dtype))
    if edges.shape != (k, s, s) or fill.shape != (k, s, s, 3):
        raise ValueError(f"constants are for other masks: edges {edges.shape}, fill {fill.shape}, "
                         f"expected {(k, s, s)} and {(k, s, s, 3)}")

    hidden = masks.any(axis=0)
    visible = jnp.where(hidden[..., None], jnp.zeros((), dtype), rgb)  # no hidden pixel is ever read
    batch = []
    for c in crops:
        b = c.box
        rv, ru = (jnp.asarray(r, dtype) for r in c.down)
        x = jnp.einsum("iv,vuc,ju->ijc", rv, visible[b.v0:b.v1, b.u0:b.u1], ru)
        x = jnp.where(c.hole[..., None], jnp.zeros((), dtype), jnp.clip(x, 0.0, 1.0))
        batch.append(x)
    rgb_s = jnp.stack(batch)
    grey_s = rgb_s @ jnp.asarray(GREY_WEIGHTS, dtype)
    f = lambda a: jnp.asarray(a, dtype)[..., None]  # noqa: E731
    hole = f(np.stack([c.hole for c in crops]))
    edge_hole = f(np.stack([c.edge_hole for c in crops]))
    eg, ig = nnx.merge(model.graphdef, params)
    out_s, _, _ = edgeconnect_forward(eg, ig, rgb_s, grey_s[..., None], edges[..., None], hole, edge_hole,
                                      model.use_edge_model, fill, cfg.residual)

    acc = jnp.zeros((h, w, 3), dtype)
    count = np.zeros((h, w), np.int32)
    for i, c in enumerate(crops):
        b = c.box
        pv, pu = (jnp.asarray(r, dtype) for r in c.up)
        paste = jnp.einsum("iv,vuc,ju->ijc", pv, out_s[i], pu)
        paste = jnp.where(c.own[..., None], paste, jnp.zeros((), dtype))
        acc = acc + jnp.pad(paste, ((b.v0, h - b.v1), (b.u0, w - b.u1), (0, 0)))
        count[b.v0:b.v1, b.u0:b.u1] += c.own
    blend = acc / jnp.asarray(np.maximum(count, 1), dtype)[..., None]
    out = jnp.where(hidden[..., None], blend, rgb)
    return out[..., 0] if image.ndim == 2 else out
