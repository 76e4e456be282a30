"""Lines of road points laid parallel to the road (``privslam_jax.privacy.road``): every line still through
its point, the near-road ones parallel to their keyframe's road plane and the others untouched, and the
road-surface attack left with nothing to intersect on the hilly street of tests/test_plane_attack.py."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.attacks.plane import road_planes, road_surface_attack
from privslam_jax.privacy.lift import fixed_key, random_lift
from privslam_jax.privacy.road import road_parallel
from test_plane_attack import _hilly_road


def test_near_road_lines_lie_parallel_to_their_road_and_the_road_attack_loses_them():
    X, road, T = _hilly_road()
    lines = random_lift(X, fixed_key(5))
    out = road_parallel(lines, X, T, 1.65, within=0.5)
    d0, d = np.asarray(lines.directions, np.float64), np.asarray(out.directions, np.float64)
    assert d.dtype == np.asarray(lines.directions).dtype and d.shape == d0.shape
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(X, d), np.asarray(out.moments), atol=1e-9)  # each line through its point
    # reference, point by point: its nearest keyframe foot, its height above that road plane
    n, feet = road_planes(T, 1.65)
    for i in range(len(X)):
        j = int(np.argmin(np.linalg.norm(X[i] - feet, axis=1)))
        if abs((X[i] - feet[j]) @ n[j]) < 0.5:
            assert abs(d[i] @ n[j]) < 1e-9
            flat = d0[i] - (d0[i] @ n[j]) * n[j]
            np.testing.assert_allclose(d[i], flat / np.linalg.norm(flat), atol=1e-9)
        else:
            np.testing.assert_array_equal(d[i], d0[i])
            np.testing.assert_array_equal(np.asarray(out.moments)[i], np.asarray(lines.moments)[i])
    assert road.mean() > 0.4 and (np.abs(d - d0).max(axis=1) > 0)[road].all()  # every road line was moved
    before = np.linalg.norm(road_surface_attack(lines, T, 1.65) - X, axis=1)
    after = np.linalg.norm(road_surface_attack(out, T, 1.65) - X, axis=1)
    # what the attack still gets (measured 13.5 % against 98.5 %): lines that pass near their keyframe's
    # foot (a line parallel to the plane gives its point nearest the foot) or meet the next keyframe's
    # plane near the point, where the street bends
    assert np.mean(before[road] <= 0.5) > 0.9 and np.mean(after[road] <= 0.5) < 0.2, (
        np.mean(before[road] <= 0.5), np.mean(after[road] <= 0.5))


def test_a_direction_along_the_normal_and_bad_inputs():
    from privslam_jax.types import LineCloud

    T = np.eye(4)[None]
    X = np.array([[0.0, 1.65, 5.0], [0.0, 1.0, 5.0]])  # on the road, and 0.65 m above it
    vertical = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    lines = LineCloud(directions=vertical, moments=np.cross(X, vertical))
    d = np.asarray(road_parallel(lines, X, T, 1.65, within=0.5).directions)
    assert abs(d[0] @ [0, 1, 0]) < 1e-12 and abs(np.linalg.norm(d[0]) - 1) < 1e-12
    np.testing.assert_array_equal(d[1], vertical[1])
    for kwargs, match in (({"within": 0.0}, "within"), ({"within": np.inf}, "within"), ({"height": -1.0}, "height")):
        args = {"height": 1.65, **kwargs}
        with pytest.raises(ValueError, match=match):
            road_parallel(lines, X, T, **args)
    with pytest.raises(ValueError, match="match"):
        road_parallel(lines, X[:1], T, 1.65)


def test_privslam_lift_road_parallel(tmp_path, capsys, monkeypatch):
    """``privslam lift --road-parallel KEYFRAMES.txt`` (the keyframes as ``privslam slam`` writes them) equals
    ``road_parallel`` of the same seeded random lift (to the float32 PLY's rounding); a lift of fixed directions
    is refused."""
    from privslam_jax.cli import main
    from privslam_jax.data.ply import load_line_cloud, save_point_cloud
    from privslam_jax.data.trajectory_io import write_tum_matrices
    from privslam_jax.types import PointCloud

    X, _, T = _hilly_road()
    save_point_cloud(tmp_path / "p.ply", PointCloud(xyz=jnp.asarray(X, jnp.float32)))
    write_tum_matrices(tmp_path / "keyframes.txt", np.arange(len(T)) * 0.1, T)
    assert main(["lift", str(tmp_path / "p.ply"), "--out", str(tmp_path / "l.ply"), "--seed", "3", "--road-parallel",
                 str(tmp_path / "keyframes.txt"), "--road-within", "0.5"]) == 0
    got = load_line_cloud(tmp_path / "l.ply")
    x32 = X.astype(np.float32)
    ref = road_parallel(random_lift(x32, fixed_key(3)), x32, T, 1.65, within=0.5)
    # the PLY stores each line as a float32 unit segment at its closest point to the origin (up to 60 m out)
    np.testing.assert_allclose(np.asarray(got.directions), np.asarray(ref.directions), atol=5e-5)
    np.testing.assert_allclose(np.asarray(got.moments), np.asarray(ref.moments), atol=5e-3)
    capsys.readouterr()
    assert main(["lift", str(tmp_path / "p.ply"), "--out", str(tmp_path / "x.ply"), "--method", "sphere",
                 "--road-parallel", str(tmp_path / "keyframes.txt")]) == 2
    assert "--road-parallel" in capsys.readouterr().err and not (tmp_path / "x.ply").exists()
    # the keyframes are read and checked before the lift (an optimised lift takes minutes): a bad file is
    # refused without lifting
    import privslam_jax.privacy.optimised_lift as optimised

    def must_not_run(*args, **kwargs):
        raise AssertionError("lifted before the keyframes were checked")

    monkeypatch.setattr(optimised, "optimised_lift", must_not_run)
    (tmp_path / "bad.txt").write_text("0 1 2 3\n")
    assert main(["lift", str(tmp_path / "p.ply"), "--out", str(tmp_path / "x.ply"), "--method", "optimised",
                 "--road-parallel", str(tmp_path / "bad.txt")]) == 2
    assert "bad.txt" in capsys.readouterr().err and not (tmp_path / "x.ply").exists()


def test_keyframe_up_is_the_mean_up_axis_and_bad_input_is_refused():
    """The keyframes' mean up axis: cameras pitched −5°, 0° and +5° about x on a road tilted by 3° give the
    tilted road's normal; bad poses and up axes that cancel are refused."""
    from privslam_jax.privacy.road import keyframe_up

    def rot_x(deg):
        a = np.radians(deg)
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    T = np.tile(np.eye(4), (3, 1, 1))
    for k, pitch in enumerate((-5.0, 0.0, 5.0)):
        T[k, :3, :3] = rot_x(3.0 + pitch)
        T[k, :3, 3] = [0.0, 0.0, 10.0 * k]
    np.testing.assert_allclose(keyframe_up(T), -rot_x(3.0) @ np.array([0.0, 1.0, 0.0]), atol=1e-12)
    with pytest.raises(ValueError, match="keyframe poses"):
        keyframe_up(T[:, :3])
    opposite = T[:2].copy()
    opposite[1, :3, :3] = rot_x(180.0) @ opposite[0, :3, :3]  # one camera upside down
    with pytest.raises(ValueError, match="cancel"):
        keyframe_up(opposite)
