"""Two-peak finding (TPF): the density attack on paired-point lifting (Lee et al., CVPR 2023).

A paired lift (:func:`~privslam_jax.privacy.lift.paired_lift`) publishes one line through two points,
twice (the two points of a pair get bit-identical lines, so the pairs are visible).  Line2Point looks
for one density peak per line and can return at most one of the two points; Lee et al. attack their
own lifting with the two highest peaks instead (``estimate_all_pts_two_peaks`` / ``get_peak_kde`` in
``utils/l2precon/calculate.py`` of github.com/Fusroda-h/ppl):

1. **Neighbours**: the ``k = int(min(1000, 0.05·N))`` nearest lines of line ``i`` by Line2Point's
   line–line distance (:mod:`~privslam_jax.attacks.line2point`), without the lines parallel to line
   ``i`` — itself and its pair's copy, whose closest approach is undefined (the authors drop the one
   nearest line, which is one of the two).
2. **Offsets**: the offset along line ``i`` of the closest approach to each neighbour (Line2Point's
   estimate, authors' ``1e-6`` guards).
3. **Two peaks**: a Gaussian kernel density estimate of the offsets with scipy's scalar bandwidth
   factor 0.07 (``gaussian_kde(bw_method=0.07)``: ``h = 0.07 · std``), evaluated on a grid; its two
   highest local maxima are the two estimates (one maximum: it twice; none: the median twice).
   **Departures (deliberate):** the density is binned (2,048 bins over the offsets' range, then a
   Gaussian filter: the same curve to within the bin width, ``O(k + bins)`` per line instead of
   ``O(k · grid)``); the authors' grid ``[−10, 0.75 · max distance]`` is measured from the *true* first
   point (their anchor), as is their ordering of the two peaks by ``|offset|``, which tells the attack
   which peak belongs to the first point.  Here lines are anchored at their closest point to the origin,
   as in Line2Point, and nothing says which peak is whose.

**Which point gets which peak.** The authors score TPF with a *swap ratio*: the share of pairs
whose two estimates are handed to the wrong points.  :func:`two_peak_attack` returns both peaks
of every line; :func:`assign_pairs` hands them out by a rule: ``"oracle"`` (each pair the assignment
with the smaller total error: swap ratio 0, an upper bound no attacker reaches without the truth),
``"random"`` (a fair coin per pair: swap ratio ½, what an attacker without side information gets).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from jaxtyping import Float, Int
from scipy.ndimage import gaussian_filter1d
from scipy.signal import find_peaks

from privslam_jax.attacks._host import host_lines
from privslam_jax.types import LineCloud

__all__ = ["TwoPeakResult", "assign_pairs", "line_pairs", "two_peak_attack", "two_peaks"]

_EPS = 1e-6  # the authors' ``10e-7``


@dataclass(frozen=True)
class TwoPeakResult:
    """Both estimates of every line: ``first`` at the higher density peak, ``second`` at the other."""

    first: Float[np.ndarray, "N 3"]
    second: Float[np.ndarray, "N 3"]
    partner: Int[np.ndarray, " N"]
    """The other line of a pair (bit-identical line), ``-1`` for a line that is not paired."""


def two_peaks(offsets: Float[np.ndarray, " K"], bandwidth: float = 0.07, bins: int = 2048) -> tuple[float, float]:
    """The two highest local maxima of a Gaussian KDE of ``offsets`` (bandwidth ``bandwidth · std``),
    higher first; one maximum: it twice; a degenerate sample (fewer than 2 values or zero spread): the
    median twice.  Binned on ``bins`` bins over the offsets' range (module docstring)."""
    t = np.asarray(offsets, np.float64)
    t = t[np.isfinite(t)]
    if len(t) < 2 or not np.ptp(t) > 0:
        m = float(np.median(t)) if len(t) else 0.0
        return m, m
    h = bandwidth * float(np.std(t, ddof=1))
    lo, hi = float(t.min()) - 3 * h, float(t.max()) + 3 * h
    width = (hi - lo) / bins
    counts = np.bincount(np.minimum(((t - lo) / width).astype(np.int64), bins - 1), minlength=bins).astype(np.float64)
    density = gaussian_filter1d(counts, h / width, mode="constant")
    peaks, _ = find_peaks(density)
    if len(peaks) == 0:
        m = float(np.median(t))
        return m, m
    top = peaks[np.argsort(density[peaks], kind="stable")[::-1][:2]]
    centres = lo + (top + 0.5) * width
    return float(centres[0]), float(centres[-1])


