"""ATE / RPE against evo (evo.main_ape / evo.main_rpe on the same TUM files) and closed forms."""

import copy

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core import sync
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe
from evo.tools.file_interface import read_tum_trajectory_file
from scipy.spatial.transform import Rotation

from privslam_jax.data.trajectory_io import read_kitti_matrices, read_tum_matrices, write_tum_matrices
from privslam_jax.metrics.trajectory import ate, associate, rotation_angle_deg, rpe, trajectory_metrics
from privslam_jax.types import Trajectory


def _street_path(n: int = 60) -> np.ndarray:
    """A drive with a turn: camera-to-world poses, z forward, y down (KITTI-like)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    yaw = np.clip(np.arange(n) - n / 2, 0, None) * np.radians(3.0)
    pos = np.zeros(3)
    for i in range(n):
        R = Rotation.from_euler("y", yaw[i]).as_matrix()
        if i:
            pos = pos + R @ np.array([0.0, 0.0, 1.2])
        T[i, :3, :3] = R
        T[i, :3, 3] = pos
    return T


def _noisy_estimate(T_ref: np.ndarray, seed: int, scale: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = T_ref.shape[0]
    T = T_ref.copy()
    T[:, :3, 3] += np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=0.01, size=(n, 3))).as_matrix() @ T[:, :3, :3]
    # express in another world frame and scale (monocular-like)
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("xyz", [10, -30, 5], degrees=True).as_matrix()
    G[:3, 3] = [3.0, -1.0, 7.0]
    T = G[None] @ T
    T[:, :3, 3] *= scale
    return T


@pytest.fixture()
def tum_pair(tmp_path):
    T_ref = _street_path()
    T_est = _noisy_estimate(T_ref, seed=0, scale=0.37)
    t = 1317384506.4 + np.arange(T_ref.shape[0]) * 0.1
    write_tum_matrices(tmp_path / "ref.txt", t, T_ref)
    write_tum_matrices(tmp_path / "est.txt", t, T_est)
    return tmp_path / "ref.txt", tmp_path / "est.txt"


def _evo_pair(ref_path, est_path):
    ref = read_tum_trajectory_file(str(ref_path))
    est = read_tum_trajectory_file(str(est_path))
    return sync.associate_trajectories(ref, est)


@pytest.mark.parametrize("align", ["none", "se3", "sim3"])
def test_ate_equals_evo(tum_pair, align):
    ref_path, est_path = tum_pair
    ref, est = _evo_pair(ref_path, est_path)
    res = evo_ape(
        copy.deepcopy(ref),
        copy.deepcopy(est),
        evo_metrics.PoseRelation.translation_part,
        align=align != "none",
        correct_scale=align == "sim3",
    )
    ours = ate(read_tum_matrices(est_path), read_tum_matrices(ref_path), align=align)
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        assert getattr(ours, key) == pytest.approx(res.stats[key], abs=1e-6), key
    np.testing.assert_allclose(ours.errors, res.np_arrays["error_array"], atol=1e-6)


@pytest.mark.parametrize("align", ["none", "sim3"])
def test_rpe_equals_evo(tum_pair, align):
    ref_path, est_path = tum_pair
    ref, est = _evo_pair(ref_path, est_path)
    kw = dict(delta=1, delta_unit=evo_metrics.Unit.frames, align=align != "none", correct_scale=align == "sim3")
    r_t = evo_rpe(copy.deepcopy(ref), copy.deepcopy(est), evo_metrics.PoseRelation.translation_part, **kw)
    r_r = evo_rpe(copy.deepcopy(ref), copy.deepcopy(est), evo_metrics.PoseRelation.rotation_angle_deg, **kw)
    trans, rot = rpe(read_tum_matrices(est_path), read_tum_matrices(ref_path), delta=1, align=align)
    assert trans.rmse == pytest.approx(r_t.stats["rmse"], abs=1e-6)
    assert rot.rmse == pytest.approx(r_r.stats["rmse"], abs=1e-6)
    np.testing.assert_allclose(trans.errors, r_t.np_arrays["error_array"], atol=1e-6)
    np.testing.assert_allclose(rot.errors, r_r.np_arrays["error_array"], atol=1e-6)


@pytest.mark.parametrize("all_pairs", [False, True])
def test_rpe_delta_equals_evo(tum_pair, all_pairs):
    ref_path, est_path = tum_pair
    ref, est = _evo_pair(ref_path, est_path)
    rel = evo_metrics.PoseRelation.translation_part
    r = evo_rpe(ref, est, rel, delta=5, delta_unit=evo_metrics.Unit.frames, all_pairs=all_pairs)
    trans, _ = rpe(read_tum_matrices(est_path), read_tum_matrices(ref_path), delta=5, all_pairs=all_pairs)
    assert trans.errors.shape == r.np_arrays["error_array"].shape
    assert trans.rmse == pytest.approx(r.stats["rmse"], abs=1e-6)


def test_metrics_on_kitti_ground_truth_equal_evo(shared, tmp_path):
    T_ref = read_kitti_matrices(shared / "data/kitti_odometry/poses/seq1.txt")
    t = np.arange(T_ref.shape[0]) / 10.0
    T_est = _noisy_estimate(T_ref, seed=3, scale=2.0)
    write_tum_matrices(tmp_path / "ref.txt", t, T_ref)
    write_tum_matrices(tmp_path / "est.txt", t, T_est)
    ref, est = _evo_pair(tmp_path / "ref.txt", tmp_path / "est.txt")
    res = evo_ape(ref, est, evo_metrics.PoseRelation.translation_part, align=True, correct_scale=True)
    m = trajectory_metrics((t, T_est), (t, T_ref))
    assert m["ate_rmse_sim3"] == pytest.approx(res.stats["rmse"], abs=1e-6)
    assert m["sim3_scale"] == pytest.approx(0.5, rel=0.05)
    assert m["matched"] == 51


def test_exact_estimate_has_zero_error_and_sim3_undoes_scale():
    T = _street_path(30)
    t = np.arange(30) * 0.1
    est = _noisy_estimate(T, seed=0, scale=3.0)
    est_clean = T.copy()
    est_clean[:, :3, 3] *= 3.0
    m = trajectory_metrics((t, T), (t, T))
    assert m["ate_rmse_se3"] < 1e-9 and m["rpe_trans"] < 1e-9 and m["rpe_rot"] < 1e-6
    assert ate((t, est_clean), (t, T), "sim3").rmse < 1e-9
    assert ate((t, est_clean), (t, T), "se3").rmse > 1.0
    assert ate((t, est), (t, T), "sim3").rmse < ate((t, est), (t, T), "se3").rmse


def test_trajectory_input_and_subset_association():
    T = _street_path(20)
    t = np.arange(20) * 0.1
    traj = Trajectory.from_matrices(t, T)
    sub = (t[::2], T[::2])
    res = ate(sub, traj, "se3")
    assert res.errors.shape == (10,)
    assert res.rmse < 1e-4  # float32 trajectory vs float64 subset
    i_e, i_r = associate(t[::2] + 1e-9, t)
    np.testing.assert_array_equal(i_e, np.arange(10))
    np.testing.assert_array_equal(i_r, np.arange(0, 20, 2))


def test_rotation_angle_matches_scipy():
    rv = Rotation.random(50, random_state=0).as_rotvec()
    rv[0] = [1e-9, 0, 0]
    R = Rotation.from_rotvec(rv).as_matrix()
    np.testing.assert_allclose(rotation_angle_deg(R), np.degrees(np.linalg.norm(rv, axis=1)), atol=1e-9)


def test_bad_input():
    T = _street_path(10)
    t = np.arange(10.0)
    with pytest.raises(ValueError, match="no matching timestamps"):
        ate((t + 100.0, T), (t, T))
    with pytest.raises(ValueError, match="align"):
        ate((t, T), (t, T), align="affine")
    with pytest.raises(ValueError, match="delta"):
        rpe((t, T), (t, T), delta=0)
    with pytest.raises(ValueError, match="more than 10"):
        rpe((t, T), (t, T), delta=10)
    bad = T.copy()
    bad[3, 0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ate((t, bad), (t, T))
