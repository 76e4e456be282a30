"""Temporal propagation and TTA of privacy detections, on image motion with a known answer."""

from __future__ import annotations

import dataclasses

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.detect.decode import box_iou
from privslam_jax.detect.temporal import (
    DETECTED,
    PROMOTED,
    PROPAGATED,
    PropagationConfig,
    box_flow,
    consecutive_runs,
    dense_flow,
    detect_sequence,
    detect_tta,
    flow_grey,
    propagate_detections,
)
from privslam_jax.types import Detections

H, W = 160, 320


def _texture(seed: int, h: int = H + 200, w: int = W + 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = cv2.resize(rng.uniform(0, 255, (h // 4, w // 4)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(base + rng.normal(0, 10, (h, w)), 0, 255).astype(np.uint8)


def _warp(tex: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Frame = texture seen through the affine map x_tex = A @ [x, y, 1]."""
    return cv2.warpAffine(tex, A, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def _map_box(box: np.ndarray, A_from: np.ndarray, A_to: np.ndarray) -> np.ndarray:
    """A box of frame 'from' in frame 'to' (both views of the same texture, axis-aligned affines)."""
    corners = np.array([[box[0], box[1], 1], [box[2], box[3], 1]]).T
    tex = A_from @ corners
    M = np.vstack([A_to, [0, 0, 1]])
    to = np.linalg.solve(M, np.vstack([tex, np.ones(2)]))[:2]
    return np.array([to[0, 0], to[1, 0], to[0, 1], to[1, 1]])


@pytest.mark.parametrize("shift,zoom", [((7.0, -4.0), 1.0), ((-12.0, 3.0), 1.0), ((2.0, 1.0), 1.08)])
def test_box_flow_follows_known_motion(shift, zoom):
    tex = _texture(0)
    A0 = np.array([[1.0, 0, 150], [0, 1.0, 80]])
    # frame 1: the texture zoomed by `zoom` about the image centre, then shifted by `shift`
    c = np.array([W / 2, H / 2])
    A1 = np.array([[1 / zoom, 0, 0], [0, 1 / zoom, 0]], float)
    A1[:, 2] = A0[:, 2] + c - c / zoom - np.array(shift) / zoom
    f0, f1 = _warp(tex, A0), _warp(tex, A1)
    flow = dense_flow(flow_grey(f0, 0.5), flow_grey(f1, 0.5))
    box = np.array([100.0, 50, 180, 110])
    truth = _map_box(box, A0, A1)
    moved = box_flow(box, flow, 0.5)
    np.testing.assert_allclose(moved, truth, atol=2.0)
    assert box_iou(moved[None], truth[None])[0, 0] > 0.9


def _pan_sequence(n: int, step: float = 5.0):
    tex = _texture(1)
    affines = [np.array([[1.0, 0, 100 + step * t], [0, 1.0, 60]]) for t in range(n)]
    frames = [_warp(tex, A) for A in affines]
    box0 = np.array([150.0, 40, 210, 100])
    truth = [_map_box(box0, affines[0], A) for A in affines]
    return frames, truth


def _det(boxes, scores, classes=None):
    boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
    classes = np.full(len(boxes), 2) if classes is None else classes
    return Detections(boxes=jnp.asarray(boxes), scores=jnp.asarray(np.asarray(scores, np.float32)),
                      class_ids=jnp.asarray(np.asarray(classes, np.int32)))


def test_propagation_fills_misses_promotes_low_scores_and_respects_the_window():
    frames, truth = _pan_sequence(7)
    empty = _det(np.zeros((0, 4)), [])
    dets = [empty] * 7
    dets[0] = _det([truth[0]], [0.9])
    low_box = truth[2] + np.array([1.0, -1.0, 2.0, 0.0])  # the detector's own (slightly different) box
    dets[2] = _det([low_box], [0.2])
    dets[5] = _det([truth[5]], [0.2])  # low score, no high detection within 3 frames of it
    out, origins = propagate_detections(frames, dets, PropagationConfig(window=3, high_conf=0.4, low_conf=0.1))
    assert [o.tolist() for o in origins] == [[DETECTED], [PROPAGATED], [PROMOTED], [PROPAGATED], [], [], []]
    for t in (1, 3):
        assert box_iou(np.asarray(out[t].boxes), truth[t][None])[0, 0] > 0.85
        assert int(out[t].class_ids[0]) == 2 and float(out[t].scores[0]) == pytest.approx(0.9)
    np.testing.assert_allclose(np.asarray(out[2].boxes)[0], low_box, atol=1e-4)  # promoted: its own box


def test_propagation_runs_backwards_and_skips_covered_objects():
    frames, truth = _pan_sequence(5)
    dets = [_det(np.zeros((0, 4)), [])] * 5
    dets[4] = _det([truth[4]], [0.8])
    dets[3] = _det([truth[3]], [0.7])
    out, origins = propagate_detections(frames, dets, PropagationConfig(window=2))
    assert [o.tolist() for o in origins] == [[], [PROPAGATED], [PROPAGATED], [DETECTED], [DETECTED]]
    for t in (1, 2):
        assert box_iou(np.asarray(out[t].boxes), truth[t][None])[0, 0] > 0.85
    # window 0: the detector's own high boxes only
    out0, origins0 = propagate_detections(frames, dets, PropagationConfig(window=0))
    assert [len(d) for d in out0] == [0, 0, 0, 1, 1]


def test_propagation_errors():
    frames, _ = _pan_sequence(3)
    with pytest.raises(ValueError, match="3 images but 2"):
        propagate_detections(frames, [_det(np.zeros((0, 4)), [])] * 2)
    with pytest.raises(ValueError, match="one size"):
        propagate_detections([frames[0], frames[1][:, :100]], [_det(np.zeros((0, 4)), [])] * 2)
    with pytest.raises(ValueError):
        PropagationConfig(low_conf=0.5, high_conf=0.4)


@dataclasses.dataclass(frozen=True)
class _Cfg:
    imgsz: int = 640
    conf: float = 0.4


class _BlobDetector:
    """A stand-in detector: one box around the bright pixels, found only at ``imgsz`` ≥ ``needs``
    and, when ``mirror_only``, only in mirrored frames (so TTA has to map the box back)."""

    def __init__(self, config=_Cfg(), needs: int = 0, mirror_only: bool = False):
        self.config, self.needs, self.mirror_only, self.calls = config, needs, mirror_only, []

    def with_config(self, config):
        other = _BlobDetector(config, self.needs, self.mirror_only)
        other.calls = self.calls
        return other

    def detect(self, images):
        out = []
        for im in images:
            self.calls.append(self.config.imgsz)
            ys, xs = np.nonzero(np.asarray(im) > 200)
            mirrored = len(xs) and xs.mean() > im.shape[1] / 2  # the blob sits left of centre in the original
            if not len(xs) or self.config.imgsz < self.needs or (self.mirror_only and not mirrored):
                out.append(_det(np.zeros((0, 4)), []))
            else:
                out.append(_det([[xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]], [0.9]))
        return out


def test_tta_maps_flipped_and_rescaled_boxes_back():
    img = np.zeros((H, W), np.uint8)
    img[30:70, 40:100] = 255
    truth = np.array([40, 30, 100, 70], np.float32)
    for det in (_BlobDetector(mirror_only=True), _BlobDetector(needs=960)):
        out = detect_tta(det, [img], scales=(1.0, 1.5), flip=True)[0]
        assert len(out) == 1  # found in several passes, merged by NMS
        np.testing.assert_allclose(np.asarray(out.boxes)[0], truth)
    det = _BlobDetector()
    detect_tta(det, [img], scales=(1.0, 1.5), flip=False)
    assert det.calls == [640, 960]
    with pytest.raises(ValueError):
        detect_tta(det, [img], scales=())


def test_detect_sequence_lowers_the_threshold_only_with_propagation():
    frames, truth = _pan_sequence(3)
    det = _BlobDetector()
    _, origins = detect_sequence(det, frames, None)
    assert all((o == DETECTED).all() for o in origins)

    seen = []

    class Recording(_BlobDetector):
        def with_config(self, config):
            seen.append(config.conf)
            return super().with_config(config)

    detect_sequence(Recording(), frames, PropagationConfig(window=1, high_conf=0.4, low_conf=0.05))
    assert seen == [0.05]


def test_runs_follow_the_sequence_step_and_break_at_larger_gaps():
    """Against a plain re-implementation: a run is a maximal stretch whose neighbouring numbers differ
    by the smallest positive difference of the whole sequence."""
    def reference(ids):
        if not ids:
            return []
        step = min([b - a for a, b in zip(ids, ids[1:]) if b > a] or [1])
        runs, start = [], 0
        for i in range(1, len(ids) + 1):
            if i == len(ids) or ids[i] - ids[i - 1] != step:
                runs.append((start, i))
                start = i
        return runs

    assert consecutive_runs(range(0, 91, 3)) == [(0, 31)]  # every third frame (kitti_raw_b): one run
    assert consecutive_runs(list(range(40)) + list(range(220, 260))) == [(0, 40), (40, 80)]  # two drives
    assert consecutive_runs([0, 3, 6, 12, 15]) == [(0, 3), (3, 5)]  # a dropped frame ends a run
    assert consecutive_runs([7]) == [(0, 1)] and consecutive_runs([]) == []
    rng = np.random.default_rng(0)
    for _ in range(200):
        ids = np.cumsum(rng.choice([-1, 0, 1, 1, 2, 2, 2, 5], size=int(rng.integers(0, 12)))).tolist()
        assert consecutive_runs(ids) == reference(ids), ids
