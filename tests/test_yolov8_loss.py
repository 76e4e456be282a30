"""YOLOv8 loss: ultralytics v8DetectionLoss reference (TAL fg anchors, box/cls/dfl), CIoU, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.detect.loss import LossConfig, bbox_ciou, detection_loss, targets_to_padded, task_aligned_assign


@pytest.fixture(scope="module")
def reference(shared):
    d = np.load(shared / "reference" / "yolov8_loss_reference.npz")
    b = d["pred_boxes_logits"].shape[0]
    labels, boxes, mask = targets_to_padded(d["target_batch_idx"].astype(np.int32), d["target_cls"].astype(np.int32),
                                            d["target_cxcywh_norm"], b, 8, (192, 640))
    shapes = tuple(tuple(int(v) for v in s) for s in d["feat_shapes"])
    box = jnp.asarray(d["pred_boxes_logits"].transpose(0, 2, 1))
    cls = jnp.asarray(d["pred_scores_logits"].transpose(0, 2, 1))
    fn = jax.jit(detection_loss, static_argnums=(5,))
    return d, fn, (box, cls, labels, boxes, mask, shapes)


@pytest.mark.shared
def test_loss_matches_ultralytics(reference):
    d, fn, args = reference
    np.testing.assert_array_equal(d["gains_box_cls_dfl"], [LossConfig().box_gain, LossConfig().cls_gain, LossConfig().dfl_gain])
    losses, asg = fn(*args)
    expected = np.array([d["loss_box_gained"], d["loss_cls_gained"], d["loss_dfl_gained"]], np.float64)
    np.testing.assert_allclose(np.asarray(losses, np.float64), expected, rtol=1e-4)
    fg = np.asarray(asg.fg_mask)
    assert fg.sum() > 10
    np.testing.assert_array_equal(fg, d["fg_mask"])
    np.testing.assert_array_equal(np.asarray(asg.target_gt_idx)[fg], d["target_gt_idx"][fg])


@pytest.mark.shared
def test_cls_gradient_closed_form(reference):
    # the assignment is detached (as in ultralytics), so d cls_loss / d logits = gain·(σ(x) − y)/S
    _, _, (box, cls, labels, boxes, mask, shapes) = reference
    fn = jax.jit(lambda c: detection_loss(box, c, labels, boxes, mask, shapes), static_argnums=())
    (losses, asg) = fn(cls)
    g = jax.jit(jax.grad(lambda c: detection_loss(box, c, labels, boxes, mask, shapes)[0][1]))(cls)
    y = np.asarray(asg.target_scores, np.float64)
    expected = 0.5 * (1 / (1 + np.exp(-np.asarray(cls, np.float64))) - y) / max(y.sum(), 1.0)
    np.testing.assert_allclose(np.asarray(g), expected, atol=2e-7)
    gb = jax.jit(jax.grad(lambda b: detection_loss(b, cls, labels, boxes, mask, shapes)[0].sum()))(box)
    gb = np.asarray(gb)
    assert np.isfinite(gb).all()
    # box/DFL gradients only reach anchors that are positives
    fg = np.asarray(asg.fg_mask)
    assert np.abs(gb[~fg]).max() == 0 and np.abs(gb[fg]).max() > 0


def test_ciou_closed_form():
    a = jnp.array([0.0, 0.0, 4.0, 2.0])
    assert float(bbox_ciou(a, a)) == pytest.approx(1.0, abs=1e-6)
    # same aspect ratio, b shifted right by 2: IoU 4/12, centre distance² 4, enclosing diagonal² 6²+2²
    b = jnp.array([2.0, 0.0, 6.0, 2.0])
    assert float(bbox_ciou(a, b)) == pytest.approx(4 / 12 - 4 / 40, abs=1e-5)


def _ciou_numpy(b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """CIoU from the paper (Zheng et al., AAAI 2020, eqs. 9–11), float64, no ε:
    ``IoU − ρ²(b1, b2)/c² − α v``, ``v = 4/π² (arctan(w2/h2) − arctan(w1/h1))²``,
    ``α = v / ((1 − IoU) + v)``; ``c`` the diagonal of the smallest enclosing box."""
    b1, b2 = np.asarray(b1, np.float64), np.asarray(b2, np.float64)
    w1, h1 = b1[:, 2] - b1[:, 0], b1[:, 3] - b1[:, 1]
    w2, h2 = b2[:, 2] - b2[:, 0], b2[:, 3] - b2[:, 1]
    iw = np.clip(np.minimum(b1[:, 2], b2[:, 2]) - np.maximum(b1[:, 0], b2[:, 0]), 0, None)
    ih = np.clip(np.minimum(b1[:, 3], b2[:, 3]) - np.maximum(b1[:, 1], b2[:, 1]), 0, None)
    inter = iw * ih
    iou = inter / (w1 * h1 + w2 * h2 - inter)
    c2 = (np.maximum(b1[:, 2], b2[:, 2]) - np.minimum(b1[:, 0], b2[:, 0])) ** 2 + (
        np.maximum(b1[:, 3], b2[:, 3]) - np.minimum(b1[:, 1], b2[:, 1])) ** 2
    rho2 = ((b1[:, 0] + b1[:, 2]) / 2 - (b2[:, 0] + b2[:, 2]) / 2) ** 2 + ((b1[:, 1] + b1[:, 3]) / 2 - (b2[:, 1] + b2[:, 3]) / 2) ** 2
    v = 4 / np.pi**2 * (np.arctan(w2 / h2) - np.arctan(w1 / h1)) ** 2
    alpha = v / ((1 - iou) + v)
    return iou - rho2 / c2 - alpha * v


def test_ciou_with_unequal_aspect_ratios_matches_the_paper_formula():
    """Overlapping and disjoint boxes of different aspect ratios (the α·v term matters: up to ~0.3
    here). Reference: :func:`_ciou_numpy` (the paper's formula in float64)."""
    rng = np.random.default_rng(0)
    n = 64
    c1 = rng.uniform(20, 80, (n, 2))
    c2 = c1 + rng.normal(0, 8, (n, 2))
    wh1 = rng.uniform(4, 40, (n, 2))
    wh2 = wh1[:, ::-1] * rng.uniform(0.6, 1.6, (n, 1))  # roughly transposed: unequal aspect ratios
    b1 = np.concatenate([c1 - wh1 / 2, c1 + wh1 / 2], 1)
    b2 = np.concatenate([c2 - wh2 / 2, c2 + wh2 / 2], 1)
    ref = _ciou_numpy(b1, b2)
    v = 4 / np.pi**2 * (np.arctan(wh2[:, 0] / wh2[:, 1]) - np.arctan(wh1[:, 0] / wh1[:, 1])) ** 2
    assert np.median(v) > 0.05  # the aspect-ratio term is not negligible
    got = np.asarray(bbox_ciou(jnp.asarray(b1, jnp.float32), jnp.asarray(b2, jnp.float32)), np.float64)
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-5)
    # broadcasting as the assigner uses it: (n, 1, 4) against (1, n, 4)
    pair = np.asarray(bbox_ciou(jnp.asarray(b1[:5, None], jnp.float32), jnp.asarray(b2[None, :5], jnp.float32)))
    ref_pair = np.stack([_ciou_numpy(np.repeat(b1[i:i + 1], 5, 0), b2[:5]) for i in range(5)])
    np.testing.assert_allclose(pair, ref_pair, rtol=0, atol=2e-5)


