"""The EdgeConnect privacy filter as one differentiable JAX function.

``filter_image(params, image, masks, model)`` computes what
:func:`~privslam_jax.inpaint.filter.filter_frame` computes with ``method="edgeconnect"``, written
as JAX operations so that ``jax.grad`` / ``jax.jit`` / ``jax.vjp`` go through it:

1. hide: the pixels of the union of ``masks`` are set to zero (``jnp.where``);
2. crop and resize to the model size in one linear map per object: ``D_v · x · D_uᵀ`` per channel,
   where ``D_v`` (``S × H``) and ``D_u`` (``S × W``) hold the crop's resize matrices at its rows and
   columns (:func:`~privslam_jax.inpaint.crops.crop_box`) and zeros elsewhere; then clipped to
   ``[0, 1]`` and the crop's hole zeroed, as :func:`~privslam_jax.inpaint.crops.extract` does;
3. the EdgeConnect forward with the checkpoint's inference settings
   (:func:`~privslam_jax.inpaint.filter.inpaint_inference`), all
   objects in one batch;
4. resize back and paste (``U_v · out · U_uᵀ``, the transpose layout), under each object's own
   mask, averaged where masks overlap; the input is kept everywhere outside the union of the masks
   (``jnp.where``).

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
from them on the host (:func:`filter_geometry`). :func:`filter_image` closes over them (under
``jax.jit``, one compilation per set of boxes); :func:`apply_filter` takes them as fixed-shape
arrays, padded to a number of rows, so that one compilation serves every frame of a size (what a
training loop needs).
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
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig, inpaint_inference, network_share
from privslam_jax.inpaint.masks import GREY_WEIGHTS, dilate, edge_band, safe_canny, to_grey

__all__ = ["FilterConstants", "FilterGeometry", "FilterModel", "apply_filter", "filter_constants", "filter_geometry",
           "filter_image", "resize_matrices"]


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
    frame_fill: Float[np.ndarray | Array, "H W 3"] | None = None
    """The prefill of the whole frame at full resolution, which the output is blended with when
    ``InpainterConfig.blends_prefill`` (else None)."""
    frame_share: Float[np.ndarray | Array, "H W"] | None = None
    """The network's share of each pixel in that blend when it depends on the distance to the visible
    pixels (``InpainterConfig.prefill_blend_distance > 0``, :func:`~privslam_jax.inpaint.filter.network_share`;
    else None: the constant ``prefill_blend``)."""


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


class FilterGeometry(NamedTuple):
    """Where each object's crop comes from and goes back to, as fixed-shape arrays (one row per
    object, padded to ``K`` rows with empty objects), so that one compiled function serves every set
    of masks of a frame size: :func:`apply_filter` under ``jax.jit`` with the geometry as an argument.

    The crop-and-resize of object ``k`` is ``down_v[k] · x · down_u[k]ᵀ`` on the whole frame (the
    rows and columns outside its crop are zero), the paste back ``up_v[k] · y · up_u[k]ᵀ``."""

    down_v: Float[np.ndarray | Array, "K S H"]
    down_u: Float[np.ndarray | Array, "K S W"]
    up_v: Float[np.ndarray | Array, "K H S"]
    up_u: Float[np.ndarray | Array, "K W S"]
    hole: Bool[np.ndarray | Array, "K S S"]
    """Each crop's hole at the model size (the union of the masks, resized)."""
    edge_hole: Bool[np.ndarray | Array, "K S S"]
    """The hole grown by the Canny band (where G1's edges replace the input edges)."""
    own: Bool[np.ndarray | Array, "K H W"]
    """Where object ``k``'s output is pasted: its own mask (empty for padding rows)."""
    hidden: Bool[np.ndarray | Array, "H W"]
    """The union of the masks."""


