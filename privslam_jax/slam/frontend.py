"""SLAM front end: grid-distributed ORB features, stereo/depth association and descriptor matching.

Host-side numpy/OpenCV code (feature extraction and matching are not differentiable and not
jitted).  Follows ORB-SLAM3 (Campos et al., T-RO 2021; ``ORBextractor.cc``, ``ORBmatcher.cc``):

* **Extraction**: OpenCV ORB (FAST-9 + Harris ranking, 8 levels, scale 1.2, rBRIEF) detects
  ``oversample × n_features`` candidates; a grid then keeps them round-robin over cells by
  Harris response (rank inside the cell first, response second), so texture-poor cells keep their
  best corners instead of losing them to a few textured ones — the effect of ORB-SLAM's
  per-cell FAST and quadtree distribution, done with one OpenCV call.
* **Matching**: Hamming distance; Lowe's ratio test; ORB-SLAM's rotation-consistency check
  (30-bin histogram of keypoint-angle differences, keep the three largest bins).
* **Projection search** (``SearchByProjection``): every projected map point looks for keypoints
  within a radius that grows with the predicted pyramid level, in a window of octaves; best and
  second-best Hamming distances give the ratio test; each keypoint keeps its best point.
* **Stereo** (``ComputeStereoMatches``): left/right keypoints matched along the row band
  (±2·scale^octave), then a sub-pixel SAD search on 11×11 patches with a parabola fit.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "OrbConfig",
    "Features",
    "to_gray_u8",
    "extract_orb",
    "hamming_pairs",
    "knn2",
    "match_descriptors",
    "ratio_matches",
    "rotation_consistent",
    "search_by_projection",
    "stereo_depths",
    "rgbd_depths",
]

TH_HIGH = 100
"""ORB-SLAM's loose Hamming threshold (of 256 bits)."""
TH_LOW = 50
"""ORB-SLAM's strict Hamming threshold."""


@dataclasses.dataclass(frozen=True)
class OrbConfig:
    """ORB extraction settings (ORB-SLAM3 KITTI defaults)."""

    n_features: int = 2000
    """Features kept per image after grid distribution."""
    n_levels: int = 8
    """Pyramid levels."""
    scale_factor: float = 1.2
    """Scale between pyramid levels."""
    fast_threshold: int = 12
    """FAST threshold of the detector (OpenCV ORB); ORB-SLAM uses 20 with a fallback of 7."""
    oversample: float = 2.0
    """Detect ``oversample × n_features`` candidates before grid selection."""
    cell_size: int = 40
    """Grid cell size in level-0 pixels for the distribution."""
    edge_threshold: int = 19
    """Border without features (ORB-SLAM's ``EDGE_THRESHOLD``)."""


@dataclasses.dataclass
class Features:
    """Keypoints and descriptors of one image (numpy, host side)."""

    uv: np.ndarray
    """``(N, 2)`` float64 keypoint pixels at level 0."""
    octave: np.ndarray
    """``(N,)`` int pyramid level."""
    angle: np.ndarray
    """``(N,)`` float orientation in degrees."""
    desc: np.ndarray
    """``(N, 32)`` uint8 rBRIEF descriptors."""
    depth: np.ndarray | None = None
    """``(N,)`` float z-depth (stereo/RGB-D), ``nan`` where unknown."""
    _tree: cKDTree | None = dataclasses.field(default=None, repr=False)

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    @property
    def tree(self) -> cKDTree:
        """A k-d tree over ``uv`` (built once)."""
        if self._tree is None:
            self._tree = cKDTree(self.uv if len(self) else np.zeros((0, 2)))
        return self._tree

    def subset(self, idx: np.ndarray) -> "Features":
        """The features at ``idx``."""
        return Features(
            self.uv[idx], self.octave[idx], self.angle[idx], self.desc[idx],
            None if self.depth is None else self.depth[idx],
        )


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """Grey uint8 image from HW / HWC (RGB, or RGBA whose alpha is dropped) uint8, uint16 or float ``[0, 1]``.

    Other dtypes and out-of-range floats are refused (:func:`privslam_jax.data.images.as_unit_image`).
    """
    from privslam_jax.data.images import as_unit_image, like_input

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., :3]
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim != 2 and img.shape[-1:] != (3,):
        raise ValueError(f"image must be HW or HWC with 1, 3 or 4 channels, got shape {np.shape(image)}")
    if img.dtype != np.uint8:
        img = like_input(as_unit_image(img, "SLAM input image"), np.zeros(0, np.uint8))
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img)