def test_no_targets_gives_only_background_cls_loss():
    rng = np.random.default_rng(0)
    shapes = ((2, 4), (1, 2), (1, 1))
    a = 8 + 2 + 1
    box = jnp.asarray(rng.normal(size=(1, a, 64)), jnp.float32)
    cls = jnp.asarray(rng.normal(size=(1, a, 3)), jnp.float32)
    labels, boxes, mask = jnp.zeros((1, 2), jnp.int32), jnp.zeros((1, 2, 4)), jnp.zeros((1, 2), bool)
    losses, asg = jax.jit(detection_loss, static_argnums=(5,))(box, cls, labels, boxes, mask, shapes)
    assert not np.asarray(asg.fg_mask).any()
    x = np.asarray(cls, np.float64)
    bce = np.log1p(np.exp(x)).sum()  # all targets 0, normaliser max(0, 1) = 1
    np.testing.assert_allclose(np.asarray(losses), [0.0, 0.5 * bce, 0.0], rtol=1e-5)
    g = jax.jit(jax.grad(lambda b: detection_loss(b, cls, labels, boxes, mask, shapes)[0].sum()))(box)
    assert np.isfinite(np.asarray(g)).all()


def test_targets_to_padded_keeps_order_per_image():
    labels, boxes, mask = targets_to_padded(np.array([1, 0, 1]), np.array([5, 6, 7]),
                                            np.array([[0.5, 0.5, 0.5, 0.5]] * 3, np.float32), 2, 3, (10, 20))
    assert np.asarray(labels).tolist() == [[6, 0, 0], [5, 7, 0]]
    assert np.asarray(mask).tolist() == [[True, False, False], [True, True, False]]
    np.testing.assert_allclose(np.asarray(boxes)[1, 0], [5, 2.5, 15, 7.5])


