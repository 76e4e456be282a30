"""Attacks on line clouds whose lines meet at a few public centres: ray clouds (and sphere clouds).

A ray cloud (:func:`~privslam_jax.privacy.lift.ray_lift`) hides point ``p_i`` on the line through
``p_i`` and one of ``K`` anchors.  Line2Point's density argument fails on it as published: a line's
nearest lines are the other lines of its anchor (line–line distance 0), so every closest-approach
estimate lands on the anchor (measured in ``tests/test_centred_attack.py``).  Excluding those lines
is not enough either: the lines of another anchor ``B`` form a pencil, and every line of ``B`` near
the plane through ``B`` and line ``i`` meets line ``i`` somewhere, wherever its point is.  What the
geometry still gives away is agreement *between* anchors: the true point ``p_i`` has neighbours in
space that went to other anchors, and their lines all pass near ``p_i``; a wrong position along line
``i`` collects crossings of one pencil at a time.  The attack built here on that (the ray-cloud paper
gives no attack for its representation):

1. **Find the centres** (:func:`find_centres`): repeatedly take an unassigned line ``i``, the
   lines that meet it (line–line distance ``≤ tol``), and the median offset along ``i`` of those
   meetings; the point there is a centre if at least ``min_lines`` lines pass within ``tol`` of it.
   Its lines are assigned to it and the search goes on until no unassigned line has a partner.
   ``tol`` is set by the coordinates' rounding, not by the map's scale, so lines meeting by chance are
   rare.
2. **Vote across centres** (:func:`ray_cloud_attack`): for line ``i`` and every other centre ``k``,
   the offsets along line ``i`` of the closest approaches of the ``⌈f·n_k⌉`` lines of ``k`` nearest to
   line ``i`` (``n_k`` lines at ``k``, ``f`` = ``fraction``, at least 3); a candidate offset scores the
   number of centres with an offset within ``delta`` metres of it (ties: the most offsets), and
   ``t_i`` is the median of the offsets within ``delta`` of the best candidate.

A sphere cloud (:func:`~privslam_jax.privacy.lift.sphere_lift`) is the case ``K = 1``: every line
meets every other at the centroid and there is no second centre to vote; what a sphere cloud leaks is
the bearing of each point from the centroid, not its depth.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from privslam_jax.attacks._host import host_lines
from privslam_jax.types import LineCloud

__all__ = ["find_centres", "ray_cloud_attack"]


def find_centres(
    lines: LineCloud, tol: float | None = None, min_lines: int = 10
) -> tuple[Float[np.ndarray, "K 3"], Int[np.ndarray, " N"]]:
    """Points where at least ``min_lines`` lines meet, and the centre of every line.

    Args:
      lines: the line cloud.
      tol: metres within which lines count as meeting; default ``1e-5 · (1 + max |a|)`` for float32
        lines (``a`` the closest points to the origin), ``1e-9 · (1 + max |a|)`` for float64.
      min_lines: fewest lines through a point for it to count as a centre.

    Returns ``(centres, labels)``: ``(K, 3)`` float64 centres and, per line, the index of its centre or
    ``-1`` (a line through no centre, e.g. every line of a random lift).
    """
    a, d = host_lines(lines, 2)
    n = len(a)
    if tol is None:
        eps = 1e-9 if np.asarray(lines.directions).dtype == np.float64 else 1e-5
        tol = eps * (1.0 + float(np.abs(a).max()))
    labels = np.full(n, -1, np.int64)
    centres: list[np.ndarray] = []
    tried = np.zeros(n, bool)
    while True:
        todo = np.flatnonzero((labels < 0) & ~tried)
        if len(todo) == 0:
            break
        i = todo[0]
        tried[i] = True
        c = np.cross(d[i], d)  # closest approach of line i to every line
        s = np.linalg.norm(c, axis=1)
        ok = s > 1e-12
        dist = np.full(n, np.inf)
        dist[ok] = np.abs(np.sum((a[ok] - a[i]) * c[ok], axis=1)) / s[ok]
        meet = np.flatnonzero((dist <= tol) & (labels < 0))
        if len(meet) + 1 < min_lines:
            continue
        n2 = np.cross(c[meet], d[meet])
        t = np.sum((a[meet] - a[i]) * n2, axis=1) / np.sum(d[i] * n2, axis=1)
        centre = a[i] + np.median(t) * d[i]
        through = np.linalg.norm(np.cross(centre - a, d), axis=1) <= tol
        members = np.flatnonzero(through & (labels < 0))
        if len(members) < min_lines:
            continue
        labels[members] = len(centres)
        centres.append(centre)
    return np.asarray(centres, np.float64).reshape(-1, 3), labels


def _closest_approaches(a: np.ndarray, d: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
    """``(distance, offset)``: line–line distance of line ``i`` to every line and the offset along line
    ``i`` of their closest approach (parallel lines: distance ``inf``)."""
    c = np.cross(d[i], d)
    s = np.linalg.norm(c, axis=1)
    ok = s > 1e-12
    s = np.where(ok, s, 1.0)
    dist = np.where(ok, np.abs(np.sum((a - a[i]) * c, axis=1)) / s, np.inf)
    n2 = np.cross(c, d)
    den = n2 @ d[i]
    t = np.where(ok, np.sum((a - a[i]) * n2, axis=1) / np.where(ok, den, 1.0), 0.0)
    return dist, t


def ray_cloud_attack(
    lines: LineCloud, *, fraction: float = 0.05, delta: float = 0.3, tol: float | None = None, min_lines: int = 10,
    progress: bool = False,
) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, "K 3"], Int[np.ndarray, " N"]]:
    """Recover the points of a ray cloud by the vote across centres (module docstring).

    Args:
      lines: a ray cloud (at least two centres: ``ValueError`` otherwise, e.g. for a random lift,
        which Line2Point attacks, or a sphere cloud).
      fraction: share ``f`` of each other centre's lines that vote (the nearest to the line).
      delta: metres within which offsets of different centres agree.
      tol, min_lines: as in :func:`find_centres`.
      progress: a tqdm bar over the lines.

    Returns ``(points, centres, labels)``: one point per line (float64), the centres found, and each
    line's centre (``-1``: none; such a line takes votes from every centre).  ``O(N²)`` time, ``O(N)``
    memory.
    """
    if not 0.0 < fraction <= 1.0 or not delta > 0.0:
        raise ValueError(f"need 0 < fraction <= 1 and delta > 0, got fraction={fraction}, delta={delta}")
    centres, labels = find_centres(lines, tol, min_lines)
    if len(centres) < 2:
        raise ValueError(f"found {len(centres)} centre(s) where {min_lines}+ lines meet: not a ray cloud "
                         "(Line2Point attacks random lifts; a sphere cloud has one centre and no second one to vote)")
    a, d = host_lines(lines, 2)
    members = [np.flatnonzero(labels == k) for k in range(len(centres))]
    counts = [max(3, int(np.ceil(fraction * len(m)))) for m in members]
    offsets = np.zeros(len(a))
    rows = range(len(a))
    if progress:
        from tqdm import tqdm

        rows = tqdm(rows, desc="ray-cloud attack", unit="line")
    for i in rows:
        dist, t = _closest_approaches(a, d, i)
        votes = []
        for k, (m, c) in enumerate(zip(members, counts)):
            if k == labels[i]:
                continue
            near = m[np.argpartition(dist[m], c - 1)[:c]] if c < len(m) else m
            votes.append(np.sort(t[near]))
        every = np.concatenate(votes)
        score = np.zeros(len(every))
        for v in votes:
            hits = np.searchsorted(v, every + delta, "right") - np.searchsorted(v, every - delta, "left")
            score += (hits > 0) + 1e-6 * hits
        best = every[np.argmax(score)]
        offsets[i] = np.median(every[np.abs(every - best) <= delta])
    return a + offsets[:, None] * d, centres, labels
