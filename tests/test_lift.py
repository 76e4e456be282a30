"""Lifts: uniform directions (a test that rejects biased samplers), points on their lines,
naive decoders fail, default keys differ; ray and sphere clouds meet at their centres with balanced
signs and a position-blind anchor choice; axial clouds meet their axis at a right angle and carry
nothing of a point's distance from it; Plücker helpers against numpy closed forms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from privslam_jax.geometry.plucker import (
    closest_approach,
    closest_point_to_origin,
    line_line_distance,
    lines_from_points_directions,
    point_line_distance,
)
from privslam_jax.privacy.lift import (
    axial_lift,
    entropy_key,
    fixed_key,
    paired_lift,
    pairing,
    random_lift,
    ray_anchors,
    ray_lift,
    sphere_lift,
)



def axial_y(points, key=None):
    """:func:`axial_lift` with ``up = −y`` (KITTI's camera frame)."""
    return axial_lift(points, (0.0, -1.0, 0.0), key)


LIFTS = [random_lift, paired_lift, ray_lift, sphere_lift, axial_y]


def isotropy_pvalues(d: np.ndarray) -> tuple[float, float]:
    """Rayleigh test (3n‖mean‖² ~ χ²₃) and Bingham test ((15n/2)‖T − I/3‖²_F ~ χ²₅) of uniformity on S²."""
    n = d.shape[0]
    rayleigh = 3.0 * n * float(np.sum(d.mean(0) ** 2))
    T = d.T @ d / n
    bingham = 7.5 * n * float(np.sum((T - np.eye(3) / 3) ** 2))
    return float(stats.chi2.sf(rayleigh, 3)), float(stats.chi2.sf(bingham, 5))


def test_directions_uniform_and_biased_rejected():
    n = 20000
    pts = np.random.default_rng(0).normal(size=(n, 3)) * 20
    lines = random_lift(pts, fixed_key(3))
    d = np.asarray(lines.directions, np.float64)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    p_r, p_b = isotropy_pvalues(d)
    assert p_r > 1e-3 and p_b > 1e-3, (p_r, p_b)
    # the same statistics reject slightly biased samplers
    rng = np.random.default_rng(1)
    shifted = rng.normal(size=(n, 3)) + np.array([0.05, 0, 0])
    shifted /= np.linalg.norm(shifted, axis=1, keepdims=True)
    assert isotropy_pvalues(shifted)[0] < 1e-6
    squashed = rng.normal(size=(n, 3)) * np.array([1.0, 1.0, 1.1])
    squashed /= np.linalg.norm(squashed, axis=1, keepdims=True)
    assert isotropy_pvalues(squashed)[1] < 1e-6


def _points(n=300, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-30, 30, size=(n, 3))


@pytest.mark.parametrize("lift", LIFTS)
def test_points_on_lines_and_naive_decoders_fail(lift):
    pts = _points()
    with jax.enable_x64(True):
        lines = lift(jnp.asarray(pts), fixed_key(0))
        d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    assert d.dtype == np.float64
    dist = np.linalg.norm(np.cross(pts, d) - m, axis=1)
    assert dist.max() < 1e-6
    c = np.cross(d, m)  # closest point to the origin = start of the canonical segment
    for guess in (c, c + 0.5 * d):  # closest point, midpoint of the canonical unit segment
        err = np.linalg.norm(guess - pts, axis=1)
        assert np.median(err) > 5.0 and np.mean(err < 0.5) < 0.05


def test_default_lifts_differ_and_fixed_seed_reproduces():
    pts = _points(50)
    a, b = random_lift(pts), random_lift(pts)
    assert not np.allclose(np.asarray(a.directions), np.asarray(b.directions))
    for lift in (paired_lift, ray_lift, sphere_lift):
        pa, pb = lift(pts), lift(pts)
        assert not np.allclose(np.asarray(pa.directions), np.asarray(pb.directions)), lift.__name__
    k1, k2 = entropy_key(), entropy_key()
    assert not np.array_equal(np.asarray(jax.random.key_data(k1)), np.asarray(jax.random.key_data(k2)))
    np.testing.assert_array_equal(
        np.asarray(random_lift(pts, fixed_key(7)).directions), np.asarray(random_lift(pts, fixed_key(7)).directions)
    )


def test_paired_lift_structure():
    pts = _points(101)
    lines = paired_lift(pts, fixed_key(5))
    partner = pairing(101, jax.random.split(fixed_key(5), 3)[0])
    assert np.sum(partner < 0) == 1
    i = np.flatnonzero(partner >= 0)
    assert np.all(partner[partner[i]] == i)
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    # both points of a pair lie on line i (float32 here: tolerance relative to 30 m coordinates)
    j = partner[i]
    assert np.linalg.norm(np.cross(pts[j], d[i]) - m[i], axis=1).max() < 1e-4
    np.testing.assert_array_equal(d[i], d[j])
    np.testing.assert_array_equal(m[i], m[j])


def test_bad_points():
    with pytest.raises(ValueError, match="shape"):
        random_lift(np.zeros((4, 2)), fixed_key(0))
    with pytest.raises(ValueError, match="NaN"):
        paired_lift(np.full((4, 3), np.nan), fixed_key(0))
    for lift in (ray_lift, sphere_lift):
        with pytest.raises(ValueError, match="shape"):
            lift(np.zeros((4,)), fixed_key(0))
        with pytest.raises(ValueError, match="NaN"):
            lift(np.array([[0.0, 1.0, np.inf]]), fixed_key(0))
    with pytest.raises(ValueError, match="num_anchors"):
        ray_lift(np.zeros((4, 3)), fixed_key(0), num_anchors=0)


def test_plucker_helpers_against_numpy():
    rng = np.random.default_rng(2)
    p1, p2 = rng.normal(size=(2, 64, 3)) * 5
    u1, u2 = rng.normal(size=(2, 64, 3))
    u2[0] = u1[0]  # one parallel pair
    d1 = u1 / np.linalg.norm(u1, axis=1, keepdims=True)
    d2 = u2 / np.linalg.norm(u2, axis=1, keepdims=True)
    with jax.enable_x64(True):
        L1 = lines_from_points_directions(jnp.asarray(p1), jnp.asarray(u1))
        L2 = lines_from_points_directions(jnp.asarray(p2), jnp.asarray(u2))
        c1 = np.asarray(closest_point_to_origin(L1.directions, L1.moments))
        t1, t2 = (np.asarray(t) for t in closest_approach(jnp.asarray(p1), jnp.asarray(d1), jnp.asarray(p2), jnp.asarray(d2)))
        lld = np.asarray(line_line_distance(L1.directions, L1.moments, L2.directions, L2.moments))
        pld = np.asarray(point_line_distance(jnp.asarray(p2), L1.directions, L1.moments))
    np.testing.assert_allclose(c1, p1 - np.sum(p1 * d1, 1, keepdims=True) * d1, atol=1e-12)
    np.testing.assert_allclose(pld, np.linalg.norm(np.cross(p2 - p1, d1), axis=1), atol=1e-10)
    # closest approach by brute-force least squares on [d1, -d2] t = p2 - p1
    for k in range(1, 64):
        A = np.stack([d1[k], -d2[k]], 1)
        t = np.linalg.lstsq(A, p2[k] - p1[k], rcond=None)[0]
        np.testing.assert_allclose([t1[k], t2[k]], t, atol=1e-8)
        np.testing.assert_allclose(lld[k], np.linalg.norm(p1[k] + t[0] * d1[k] - p2[k] - t[1] * d2[k]), atol=1e-8)
    np.testing.assert_allclose(lld[0], np.linalg.norm(np.cross(p2[0] - p1[0], d1[0])), atol=1e-9)


@pytest.mark.parametrize("lift", LIFTS)
def test_repeated_points_share_one_line_and_the_attack_learns_nothing_more(lift):
    """Issue 15 item 5: a repeated point was lifted to distinct lines through it, and Line2Point
    recovered it to 8e-6 m. Copies now share one line; a cloud without copies lifts as before."""
    from privslam_jax.attacks.line2point import line2point

    rng = np.random.default_rng(0)
    base = rng.uniform(-20, 20, (300, 3))
    pts = np.concatenate([base, np.repeat(base[:5], 6, axis=0)])  # 5 points repeated 6 more times
    lines = lift(pts, fixed_key(1))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    for i in range(5):
        copies = np.flatnonzero((pts == base[i]).all(1))
        assert len(copies) == 7
        assert (d[copies] == d[copies[0]]).all() and (m[copies] == m[copies[0]]).all()
    # every line still passes through its point
    dist = point_line_distance(jnp.asarray(pts, jnp.float32), jnp.asarray(lines.directions, jnp.float32),
                               jnp.asarray(lines.moments, jnp.float32))
    assert np.asarray(dist).max() < 1e-3
    # unchanged for the distinct points: same lines as lifting the cloud without copies
    alone = lift(base, fixed_key(1))
    np.testing.assert_array_equal(np.asarray(alone.directions), d[:300])
    rec, _ = line2point(lines)
    err = np.linalg.norm(np.asarray(rec)[300:] - pts[300:], axis=1)
    assert np.median(err) > 0.01  # before the fix: ~1e-5 m for every repeated point


@pytest.mark.parametrize("lift", LIFTS)
@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3, 1e5, 1e7])
def test_lines_pass_through_their_points_at_any_scale_and_survive_the_ply(lift, scale, tmp_path):
    """Issue 15 item 4: float32 lifts of UTM-scale maps were off by metres, and their PLY unit
    segments collapsed to points at 1e7 m (the file could not be read back). Reference: the
    float64 point-to-line distance ``‖p × d − m‖`` for unit ``d``, relative to ``‖p‖``."""
    from privslam_jax.data.ply import load_line_cloud, read_ply, save_line_cloud

    rng = np.random.default_rng(int(np.log10(scale)) + 7)
    pts = scale * (1.0 + rng.random((400, 3)))  # float64, offset from the origin like map coordinates

    def rel(lines):
        d = np.asarray(lines.directions, np.float64)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        return (np.linalg.norm(np.cross(pts, d) - np.asarray(lines.moments, np.float64), axis=1)
                / np.linalg.norm(pts, axis=1)).max()

    lines = lift(pts, fixed_key(3))
    assert np.asarray(lines.directions).dtype == np.float64
    assert rel(lines) < 1e-12
    save_line_cloud(tmp_path / "l.ply", lines)
    assert read_ply(tmp_path / "l.ply")["vertex"]["x"].dtype == np.float64  # float64 in, float64 on disk
    back = load_line_cloud(tmp_path / "l.ply")
    assert np.asarray(back.directions).dtype == np.float64
    assert rel(back) < 1e-6
    # float32 input: float32 lines, still within float32 precision of their points
    lines32 = lift(pts.astype(np.float32), fixed_key(3))
    assert np.asarray(lines32.directions).dtype == np.float32
    pts32 = pts.astype(np.float32).astype(np.float64)
    d = np.asarray(lines32.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    assert (np.linalg.norm(np.cross(pts32, d) - np.asarray(lines32.moments, np.float64), axis=1)
            / np.linalg.norm(pts32, axis=1)).max() < 1e-6
    save_line_cloud(tmp_path / "l32.ply", lines32)  # readable at every scale (f8 on disk when far out)
    assert len(load_line_cloud(tmp_path / "l32.ply")) == len(pts)


def uniformity_pvalues(d: np.ndarray) -> list[float]:
    """p-values of six tests of ``d`` (unit rows) against the uniform distribution on S².

    Archimedes: every coordinate of a uniform unit vector is uniform on [−1, 1], so a
    Kolmogorov–Smirnov test per axis (x, y, z) against U(−1, 1); and its fourth moment is
    ``E[z⁴] = 1/5`` with ``Var[z⁴] = 1/9 − 1/25 = 16/225``, so a two-sided z-test of the sample mean
    of ``d_k⁴`` per axis. The second-moment tests of :func:`isotropy_pvalues` cannot see a sampler
    with cubic symmetry (normalised uniform-in-a-cube vectors have ``E[ddᵀ] = I/3`` exactly); these
    can (its ``E[z⁴]`` is 0.18), and the KS tests see a missing or extra polar cap."""
    n = d.shape[0]
    ks = [float(stats.kstest(d[:, k], "uniform", args=(-1.0, 2.0)).pvalue) for k in range(3)]
    z = (np.mean(d**4, axis=0) - 0.2) / np.sqrt(16.0 / 225.0 / n)
    return ks + [float(p) for p in 2.0 * stats.norm.sf(np.abs(z))]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_uniformity_tests_reject_cube_and_cap_samplers():
    """Power of :func:`uniformity_pvalues` at the sample size used below (fixed seeds)."""
    n = 50000
    rng = np.random.default_rng(1)
    assert min(uniformity_pvalues(_unit(rng.normal(size=(n, 3))))) > 1e-3  # the correct sampler passes
    cube = _unit(rng.uniform(-1.0, 1.0, (n, 3)))
    assert max(uniformity_pvalues(cube)[3:]) < 1e-20 and max(uniformity_pvalues(cube)[:3]) < 1e-20
    v = _unit(rng.normal(size=(2 * n, 3)))
    no_cap = v[v[:, 2] < np.cos(np.radians(20.0))][:n]  # a 20° cap around +z never drawn
    assert uniformity_pvalues(no_cap)[2] < 1e-20


def test_random_lift_directions_pass_the_uniformity_tests():
    """Reference: the uniform distribution on S² (:func:`uniformity_pvalues`); the fixed key's
    smallest p-value is 0.18, far above the 1e-3 threshold; a cube sampler gives < 1e-40."""
    n = 50000
    pts = np.random.default_rng(0).normal(size=(n, 3)) * 20
    d = np.asarray(random_lift(pts, fixed_key(3)).directions, np.float64)
    d = _unit(d)  # float32 output: renormalise before testing the distribution
    p = uniformity_pvalues(d)
    assert min(p) > 1e-3, p


def test_paired_lift_sign_is_balanced():
    """The direction of a pair's line must not reveal which point comes first, in index order or
    in the pairing's own order. Reference: the binomial distribution B(pairs, 1/2)
    (``scipy.stats.binomtest``); the pairs are read from the output (two points per identical line).
    With the sign fixed, every line points from the lower to the higher index (p ≈ 1e-301)."""
    n = 2001
    pts = np.random.default_rng(0).uniform(-30, 30, (n, 3))
    lines = paired_lift(pts, fixed_key(11))
    d, m = np.asarray(lines.directions, np.float64), np.asarray(lines.moments, np.float64)
    _, inverse, counts = np.unique(np.concatenate([d, m], 1), axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    assert sorted(np.bincount(counts)[1:].tolist()) == [1, 1000]  # 1000 pairs and the odd point out
    order = np.argsort(inverse, kind="stable")
    grouped = order[counts[inverse[order]] == 2].reshape(-1, 2)  # (lower index, higher index) of each pair
    lo, hi = grouped[:, 0], grouped[:, 1]
    assert np.all(lo < hi) and len(lo) == 1000
    forward = np.sum(d[lo] * (pts[hi] - pts[lo]), axis=1) > 0
    p_index = stats.binomtest(int(forward.sum()), len(lo), 0.5).pvalue
    assert p_index > 1e-3, (int(forward.sum()), p_index)
    # also balanced against the pairing order (first drawn → second drawn in the permutation)
    partner = pairing(n, jax.random.split(fixed_key(11), 3)[0])
    np.testing.assert_array_equal(partner[lo], hi)
    perm = np.asarray(jax.random.permutation(jax.random.split(fixed_key(11), 3)[0], n))
    a, b = perm[0 : n - 1 : 2], perm[1 : n - 1 : 2]
    k = int(np.sum(np.sum(d[a] * (pts[b] - pts[a]), axis=1) > 0))
    assert stats.binomtest(k, len(a), 0.5).pvalue > 1e-3, k


def _centre_of_each_line(d: np.ndarray, m: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(index, distance)`` of the centre nearest to each line (``‖c × d − m‖``, float64)."""
    dist = np.linalg.norm(np.cross(centres[None, :, :], d[:, None, :]) - m[:, None, :], axis=2)
    return dist.argmin(1), dist.min(1)


def test_ray_cloud_lines_meet_at_anchors_chosen_blind_to_position():
    """Ray clouds: every line passes through its point and, to float64 rounding, exactly one of the
    k-means anchors (``scipy.cluster.vq.kmeans2``).  The anchor a point gets must not say where it is:
    the counts per anchor pass a chi-square test of uniformity, and the share of points whose line goes
    through their *nearest* anchor is 1/k (``scipy.stats.binomtest``; a nearest-anchor rule gives
    1.0).  The sign of each direction (towards or away from the point) is a fair coin."""
    n, k = 4000, 8
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(c, 3.0, (n // 4, 3)) for c in ((0, 0, 0), (40, 0, 5), (0, 30, -5), (25, 25, 0))])
    key = fixed_key(2)
    lines = ray_lift(pts, key, num_anchors=k)
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    assert np.linalg.norm(np.cross(pts, d) - m, axis=1).max() < 1e-9
    anchors = ray_anchors(pts, k, jax.random.split(key, 3)[0])
    assert anchors.shape == (k, 3)
    which, dist = _centre_of_each_line(d, m, anchors)
    assert dist.max() < 1e-9
    counts = np.bincount(which, minlength=k)
    assert stats.chisquare(counts).pvalue > 1e-3, counts
    nearest = np.linalg.norm(pts[:, None] - anchors[None], axis=2).argmin(1)
    hits = int(np.sum(nearest == which))
    assert stats.binomtest(hits, n, 1 / k).pvalue > 1e-3, hits
    away = np.sum(d * (pts - anchors[which]), axis=1) > 0
    assert stats.binomtest(int(away.sum()), n, 0.5).pvalue > 1e-3
    # fewer distinct points than anchors: every point is its own anchor, lines still through the points
    few = pts[:3]
    small = ray_lift(few, key, num_anchors=k)
    assert np.linalg.norm(np.cross(few, np.asarray(small.directions)) - np.asarray(small.moments), axis=1).max() < 1e-9


def test_sphere_cloud_lines_meet_at_the_centroid_with_fair_signs():
    """Sphere clouds: every line passes through its point and the centroid of the distinct points; the
    direction's sign is a fair coin; a point on the centroid still gets a line through it."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(-20, 20, (3001, 3)) + np.array([100.0, -50.0, 3.0])
    c = pts.mean(0)
    lines = sphere_lift(pts, fixed_key(4))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    assert np.linalg.norm(np.cross(pts, d) - m, axis=1).max() < 1e-12 * np.abs(pts).max()
    assert np.linalg.norm(np.cross(c, d) - m, axis=1).max() < 1e-12 * np.abs(pts).max()
    away = np.sum(d * (pts - c), axis=1) > 0
    assert stats.binomtest(int(away.sum()), len(pts), 0.5).pvalue > 1e-3
    a, b = rng.normal(size=(2, 3))
    on_centre = np.stack([a, -a, b, -b, np.zeros(3)])  # centroid exactly the origin, where point 4 is
    lines = sphere_lift(on_centre, fixed_key(0))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.linalg.norm(np.cross(on_centre, d) - m, axis=1).max() < 1e-12


def test_axial_cloud_lines_meet_the_axis_at_a_right_angle_and_carry_only_height_and_bearing():
    """Axial clouds: line ``i`` passes through point ``i``, is perpendicular to ``up`` and meets the axis
    through the centroid along ``up`` (numpy closed forms); its sign is a fair coin; moving every point
    along its own line away from or towards the axis (a new distance per point) leaves the cloud's lines
    unchanged, so no attack on the lines can learn that distance; a point on the axis keeps a line."""
    rng = np.random.default_rng(2)
    up = np.array([0.1, -1.0, 0.05])
    u = up / np.linalg.norm(up)
    pts = rng.uniform(-20, 20, (2001, 3)) + np.array([50.0, 3.0, -7.0])
    c = pts.mean(0)
    lines = axial_lift(pts, up, fixed_key(5))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    scale = np.abs(pts).max()
    assert np.linalg.norm(np.cross(pts, d) - m, axis=1).max() < 1e-12 * scale
    assert np.abs(d @ u).max() < 1e-12  # perpendicular to the axis
    foot = c + ((pts - c) @ u)[:, None] * u  # the axis point at each point's height
    assert np.linalg.norm(np.cross(foot, d) - m, axis=1).max() < 1e-12 * scale
    away = np.sum(d * (pts - foot), axis=1) > 0
    assert stats.binomtest(int(away.sum()), len(pts), 0.5).pvalue > 1e-3
    # the same lines for points moved along their lines: pairs mirrored through the axis, each pair's
    # distance from the axis scaled by one factor in U(0.2, 3), keep the centroid and so the axis
    half = pts[:1000]
    foot_h = c + ((half - c) @ u)[:, None] * u
    mirrored = np.concatenate([half, 2 * foot_h - half])
    f = np.tile(rng.uniform(0.2, 3.0, 1000), 2)[:, None]
    feet = np.concatenate([foot_h, foot_h])
    a, b = (axial_lift(x, up, fixed_key(5)) for x in (mirrored, feet + f * (mirrored - feet)))
    np.testing.assert_allclose(np.asarray(b.directions), np.asarray(a.directions), atol=1e-12)
    np.testing.assert_allclose(np.asarray(b.moments), np.asarray(a.moments), atol=1e-12 * scale)
    on_axis = np.array([[0.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0], [0.0, 2.0, 0]])  # centroid (0, 0.5, 0): points 0 and 3 on the axis
    lines = axial_lift(on_axis, (0.0, 1.0, 0.0), fixed_key(0))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.linalg.norm(np.cross(on_axis, d) - m, axis=1).max() < 1e-12