def test_assigner_candidates_are_strictly_inside_on_all_four_sides():
    """Hand-made anchors inside the gt box on all four sides, on its edge, and outside on one or two
    sides. Every predicted box equals the gt box (CIoU 1) and there are ``topk`` anchors, so the
    positives are exactly the candidates. Reference: numpy ``x1 < x < x2 and y1 < y < y2``."""
    gt = np.array([20.0, 20.0, 60.0, 44.0])  # both sides ≥ 8 px: no widening
    anchors = np.array([
        [30.0, 30.0], [50.0, 40.0], [21.0, 43.0],  # inside on all four sides
        [20.0, 30.0],  # on the left edge (distance 0)
        [10.0, 30.0], [70.0, 30.0], [40.0, 10.0], [40.0, 50.0],  # outside on one side
        [10.0, 10.0], [70.0, 50.0],  # outside on two sides
    ])
    a = len(anchors)
    cfg = LossConfig(topk=a)
    boxes = jnp.asarray(np.stack([gt, [0.0, 0.0, 0.0, 0.0]])[None], jnp.float32)  # second gt: padding
    asg = task_aligned_assign(
        jnp.full((1, a, 2), 0.5, jnp.float32), jnp.asarray(np.tile(gt, (1, a, 1)), jnp.float32),
        jnp.asarray(anchors, jnp.float32), jnp.array([[1, 0]], jnp.int32), boxes, jnp.array([[True, False]]), cfg)
    inside = (anchors[:, 0] > gt[0]) & (anchors[:, 0] < gt[2]) & (anchors[:, 1] > gt[1]) & (anchors[:, 1] < gt[3])
    assert inside.sum() == 3
    np.testing.assert_array_equal(np.asarray(asg.fg_mask)[0], inside)
    np.testing.assert_array_equal(np.asarray(asg.target_gt_idx)[0][inside], 0)
    # positives: one-hot class 1 scaled by (t/max t)·max CIoU = 1; background: 0
    expected_scores = np.zeros((a, 2))
    expected_scores[inside, 1] = 1.0
    np.testing.assert_allclose(np.asarray(asg.target_scores)[0], expected_scores, atol=1e-5)


def _dfl_numpy(logits: np.ndarray, target: np.ndarray) -> np.ndarray:
    """ultralytics ``DFLoss``: ``tl = ⌊t⌋, tr = tl + 1, wl = tr − t, wr = 1 − wl``,
    ``CE(z, tl)·wl + CE(z, tr)·wr`` (float64)."""
    m = logits.max(-1, keepdims=True)
    logp = logits - m - np.log(np.sum(np.exp(logits - m), -1, keepdims=True))
    tl = np.floor(target).astype(int)
    tr = tl + 1
    wl = tr - target
    wr = 1 - wl
    ce_l = -np.take_along_axis(logp, tl[..., None], -1)[..., 0]
    ce_r = -np.take_along_axis(logp, tr[..., None], -1)[..., 0]
    return ce_l * wl + ce_r * wr


