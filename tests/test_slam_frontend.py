"""SLAM front end: descriptor distances, projection search, stereo depth, ORB grid distribution."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from privslam_jax.slam.frontend import (
    Features,
    OrbConfig,
    extract_orb,
    hamming_pairs,
    knn2,
    match_descriptors,
    _sad_refine,
    rotation_consistent,
    search_by_projection,
    stereo_depths,
    to_gray_u8,
)


def _random_features(rng: np.random.Generator, n: int, w: float = 200.0, h: float = 100.0) -> Features:
    return Features(
        uv=rng.uniform([0, 0], [w, h], (n, 2)),
        octave=rng.integers(0, 3, n),
        angle=rng.uniform(0, 360, n),
        desc=rng.integers(0, 256, (n, 32), dtype=np.uint8),
    )


def test_hamming_pairs_matches_opencv():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    ref = [cv2.norm(a[i], b[i], cv2.NORM_HAMMING) for i in range(50)]
    np.testing.assert_array_equal(hamming_pairs(a, b), np.array(ref, np.int64))


def test_knn2_equals_numpy_brute_force_and_opencv_knn_match_with_ties():
    """Descriptors drawn from 12 distinct rows, so most distances tie: the two nearest ``b`` rows by a
    numpy popcount and a stable sort (ties to the lower index), and ``cv2.BFMatcher.knnMatch``'s."""
    rng = np.random.default_rng(3)
    pool = rng.integers(0, 256, (12, 32), dtype=np.uint8)
    a, b = pool[rng.integers(0, 12, 300)], pool[rng.integers(0, 12, 200)]
    dist, idx = knn2(a, b)
    d = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=-1).sum(-1)
    ref = np.argsort(d, axis=1, kind="stable")[:, :2]
    assert dist.shape == idx.shape == (300, 2) and (dist[:, 0] == dist[:, 1]).mean() > 0.5  # ties everywhere
    np.testing.assert_array_equal(idx, ref)
    np.testing.assert_array_equal(dist, np.take_along_axis(d, ref, axis=1))
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(a, b, k=2)
    np.testing.assert_array_equal(idx, [[m.trainIdx for m in ms] for ms in knn])


def test_match_descriptors_equals_brute_force_and_handles_no_match():
    rng = np.random.default_rng(5)
    fb = _random_features(rng, 80)
    src = rng.permutation(80)[:40]
    fa = _random_features(rng, 40)
    fa.desc[:] = fb.desc[src]
    fa.desc[:, 0] ^= rng.integers(0, 8, 40).astype(np.uint8)  # ≤ 3 flipped bits
    pairs = match_descriptors(fa, fb, ratio=0.8, max_dist=50, check_orientation=False)
    # numpy reference: nearest and second nearest, ratio + distance tests, one match per b keypoint
    d = np.unpackbits(fa.desc[:, None, :] ^ fb.desc[None, :, :], axis=-1).sum(-1)
    o = np.argsort(d, axis=1, kind="stable")
    best, d1, d2 = o[:, 0], d[np.arange(40), o[:, 0]], d[np.arange(40), o[:, 1]]
    ok = (d1 <= 50) & (d1 < 0.8 * d2)
    ref = {(i, int(best[i])) for i in np.flatnonzero(ok)
           if all(d1[j] > d1[i] or j >= i for j in np.flatnonzero(ok & (best == best[i])))}
    assert {tuple(p) for p in pairs.tolist()} == ref and len(ref) == 40
    # nothing passes the distance test (a keyframe pair with no match): empty, not an error
    none = match_descriptors(fa, fb, ratio=0.8, max_dist=-1)
    assert none.shape == (0, 2) and none.dtype == np.int64


