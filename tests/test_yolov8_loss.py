"""YOLOv8 loss: ultralytics v8DetectionLoss reference (TAL fg anchors, box/cls/dfl), CIoU, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.detect.loss import LossConfig, bbox_ciou, detection_loss, targets_to_padded


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
