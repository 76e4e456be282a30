"""The three objectives of the privacy/accuracy trade-off (issue 18, item 1), as pure JAX functions.

A filter ``y = f_φ(x, M)`` hides the objects of the masks ``M = {M_k}`` of a frame ``x``.  It is
judged by

* :func:`privacy_loss` — how confidently the detector still sees a privacy-class object inside each
  mask of ``y`` (lower: more private);
* :func:`accuracy_loss` — how far the relative pose estimated from ``y`` (direct photometric
  alignment against a reference frame with known depth, :mod:`privslam_jax.tradeoff.photometric`)
  lies from the ground truth (lower: better for SLAM);
* :func:`fidelity_loss` — how far ``y`` lies from the object-free render inside the masks (lower:
  closer to the true background).

Each is a scalar, differentiable in the filtered frame (and so, through
:func:`~privslam_jax.inpaint.differentiable.filter_image`, in the inpainter's parameters).
``docs/tradeoff.md`` states them together and lists the tests that check them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, PyTree

from privslam_jax.detect.decode import decode_head
from privslam_jax.detect.predict import PRIVACY_CLASSES
from privslam_jax.detect.yolov8 import STRIDES, YOLOv8
from privslam_jax.tradeoff.photometric import PhotometricConfig, align_photometric

__all__ = ["DetectorModel", "accuracy_loss", "anchor_mask_coverage", "fidelity_loss", "geodesic_distance",
           "privacy_loss"]

_DEFAULT_ALIGNMENT = PhotometricConfig()


@dataclasses.dataclass(frozen=True)
class DetectorModel:
    """The static half of the detector: the YOLOv8 graph (eval mode) and its head settings.
    The parameters (``nnx.State``) are the other half."""

    graphdef: Any
    reg_max: int = 16
    strides: tuple[int, ...] = STRIDES

    @classmethod
    def split(cls, model: YOLOv8) -> tuple[DetectorModel, PyTree]:
        """``(model, params)`` of a YOLOv8 (put in eval mode: BatchNorm uses its running statistics)."""
        model.eval()
        graphdef, state = nnx.split(model)
        return cls(graphdef, model.config.reg_max), state


def anchor_mask_coverage(
    boxes: Float[Array, "A 4"], masks: Bool[Array | np.ndarray, "K H W"]
) -> Float[Array, "K A"]:
    """Fraction of each box covered by each mask: ``c_ka = |B_a ∩ M_k| / |B_a|``.

    ``boxes``: ``(cx, cy, w, h)`` in the masks' pixels, pixel ``(u, v)`` covering ``[u, u+1) × [v, v+1)``.
    The area is exact for real-valued boxes: it is the summed-area table ``S_k`` of the mask at the
    box corners, ``|B ∩ M_k| = S(x2, y2) − S(x1, y2) − S(x2, y1) + S(x1, y1)``, where ``S`` at
    non-integer points is the bilinear interpolation of its values at the pixel corners (exact for a
    mask constant on each pixel).  Corners are clamped to the image (the part of a box outside the
    image is not covered); ``|B_a| = w·h`` (floored at 1e-6 px²).  Continuous and piecewise
    polynomial in the box: differentiable almost everywhere.
    """
    k, h, w = masks.shape
    dtype = boxes.dtype
    m = jnp.asarray(masks).astype(dtype)
    S = jnp.zeros((k, h + 1, w + 1), dtype).at[:, 1:, 1:].set(jnp.cumsum(jnp.cumsum(m, axis=1), axis=2))
    cx, cy, bw, bh = boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3]
    x1 = jnp.clip(cx - 0.5 * bw, 0.0, float(w))
    x2 = jnp.clip(cx + 0.5 * bw, 0.0, float(w))
    y1 = jnp.clip(cy - 0.5 * bh, 0.0, float(h))
    y2 = jnp.clip(cy + 0.5 * bh, 0.0, float(h))

    def at(x: Float[Array, " A"], y: Float[Array, " A"]) -> Float[Array, "K A"]:
        x0 = jnp.clip(jnp.floor(x), 0, w - 1).astype(jnp.int32)
        y0 = jnp.clip(jnp.floor(y), 0, h - 1).astype(jnp.int32)
        a = (x - x0.astype(dtype))[None, :]
        b = (y - y0.astype(dtype))[None, :]
        return ((1 - b) * ((1 - a) * S[:, y0, x0] + a * S[:, y0, x0 + 1])
                + b * ((1 - a) * S[:, y0 + 1, x0] + a * S[:, y0 + 1, x0 + 1]))

    inter = at(x2, y2) - at(x1, y2) - at(x2, y1) + at(x1, y1)
    area = jnp.maximum(bw * bh, 1e-6)
    return inter / area[None, :]


def privacy_loss(
    params: PyTree,
    image: Float[Array, "H W 3"],
    masks: Bool[Array | np.ndarray, "K H W"],
    model: DetectorModel,
    *,
    classes: tuple[int, ...] = PRIVACY_CLASSES,
    temperature: float = 0.01,
    input_hw: tuple[int, int] | None = None,
) -> Float[Array, ""]:
    r"""The detector's privacy-class confidence inside the masks of a (filtered) frame.

    With ``p_ac`` the class-``c`` probability of anchor ``a`` (sigmoid of the YOLOv8 head, decoded as
    ultralytics, :func:`~privslam_jax.detect.decode.decode_head`), ``c`` over the privacy ``classes``,
    and ``w_ka`` the fraction of anchor ``a``'s predicted box covered by mask ``k``
    (:func:`anchor_mask_coverage`), the loss is the mean over the ``K'`` non-empty masks of a soft
    maximum (log-sum-exp at temperature ``τ``) of the coverage-weighted confidences:

        L_priv = (1/K') Σ_k τ · log Σ_{a,c} exp(w_ka · p_ac / τ),

    so that ``max_{a,c} w_ka p_ac ≤ L_k ≤ max_{a,c} w_ka p_ac + τ log(A·C)`` (``A`` anchors, ``C``
    classes; with the default ``τ = 0.01`` and a 640×192 input the offset is at most 0.096).  An
    anchor counts in proportion to how much of its predicted box lies inside the mask: a detection
    of the hidden object scores, a box elsewhere does not.  The gradient flows through the
    probabilities and through the predicted boxes (coverage is continuous in them).  No empty mask:
    ``0``.

    Args:
      params: the detector's state (:meth:`DetectorModel.split`; any float dtype).
      image: ``(H, W, 3)`` RGB in [0, 1], e.g. the filtered frame.
      masks: ``(K, H, W)`` bool, one per hidden object (empty masks are ignored).
      model: the static graph.
      classes: class ids of the privacy classes (COCO person, bicycle, car, motorcycle, bus, truck).
      temperature: ``τ`` of the soft maximum.
      input_hw: the detector's input size (multiples of 32); the image is resized to it by
        ``jax.image.resize`` (``"linear"``: OpenCV's ``INTER_LINEAR`` for up-sampling, what
        :class:`~privslam_jax.detect.predict.Detector`'s letterbox does when no padding is needed, e.g.
        a 320×96 frame → 640×192).  ``None``: the image itself (``H``, ``W`` multiples of 32).
    """
    h, w = image.shape[:2]
    hi, wi = (h, w) if input_hw is None else input_hw
    if hi % 32 or wi % 32:
        raise ValueError(f"the detector input must be a multiple of 32 on each side, got {(hi, wi)}")
    x = image if (hi, wi) == (h, w) else jax.image.resize(image, (hi, wi, 3), "linear", antialias=False)
    out = decode_head(nnx.merge(model.graphdef, params)(x[None]), model.strides, model.reg_max)[0]
    scale = jnp.asarray([wi / w, hi / h, wi / w, hi / h], out.dtype)
    boxes = out[:, :4] / scale[None, :]
    probs = out[:, 4:][:, np.asarray(classes)]
    cover = anchor_mask_coverage(boxes, masks)
    scores = cover[:, :, None] * probs[None, :, :]
    soft = temperature * jax.nn.logsumexp(scores.reshape(scores.shape[0], -1) / temperature, axis=-1)
    present = jnp.any(jnp.asarray(masks), axis=(1, 2))
    n = jnp.sum(present)
    return jnp.sum(jnp.where(present, soft, 0.0)) / jnp.maximum(n, 1).astype(soft.dtype)


def fidelity_loss(
    filtered: Float[Array, "H W *C"], target: Float[Array, "H W *C"], masks: Bool[Array | np.ndarray, "K H W"]
) -> Float[Array, ""]:
    """Mean absolute error inside the union of the masks:

        L_fid = Σ_{p ∈ U} Σ_c |y_pc − b_pc| / (|U| · C),   U = ∪_k M_k,

    ``y`` the filtered frame, ``b`` the target (the object-free render), ``C`` channels (1 for
    grey ``(H, W)`` images).  ``0`` when the union is empty.  (No perceptual term yet.)
    """
    if filtered.shape != target.shape:
        raise ValueError(f"filtered {filtered.shape} and target {target.shape} differ in shape")
    union = jnp.any(jnp.asarray(masks), axis=0)
    err = jnp.abs(filtered - target)
    if err.ndim == 3:
        err = jnp.mean(err, axis=-1)
    n = jnp.sum(union).astype(err.dtype)
    return jnp.sum(jnp.where(union, err, 0.0)) / jnp.maximum(n, 1.0)


def geodesic_distance(
    T_est: jaxlie.SE3, T_gt: jaxlie.SE3, rotation_scale: float = 1.0
) -> Float[Array, ""]:
    """``d = ‖W log(T_est⁻¹ T_gt)‖`` with ``log = (ρ, ω)`` the jaxlie SE(3) tangent and
    ``W = diag(1, 1, 1, ℓ, ℓ, ℓ)``: ``d² = ‖ρ‖² + ℓ²‖ω‖²``, ``ℓ = rotation_scale`` metres per radian
    (default 1: 1° counts as 17.5 mm).  ``ρ`` is the translation part of the twist (``V(ω)⁻¹ t``,
    equal to the translation error to first order).  A ``1e-24`` inside the square root keeps the
    derivative finite at ``d = 0``."""
    xi = (T_est.inverse() @ T_gt).log()
    w = jnp.asarray([1.0, 1.0, 1.0, rotation_scale, rotation_scale, rotation_scale], xi.dtype)
    return jnp.sqrt(jnp.sum((w * xi) ** 2) + 1e-24)


def accuracy_loss(
    target: Float[Array, "H W *C"],
    reference: Float[Array, "H W *C"],
    reference_depth: Float[Array, "H W"],
    intrinsics: Float[Array, " 4"],
    T_gt: jaxlie.SE3,
    *,
    T_init: jaxlie.SE3 | None = None,
    config: PhotometricConfig = _DEFAULT_ALIGNMENT,
    rotation_scale: float = 1.0,
) -> Float[Array, ""]:
    """The pose error of direct photometric alignment run on a (filtered) target frame:

        L_acc = ‖W log(T̂⁻¹ T_gt)‖,   T̂ = argmin_T ½ Σ_i ρ((I_t(π(T X_i)) − I_r(u_i))²),

    ``T̂``, ``T_gt`` reference-camera → target-camera (``T_t_r = T_w_t⁻¹ T_w_r``),
    :func:`~privslam_jax.tradeoff.photometric.align_photometric` (coarse to fine, Huber, reference
    depth from the synthetic world's ground truth), ``W`` as in :func:`geodesic_distance`.

    Differentiable in ``target`` and ``reference`` by the implicit-function theorem (the solve is not
    unrolled); NaN gradients when the finest solve did not converge (see
    :func:`~privslam_jax.tradeoff.photometric.align_photometric` for the summary).
    """
    T_est, _ = align_photometric(target, reference, reference_depth, intrinsics, T_init, config)
    T_gt = jax.tree.map(lambda a: jnp.asarray(a, T_est.wxyz_xyz.dtype), T_gt)
    return geodesic_distance(T_est, T_gt, rotation_scale)
