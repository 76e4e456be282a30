"""Core types against plain numpy/scipy references."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from privslam_jax import Camera, LineCloud, Trajectory


def test_trajectory_from_matrices_roundtrip():
    rng = np.random.default_rng(0)
    R = Rotation.random(5, random_state=1).as_matrix()
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = rng.normal(size=(5, 3))
    traj = Trajectory.from_matrices(np.arange(5) * 0.1, T)
    np.testing.assert_allclose(np.asarray(traj.as_matrices()), T, atol=1e-5)
    np.testing.assert_allclose(np.asarray(traj.positions), T[:, :3, 3], atol=1e-6)
    assert len(traj) == 5


def test_trajectory_rejects_bad_input():
    with pytest.raises(ValueError, match="shape"):
        Trajectory.from_matrices(np.arange(2), np.zeros((2, 3, 3)))
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        Trajectory.from_matrices(np.arange(2), T)


def test_camera_project_unproject_matches_K():
    cam = Camera(fx=700.0, fy=710.0, cx=320.0, cy=96.0, width=640, height=192)
    p = jnp.array([[1.0, -0.5, 10.0], [0.2, 0.3, 4.0]])
    uv = cam.project(p)
    K = np.array([[700.0, 0, 320.0], [0, 710.0, 96.0], [0, 0, 1]])
    h = (K @ np.asarray(p).T).T
    np.testing.assert_allclose(np.asarray(uv), h[:, :2] / h[:, 2:], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(cam.K), K)
    np.testing.assert_allclose(np.asarray(cam.unproject(uv, p[:, 2])), np.asarray(p), rtol=1e-5)


def test_linecloud_closest_point():
    p = np.array([[1.0, 2.0, 3.0]])
    d = np.array([[0.0, 0.0, 1.0]])
    lines = LineCloud(directions=jnp.asarray(d), moments=jnp.cross(jnp.asarray(p), jnp.asarray(d)))
    np.testing.assert_allclose(np.asarray(lines.closest_points), [[1.0, 2.0, 0.0]], atol=1e-6)