def test_search_by_projection_equals_brute_force():
    rng = np.random.default_rng(1)
    feats = _random_features(rng, 300)
    m = 120
    src = rng.integers(0, 300, m)
    # queries near keypoints, descriptors a few bits away from theirs
    uv = feats.uv[src] + rng.normal(0, 2.0, (m, 2))
    desc = feats.desc[src].copy()
    flip = rng.integers(0, 32, (m, 3))
    for i in range(m):
        desc[i, flip[i]] ^= 1
    radius = np.full(m, 6.0)
    lo, hi = np.zeros(m, np.int64), np.full(m, 2, np.int64)
    kp, dist = search_by_projection(uv, desc, radius, feats, lo, hi, max_dist=100, ratio=0.8)
    # plain-numpy reference: best/second-best within the radius, then one point per keypoint
    best = np.full(m, -1)
    bestd = np.full(m, 10**6)
    for i in range(m):
        near = np.flatnonzero(np.linalg.norm(feats.uv - uv[i], axis=1) <= 6.0)
        if near.size == 0:
            continue
        d = np.array([cv2.norm(desc[i], feats.desc[j], cv2.NORM_HAMMING) for j in near])
        o = np.lexsort((near, d))
        second = d[o[1]] if near.size > 1 else 10**6
        if d[o[0]] <= 100 and d[o[0]] < 0.8 * second:
            best[i], bestd[i] = near[o[0]], d[o[0]]
    for j in np.unique(best[best >= 0]):
        owners = np.flatnonzero(best == j)
        keep = owners[np.lexsort((owners, bestd[owners]))[0]]
        best[owners[owners != keep]] = -1
    np.testing.assert_array_equal(kp, best)
    assert (kp == src).mean() > 0.8


def _three_maxima_keep(angle_a: np.ndarray, angle_b: np.ndarray, bins: int = 30) -> np.ndarray:
    """ORB-SLAM's ``ComputeThreeMaxima`` written as its loop: histogram of ``(a − b) mod 360`` in
    ``bins`` bins of 360/bins degrees; the three largest bins (strict ``>``: on ties the earlier
    bin), the second and third dropped when below 10 % of the largest; keep the matches in them."""
    rot = [(x - y) % 360.0 for x, y in zip(angle_a.tolist(), angle_b.tolist())]
    which = [min(int(r * bins / 360.0), bins - 1) for r in rot]
    hist = [which.count(k) for k in range(bins)]
    m1 = m2 = m3 = 0
    i1 = i2 = i3 = -1
    for k, c in enumerate(hist):
        if c > m1:
            m3, i3, m2, i2, m1, i1 = m2, i2, m1, i1, c, k
        elif c > m2:
            m3, i3, m2, i2 = m2, i2, c, k
        elif c > m3:
            m3, i3 = c, k
    if m2 < 0.1 * m1:
        i2 = i3 = -1
    elif m3 < 0.1 * m1:
        i3 = -1
    return np.array([w in (i1, i2, i3) for w in which])