_ORB_CACHE: dict[OrbConfig, "cv2.ORB"] = {}


def _orb(config: OrbConfig) -> "cv2.ORB":
    if config not in _ORB_CACHE:
        _ORB_CACHE[config] = cv2.ORB_create(
            nfeatures=int(config.n_features * config.oversample),
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            edgeThreshold=config.edge_threshold,
            patchSize=31,
            fastThreshold=config.fast_threshold,
        )
    return _ORB_CACHE[config]


def _empty_features() -> Features:
    return Features(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 32), np.uint8))


def extract_orb(gray: np.ndarray, config: OrbConfig = OrbConfig(), ignore: np.ndarray | None = None) -> Features:
    """Grid-distributed ORB keypoints and descriptors of a grey uint8 image.

    Candidates are ranked inside their ``cell_size`` grid cell by Harris response; the kept set is
    the first ``n_features`` in the order (rank in cell, −response), i.e. round-robin over cells.
    ``ignore`` (``(H, W)`` bool, True = no keypoint here, e.g. the filled-in regions of a privacy
    filter) goes to OpenCV's detector as its mask (``mask = ~ignore``, rescaled per pyramid level).
    """
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"extract_orb needs a grey uint8 HW image, got {gray.dtype} {gray.shape}")
    mask = None
    if ignore is not None:
        if ignore.shape != gray.shape:
            raise ValueError(f"ignore mask shape {ignore.shape} != image shape {gray.shape}")
        mask = np.where(np.asarray(ignore, bool), 0, 255).astype(np.uint8)
    orb = _orb(config)
    kps = orb.detect(gray, mask)
    if not kps:
        return _empty_features()
    pts = np.array([k.pt for k in kps], np.float64)
    resp = np.array([k.response for k in kps], np.float64)
    cells_x = max(1, int(np.ceil(gray.shape[1] / config.cell_size)))
    cell = (pts[:, 1] // config.cell_size).astype(np.int64) * cells_x + (pts[:, 0] // config.cell_size).astype(np.int64)
    order = np.lexsort((-resp, cell))  # by cell, best response first
    cell_sorted = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(cell_sorted)) + 1]
    rank = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    rank_of = np.empty(len(order), np.int64)
    rank_of[order] = rank
    keep = np.lexsort((-resp, rank_of))[: config.n_features]
    keep.sort()
    kps_kept = [kps[i] for i in keep]
    kps_kept, desc = orb.compute(gray, kps_kept)
    if desc is None or not kps_kept:
        return _empty_features()
    return Features(
        uv=np.array([k.pt for k in kps_kept], np.float64),
        octave=np.array([k.octave for k in kps_kept], np.int64),
        angle=np.array([k.angle for k in kps_kept], np.float64),
        desc=np.ascontiguousarray(desc, dtype=np.uint8),
    )


def hamming_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances between ``(P, 32)`` uint8 descriptor arrays."""
    x = np.bitwise_xor(np.ascontiguousarray(a).view(np.uint64), np.ascontiguousarray(b).view(np.uint64))
    return np.bitwise_count(x).sum(axis=1).astype(np.int64)


def rotation_consistent(angle_a: np.ndarray, angle_b: np.ndarray, bins: int = 30) -> np.ndarray:
    """ORB-SLAM's orientation check: keep matches in the 3 most populated angle-difference bins.

    A bin is kept only if it holds at least 10 % of the largest (``ComputeThreeMaxima``).
    """
    if angle_a.size == 0:
        return np.zeros(0, bool)
    rot = np.mod(angle_a - angle_b, 360.0)
    b = np.minimum((rot * bins / 360.0).astype(np.int64), bins - 1)
    hist = np.bincount(b, minlength=bins)
    top = np.argsort(-hist, kind="stable")[:3]
    top = top[hist[top] >= 0.1 * hist[top[0]]]
    return np.isin(b, top)


def knn2(desc_a: np.ndarray, desc_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two nearest ``b`` rows of every ``a`` row by Hamming distance: ``(dist, idx)``, both
    ``(len(a), 2)`` int32, nearest first, ties to the lower ``b`` index (OpenCV's ``batchDistance``,
    the kernel of ``cv2.BFMatcher.knnMatch``; without its per-match Python objects).  Needs
    ``len(b) >= 2``."""
    return cv2.batchDistance(np.ascontiguousarray(desc_a), np.ascontiguousarray(desc_b), cv2.CV_32S,
                             normType=cv2.NORM_HAMMING, K=2)


