"""Issue 15 item 3: every loop of a jitted solver or attack ends within its stated bound on
degenerate input (identical points, collinear points, parallel or identical lines), and says so.

Bounds: pose refinement ≤ ``rounds × max_iterations`` LM iterations, bundle adjustment ≤
``max_iterations``; the gradient attack's NonlinearCG ≤ ``max_steps`` (optimistix, ``throw=False``);
Line2Point's peak search: ``tests/test_line2point.py::test_equal_offsets_end_the_peak_search``.
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from privslam_jax.slam.ba import BAConfig, bundle_adjust
from privslam_jax.slam.refine import RefineConfig, refine_pose
from privslam_jax.types import Camera

CAM = Camera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)


def _degenerate_points(kind: str, n: int = 24) -> np.ndarray:
    if kind == "identical":
        return np.tile([[0.5, -0.2, 8.0]], (n, 1))
    if kind == "collinear":  # one line through the camera's view, seen edge-on
        return np.stack([np.linspace(-2, 2, n), np.zeros(n), np.full(n, 8.0)], 1)
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["identical", "collinear"])
def test_pose_refinement_ends_within_its_bound(kind):
    p = _degenerate_points(kind)
    uv = p[:, :2] / p[:, 2:] * CAM.fx + np.array([CAM.cx, CAM.cy])
    cfg = RefineConfig(rounds=3, max_iterations=7)
    T0 = jaxlie.SE3.exp(jnp.asarray([0.05, -0.02, 0.1, 0.01, 0.02, -0.01]))
    res = refine_pose(T0, p, uv + 0.3, None, CAM, cfg)
    assert 0 <= int(res.iterations) <= cfg.rounds * cfg.max_iterations
    assert np.all(np.isfinite(np.asarray(res.T_c_w.wxyz_xyz))) and np.isfinite(float(res.cost))
    assert float(res.cost) <= float(res.initial_cost) + 1e-6  # LM never accepts a worse step


@pytest.mark.parametrize("kind", ["identical", "collinear"])
def test_bundle_adjustment_ends_within_its_bound(kind):
    p = _degenerate_points(kind, 12)
    m = 3
    T = jaxlie.SE3(jnp.tile(jaxlie.SE3.identity().wxyz_xyz[None], (m, 1)))  # all cameras at one place too
    obs_cam = np.repeat(np.arange(m), len(p))
    obs_pt = np.tile(np.arange(len(p)), m)
    uv = np.tile(p[:, :2] / p[:, 2:] * CAM.fx + np.array([CAM.cx, CAM.cy]), (m, 1)) + 0.5
    cfg = BAConfig(max_iterations=9)
    fixed = np.array([True] + [False] * (m - 1))
    res = bundle_adjust(T, p + 0.01, obs_cam, obs_pt, uv, None, fixed, CAM, cfg)
    assert 0 <= int(res.iterations) <= cfg.max_iterations
    assert np.all(np.isfinite(np.asarray(res.points))) and np.all(np.isfinite(np.asarray(res.T_c_w.wxyz_xyz)))
    assert float(res.cost) <= float(res.initial_cost) + 1e-6


@pytest.mark.parametrize("kind", ["parallel", "one_point", "identical_lines"])
def test_gradient_attack_ends_within_its_bound(kind):
    from privslam_jax.attacks.gradient import GradientAttackConfig, _minimise, line_neighbours
    from privslam_jax.types import LineCloud

    n = 16
    rng = np.random.default_rng(0)
    if kind == "parallel":  # no two lines meet: the energy has no finite minimiser along them
        d = np.tile([[0.0, 0.0, 1.0]], (n, 1))
        p = np.stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)], 1)
    elif kind == "one_point":  # every line through the same point
        d = rng.normal(size=(n, 3))
        p = np.zeros((n, 3))
    else:  # one line repeated: every neighbour is the line itself (all offsets equal)
        d = np.tile(rng.normal(size=(1, 3)), (n, 1))
        p = np.ones((n, 3))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    lines = LineCloud(directions=jnp.asarray(d), moments=jnp.asarray(np.cross(p, d)))
    cfg = GradientAttackConfig(num_neighbours=4, max_steps=25)
    a = jnp.cross(lines.directions, lines.moments)
    nb = line_neighbours(a, lines.directions, k=cfg.num_neighbours, chunk_size=cfg.chunk_size)
    t, _, steps = _minimise(jnp.zeros(n), a, lines.directions, nb, cfg)
    assert int(steps) <= cfg.max_steps and t.shape == (n,)
