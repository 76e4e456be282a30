"""Atlas maps inside the SLAM system: a long loss starts a new map, revisiting merges it back.

The camera drives frames 0-69 of a synthetic street, sees nothing (black frames) for a while,
then drives frames 20-89 again: the second pass starts where the first one already mapped, so
place recognition must find the first map and merge the second into it.  Judged by the ground
truth (one alignment for both passes) and against a run without Atlas.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.metrics.trajectory import ate
from privslam_jax.slam.system import SlamConfig, run_slam
from privslam_jax.slam.tracking import motion_deviation

pytestmark = pytest.mark.xla_optimized  # SLAM on whole sequences (tests/conftest.py)

FIRST, BLACK, SECOND = range(0, 70), 25, range(20, 90)


@pytest.fixture(scope="module")
def revisit():
    seq = make_sequence(SynthConfig(num_frames=90, seed=5, stereo=True))

    def grey(img):
        return cv2.cvtColor((np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), cv2.COLOR_RGB2GRAY)

    pairs = [(grey(seq[i].image), grey(seq[i].image_right)) for i in range(90)]
    black = np.zeros_like(pairs[0][0])
    order = [*FIRST, *([-1] * BLACK), *SECOND]
    frames = [pairs[i] if i >= 0 else (black, black) for i in order]
    gt = np.stack([seq.poses[i] if i >= 0 else np.eye(4) for i in order])
    return seq, frames, gt, np.array(order)


def _ate_of(res, gt, order, sel):
    T = np.asarray(res.trajectory.as_matrices(), np.float64)
    ts = np.arange(len(order), dtype=np.float64)
    return ate((ts[sel], T[sel]), (ts[sel], gt[sel]), "se3").rmse


@pytest.mark.parametrize("mode", [pytest.param("stereo", marks=pytest.mark.slow), "mono"])
def test_a_long_loss_starts_a_new_map_that_merges_back_where_the_first_one_was(revisit, mode):
    """The stereo case is left to ``-m slow`` (it took 44 s of the README's test command), which checks
    instead the new map and its merge with the mono case, and a stereo loop closed with SE(3) (scale
    1) by the same place recognition and correction in ``tests/test_slam_loop.py``."""
    seq, frames, gt, order = revisit
    items = frames if mode == "stereo" else [f[0] for f in frames]
    cfg = SlamConfig(mode=mode, new_map_after=20)
    res = run_slam(items, seq.camera, cfg)
    assert any("new map 1 started" in e for e in res.events), res.events
    merges = [lc for lc in res.loops if lc.merged]
    assert len(merges) == 1, res.events
    kf = res.keyframe_indices
    lc = merges[0]
    assert (lc.query_map, lc.match_map) == (1, 0)
    # the merge joins two keyframes the ground truth puts at the same place
    assert np.linalg.norm(gt[kf[lc.query], :3, 3] - gt[kf[lc.match], :3, 3]) <= 5.0
    if mode == "stereo":
        assert lc.scale == pytest.approx(1.0, abs=1e-12)
    # one map at the end; the black frames belong to none, the tracked ones to map 0
    assert res.n_maps == 1 and set(res.keyframe_maps.tolist()) == {0}
    black = order < 0
    assert not res.tracked[black].any()
    n1 = len(FIRST)
    assert set(res.frame_maps[res.tracked].tolist()) == {0}
    # both passes in one world frame: one alignment fits them both
    good = res.tracked & ~black
    second = good.copy()
    second[:n1] = False
    assert second.sum() >= 40
    path = np.linalg.norm(np.diff(gt[:n1, :3, 3], axis=0), axis=1).sum()
    err = _ate_of(res, gt, order, good) if mode == "stereo" else ate(
        (np.flatnonzero(good).astype(float), np.asarray(res.trajectory.as_matrices(), np.float64)[good]),
        (np.flatnonzero(good).astype(float), gt[good]), "sim3").rmse
    assert err < 0.02 * path, (err, path)


def test_without_atlas_a_long_loss_relocalises_in_the_one_map(revisit):
    """new_map_after=0: 30 frames, the black gap, then frames 20-29 again (mapped): relocalisation, one map."""
    seq, frames, gt, order = revisit
    n1 = len(FIRST)
    keep = [*range(30), *range(n1, n1 + BLACK), *range(n1 + BLACK, n1 + BLACK + 10)]
    res = run_slam([frames[i] for i in keep], seq.camera, SlamConfig(mode="stereo", new_map_after=0))
    assert res.n_maps == 1 and res.loops == []
    assert not any("new map" in e for e in res.events)
    assert any("relocalised" in e for e in res.events), res.events
    assert res.tracked[-5:].all() and set(res.frame_maps.tolist()) == {0}


def test_new_map_after_must_not_be_negative():
    with pytest.raises(ValueError, match="new_map_after"):
        SlamConfig(new_map_after=-1)


def _T(yaw_deg: float = 0.0, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """World-to-camera pose of a camera at ``centre`` turned by ``yaw_deg`` about its y axis."""
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ np.asarray(centre, float)
    return T


@pytest.mark.parametrize(
    ("centre", "yaw", "steps", "ratio"),
    [((0, 0, 5), 0, 1, 0.0),      # where the prediction is
     ((3, 0, 5), 30, 1, 0.6),     # 3 m aside after 5 m of travel, turned 30°
     ((0, 0, 0), 0, 1, 1.0),      # stopped
     ((0, 0, -5), 0, 12, 2.0),    # behind the start: nearest prediction is the first one
     ((0, 0, 14), 0, 12, 0.0),    # frames that never arrived: 9 more frames of travel
     ((0, 0, 19), 0, 12, 0.6),    # beyond the last step (16)
     ((0, 0, 8), 0, 0, 0.6)],     # no steps: only the prediction 5 frames on
)
def test_motion_deviation_in_closed_form(centre, yaw, steps, ratio):
    """Camera moving 1 m per frame along +z; lost for 5 frames: the prediction is at z = 5 … 4 + steps."""
    velocity = _T(centre=(0, 0, 1))  # T_c_w(t+1) = velocity @ T_c_w(t), here from T_c_w(0) = I
    got, deg = motion_deviation(_T(yaw, centre), np.eye(4), velocity, 5, steps)
    assert got == pytest.approx(ratio, abs=1e-12)
    assert deg == pytest.approx(yaw, abs=1e-9)


def test_motion_deviation_under_a_turning_prediction_matches_a_plain_loop():
    """Yaw 4° and 0.8 m per frame: the predicted centres lie on an arc; nearest one by brute force."""
    velocity = _T(4.0, (0.0, 0.0, 0.8))
    T_last = _T(10.0, (2.0, 0.0, 7.0))
    cand = _T(80.0, (12.0, 0.5, 11.0))
    poses = [np.linalg.matrix_power(velocity, j) @ T_last for j in range(18 + 12)]
    centres = np.array([-P[:3, :3].T @ P[:3, 3] for P in poses])
    c = -cand[:3, :3].T @ cand[:3, 3]
    want = np.linalg.norm(centres[18:] - c, axis=1).min() / np.linalg.norm(centres[18] - centres[0])
    got, deg = motion_deviation(cand, T_last, velocity, 18, 12)
    assert got == pytest.approx(want, rel=1e-12)
    assert deg == pytest.approx(2.0, abs=1e-9)  # yaws about one axis add: 80° against 10° + 18 × 4°

