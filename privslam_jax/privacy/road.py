"""Lines of road points laid parallel to the road: a defence against the road-surface attack; the map's
up axis from its keyframes (:func:`keyframe_up`, the axis of an axial cloud).

Every lift keeps each point on its line, so the line of a point on the road meets the road exactly at
the point, and :func:`privslam_jax.attacks.plane.road_surface_attack` gives it away whatever the
line's direction — unless the line never meets the road: a line parallel to the road plane at the
point's height has no intersection to give.  :func:`road_parallel` takes a lifted cloud and, for every
point within ``within`` metres of the road under its nearest keyframe (the planes of
:func:`~privslam_jax.attacks.plane.road_planes`, the keyframe whose foot is nearest the point), removes
the road normal's component from its line's direction (``d ← (d − (n·d) n) / ‖·‖``; a direction along
the normal is replaced by ``n × e`` for the axis ``e`` least aligned with ``n``).  The line still passes
through its point, so localisation against it is unchanged in kind.

What it gives away: which lines lie parallel to the road, i.e. which points are within ``within`` of
it, and their height above it (the line's), but not where along the line they are.  What it costs and
what it protects against the other attacks is measured by ``experiments/table_map_privacy.py``
(docs/privacy.md, "Which lift to choose").  Not from a paper.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike
from scipy.spatial import cKDTree

from privslam_jax.attacks.plane import road_planes
from privslam_jax.privacy.lift import _as_points, _lines
from privslam_jax.types import LineCloud

__all__ = ["keyframe_up", "road_parallel"]


def road_parallel(lines: LineCloud, points: ArrayLike, T_w_c: np.ndarray, height: float, within: float = 1.0,
                  down: np.ndarray | tuple | list = (0.0, 1.0, 0.0)) -> LineCloud:
    """``lines`` (line ``i`` through point ``i`` of ``points (N, 3)``) with the lines of the points within
    ``within`` metres of the road under the keyframes ``T_w_c (M, 4, 4)`` laid parallel to it (module
    docstring); the other lines unchanged.  Same dtype as ``lines``; ``height`` and ``down`` as for
    :func:`~privslam_jax.attacks.plane.road_surface_attack`."""
    p, _ = _as_points(points)
    d = np.asarray(lines.directions, np.float64)
    if d.shape != p.shape:
        raise ValueError(f"lines and points must match: {d.shape[0]} lines, {p.shape[0]} points")
    if not (np.isfinite(within) and within > 0):
        raise ValueError(f"within must be finite and > 0 metres, got {within}")
    n, feet = road_planes(T_w_c, height, down)
    nearest = cKDTree(feet).query(p)[1]  # the keyframe whose foot is nearest each point
    nk = n[nearest]
    near = np.abs(np.einsum("ik,ik->i", p - feet[nearest], nk)) < within
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    flat = unit - np.einsum("ik,ik->i", unit, nk)[:, None] * nk
    size = np.linalg.norm(flat, axis=1)
    axis = np.eye(3)[np.argmin(np.abs(nk), axis=1)]
    flat = np.where((size > 1e-6)[:, None], flat, np.cross(nk, axis))
    flat /= np.linalg.norm(flat, axis=1, keepdims=True)
    # the other lines exactly as they were
    d = np.where(near[:, None], flat, d)
    m = np.where(near[:, None], np.cross(p, flat), np.asarray(lines.moments, np.float64))
    return _lines(d, m, np.dtype(np.asarray(lines.directions).dtype))


def keyframe_up(T_w_c: np.ndarray, down: np.ndarray | tuple | list = (0.0, 1.0, 0.0)) -> np.ndarray:
    """The map's up axis, e.g. for :func:`~privslam_jax.privacy.lift.axial_lift`: ``(3,)`` unit, the mean of
    the keyframes' up axes ``−R_w_c · down`` (``T_w_c (M, 4, 4)`` camera to map; ``down``, the camera's down
    axis, is ``+y`` in KITTI's and the synthetic world's camera frames).  A road vehicle's cameras pitch and
    roll with the road, so this is the normal of the mean road under the keyframes
    (:func:`~privslam_jax.attacks.plane.road_planes`), not gravity."""
    n, _ = road_planes(T_w_c, 1.0, down)  # the height only places the feet, unused here
    up = -n.mean(axis=0)
    if np.linalg.norm(up) < 1e-6:
        raise ValueError("the keyframes' up axes cancel out: no common up direction")
    return up / np.linalg.norm(up)
