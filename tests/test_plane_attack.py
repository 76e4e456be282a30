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


def _hilly_road(n_cams=12, spacing=6.0, h=1.65, seed=0):
    """A road of planar segments along z whose slope changes at every keyframe (y down, ±4°), the camera
    of segment k pitched with it, ``h`` above its foot; points on the road within 40 % of the spacing of
    their segment's foot (so that foot is their nearest), the other half on facades."""
    rng = np.random.default_rng(seed)
    slopes = np.deg2rad(rng.uniform(-4, 4, n_cams))
    feet, T = [np.zeros(3)], []
    for k, a in enumerate(slopes):
        along = np.array([0.0, -np.sin(a), np.cos(a)])  # the road's forward direction (y down: climbing is −y)
        down = np.array([0.0, np.cos(a), np.sin(a)])
        R = np.stack([np.array([1.0, 0, 0]), down, along], axis=1)  # camera x, y (down), z (forward) in the map
        Tk = np.eye(4)
        Tk[:3, :3], Tk[:3, 3] = R, feet[k] - h * down
        T.append(Tk)
        feet.append(feet[k] + spacing * along)
    T = np.stack(T)
    k = rng.integers(0, n_cams, 2 * 400)
    f, R = T[k, :3, 3] + h * T[k, :3, 1], T[k, :3, :3]
    local = np.stack([rng.uniform(-3, 3, len(k)), np.zeros(len(k)), rng.uniform(-0.4, 0.4, len(k)) * spacing], 1)
    X = f + np.einsum("nij,nj->ni", R, local)
    road = np.arange(len(k)) < 400
    X[~road] += np.einsum("nij,nj->ni", R[~road], np.c_[rng.choice([-6.0, 6.0], (~road).sum()),
                                                      -rng.uniform(0.5, 8, (~road).sum()), np.zeros((~road).sum())])
    return X, road, T


def test_road_surface_attack_recovers_the_road_points_of_a_hilly_street_that_one_plane_misses():
    """Reference: per line and keyframe the numpy solve of the first test, the nearest-to-its-foot
    intersection kept.  Road points whose line is not grazing come back exactly (float32 lifts: mm); the
    one plane under the first keyframe puts most of them metres off."""
    from privslam_jax.attacks.plane import road_surface_attack

    X, road, T = _hilly_road()
    h = 1.65
    for lift in (random_lift, ray_lift, sphere_lift):
        lines = lift(X, fixed_key(5))
        got = road_surface_attack(lines, T, h, chunk=97)
        d = np.asarray(lines.directions, np.float64)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p0 = np.cross(d, np.asarray(lines.moments, np.float64))
        sample = np.random.default_rng(1).choice(len(X), 150, replace=False)
        for i in sample:
            cands = []
            for Tk in T:
                q, b1, b2 = Tk[:3, 3] + h * Tk[:3, 1], Tk[:3, 0], Tk[:3, 2]
                x = p0[i] + np.linalg.solve(np.stack([d[i], -b1, -b2], 1), q - p0[i])[0] * d[i]
                cands.append((np.linalg.norm(x - q), tuple(x)))
            np.testing.assert_allclose(got[i], min(cands)[1], rtol=1e-9, atol=1e-6)
        steep = np.abs(np.einsum("ni,ni->n", d, T[0, :3, 1][None, :])) > 0.3
        err = np.linalg.norm(got - X, axis=1)
        assert np.median(err[road & steep]) < 1e-3 and np.mean(err[road & steep] < 0.01) > 0.95, lift.__name__
        one = np.linalg.norm(ground_plane_attack(lines, T[0, :3, 1], T[0, :3, 1] @ (T[0, :3, 3] + h * T[0, :3, 1])) - X, axis=1)
        assert np.mean(one[road & steep] <= 0.5) < 0.6 * np.mean(err[road & steep] <= 0.5), lift.__name__


def test_road_surface_attack_on_one_shared_plane_is_the_ground_plane_attack_and_bad_inputs_are_refused():
    from privslam_jax.attacks.plane import road_surface_attack

    X, _ = _street()
    lines = random_lift(X, fixed_key(2))
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, 3] = np.c_[np.zeros(5), np.zeros(5), np.linspace(0, 40, 5)]  # level cameras 1.65 above y = 1.65
    T[:, 1, 3] = 0.0
    np.testing.assert_allclose(road_surface_attack(lines, T, 1.65), ground_plane_attack(lines, (0, 1, 0), 1.65),
                               atol=1e-9)
    for bad_T, h, down, match in ((T[0], 1.65, (0, 1, 0), "T_w_c"), (T[:0], 1.65, (0, 1, 0), "T_w_c"),
                                  (T, 0.0, (0, 1, 0), "height"), (T, np.nan, (0, 1, 0), "height"),
                                  (T, 1.65, (0, 0, 0), "down"), (T, 1.65, (0, 1), "down")):
        with pytest.raises(ValueError, match=match):
            road_surface_attack(lines, bad_T, h, down)


def test_path_attack_takes_each_lines_point_nearest_a_keyframe_and_refuses_bad_poses():
    """Reference per line: the closest point of the line to each camera centre (numpy projection), the
    nearest of them kept; a point on the path comes back exactly, an axial cloud's street points do not."""
    from privslam_jax.attacks.plane import path_attack
    from privslam_jax.privacy.lift import axial_lift

    X, road, T = _hilly_road()
    X = np.concatenate([X, T[:3, :3, 3]])  # three points on the path itself
    lines = random_lift(X, fixed_key(6))
    got = path_attack(lines, T, chunk=101)
    d = np.asarray(lines.directions, np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p0 = np.cross(d, np.asarray(lines.moments, np.float64))
    C = T[:, :3, 3]
    for i in range(len(X)):
        cands = [p0[i] + np.dot(c - p0[i], d[i]) * d[i] for c in C]  # the line's point nearest each centre
        k = np.argmin([np.linalg.norm(x - c) for x, c in zip(cands, C)])
        np.testing.assert_allclose(got[i], cands[k], atol=1e-9)
    np.testing.assert_allclose(got[-3:], X[-3:], atol=1e-4)  # float32 lines
    axial = path_attack(axial_lift(X[:-3], (0.0, -1.0, 0.0), fixed_key(6)), T)
    assert np.mean(np.linalg.norm(axial - X[:-3], axis=1) <= 0.5) < 0.2
    for bad in (T[0], T[:0], np.full_like(T, np.nan)):
        with pytest.raises(ValueError, match="T_w_c"):
            path_attack(lines, bad)
