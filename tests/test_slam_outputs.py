"""``privslam slam`` outputs: straight drives get ATE; an ill-posed alignment loses nothing."""

import json
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from privslam_jax import PointCloud, Trajectory
from privslam_jax.slam.outputs import write_outputs
from privslam_jax.data.trajectory_io import read_tum_matrices


def _result(est, n):
    return SimpleNamespace(
        trajectory=Trajectory.from_matrices(np.arange(n) * 0.1, est),
        keyframe_indices=np.array([0, 3]),
        keyframe_poses=est[[0, 3]],
        map=PointCloud(xyz=jnp.ones((4, 3)), observations=jnp.full((4,), 2)),
        timings={"total": np.full(n, 0.05)},
        tracked=np.ones(n, bool),
        events=[],
    )


def test_straight_drive_gets_sim3_ate(tmp_path):
    n = 6
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 2, 3] = np.arange(n) * 1.0  # straight drive along z: collinear positions
    est = gt.copy()
    est[:, 2, 3] *= 0.5  # monocular: half the true scale
    metrics = write_outputs(tmp_path, _result(est, n), np.arange(n) * 0.1, gt, "mono", wall_time=1.0, plots=False)
    assert metrics["ate_rmse_sim3"] < 1e-6
    # SE(3): the best rigid fit of a half-length copy; closed form: RMS of (0.5 s_i - s_i) about the mean
    s = np.arange(n) * 1.0
    expect = np.sqrt(np.mean((0.5 * (s - s.mean()) - (s - s.mean())) ** 2))
    assert abs(metrics["ate_rmse_se3"] - expect) < 1e-6


def test_static_ground_truth_keeps_trajectory_map_and_reports_why(tmp_path, capsys):
    """The library records why there is no ATE and prints nothing (the command prints it)."""
    n = 6
    gt = np.tile(np.eye(4), (n, 1, 1))  # the camera never moves: alignment is ill-posed
    est = gt.copy()
    est[:, 2, 3] = np.arange(n) * 0.01
    metrics = write_outputs(tmp_path, _result(est, n), np.arange(n) * 0.1, gt, "mono", wall_time=1.0, plots=True)
    assert "identical" in metrics["alignment_error"]
    assert "ate_rmse_sim3" not in metrics
    assert metrics["path_length"] == 0.0
    assert json.loads((tmp_path / "metrics.json").read_text())["frames"] == n
    ts, T = read_tum_matrices(tmp_path / "trajectory.txt")
    np.testing.assert_allclose(T[:, :3, 3], est[:, :3, 3], atol=1e-6)
    for name in ("keyframes.txt", "map.ply", "trajectory_xz.png", "ate_over_time.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert capsys.readouterr().err == ""
