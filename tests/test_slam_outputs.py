"""``privslam slam`` outputs: straight drives get ATE; an ill-posed alignment loses nothing."""

import json
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax import PointCloud, Trajectory
from privslam_jax.slam.outputs import write_outputs
from privslam_jax.data.trajectory_io import read_tum_matrices, write_kitti_matrices


def _result(est, n, frame_maps=None):
    frame_maps = np.zeros(n, np.int64) if frame_maps is None else frame_maps
    return SimpleNamespace(
        trajectory=Trajectory.from_matrices(np.arange(n) * 0.1, est),
        keyframe_indices=np.array([0, 3]),
        keyframe_poses=est[[0, 3]],
        map=PointCloud(xyz=jnp.ones((4, 3)), observations=jnp.full((4,), 2)),
        timings={"total": np.full(n, 0.05)},
        tracked=frame_maps >= 0,
        events=[],
        loops=[],
        frame_maps=frame_maps,
        n_maps=len(np.unique(frame_maps[frame_maps >= 0])),
    )


def test_two_atlas_maps_are_marked_per_frame_and_measured_on_the_main_one(tmp_path):
    """Frames 0-7 in map 0 (exact), 8-9 lost, 10-13 in map 1 (another world frame): the errors come from
    map 0's frames only, and frames.txt says which pose is where."""
    n = 14
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n) * 0.7
    gt[:, 2, 3] = np.arange(n) ** 2 * 0.1
    est = gt.copy()
    est[10:, :3, 3] += 50.0  # map 1 lives in its own frame
    maps = np.array([0] * 8 + [-1] * 2 + [1] * 4)
    metrics = write_outputs(tmp_path, _result(est, n, maps), np.arange(n) * 0.1, gt, "stereo", wall_time=1.0,
                            plots=False)
    assert metrics["maps"] == 2 and metrics["metrics_map"] == 0 and metrics["metrics_frames"] == 8
    assert metrics["ate_rmse_se3"] < 1e-5  # (float32 trajectory); with map 1 it would be metres
    rows = [line.split() for line in (tmp_path / "frames.txt").read_text().splitlines()[1:]]
    assert [int(r[1]) for r in rows] == [1] * 8 + [0] * 2 + [1] * 4
    assert [int(r[2]) for r in rows] == maps.tolist()
    np.testing.assert_allclose([float(r[0]) for r in rows], np.arange(n) * 0.1, rtol=0, atol=0)


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


def test_outputs_are_written_atomically(tmp_path, monkeypatch):
    """Issue 15: trajectory, pose, PLY and metrics files were written in place, so a run killed or a
    disk filled mid-write left a truncated file that looked like a result. A write that fails at
    the last step (the rename) now leaves the earlier file whole and no temporary behind."""
    import os

    from privslam_jax.data import files
    from privslam_jax.data.ply import load_point_cloud
    from privslam_jax.data.trajectory_io import read_kitti_matrices

    n = 6
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n)
    gt[:, 2, 3] = np.arange(n) ** 2 * 0.1
    write_outputs(tmp_path, _result(gt, n), np.arange(n) * 0.1, gt, "mono", wall_time=1.0, plots=True)
    write_kitti_matrices(tmp_path / "poses.txt", gt)
    names = sorted(p.name for p in tmp_path.iterdir())
    before = {name: (tmp_path / name).read_bytes() for name in names}

    def disk_full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files.os, "replace", disk_full)
    moved = gt.copy()
    moved[:, 1, 3] += 5.0
    with pytest.raises(OSError, match="No space left"):
        write_outputs(tmp_path, _result(moved, n), np.arange(n) * 0.1, gt, "mono", wall_time=1.0, plots=True)
    with pytest.raises(OSError, match="No space left"):
        write_kitti_matrices(tmp_path / "poses.txt", moved)
    monkeypatch.setattr(files.os, "replace", os.replace)
    assert sorted(p.name for p in tmp_path.iterdir()) == names  # no temporaries left behind
    assert {name: (tmp_path / name).read_bytes() for name in names} == before  # the earlier files are whole
    np.testing.assert_allclose(read_tum_matrices(tmp_path / "trajectory.txt")[1], gt, atol=1e-6)
    np.testing.assert_allclose(read_kitti_matrices(tmp_path / "poses.txt"), gt)
    assert len(load_point_cloud(tmp_path / "map.ply")) == len(_result(gt, n).map)
