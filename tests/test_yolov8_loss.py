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
