"""TUM / KITTI trajectory files: round trips, evo reads our files, bad input."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from privslam_jax.data.trajectory_io import (
    load_kitti,
    load_tum,
    read_kitti_matrices,
    read_tum_matrices,
    save_kitti,
    save_tum,
    write_kitti_matrices,
    write_tum_matrices,
)
from privslam_jax.types import Trajectory


def _random_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.normal(scale=50.0, size=(n, 3))
    return T


def test_tum_roundtrip_float64(tmp_path):
    T = _random_poses(20)
    t = 1305031102.175304 + np.arange(20) * 0.0333
    path = tmp_path / "traj.txt"
    write_tum_matrices(path, t, T)
    t2, T2 = read_tum_matrices(path)
    np.testing.assert_array_equal(t2, t)  # repr formatting: timestamps exact
    np.testing.assert_allclose(T2, T, rtol=0, atol=1e-12)


def test_tum_file_layout(tmp_path):
    T = _random_poses(3, seed=4)
    path = tmp_path / "t.txt"
    write_tum_matrices(path, np.arange(3.0), T)
    rows = np.loadtxt(path)
    assert rows.shape == (3, 8)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    q *= np.sign(q[:, 3:4])
    np.testing.assert_allclose(rows[:, 1:4], T[:, :3, 3], atol=0)
    np.testing.assert_allclose(rows[:, 4:], q, atol=1e-15)
    assert np.all(rows[:, 7] >= 0)


def test_evo_reads_our_tum_files(tmp_path):
    from evo.tools.file_interface import read_tum_trajectory_file

    T = _random_poses(15, seed=2)
    t = 1e9 + np.arange(15) * 0.1
    path = tmp_path / "est.txt"
    write_tum_matrices(path, t, T)
    traj = read_tum_trajectory_file(str(path))
    np.testing.assert_array_equal(traj.timestamps, t)
    np.testing.assert_allclose(np.stack(traj.poses_se3), T, rtol=0, atol=1e-9)


def test_kitti_roundtrip_and_layout(tmp_path):
    T = _random_poses(7, seed=1)
    path = tmp_path / "poses" / "00.txt"
    write_kitti_matrices(path, T)
    np.testing.assert_array_equal(read_kitti_matrices(path), T)
    np.testing.assert_array_equal(np.loadtxt(path).reshape(-1, 3, 4), T[:, :3, :])


def test_kitti_reads_shared_ground_truth(shared):
    path = shared / "data/kitti_odometry/poses/seq1.txt"
    T = read_kitti_matrices(path)
    ref = np.loadtxt(path).reshape(-1, 3, 4)
    assert T.shape == (51, 4, 4)
    np.testing.assert_array_equal(T[:, :3, :], ref)
    np.testing.assert_array_equal(T[:, 3, :], np.tile([0, 0, 0, 1.0], (51, 1)))


def test_trajectory_wrappers(tmp_path):
    T = _random_poses(5, seed=3)
    traj = Trajectory.from_matrices(np.arange(5) * 0.1, T)
    save_tum(tmp_path / "a.txt", traj)
    save_kitti(tmp_path / "b.txt", traj)
    a = load_tum(tmp_path / "a.txt")
    b = load_kitti(tmp_path / "b.txt")
    tol = 1e-5  # Trajectory holds JAX default precision (float32)
    np.testing.assert_allclose(np.asarray(a.as_matrices()), T, atol=tol * 50)
    np.testing.assert_allclose(np.asarray(b.as_matrices()), T, atol=tol * 50)
    np.testing.assert_allclose(np.asarray(b.timestamps), np.arange(5) / 10.0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(a.timestamps), np.arange(5) * 0.1, atol=1e-7)


@pytest.mark.parametrize(
    "content,match",
    [
        ("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 1\n", r"bad\.txt:2: expected 8"),
        ("0 1 2 3 0 0 0 1\n1 1 2 x 0 0 0 1\n", r"bad\.txt:2: not a number"),
        ("0 1 2 3 0 0 0 1\n1 1 nan 3 0 0 0 1\n", r"bad\.txt:2: NaN"),
        ("0 1 2 3 0 0 0 0\n", r"bad\.txt: zero quaternion"),
        ("1 1 2 3 0 0 0 1\n1 1 2 3 0 0 0 1\n", r"bad\.txt: timestamps must increase"),
        ("# only a comment\n", r"bad\.txt: no poses"),
    ],
)
def test_tum_bad_input(tmp_path, content, match):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(ValueError, match=match):
        read_tum_matrices(path)


def test_missing_and_bad_kitti(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        read_kitti_matrices(tmp_path / "nope.txt")
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        read_tum_matrices(tmp_path / "nope.txt")
    path = tmp_path / "bad.txt"
    path.write_text(" ".join(["1"] * 11) + "\n")
    with pytest.raises(ValueError, match=r"bad\.txt:1: expected 12"):
        read_kitti_matrices(path)
    with pytest.raises(ValueError, match="shape"):
        write_kitti_matrices(tmp_path / "x.txt", np.zeros((2, 3, 3)))
    with pytest.raises(ValueError, match="timestamps"):
        write_tum_matrices(tmp_path / "x.txt", np.zeros(3), np.tile(np.eye(4), (2, 1, 1)))
