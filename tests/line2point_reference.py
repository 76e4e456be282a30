"""Plain numpy Line2Point, written from the authors' Utils.py / Recover.py (kunalchelani/Line2Point)
with one loop iteration per line, as they do.  Differences from their script, all deliberate and
shared with privslam_jax.attacks.line2point: lines are anchored at the closest point to the origin
(not the true point), neighbours are a stable argsort's first k (their argpartition leaves ties
unspecified), and the intersection set is sorted (their set → list order is arbitrary; the peak
finder sorts anyway)."""

from __future__ import annotations

import numpy as np

EPS = 10e-7


def closest_lines_from_line(pt, line, pts, lines, k):
    n = np.cross(line, lines)
    n /= np.linalg.norm(n, axis=1, keepdims=True) + EPS
    dist = np.abs(np.sum(np.multiply(pts - pt, n), axis=1))
    return np.argsort(dist, kind="stable")[:k]


def closest_points_from_line(pt, line, pts, k):
    n = np.cross(pts - pt, line)
    n /= np.linalg.norm(n, axis=1, keepdims=True) + EPS
    n1 = np.cross(n, line)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True) + EPS
    dist = np.abs(np.sum(np.multiply(pts - pt, n1), axis=1))
    return np.argsort(dist, kind="stable")[:k]


def closest_lines_from_point(pt, pts, lines, k):
    n = np.cross(pts - pt, lines)
    n /= np.linalg.norm(n, axis=1, keepdims=True) + EPS
    n1 = np.cross(n, lines)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True) + EPS
    dist = np.abs(np.sum(np.multiply(pts - pt, n1), axis=1))
    return np.argsort(dist, kind="stable")[:k]


def estimates_from_lines(pt, line, neigh_pts, neigh_lines):
    # calc_estimate_from_line for every neighbour at once (their loop, vectorised over neighbours)
    n = np.cross(line, neigh_lines)
    n /= np.linalg.norm(n, axis=1, keepdims=True) + EPS
    n2 = np.cross(n, neigh_lines)
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True) + EPS
    return np.sum((neigh_pts - pt) * n2, axis=1) / (np.sum(line * n2, axis=1) + EPS)


def find_peak(estimates, num_bins=500):
    hist_cs = np.zeros(num_bins + 1)
    uni_cs = np.zeros(num_bins + 1)
    uni = np.ones(num_bins) / num_bins
    hist, edges = np.histogram(estimates, bins=num_bins)
    hist_cs[1:] = np.cumsum(hist) / np.sum(hist)
    uni_cs[1:] = np.cumsum(uni) / np.sum(uni)
    min_i = np.argmin(hist_cs[0 : int(0.9 * num_bins)] - uni_cs[0 : int(0.9 * num_bins)])
    max_i = np.argmax(hist_cs[min_i:-1] - uni_cs[min_i:-1]) + min_i
    kv = hist_cs[max_i] + uni_cs[min_i] - hist_cs[min_i] - uni_cs[max_i]
    in_peak = (estimates < edges[max_i]) & (estimates > edges[min_i])
    return in_peak, kv


def get_peak(estimates, num_bins=500, nro=5):
    est_clean = np.sort(estimates)[nro : -1 * nro]
    kv = 1
    while est_clean.shape[0] > 5 and kv > 0.3:
        in_peak, kv = find_peak(est_clean, num_bins)
        est_clean = est_clean[in_peak]
    if est_clean.shape[0] == 0:
        return np.median(estimates)
    return np.median(est_clean)


def line2point_reference(pts, lines, num_refine_iterations=2, num_nn_l2p=100, num_nn_p2l=100):
    """pts: (N, 3) anchors on the lines; lines: (N, 3) unit directions. Returns (points, offsets)."""
    num_pts = pts.shape[0]
    k = int(min(500, 0.05 * num_pts))
    est_peak = np.zeros(num_pts)
    for i in range(num_pts):
        nn = closest_lines_from_line(pts[i], lines[i], pts, lines, k)
        est_peak[i] = get_peak(estimates_from_lines(pts[i], lines[i], pts[nn], lines[nn]))
    for _ in range(num_refine_iterations):
        pts_est = pts + est_peak.reshape(-1, 1) * lines
        new = np.zeros(num_pts)
        for i in range(num_pts):
            l2p = closest_points_from_line(pts[i], lines[i], pts_est, num_nn_l2p)
            p2l = closest_lines_from_point(pts_est[i], pts, lines, num_nn_p2l)
            inter = np.array(sorted(set(l2p.tolist()) & set(p2l.tolist())), dtype=np.int64)
            nn = inter if len(inter) > 10 else l2p
            new[i] = get_peak(estimates_from_lines(pts[i], lines[i], pts[nn], lines[nn]))
        est_peak = new
    return pts + est_peak.reshape(-1, 1) * lines, est_peak