def test_loss_on_a_hand_made_case_matches_numpy():
    """One gt box on a 32×32 input (levels 4×4, 2×2, 1×1), DFL logits peaked near every anchor's
    distances to the gt (so the candidates overlap it). Given the returned assignment, the three
    gained terms are recomputed in float64 numpy: predicted distances ``Σ_k k·softmax_k`` over bins
    ``k = 0..15``, box ``Σ (1 − CIoU)·w / S`` (:func:`_ciou_numpy`), DFL by :func:`_dfl_numpy` on the
    target distances clamped to ``[0, 14.99]``, BCE ``Σ (1 − y)x + log(1 + e^{−x}) / S``."""
    rng = np.random.default_rng(5)
    shapes, strides, r = ((4, 4), (2, 2), (1, 1)), (8, 16, 32), 16
    anc, strd = [], []
    for (h, w), s in zip(shapes, strides):
        yy, xx = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
        anc.append(np.stack([xx.ravel(), yy.ravel()], 1))
        strd.append(np.full(h * w, float(s)))
    anchors, stride = np.concatenate(anc), np.concatenate(strd)[:, None]
    a = len(anchors)
    gt = np.array([5.3, 6.1, 27.7, 24.9])  # pixels; distances are not whole grid units
    dist_gt = np.concatenate([anchors - gt[:2] / stride, gt[2:] / stride - anchors], 1)  # (A, 4) grid units
    k = np.arange(r)
    logits = -((k[None, None] - np.clip(dist_gt, 0, r - 1)[..., None]) ** 2) / (2 * 0.7**2)
    logits = logits + rng.normal(0, 0.3, logits.shape)  # (A, 4, 16)
    cls = rng.normal(0, 1.5, (1, a, 2))
    labels, boxes, mask = jnp.array([[1]], jnp.int32), jnp.asarray(gt[None, None], jnp.float32), jnp.array([[True]])
    losses, asg = jax.jit(detection_loss, static_argnums=(5,))(
        jnp.asarray(logits.reshape(1, a, 4 * r), jnp.float32), jnp.asarray(cls, jnp.float32), labels, boxes, mask, shapes)
    fg = np.asarray(asg.fg_mask)[0]
    y = np.asarray(asg.target_scores, np.float64)[0]
    w = np.where(fg, y.sum(-1), 0.0)
    assert fg.sum() >= 4 and (w > 0.1).sum() >= 4
    inside = (anchors * stride > gt[:2]).all(1) & (anchors * stride < gt[2:]).all(1)
    assert not (fg & ~inside).any()  # positives are candidates
    S = max(y.sum(), 1.0)
    # predicted boxes (grid units) from bins 0..15
    p = np.exp(logits - logits.max(-1, keepdims=True))
    dist = (p / p.sum(-1, keepdims=True)) @ k.astype(np.float64)
    pred = np.concatenate([anchors - dist[:, :2], anchors + dist[:, 2:]], 1)
    tbox = np.asarray(asg.target_boxes, np.float64)[0] / stride
    box = np.sum((1 - _ciou_numpy(pred[fg], tbox[fg])) * w[fg]) / S
    tdist = np.clip(np.concatenate([anchors - tbox[:, :2], tbox[:, 2:] - anchors], 1), 0, r - 1 - 0.01)
    frac = tdist[fg] - np.floor(tdist[fg])
    assert np.abs(frac - 0.5).max() > 0.2  # the two bin weights differ
    dfl = np.sum(_dfl_numpy(logits[fg], tdist[fg]).mean(-1) * w[fg]) / S
    x = cls[0]
    bce = np.sum((1 - y) * x + np.logaddexp(0.0, -x)) / S
    expected = np.array([7.5 * box, 0.5 * bce, 1.5 * dfl])
    np.testing.assert_allclose(np.asarray(losses, np.float64), expected, rtol=2e-5)