def ratio_matches(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8, max_dist: int = TH_LOW) -> np.ndarray:
    """Brute-force Hamming matches ``a → b`` that pass ``max_dist`` and Lowe's ratio test, one per ``b`` row
    (the closest); ``(M, 2)`` int index pairs ``(i_a, i_b)``, in no particular order."""
    if len(desc_a) == 0 or len(desc_b) < 2:
        return np.zeros((0, 2), np.int64)
    dist, idx = knn2(desc_a, desc_b)
    d1, d2 = dist[:, 0], dist[:, 1]
    ok = (d1 <= max_dist) & (d1 < ratio * d2)
    q, t, d1 = np.flatnonzero(ok), idx[ok, 0].astype(np.int64), d1[ok]
    # one match per b row: keep the smallest distance
    order = np.lexsort((d1, t))
    first = np.r_[True, np.diff(t[order]) != 0] if len(order) else np.zeros(0, bool)
    sel = order[first]
    return np.stack([q[sel], t[sel]], axis=1).reshape(-1, 2)


def match_descriptors(
    fa: Features,
    fb: Features,
    ratio: float = 0.8,
    max_dist: int = TH_LOW,
    check_orientation: bool = True,
    mask_a: np.ndarray | None = None,
    mask_b: np.ndarray | None = None,
) -> np.ndarray:
    """Brute-force Hamming matching ``a → b`` with ratio test, mutual uniqueness and orientation check.

    Returns ``(M, 2)`` int index pairs ``(i_a, i_b)``.  ``mask_a``/``mask_b`` restrict the
    candidates (boolean per keypoint).
    """
    ia = np.flatnonzero(mask_a) if mask_a is not None else np.arange(len(fa))
    ib = np.flatnonzero(mask_b) if mask_b is not None else np.arange(len(fb))
    pairs = ratio_matches(fa.desc[ia], fb.desc[ib], ratio, max_dist)
    pairs = np.stack([ia[pairs[:, 0]], ib[pairs[:, 1]]], axis=1)
    if check_orientation and len(pairs):
        pairs = pairs[rotation_consistent(fa.angle[pairs[:, 0]], fb.angle[pairs[:, 1]])]
    return pairs[np.argsort(pairs[:, 0], kind="stable")]


