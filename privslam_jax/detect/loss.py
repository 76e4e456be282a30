"""YOLOv8 training loss: TaskAlignedAssigner, CIoU box loss, DFL and BCE (ultralytics 8.4).

Sources: ultralytics ``utils/tal.py`` (``TaskAlignedAssigner``, ``bbox2dist``), ``utils/loss.py``
(``v8DetectionLoss``, ``BboxLoss``, ``DFLoss``), ``utils/metrics.py`` (``bbox_iou``); Feng et al.,
*TOOD* (ICCV 2021) for task alignment; Li et al., *Generalized Focal Loss* (NeurIPS 2020) for DFL;
Zheng et al., *Distance-IoU loss* (AAAI 2020) for CIoU. Everything is fixed-shape and jit-able:
ground truth comes padded to ``M`` boxes per image with a validity mask.

**Assigner** (no gradient; ``α = 0.5``, ``β = 6``, ``topk = 10``, ``eps = 1e-9``), per image, gt ``j``
and anchor ``a`` (anchor centres and boxes in input pixels):

1. candidate ``a ∈ gt j`` when its centre lies strictly inside the gt box (all four distances
   ``> eps``); gt sides shorter than the smallest stride (8) are first widened to the second
   stride (16) about the box centre (ultralytics 8.4);
2. ``t_ja = s_ja^α · u_ja^β`` with ``s`` the predicted probability of gt ``j``'s class and ``u`` the
   CIoU of the predicted box with the gt box clamped at 0 (both 0 outside candidates);
3. positives: the ``topk`` anchors of largest ``t_j·`` that are candidates; an anchor positive for
   several gts keeps the gt of largest ``u``;
4. targets: the assigned box and a one-hot class scaled by
   ``max_j t_ja · max_a' u_ja' / (max_a' t_ja' + eps)`` (over positives).

**Loss** with ``S = max(Σ target scores, 1)``, ``w_a = Σ_c target_ac`` (positives ``a``):
``cls = Σ BCE(logits, targets) / S``; ``box = Σ_a (1 − CIoU(pred_a, gt_a)) w_a / S`` (boxes in grid
units); ``dfl = Σ_a w_a · mean_sides[CE(z, ⌊d⌋)(⌊d⌋+1−d) + CE(z, ⌊d⌋+1)(d−⌊d⌋)] / S`` with the target
distance ``d`` (grid units) clamped to ``[0, reg_max − 1.01]``; then gains 7.5 / 0.5 / 1.5. The
value ultralytics back-propagates is ``(box + cls + dfl) · batch_size``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from privslam_jax.detect.decode import make_anchors

__all__ = ["LossConfig", "bbox_ciou", "task_aligned_assign", "detection_loss", "targets_to_padded", "Assignment"]


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """Hyper-parameters of ``v8DetectionLoss`` (ultralytics defaults)."""

    box_gain: float = 7.5
    """Weight of the CIoU box loss."""
    cls_gain: float = 0.5
    """Weight of the BCE class loss."""
    dfl_gain: float = 1.5
    """Weight of the distribution focal loss."""
    topk: int = 10
    """Candidates per gt in the assigner."""
    alpha: float = 0.5
    """Exponent of the class score in the alignment metric."""
    beta: float = 6.0
    """Exponent of the IoU in the alignment metric."""
    reg_max: int = 16
    """DFL bins."""
    strides: tuple[int, ...] = (8, 16, 32)
    """Feature strides (P3, P4, P5)."""


def bbox_ciou(b1: Float[Array, "*#n 4"], b2: Float[Array, "*#n 4"], eps: float = 1e-7) -> Float[Array, "..."]:
    """Complete IoU of ``xyxy`` boxes (ultralytics ``bbox_iou(..., CIoU=True)``, α without gradient)."""
    w1, h1 = b1[..., 2] - b1[..., 0], b1[..., 3] - b1[..., 1] + eps
    w2, h2 = b2[..., 2] - b2[..., 0], b2[..., 3] - b2[..., 1] + eps
    inter = jnp.clip(jnp.minimum(b1[..., 2], b2[..., 2]) - jnp.maximum(b1[..., 0], b2[..., 0]), 0) * jnp.clip(
        jnp.minimum(b1[..., 3], b2[..., 3]) - jnp.maximum(b1[..., 1], b2[..., 1]), 0
    )
    union = w1 * h1 + w2 * h2 - inter + eps
    iou = inter / union
    cw = jnp.maximum(b1[..., 2], b2[..., 2]) - jnp.minimum(b1[..., 0], b2[..., 0])
    ch = jnp.maximum(b1[..., 3], b2[..., 3]) - jnp.minimum(b1[..., 1], b2[..., 1])
    c2 = cw**2 + ch**2 + eps
    rho2 = ((b2[..., 0] + b2[..., 2] - b1[..., 0] - b1[..., 2]) ** 2 + (b2[..., 1] + b2[..., 3] - b1[..., 1] - b1[..., 3]) ** 2) / 4
    v = (4 / math.pi**2) * (jnp.arctan(w2 / h2) - jnp.arctan(w1 / h1)) ** 2
    alpha = jax.lax.stop_gradient(v / (v - iou + (1 + eps)))
    return iou - (rho2 / c2 + v * alpha)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Assignment:
    """Output of :func:`task_aligned_assign` for a batch."""

    target_boxes: Float[Array, "B A 4"]
    """Assigned gt ``xyxy`` (pixels); meaningful where ``fg_mask``."""
    target_scores: Float[Array, "B A C"]
    """Soft one-hot class targets (alignment-normalised)."""
    fg_mask: Bool[Array, "B A"]
    """Positive anchors."""
    target_gt_idx: Int[Array, "B A"]
    """Index of the assigned gt (0 for background, as ultralytics)."""


def task_aligned_assign(
    pd_scores: Float[Array, "B A C"],
    pd_boxes: Float[Array, "B A 4"],
    anchors: Float[Array, "A 2"],
    gt_labels: Int[Array, "B M"],
    gt_boxes: Float[Array, "B M 4"],
    gt_mask: Bool[Array, "B M"],
    config: LossConfig = LossConfig(),
    eps: float = 1e-9,
) -> Assignment:
    """TaskAlignedAssigner (ultralytics 8.4), all in pixels; see the module docstring."""
    pd_scores, pd_boxes = jax.lax.stop_gradient(pd_scores), jax.lax.stop_gradient(pd_boxes)
    n_cls = pd_scores.shape[-1]
    m = gt_mask.astype(pd_scores.dtype)[..., None]  # (B, M, 1)
    # 1. candidates: anchor centre inside the (small-side-widened) gt box
    cxy = (gt_boxes[..., :2] + gt_boxes[..., 2:]) / 2
    wh = gt_boxes[..., 2:] - gt_boxes[..., :2]
    wh = jnp.where((wh < config.strides[0]) & gt_mask[..., None], float(config.strides[min(1, len(config.strides) - 1)]), wh)
    lt, rb = cxy - wh / 2, cxy + wh / 2
    deltas = jnp.concatenate([anchors[None, None] - lt[:, :, None], rb[:, :, None] - anchors[None, None]], axis=-1)
    in_gts = (deltas.min(-1) > eps).astype(pd_scores.dtype) * m  # (B, M, A)
    # 2. alignment metric
    labels = jnp.clip(gt_labels, 0, n_cls - 1)
    scores = jnp.take_along_axis(jnp.swapaxes(pd_scores, 1, 2), labels[..., None], axis=1)  # (B, M, A)
    scores = jnp.where(in_gts > 0, scores, 0.0)
    overlaps = jnp.clip(bbox_ciou(gt_boxes[:, :, None, :], pd_boxes[:, None, :, :]), 0)
    overlaps = jnp.where(in_gts > 0, overlaps, 0.0)
    align = scores**config.alpha * overlaps**config.beta
    # 3. top-k per gt (invalid gts select nothing), then resolve anchors claimed by several gts
    _, top_idx = jax.lax.top_k(align, config.topk)
    topk_mask = jnp.zeros_like(align).at[
        jnp.arange(align.shape[0])[:, None, None], jnp.arange(align.shape[1])[None, :, None], top_idx
    ].set(1.0)
    mask_pos = topk_mask * in_gts * m
    multi = mask_pos.sum(1, keepdims=True) > 1
    best = jax.nn.one_hot(overlaps.argmax(1), overlaps.shape[1], axis=1, dtype=mask_pos.dtype)
    mask_pos = jnp.where(multi, best, mask_pos)
    fg = mask_pos.sum(1) > 0
    gt_idx = mask_pos.argmax(1)
    # 4. targets
    tboxes = jnp.take_along_axis(gt_boxes, gt_idx[..., None], axis=1)
    tlabels = jnp.take_along_axis(labels, gt_idx, axis=1)
    tscores = jax.nn.one_hot(tlabels, n_cls, dtype=pd_scores.dtype) * fg[..., None]
    align = align * mask_pos
    pos_align = align.max(-1, keepdims=True)
    pos_ov = (overlaps * mask_pos).max(-1, keepdims=True)
    norm = (align * pos_ov / (pos_align + eps)).max(1)[..., None]  # (B, A, 1)
    return Assignment(tboxes, tscores * norm, fg, gt_idx)


def targets_to_padded(
    batch_idx: ArrayLike, cls: ArrayLike, boxes_cxcywh_norm: ArrayLike,
    batch_size: int, max_boxes: int, image_hw: tuple[int, int],
) -> tuple[Int[Array, "B M"], Float[Array, "B M 4"], Bool[Array, "B M"]]:
    """Flat YOLO targets → per-image padded ``(labels, xyxy pixels, mask)`` (order kept per image).

    ``batch_idx (T,)``, ``cls (T,)``, ``boxes_cxcywh_norm (T, 4)`` as in an ultralytics batch; targets
    beyond ``max_boxes`` in one image are dropped.
    """
    h, w = image_hw
    b = jnp.asarray(batch_idx, jnp.int32)
    onehot = jax.nn.one_hot(b, batch_size, dtype=jnp.int32)
    within = (jnp.cumsum(onehot, axis=0) - onehot)[jnp.arange(b.shape[0]), b]
    xywh = jnp.asarray(boxes_cxcywh_norm, jnp.float32).reshape(-1, 4) * jnp.array([[w, h, w, h]], jnp.float32)
    xyxy = jnp.concatenate([xywh[:, :2] - xywh[:, 2:] / 2, xywh[:, :2] + xywh[:, 2:] / 2], axis=-1)
    labels = jnp.zeros((batch_size, max_boxes), jnp.int32).at[b, within].set(jnp.asarray(cls, jnp.int32), mode="drop")
    boxes = jnp.zeros((batch_size, max_boxes, 4), jnp.float32).at[b, within].set(xyxy, mode="drop")
    mask = jnp.zeros((batch_size, max_boxes), bool).at[b, within].set(True, mode="drop")
    return labels, boxes, mask


def _dfl_ce(logits: Float[Array, "*n R"], target: Float[Array, "*n"]) -> Float[Array, "*n"]:
    logp = jax.nn.log_softmax(logits, axis=-1)
    left = jnp.floor(target).astype(jnp.int32)
    wl = left + 1 - target
    lp_l = jnp.take_along_axis(logp, left[..., None], axis=-1)[..., 0]
    lp_r = jnp.take_along_axis(logp, (left + 1)[..., None], axis=-1)[..., 0]
    return -lp_l * wl - lp_r * (1 - wl)


def detection_loss(
    box_logits: Float[Array, "B A F"],
    cls_logits: Float[Array, "B A C"],
    gt_labels: Int[Array, "B M"],
    gt_boxes: Float[Array, "B M 4"],
    gt_mask: Bool[Array, "B M"],
    feat_shapes: tuple[tuple[int, int], ...],
    config: LossConfig = LossConfig(),
) -> tuple[Float[Array, "3"], Assignment]:
    """Gained ``(box, cls, dfl)`` losses (ultralytics ``loss_items``) and the assignment.

    ``box_logits`` are the DFL logits ``(B, A, 4·reg_max)`` and ``cls_logits`` the class logits of
    the anchors of all levels in order; gt boxes are ``xyxy`` pixels of the network input.
    """
    r = config.reg_max
    anchors, stride = make_anchors(feat_shapes, config.strides)
    b, a, _ = box_logits.shape
    dist_logits = box_logits.reshape(b, a, 4, r)
    dist = jax.nn.softmax(dist_logits, axis=-1) @ jnp.arange(r, dtype=box_logits.dtype)
    pred = jnp.concatenate([anchors[None] - dist[..., :2], anchors[None] + dist[..., 2:]], axis=-1)  # grid units
    asg = task_aligned_assign(jax.nn.sigmoid(cls_logits), pred * stride[None], anchors * stride,
                              gt_labels, gt_boxes, gt_mask, config)
    tss = jnp.maximum(asg.target_scores.sum(), 1.0)
    # BCE with logits in torch's form (1 - y)·x − log σ(x): in float32 the terms exp(x) of very
    # negative logits vanish below half an ulp of |x| exactly as in torch; the log1p form
    # max(x, 0) − x·y + log1p(exp(−|x|)) keeps them and differs by 4e-4 relative on the reference.
    x, y = cls_logits, asg.target_scores
    bce = (1 - y) * x - jax.nn.log_sigmoid(x)
    loss_cls = bce.sum() / tss
    fg = asg.fg_mask
    weight = jnp.where(fg, asg.target_scores.sum(-1), 0.0)
    tbox = asg.target_boxes / stride[None]
    safe_tbox = jnp.where(fg[..., None], tbox, pred)  # background rows: any finite box
    iou = bbox_ciou(pred, jax.lax.stop_gradient(safe_tbox))
    loss_box = ((1.0 - iou) * weight).sum() / tss
    tdist = jnp.concatenate([anchors[None] - safe_tbox[..., :2], safe_tbox[..., 2:] - anchors[None]], axis=-1)
    tdist = jnp.clip(tdist, 0, r - 1 - 0.01)
    loss_dfl = (_dfl_ce(dist_logits, jax.lax.stop_gradient(tdist)).mean(-1) * weight).sum() / tss
    losses = jnp.stack([loss_box * config.box_gain, loss_cls * config.cls_gain, loss_dfl * config.dfl_gain])
    return losses, asg