def line_pairs(lines: LineCloud) -> Int[np.ndarray, " N"]:
    """``partner[i]``: the other line bit-identical to line ``i`` (a pair of a paired lift), or ``-1``."""
    key = np.concatenate([np.asarray(lines.directions), np.asarray(lines.moments)], axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    partner = np.full(len(key), -1, np.int64)
    order = np.argsort(inverse, kind="stable")
    grouped = order[counts[inverse[order]] == 2].reshape(-1, 2)
    partner[grouped[:, 0]], partner[grouped[:, 1]] = grouped[:, 1], grouped[:, 0]
    return partner


def two_peak_attack(
    lines: LineCloud, *, max_neighbours: int = 1000, neighbour_fraction: float = 0.05, bandwidth: float = 0.07,
    chunk_size: int = 128, progress: bool = False,
) -> TwoPeakResult:
    """TPF on a line cloud (module docstring): both density peaks of every line.  Host numpy,
    ``O(N²)`` time, ``O(chunk_size · N)`` memory."""
    a, d = host_lines(lines, 3)
    n = len(d)
    k = max(1, min(n - 2, int(min(max_neighbours, neighbour_fraction * n))))
    t1, t2 = np.zeros(n), np.zeros(n)
    starts = range(0, n, chunk_size)
    if progress:
        from tqdm import tqdm

        starts = tqdm(starts, desc="two-peak attack", unit="block")
    for s in starts:
        rows = np.arange(s, min(s + chunk_size, n))
        c = np.cross(d[rows, None, :], d[None, :, :])  # (r, N, 3)
        cn = np.linalg.norm(c, axis=2, keepdims=True)
        diff = a[None, :, :] - a[rows, None, :]
        dist = np.abs(np.sum(diff * c / (cn + _EPS), axis=2))
        dist[cn[..., 0] < 1e-12] = np.inf  # itself and its pair's copy: no closest approach
        nb = np.argpartition(dist, k - 1, axis=1)[:, :k]
        cj = np.take_along_axis(c, nb[..., None], axis=1)
        nvec = cj / (np.linalg.norm(cj, axis=2, keepdims=True) + _EPS)
        n2 = np.cross(nvec, d[nb])
        n2 = n2 / (np.linalg.norm(n2, axis=2, keepdims=True) + _EPS)
        dj = np.take_along_axis(diff, nb[..., None], axis=1)
        est = np.sum(dj * n2, axis=2) / (np.sum(d[rows, None, :] * n2, axis=2) + _EPS)
        for r, i in enumerate(rows):
            t1[i], t2[i] = two_peaks(est[r], bandwidth)
    return TwoPeakResult(first=a + t1[:, None] * d, second=a + t2[:, None] * d, partner=line_pairs(lines))


def assign_pairs(result: TwoPeakResult, rule: str = "random", truth: Float[np.ndarray, "N 3"] | None = None,
                 seed: int = 0) -> Float[np.ndarray, "N 3"]:
    """One point per line from both peaks: within a pair ``(i, j)``, ``i < j``, line ``i`` gets one peak
    and line ``j`` the other.  ``"random"``: a fair coin per pair (``seed``); ``"oracle"``: the
    assignment with the smaller summed error against ``truth`` (the swap-ratio-0 upper bound).  A line
    without a pair gets its higher peak."""
    if rule not in ("random", "oracle"):
        raise ValueError(f"unknown rule {rule!r} (use 'random' or 'oracle')")
    if rule == "oracle" and truth is None:
        raise ValueError("the oracle assignment needs the true points")
    out = result.first.copy()
    i = np.flatnonzero(result.partner > np.arange(len(out)))
    j = result.partner[i]
    if rule == "random":
        swap = np.random.default_rng(seed).random(len(i)) < 0.5
    else:
        p = np.asarray(truth, np.float64)
        err = lambda x, y: np.linalg.norm(x - p[y], axis=1)  # noqa: E731
        keep = err(result.first[i], i) + err(result.second[j], j)
        swap = err(result.second[i], i) + err(result.first[j], j) < keep
    out[i] = np.where(swap[:, None], result.second[i], result.first[i])
    out[j] = np.where(swap[:, None], result.first[j], result.second[j])
    return out