def test_rotation_consistency_keeps_the_dominant_rotation():
    """Reference: :func:`_three_maxima_keep`. Inliers rotate by 30 ± 2° (all in bin 2, 24–36°); the
    20 outliers are uniform, so none of their bins reaches 10 % of the 180 inliers: exactly the
    inliers and the outliers that happen to fall in bin 2 are kept."""
    rng = np.random.default_rng(2)
    a = rng.uniform(0, 360, 200)
    b = np.mod(a - 30.0 + rng.uniform(-2, 2, 200), 360)
    b[:20] = rng.uniform(0, 360, 20)  # outliers
    keep = rotation_consistent(a, b)
    np.testing.assert_array_equal(keep, _three_maxima_keep(a, b))
    assert keep[20:].all()
    outlier_bin = (np.mod(a[:20] - b[:20], 360) // 12).astype(int)
    np.testing.assert_array_equal(keep[:20], outlier_bin == 2)
    assert keep[:20].sum() <= 2


def test_rotation_consistency_three_bins_and_the_ten_percent_rule():
    """Groups of 100, 20, 15 and 5 matches at 30°, 100°, 200°, 300° (bins 2, 8, 16 and 24–25): the three
    largest bins are kept; with the third group cut to 9 (< 10 % of 100) only two bins are kept,
    and a group of 9 in second place drops both smaller bins. Reference: :func:`_three_maxima_keep`."""
    rng = np.random.default_rng(3)
    for sizes, kept_groups in (((100, 20, 15, 5), (0, 1, 2)), ((100, 20, 9, 5), (0, 1)), ((100, 9, 5, 5), (0,))):
        groups = np.repeat(np.arange(4), sizes)
        a = rng.uniform(0, 360, len(groups))
        b = np.mod(a - np.array([30.0, 100.0, 200.0, 300.0])[groups] + rng.uniform(-3, 3, len(groups)), 360)
        keep = rotation_consistent(a, b)
        np.testing.assert_array_equal(keep, _three_maxima_keep(a, b))
        np.testing.assert_array_equal(keep, np.isin(groups, kept_groups))


def test_stereo_depth_of_a_shifted_texture():
    rng = np.random.default_rng(3)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (160, 400)).astype(np.float32), (0, 0), 1.5)
    left = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    disparity = 12.4  # sub-pixel shift of the whole image
    M = np.float32([[1, 0, -disparity], [0, 1, 0]])
    right = cv2.warpAffine(left, M, (400, 160), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    cfg = OrbConfig(n_features=500)
    fl, fr = extract_orb(left, cfg), extract_orb(right, cfg)
    fx, b = 400.0, 0.5
    z = stereo_depths(left, right, fl, fr, fx, b)
    ok = np.isfinite(z)
    assert ok.sum() > 0.3 * len(fl)
    d = fx * b / z[ok]
    assert np.median(np.abs(d - disparity)) < 0.25


def _sad_reference(left, right, ul, v, ur, half=5, span=5, zero_mean=False):
    """``_sad_refine`` as plain loops in float64, one keypoint and one shift at a time (patches minus
    their centre pixel, or minus their mean)."""
    h, w = left.shape
    out, good = ur.astype(np.float64).copy(), np.zeros(ul.size, bool)
    for i, (a, b, c) in enumerate(zip(ul, v, ur)):
        ui, vi, uri = (int(np.rint(x)) for x in (a, b, c))
        if not (half <= vi < h - half and half <= ui < w - half and half + span <= uri < w - half - span):
            continue
        lp = left[vi - half:vi + half + 1, ui - half:ui + half + 1].astype(np.float64)
        lp -= lp.mean() if zero_mean else lp[half, half]
        sad = []
        for s in range(-span, span + 1):
            rp = right[vi - half:vi + half + 1, uri + s - half:uri + s + half + 1].astype(np.float64)
            sad.append(np.abs(rp - (rp.mean() if zero_mean else rp[half, half]) - lp).sum())
        k = int(np.argmin(sad))
        delta = 0.0
        if 0 < k < 2 * span:
            den = 2.0 * (sad[k - 1] + sad[k + 1] - 2.0 * sad[k])
            delta = (sad[k - 1] - sad[k + 1]) / den if abs(den) > 1e-9 else 0.0
            good[i] = abs(delta) <= 1.0
        out[i] = uri + k - span + (delta if good[i] else 0.0)
    return out, good


@pytest.mark.parametrize("zero_mean, half, contrast", [(False, 5, False), (True, 5, False), (True, 5, True),
                                                     (True, 6, True)])
def test_sub_pixel_stereo_search_matches_a_plain_loop(zero_mean, half, contrast):
    """Against float64 loops; ``contrast``: black/white pixels, the extremes of the integer ranges
    (zero-mean 11×11 patches in int16, 13×13 in int32)."""
    rng = np.random.default_rng(4)
    left = cv2.GaussianBlur(rng.integers(0, 256, (60, 120)).astype(np.uint8), (0, 0), 1.0)
    if contrast:
        left = np.where(left > 127, 255, 0).astype(np.uint8)
    right = np.roll(left, -6, axis=1)
    n = 300  # in the middle, at the borders and outside
    ul, v = rng.uniform(-3, 123, n), rng.uniform(-3, 63, n)
    ur = ul - 6 + rng.uniform(-4, 4, n)
    out, good = _sad_refine(left, right, ul, v, ur, half=half, zero_mean=zero_mean)
    ref_out, ref_good = _sad_reference(left, right, ul, v, ur, half=half, zero_mean=zero_mean)
    np.testing.assert_array_equal(good, ref_good)
    assert 100 < good.sum() < n
    np.testing.assert_allclose(out, ref_out, rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="uint8"):
        stereo_depths(left.astype(np.float32), right, *(extract_orb(left, OrbConfig()),) * 2, 100.0, 0.5)


def test_zero_mean_sad_removes_the_disparity_bias_of_coarse_octaves():
    """A texture shifted by known sub-pixel amounts: the disparity error of the keypoints of pyramid
    levels ≥ 1 (the measured disparity minus the shift, minus the keypoint's rounding to the patch
    centre, which is zero-mean) averages 0.04-0.07 px short with ORB-SLAM's centre-pixel SAD and
    within 0.01 px of zero with zero-mean SAD; octave 0 is unbiased with both."""
    rng = np.random.default_rng(0)
    errors = {False: [], True: []}
    for shift in np.arange(10.0, 11.0, 0.125):
        tex = cv2.normalize(cv2.GaussianBlur(rng.uniform(0, 255, (240, 640)).astype(np.float32), (0, 0), 1.5),
                            None, 0, 255, cv2.NORM_MINMAX)
        right = cv2.warpAffine(tex, np.float32([[1, 0, -shift], [0, 1, 0]]), (640, 240), flags=cv2.INTER_CUBIC,
                               borderMode=cv2.BORDER_REFLECT)
        left, right = (np.clip(x + 0.5, 0, 255).astype(np.uint8) for x in (tex, right))
        fl, fr = extract_orb(left), extract_orb(right)
        for zero_mean in errors:
            z = stereo_depths(left, right, fl, fr, 400.0, 0.5, zero_mean=zero_mean)
            ok = np.isfinite(z) & (fl.octave >= 1)
            e = 200.0 / z[ok] - (fl.uv[ok, 0] - np.rint(fl.uv[ok, 0])) - shift
            errors[zero_mean].append(e[np.abs(e) < 1.0])
    centre, zero_mean = (np.concatenate(errors[k]) for k in (False, True))
    assert min(centre.size, zero_mean.size) > 5000
    assert centre.mean() < -0.02
    assert abs(zero_mean.mean()) < 0.01


def test_orb_grid_distribution_on_kitti(shared):
    path = shared / "data/kitti_odometry/sequences/seq1/image_0/000000.png"
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    cfg = OrbConfig()
    f = extract_orb(gray, cfg)
    assert 1800 <= len(f) <= cfg.n_features
    assert f.desc.shape == (len(f), 32) and f.desc.dtype == np.uint8
    assert set(np.unique(f.octave)) <= set(range(8)) and f.octave.max() >= 5
    # more of the image covered than OpenCV's plain ORB with the same budget
    plain = cv2.ORB_create(nfeatures=cfg.n_features, scaleFactor=1.2, nlevels=8).detect(gray, None)
    pts = np.array([k.pt for k in plain])

    def cells(uv: np.ndarray) -> int:
        return len({(int(u // 40), int(v // 40)) for u, v in uv})

    assert cells(f.uv) > cells(pts)


def test_bad_image_input():
    with pytest.raises(ValueError, match="image"):
        to_gray_u8(np.zeros((4, 4, 2), np.float32))
    with pytest.raises(ValueError, match="grey uint8"):
        extract_orb(np.zeros((10, 10), np.float32))
    assert to_gray_u8(np.full((5, 6, 3), 1.0, np.float32)).max() == 255


def test_ignore_mask_keeps_features_off_the_masked_region():
    rng = np.random.default_rng(7)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (192, 400)).astype(np.float32), (0, 0), 1.2)
    gray = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    cfg = OrbConfig(n_features=800)
    plain = extract_orb(gray, cfg)
    # an all-False mask is no mask
    same = extract_orb(gray, cfg, np.zeros(gray.shape, bool))
    np.testing.assert_array_equal(same.uv, plain.uv)
    np.testing.assert_array_equal(same.desc, plain.desc)
    ignore = np.zeros(gray.shape, bool)
    ignore[:, 150:300] = True
    masked = extract_orb(gray, cfg, ignore)
    assert ((plain.uv[:, 0] > 160) & (plain.uv[:, 0] < 290)).sum() > 100  # the region has features
    # OpenCV rescales the mask to each pyramid level: allow a few pixels at the border
    inside = (masked.uv[:, 0] > 150 + 4) & (masked.uv[:, 0] < 300 - 4)
    assert inside.sum() == 0, masked.uv[inside]
    assert len(masked) > 0.5 * len(plain)
    with pytest.raises(ValueError, match="ignore mask shape"):
        extract_orb(gray, cfg, ignore[:, :10])


def test_run_slam_needs_a_mask_per_frame():
    from privslam_jax.slam.system import SlamConfig, run_slam
    from privslam_jax.types import Camera

    cam = Camera(fx=100.0, fy=100.0, cx=50.0, cy=40.0, width=100, height=80)
    frames = [np.zeros((80, 100), np.uint8)] * 2
    with pytest.raises(ValueError, match="fewer masks than frames"):
        run_slam(frames, cam, SlamConfig(mode="mono"), ignore=[])


def test_far_stereo_keypoints_can_be_kept_monocular():
    """``SlamConfig.stereo_max_depth_baselines``: the frame's depths are :func:`stereo_depths`'s
    with every depth of that many baselines or more dropped (the shifted texture sits at
    400·0.5/12.4 = 16.1 m = 32.3 baselines); ``inf`` (default) keeps them all."""
    from privslam_jax.slam.system import Slam, SlamConfig
    from privslam_jax.types import Camera

    rng = np.random.default_rng(3)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (160, 400)).astype(np.float32), (0, 0), 1.5)
    left = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    right = cv2.warpAffine(left, np.float32([[1, 0, -12.4], [0, 1, 0]]), (400, 160), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
    cam = Camera(fx=400.0, fy=400.0, cx=199.5, cy=79.5, width=400, height=160, baseline=0.5)
    ref = stereo_depths(left, right, extract_orb(left), extract_orb(right), cam.fx, 0.5, zero_mean=True)
    assert np.isfinite(ref).sum() > 50 and np.nanmax(ref) < 40 * 0.5 <= np.nanmax(ref) * 1.3
    default, _ = Slam(cam, SlamConfig(mode="stereo")).features(0, left, right)
    np.testing.assert_array_equal(default.feats.depth, ref)  # zero-mean SAD by default
    centre, _ = Slam(cam, SlamConfig(mode="stereo", stereo_zero_mean_sad=False)).features(0, left, right)
    np.testing.assert_array_equal(centre.feats.depth, stereo_depths(left, right, extract_orb(left), extract_orb(right),
                                                                    cam.fx, 0.5, zero_mean=False))
    for limit in (math.inf, 40.0, 32.0, 20.0):
        frame, _ = Slam(cam, SlamConfig(mode="stereo", stereo_max_depth_baselines=limit)).features(0, left, right)
        np.testing.assert_array_equal(frame.feats.depth, np.where(ref >= limit * 0.5, np.nan, ref))
    with pytest.raises(ValueError, match="stereo_max_depth_baselines"):
        SlamConfig(stereo_max_depth_baselines=0.0)
