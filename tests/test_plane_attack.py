"""The ground-plane attack (``privslam_jax.attacks.plane``): against a plain linear solve per line, exact
on points of the plane for every lift (sphere clouds included), parallel lines and bad planes handled."""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.attacks.plane import ground_plane_attack
from privslam_jax.privacy.lift import fixed_key, paired_lift, random_lift, ray_lift, sphere_lift
from privslam_jax.types import LineCloud


def _street(n=600, seed=0):
    """A third of the points on the road ``y = 1.65`` (y down), the rest on facades and in the air."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-8, -4, 2], [8, 1.5, 60], (n, 3))
    ground = np.arange(n) < n // 3
    X[ground, 1] = 1.65
    return X, ground


def test_every_lift_gives_its_ground_points_away_and_the_rest_where_the_lines_meet_the_plane():
    """Reference per line: ``[d | −b₁ | −b₂] (t, u, v)ᵀ = q − p₀`` solved with numpy (the line point
    ``p₀ + t d`` equal to the plane point ``q + u b₁ + v b₂``, ``q`` on the plane, ``b`` spanning it)."""
    X, ground = _street()
    n = np.array([0.0, 2.0, 0.0])  # not unit length: the plane 2y = 3.3
    q, b1, b2 = np.array([0.0, 1.65, 0.0]), np.array([1.0, 0, 0]), np.array([0.0, 0, 1])
    for lift in (random_lift, paired_lift, ray_lift, sphere_lift):
        lines = lift(X, fixed_key(3))
        got = ground_plane_attack(lines, n, 3.3)
        d = np.asarray(lines.directions, np.float64)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p0 = np.cross(d, np.asarray(lines.moments, np.float64))
        # a paired line through two road points lies in the plane: it meets it nowhere in particular
        meets = np.abs(d[:, 1]) > 1e-6
        assert meets.mean() > (0.8 if lift is paired_lift else 0.99)
        ref = np.array([p + np.linalg.solve(np.stack([dd, -b1, -b2], 1), q - p)[0] * dd for p, dd in zip(p0[meets], d[meets])])
        np.testing.assert_allclose(got[meets], ref, rtol=1e-6, atol=1e-6 * (1 + np.abs(ref)).max())
        np.testing.assert_allclose(got[ground & meets], X[ground & meets], atol=1e-3)  # float32 lifts: mm
        err = np.linalg.norm(got[~ground] - X[~ground], axis=1)
        assert np.mean(err <= 0.5) < 0.2, lift.__name__  # off the plane the guess is (mostly) wrong


def test_a_line_parallel_to_the_plane_keeps_its_point_nearest_the_plane_and_bad_planes_are_refused():
    lines = LineCloud(directions=np.array([[1.0, 0, 0], [0, 1, 0]]),
                      moments=np.cross(np.array([[0.0, 5, 3], [2.0, 0, 1]]), np.array([[1.0, 0, 0], [0, 1, 0]])))
    got = ground_plane_attack(lines, (0, 1, 0), 1.65)
    np.testing.assert_allclose(got, [[0.0, 5, 3], [2.0, 1.65, 1]], atol=1e-12)
    for normal, offset in (((0, 0, 0), 1.0), ((0, 1, 0), np.nan), ((0, 1), 1.0)):
        with pytest.raises(ValueError, match="plane"):
            ground_plane_attack(lines, normal, offset)
