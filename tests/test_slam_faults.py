"""The fast part of the SLAM fault suite (issue 15 item 2; the long part is experiments/robustness.py).

Fault injection is checked against sequences built by hand; SLAM runs with injected faults must
not crash, must give a finite pose for every frame, mark the lost ones, record the loss, and track
again within 3 frames of the fault's end.
"""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.data.faults import FAULT_KINDS, Fault, inject_fault, recovery_delay
from privslam_jax.slam.system import SlamConfig, run_slam

pytestmark = pytest.mark.xla_optimized  # SLAM on whole sequences (tests/conftest.py)

FRAMES = [np.full((4, 6), 10 * i, np.uint8) for i in range(10)]


@pytest.mark.parametrize(("fault", "source", "window"), [
    (Fault("duplicate", 3, 2), [0, 1, 2, 3, 3, 3, 4, 5, 6, 7, 8, 9], (4, 6)),
    (Fault("drop", 3, 2), [0, 1, 2, 5, 6, 7, 8, 9], (3, 4)),
    (Fault("swap", 3, 2), [0, 1, 2, 4, 3, 6, 5, 7, 8, 9], (3, 7)),
])
def test_temporal_faults_reorder_frames_as_stated(fault, source, window):
    out, src, win = inject_fault(FRAMES, fault)
    assert src.tolist() == source and win == window
    assert [int(f[0, 0]) for f in out] == [10 * i for i in source]  # frames themselves untouched


def test_photometric_faults_touch_only_the_window_and_keep_the_dtype():
    cases = {"black": 0, "white": 255, "exposure": 2 * 40}
    for kind, value in cases.items():
        out, src, win = inject_fault(FRAMES, Fault(kind, 4, 3, 2.0 if kind == "exposure" else 0.0))
        assert src.tolist() == list(range(10)) and win == (4, 7)
        assert [int(f[0, 0]) for f in out[:4] + out[7:]] == [0, 10, 20, 30, 70, 80, 90]
        assert int(out[4][0, 0]) == value and all(f.dtype == np.uint8 for f in out)
    # exposure clips; float images saturate at 1
    assert int(inject_fault(FRAMES, Fault("exposure", 8, 1, 3.0))[0][8][0, 0]) == 240
    floats = [f / 255.0 for f in FRAMES]
    assert inject_fault(floats, Fault("white", 2, 1))[0][2].max() == 1.0
    # blur: a Gaussian of the frame (checked against scipy), σ = strength
    from scipy.ndimage import gaussian_filter

    img = np.random.default_rng(0).random((40, 50)).astype(np.float32)
    out = inject_fault([img] * 4, Fault("blur", 1, 1, 2.0))[0]
    np.testing.assert_allclose(out[1][10:-10, 10:-10], gaussian_filter(img, 2.0, truncate=4.0)[10:-10, 10:-10], atol=2e-3)


def test_stereo_pairs_are_damaged_together_and_depth_is_left_alone():
    pairs = [(f, f + 1, np.full((4, 6), 5.0)) for f in FRAMES]
    out = inject_fault(pairs, Fault("black", 2, 1), n_images=2)[0]
    assert out[2][0].max() == 0 and out[2][1].max() == 0 and out[2][2].min() == 5.0
    assert out[1][0] is pairs[1][0]


def test_bad_faults_are_refused():
    with pytest.raises(ValueError, match="kind"):
        Fault("smoke", 2)
    with pytest.raises(ValueError, match="start"):
        Fault("black", 0)
    with pytest.raises(ValueError, match="sigma"):
        Fault("blur", 2, 1)
    with pytest.raises(ValueError, match="gain"):
        Fault("exposure", 2, 1, float("inf"))
    with pytest.raises(ValueError, match="before the last"):
        inject_fault(FRAMES, Fault("black", 8, 2))
    with pytest.raises(ValueError, match="before the last"):
        inject_fault(FRAMES, Fault("swap", 6, 2))
    assert set(FAULT_KINDS) == {"black", "white", "blur", "exposure", "duplicate", "drop", "swap"}


def test_recovery_delay_counts_from_the_faults_last_frame():
    tracked = np.array([1, 1, 0, 0, 0, 0, 1, 1], bool)
    assert recovery_delay(tracked, (2, 4)) == 3  # frames 4, 5 lost, 6 tracked
    assert recovery_delay(tracked, (2, 6)) == 1
    assert recovery_delay(np.array([1, 0, 0], bool), (1, 2)) is None


@pytest.fixture(scope="module")
def world():
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    seq = make_sequence(SynthConfig(num_frames=26, seed=0, stereo=True))
    return seq, [seq[i] for i in range(26)]


def _check_run(res, items, window, fault_kind):
    T = np.asarray(res.trajectory.as_matrices())
    assert len(T) == len(items) and np.isfinite(T).all()
    assert res.tracked[: window[0]].all(), res.events
    delay = recovery_delay(res.tracked, window)
    assert delay is not None and delay <= 3, (fault_kind, res.tracked.astype(int), res.events)
    if not res.tracked[window[0]: window[1]].all():  # a loss is recorded
        assert any("lost" in e for e in res.events) and any("resumed" in e for e in res.events), res.events


@pytest.mark.parametrize(("mode", "fault"), [
    ("stereo", Fault("black", 12, 4)),
    ("stereo", Fault("drop", 12, 3)),
    ("rgbd", Fault("white", 12, 3)),
    ("rgbd", Fault("duplicate", 12, 3)),
    ("stereo", Fault("swap", 12, 2)),
    ("stereo", Fault("exposure", 12, 3, 3.0)),
])
def test_depth_modes_survive_faults_and_resume(world, mode, fault):
    seq, frames = world
    if mode == "stereo":
        items, n_img, camera = [(f.image, f.image_right) for f in frames], 2, seq.camera
    else:
        items, n_img, camera = [(f.image, f.depth) for f in frames], 1, seq.camera.replace(baseline=None)
    items, _, window = inject_fault(items, fault, n_img)
    _check_run(run_slam(items, camera, SlamConfig(mode=mode, seed=1)), items, window, fault.kind)


@pytest.mark.parametrize("fault", [Fault("black", 20, 4), Fault("drop", 20, 3), Fault("blur", 20, 5, 10.0)])
def test_monocular_kitti_resumes_after_a_fault(shared, fault):
    """KITTI seq1 moves 1.2 m per frame: after 4 black frames the last frame's matches no longer
    reach 20 inliers and appearance-based relocalisation finds ~10 ratio-test matches per keyframe,
    so tracking never came back (0 of 27 frames) before relocalisation along the motion model."""
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.slam.frontend import to_gray_u8

    seq = KittiSequence(shared / "data/kitti_odometry/sequences/seq1", grey=True)
    items, _, window = inject_fault([to_gray_u8(seq.image(i)) for i in range(32)], fault)
    _check_run(run_slam(items, seq.camera, SlamConfig(seed=3)), items, window, fault.kind)