def search_by_projection(
    uv: np.ndarray,
    desc: np.ndarray,
    radius: np.ndarray,
    feats: Features,
    octave_lo: np.ndarray | None = None,
    octave_hi: np.ndarray | None = None,
    max_dist: int = TH_HIGH,
    ratio: float = 0.8,
    available: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Match projected map points to keypoints in a window (ORB-SLAM ``SearchByProjection``).

    Args:
        uv: ``(M, 2)`` predicted pixels of the map points.
        desc: ``(M, 32)`` their descriptors.
        radius: ``(M,)`` search radius in pixels.
        feats: keypoints of the frame.
        octave_lo, octave_hi: ``(M,)`` allowed keypoint octaves (inclusive), or ``None``.
        max_dist: Hamming threshold.
        ratio: best/second-best ratio (applied when both candidates exist).
        available: ``(N,)`` bool, keypoints that may be matched (e.g. not yet matched).

    Returns:
        ``(kp_index (M,), distance (M,))``, ``-1`` where no match.
    """
    m = uv.shape[0]
    out = np.full(m, -1, np.int64)
    dist = np.full(m, 10**6, np.int64)
    if m == 0 or len(feats) == 0:
        return out, dist
    res = feats.tree.query_ball_point(uv, r=radius, return_sorted=False)
    lens = np.fromiter((len(r) for r in res), np.int64, count=m)
    if lens.sum() == 0:
        return out, dist
    qi = np.repeat(np.arange(m), lens)
    ki = np.fromiter((k for r in res for k in r), np.int64, count=int(lens.sum()))
    ok = np.ones(qi.size, bool)
    if available is not None:
        ok &= available[ki]
    if octave_lo is not None:
        ok &= feats.octave[ki] >= octave_lo[qi]
    if octave_hi is not None:
        ok &= feats.octave[ki] <= octave_hi[qi]
    qi, ki = qi[ok], ki[ok]
    if qi.size == 0:
        return out, dist
    d = hamming_pairs(desc[qi], feats.desc[ki])
    order = np.lexsort((d, qi))
    qi, ki, d = qi[order], ki[order], d[order]
    first = np.r_[True, qi[1:] != qi[:-1]]
    best = np.flatnonzero(first)
    has_second = np.r_[best[1:], qi.size] - best > 1
    second_d = np.where(has_second, d[np.minimum(best + 1, qi.size - 1)], 10**6)
    good = (d[best] <= max_dist) & (d[best] < ratio * second_d)
    best = best[good]
    if best.size == 0:
        return out, dist
    q, k, dd = qi[best], ki[best], d[best]
    # a keypoint keeps the point with the smallest distance
    order = np.lexsort((dd, k))
    keep = order[np.r_[True, k[order][1:] != k[order][:-1]]]
    out[q[keep]] = k[keep]
    dist[q[keep]] = dd[keep]
    return out, dist


def _sad_refine(left: np.ndarray, right: np.ndarray, ul: np.ndarray, v: np.ndarray, ur: np.ndarray,
                half: int = 5, span: int = 5, zero_mean: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel right ``u`` by SAD over ``(2·half+1)²`` patches at offsets ``±span`` + parabola.

    Each patch is compared minus its centre pixel (ORB-SLAM's ``IL - IL.at(w, w)``) or, with
    ``zero_mean``, minus its mean.  Centre-pixel SAD is biased when the feature is not centred in
    the patch, which is where keypoints of pyramid levels ≥ 1 sit (their level-0 position ``x_k·s``
    is off the feature by about ``(s − 1)/2``): on a texture shifted by a known sub-pixel amount the
    disparities of octaves 1-3 come out 0.04-0.07 px short (depth too large), octave 0's unbiased;
    zero-mean SAD leaves every octave unbiased (``tests/test_slam_frontend.py``).
    Patches are read through a strided window view of the images (no index grid per pixel) and
    compared in integers: centre-pixel patches as they are, zero-mean patches scaled by the pixel
    count ``P`` (``P·x − Σx``; int16 up to 11×11), absolute differences summed exactly (at most
    ``P²·510`` < 2²⁴), so the float32 SADs are exact, bit for bit on every machine."""
    h, w = left.shape
    n = ul.size
    ui, vi, uri = np.rint(ul).astype(np.int64), np.rint(v).astype(np.int64), np.rint(ur).astype(np.int64)
    ok = (vi - half >= 0) & (vi + half < h) & (ui - half >= 0) & (ui + half < w)
    ok &= (uri - half - span >= 0) & (uri + half + span < w)
    out = ur.astype(np.float64).copy()
    if not ok.any():
        return out, ok
    idx = np.flatnonzero(ok)
    size = 2 * half + 1
    left_windows = np.lib.stride_tricks.sliding_window_view(left, (size, size))  # [y, x] = patch at (y, x)
    right_windows = np.lib.stride_tricks.sliding_window_view(right, (size, size))
    shifts = np.arange(-span, span + 1)
    # int16 holds centre-pixel differences (±255) and, up to 11×11 patches, the scaled zero-mean
    # values P·x − Σx (|·| ≤ P·255 < 2¹⁵); larger zero-mean patches need int32
    wide = zero_mean and size * size * 255 >= 2 ** 15
    dtype = np.int32 if wide else np.int16
    lp = left_windows[vi[idx] - half, ui[idx] - half].astype(dtype)  # (n, P, P)
    rp = right_windows[vi[idx, None] - half, uri[idx, None] + shifts[None, :] - half].astype(dtype)  # (n, S, P, P)
    if zero_mean:
        lp = size * size * lp - lp.sum(axis=(1, 2), keepdims=True, dtype=dtype)
        rp = size * size * rp - rp.sum(axis=(2, 3), keepdims=True, dtype=dtype)
    else:
        lp = lp - lp[:, half:half + 1, half:half + 1]
        rp = rp - rp[:, :, half:half + 1, half:half + 1]
    lq = lp[:, None]
    if zero_mean and not wide:  # |a − b| ≤ 2·P·255 < 2¹⁶: max − min, wrapped in int16, read as uint16
        diff = (np.maximum(rp, lq) - np.minimum(rp, lq)).view(np.uint16)
    else:
        diff = np.abs(rp - lq)
    sad = diff.sum(axis=(2, 3), dtype=np.int32).astype(np.float32)  # (n, S)
    b = np.argmin(sad, axis=1)
    inner = (b > 0) & (b < 2 * span)
    bc = np.clip(b, 1, 2 * span - 1)
    d1, d2, d3 = sad[np.arange(idx.size), bc - 1], sad[np.arange(idx.size), bc], sad[np.arange(idx.size), bc + 1]
    den = 2.0 * (d1 + d3 - 2.0 * d2)
    delta = np.where(np.abs(den) > 1e-9, (d1 - d3) / np.where(np.abs(den) > 1e-9, den, 1.0), 0.0)
    inner &= np.abs(delta) <= 1.0
    out[idx] = uri[idx] + shifts[b] + np.where(inner, delta, 0.0)
    good = np.zeros(n, bool)
    good[idx] = inner
    return out, good


def stereo_depths(
    left: np.ndarray, right: np.ndarray, fl: Features, fr: Features, fx: float, baseline: float,
    scale_factor: float = 1.2, zero_mean: bool = False,
) -> np.ndarray:
    """Depth of each left keypoint from a rectified right image (``nan`` where unmatched);
    ``left``/``right``: uint8 grey images.

    Candidates: right keypoints within ±2·scale^octave rows, octave ±1, ``u_r ∈ (u_l − fx, u_l]``;
    the best Hamming distance must be ≤ (TH_HIGH+TH_LOW)/2; then an 11×11 SAD search over ±5 px
    with a parabola fit gives sub-pixel ``u_r`` (matches whose SAD minimum lies on the search
    border are dropped; ``zero_mean``: patches minus their mean instead of their centre pixel,
    :func:`_sad_refine`).  Departure: SAD on level 0, not on the keypoint's pyramid level.
    """
    if left.dtype != np.uint8 or right.dtype != np.uint8 or left.shape != right.shape or left.ndim != 2:
        raise ValueError(f"stereo_depths takes two uint8 grey images of one size, got {left.dtype} {left.shape} "
                         f"and {right.dtype} {right.shape}")
    n = len(fl)
    depth = np.full(n, np.nan)
    if n == 0 or len(fr) == 0:
        return depth
    # candidate pairs by row band: use the k-d tree on (u, v·big) is awkward; bucket by row instead
    rows = np.rint(fr.uv[:, 1]).astype(np.int64)
    order = np.argsort(rows, kind="stable")
    rs = rows[order]
    band = np.ceil(2.0 * scale_factor ** fl.octave).astype(np.int64)
    lo = np.searchsorted(rs, np.rint(fl.uv[:, 1]).astype(np.int64) - band, "left")
    hi = np.searchsorted(rs, np.rint(fl.uv[:, 1]).astype(np.int64) + band, "right")
    lens = hi - lo
    qi = np.repeat(np.arange(n), lens)
    ki = order[np.repeat(lo - np.cumsum(lens) + lens, lens) + np.arange(lens.sum())]  # order[lo_q .. hi_q) per q
    disp = fl.uv[qi, 0] - fr.uv[ki, 0]
    ok = (disp >= 0) & (disp < fx) & (np.abs(fl.octave[qi] - fr.octave[ki]) <= 1)
    qi, ki = qi[ok], ki[ok]
    if qi.size == 0:
        return depth
    d = hamming_pairs(fl.desc[qi], fr.desc[ki])
    order = np.lexsort((d, qi))
    qi, ki, d = qi[order], ki[order], d[order]
    first = np.r_[True, qi[1:] != qi[:-1]]
    sel = first & (d <= (TH_HIGH + TH_LOW) // 2)
    q, k = qi[sel], ki[sel]
    ur, good = _sad_refine(left, right, fl.uv[q, 0], fl.uv[q, 1], fr.uv[k, 0], zero_mean=zero_mean)
    disp = fl.uv[q, 0] - ur
    good &= disp > 0.5
    if good.sum() == 0:
        return depth
    depth[q[good]] = fx * baseline / disp[good]
    return depth


def rgbd_depths(depth_image: np.ndarray, feats: Features, max_depth: float = np.inf) -> np.ndarray:
    """Depth at each keypoint (nearest pixel) from a z-depth image; ``nan`` where invalid."""
    h, w = depth_image.shape[:2]
    u = np.clip(np.rint(feats.uv[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(feats.uv[:, 1]).astype(np.int64), 0, h - 1)
    z = np.asarray(depth_image, np.float64)[v, u]
    return np.where(np.isfinite(z) & (z > 0) & (z < max_depth), z, np.nan)