def filter_geometry(masks: Bool[np.ndarray, "K H W"], config: InpainterConfig, rows: int | None = None) -> FilterGeometry:
    """:class:`FilterGeometry` of the non-empty ``masks`` (host side), padded to ``rows`` objects
    (default: as many as there are non-empty masks; fewer rows than objects is refused)."""
    masks = np.asarray(masks)
    if masks.dtype != np.bool_ or masks.ndim != 3:
        raise ValueError(f"masks must be bool (K, H, W), got {masks.dtype} {masks.shape}")
    h, w = masks.shape[1:]
    masks = masks[masks.any(axis=(1, 2))]
    crops = _crops(masks, config)
    k = len(crops) if rows is None else rows
    if k < len(crops):
        raise ValueError(f"{len(crops)} objects do not fit in {k} rows")
    s = config.size
    g = FilterGeometry(np.zeros((k, s, h), np.float32), np.zeros((k, s, w), np.float32),
                       np.zeros((k, h, s), np.float32), np.zeros((k, w, s), np.float32),
                       np.zeros((k, s, s), bool), np.zeros((k, s, s), bool), np.zeros((k, h, w), bool),
                       masks.any(axis=0) if len(masks) else np.zeros((h, w), bool))
    for i, c in enumerate(crops):
        b = c.box
        g.down_v[i, :, b.v0:b.v1], g.down_u[i, :, b.u0:b.u1] = c.down
        g.up_v[i, b.v0:b.v1], g.up_u[i, b.u0:b.u1] = c.up
        g.hole[i], g.edge_hole[i] = c.hole, c.edge_hole
        g.own[i, b.v0:b.v1, b.u0:b.u1] = c.own
    return g


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
    frame_fill = baselines.fill(rgb, hidden, config.prefill).astype(np.float32) if config.blends_prefill else None
    frame_share = network_share(masks, config) if config.prefill_blend_distance > 0.0 else None
    return FilterConstants(edges, fill, frame_fill, frame_share)


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
    geometry = filter_geometry(masks, cfg)
    k, s = len(masks), cfg.size
    if constants is None:
        rgb = jnp.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image
        shapes = FilterConstants(jax.ShapeDtypeStruct((k, s, s), jnp.float32),
                                 jax.ShapeDtypeStruct((k, s, s, 3), jnp.float32),
                                 jax.ShapeDtypeStruct((h, w, 3), jnp.float32) if cfg.blends_prefill else None,
                                 jax.ShapeDtypeStruct((h, w), jnp.float32) if cfg.prefill_blend_distance > 0.0 else None)
        constants = jax.pure_callback(lambda x: filter_constants(np.asarray(x), masks, cfg), shapes,
                                      jax.lax.stop_gradient(rgb), vmap_method="sequential")
    if np.shape(constants.edges) != (k, s, s) or np.shape(constants.fill) != (k, s, s, 3):
        raise ValueError(f"constants are for other masks: edges {np.shape(constants.edges)}, fill "
                         f"{np.shape(constants.fill)}, expected {(k, s, s)} and {(k, s, s, 3)}")
    return apply_filter(params, image, geometry, model, constants)


def apply_filter(
    params: PyTree,
    image: Float[Array | np.ndarray, "H W *C"],
    geometry: FilterGeometry,
    model: FilterModel,
    constants: FilterConstants,
) -> Float[Array, "H W *C"]:
    """:func:`filter_image` on precomputed, fixed-shape inputs: traceable in all of them, so that one
    ``jax.jit`` compilation serves every frame of a size and every set of masks with the same number
    of rows (:func:`filter_geometry` pads them; ``constants`` must have as many rows, zeros for
    padding). The gradient is as in :func:`filter_image` (edges and prefill held fixed)."""
    image = jnp.asarray(image)
    h, w = _image_shape(image.shape)
    dtype = image.dtype
    rgb = jnp.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image
    g = jax.tree.map(jnp.asarray, geometry)
    if g.hidden.shape != (h, w) or g.own.shape[1:] != (h, w):
        raise ValueError(f"geometry is for {g.hidden.shape} frames, the image is {(h, w)}")
    cast = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    edges = jax.lax.stop_gradient(cast(constants.edges))
    fill = jax.lax.stop_gradient(cast(constants.fill))
    if edges.shape != g.hole.shape or fill.shape != g.hole.shape + (3,):
        raise ValueError(f"constants have {edges.shape[0]} rows, the geometry {g.hole.shape[0]}")
    zero = jnp.zeros((), dtype)
    visible = jnp.where(g.hidden[..., None], zero, rgb)  # no hidden pixel is ever read
    x = jnp.einsum("ksh,hwc,ktw->kstc", cast(g.down_v), visible, cast(g.down_u))
    rgb_s = jnp.where(g.hole[..., None], zero, jnp.clip(x, 0.0, 1.0))
    grey_s = rgb_s @ jnp.asarray(GREY_WEIGHTS, dtype)
    eg, ig = nnx.merge(model.graphdef, params)
    out_s = inpaint_inference(eg, ig, rgb_s, grey_s[..., None], edges[..., None], cast(g.hole)[..., None],
                              cast(g.edge_hole)[..., None], model.config, model.use_edge_model, fill)
    paste = jnp.einsum("khs,kstc,kwt->khwc", cast(g.up_v), out_s, cast(g.up_u))
    acc = jnp.sum(jnp.where(g.own[..., None], paste, zero), axis=0)
    count = jnp.sum(g.own, axis=0).astype(dtype)
    blend = acc / jnp.maximum(count, 1.0)[..., None]
    cfg = model.config
    if cfg.blends_prefill:  # mixed with the full-resolution prefill of the frame (InpainterConfig.prefill_blend)
        if constants.frame_fill is None or np.shape(constants.frame_fill) != (h, w, 3):
            raise ValueError(f"this inpainter blends with the frame's prefill (prefill_blend {cfg.prefill_blend}): "
                             f"constants need frame_fill of shape {(h, w, 3)} (filter_constants makes it)")
        a = cfg.prefill_blend
        if cfg.prefill_blend_distance > 0.0:
            if constants.frame_share is None or np.shape(constants.frame_share) != (h, w):
                raise ValueError(f"this inpainter's blend depends on the distance to the visible pixels: constants "
                                 f"need frame_share of shape {(h, w)} (filter_constants makes it)")
            a = jax.lax.stop_gradient(cast(constants.frame_share))[..., None]
        blend = a * blend + (1.0 - a) * jax.lax.stop_gradient(cast(constants.frame_fill))
    out = jnp.where(g.hidden[..., None], blend, rgb)
    return out[..., 0] if image.ndim == 2 else out
