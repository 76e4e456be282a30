"""Projection helpers and analytic Jacobians against jax.jacfwd and numpy finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from privslam_jax.geometry.projection import (
    pinhole,
    pinhole_stereo,
    project_points,
    reprojection_jacobians,
    reprojection_residual,
    reprojection_residuals,
    stereo_jacobians,
    world_to_camera,
    world_to_camera_from_pose,
)
from privslam_jax.types import Camera


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def _pose(seed: int) -> jaxlie.SE3:
    rng = np.random.default_rng(seed)
    return jaxlie.SE3.exp(jnp.asarray(rng.normal(0, 0.3, 6)))


def test_world_to_camera_matches_matrices(x64):
    T_c_w = _pose(0)
    p_w = jnp.asarray(np.random.default_rng(1).normal(size=(7, 3)))
    M = np.asarray(T_c_w.as_matrix())
    ref = np.asarray(p_w) @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(world_to_camera(T_c_w, p_w), ref, atol=1e-12)
    np.testing.assert_allclose(world_to_camera_from_pose(T_c_w.inverse(), p_w), ref, atol=1e-12)


def test_projection_and_residuals_agree_with_camera(x64):
    cam = Camera(fx=500.0, fy=480.0, cx=320.0, cy=240.0, width=640, height=480)
    T_c_w = jaxlie.SE3.identity()
    p_w = jnp.asarray([[0.5, -0.2, 4.0], [1.0, 1.0, 2.0]])
    uv = project_points(T_c_w, p_w, cam)
    ref = np.array([[320 + 500 * 0.125, 240 - 480 * 0.05], [320 + 250.0, 240 + 240.0]])
    np.testing.assert_allclose(uv, ref, atol=1e-12)
    r = reprojection_residuals(T_c_w, p_w, uv + 1.0, cam)
    np.testing.assert_allclose(r, -np.ones((2, 2)), atol=1e-12)
    np.testing.assert_allclose(pinhole(p_w[0], 500.0, 480.0, 320.0, 240.0), ref[0], atol=1e-12)
    s = pinhole_stereo(p_w[0], 500.0, 480.0, 320.0, 240.0, 500.0 * 0.5)
    np.testing.assert_allclose(s, [ref[0, 0], ref[0, 1], ref[0, 0] - 500 * 0.5 / 4.0], atol=1e-12)


def _numeric_jac(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(x.size):
        d = np.zeros_like(x)
        d[k] = eps
        cols.append((np.asarray(f(x + d)) - np.asarray(f(x - d))) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mono_jacobians_vs_jacfwd_and_finite_differences(x64, seed):
    rng = np.random.default_rng(seed)
    T = _pose(seed + 10)
    p_c0 = np.array([rng.uniform(-2, 2), rng.uniform(-1, 1), rng.uniform(3, 10)])
    p_w = np.asarray(T.inverse() @ jnp.asarray(p_c0))
    fx, fy = 700.0, 690.0
    cam = Camera(fx=fx, fy=fy, cx=600.0, cy=180.0)
    uv = jnp.asarray([650.0, 170.0])

    def r_of_xi(xi):
        return reprojection_residual(jaxlie.SE3.exp(jnp.asarray(xi)) @ T, jnp.asarray(p_w), uv, cam)

    def r_of_p(p):
        return reprojection_residual(T, jnp.asarray(p), uv, cam)

    Jc, Jp = reprojection_jacobians(T @ jnp.asarray(p_w), T.rotation().as_matrix(), fx, fy)
    np.testing.assert_allclose(Jc, jax.jacfwd(r_of_xi)(jnp.zeros(6)), rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(Jp, jax.jacfwd(r_of_p)(jnp.asarray(p_w)), rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(Jc, _numeric_jac(r_of_xi, np.zeros(6)), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(Jp, _numeric_jac(r_of_p, p_w), rtol=1e-5, atol=1e-4)


def test_stereo_jacobians_vs_finite_differences(x64):
    T = _pose(5)
    p_w = np.asarray(T.inverse() @ jnp.asarray([0.7, -0.4, 6.0]))
    fx, fy, b = 720.0, 720.0, 0.54
    cam = Camera(fx=fx, fy=fy, cx=610.0, cy=175.0, baseline=b)

    def r_of_xi(xi):
        p_c = (jaxlie.SE3.exp(jnp.asarray(xi)) @ T) @ jnp.asarray(p_w)
        return pinhole_stereo(p_c, fx, fy, cam.cx, cam.cy, fx * b)

    Jc, Jp = stereo_jacobians(T @ jnp.asarray(p_w), T.rotation().as_matrix(), fx, fy, fx * b)
    np.testing.assert_allclose(Jc, _numeric_jac(r_of_xi, np.zeros(6)), rtol=1e-5, atol=1e-4)
    r_of_p = lambda p: pinhole_stereo(T @ jnp.asarray(p), fx, fy, cam.cx, cam.cy, fx * b)  # noqa: E731
    np.testing.assert_allclose(Jp, _numeric_jac(r_of_p, p_w), rtol=1e-5, atol=1e-4)
