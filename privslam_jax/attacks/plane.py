"""A scene-prior attack on every line cloud: intersect each line with the ground plane.

A street map's points are largely on the road (30 % of the synthetic street map's points lie within
5 cm of the ground), and the ground plane is public knowledge in the map's own frame: a SLAM map is
expressed in its first camera's frame, gravity-aligned up to the road's slope, with the ground at the
vehicle's camera height below it (KITTI: ``y = +1.65`` m, y pointing down; the synthetic world:
``y = +camera_height``).  Every lift keeps each point on its line, so the line of a ground point
meets the plane ``n·x = h`` exactly at the point::

    x = p₀ + t d,   t = (h − n·p₀) / (n·d)

whatever the line's direction: random and paired lines, ray clouds, and sphere clouds, whose lines
all pass through the centroid and so give no other attack a distance to work with.  Points off the
plane are put where their line meets it (wrong, but no worse than any other guess); a line parallel to
the plane (``|n·d| ≤ 1e-9``) keeps its point nearest the plane's foot of the origin.

This is not from a paper: it is the strongest attack we could build from the geometry for sphere
clouds (issue 19 item 2), and it applies to every lift.  It needs only the plane, not the descriptors
or any learning; a map published in a frame whose ground plane is unknown (e.g. COLMAP's arbitrary
frame) does not give it away, but one ground-plane fit on any part of the scene does.
"""

from __future__ import annotations

import numpy as np

from privslam_jax.types import LineCloud

__all__ = ["ground_plane_attack"]


def ground_plane_attack(lines: LineCloud, normal: np.ndarray | tuple | list, offset: float) -> np.ndarray:
    """``(N, 3)`` float64: where each line of ``lines`` meets the plane ``normal · x = offset`` (module
    docstring); ``normal``: ``(3,)``, need not be unit length."""
    n = np.asarray(normal, np.float64)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0 or not np.isfinite(offset):
        raise ValueError(f"the plane needs a finite non-zero normal (3,) and a finite offset, got {n} and {offset}")
    h = float(offset) / np.linalg.norm(n)
    n = n / np.linalg.norm(n)
    d = np.asarray(lines.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    p0 = np.cross(d, np.asarray(lines.moments, np.float64))  # each line's point nearest the origin
    nd = d @ n
    parallel = np.abs(nd) <= 1e-9
    t = np.where(parallel, 0.0, (h - p0 @ n) / np.where(parallel, 1.0, nd))
    # a parallel line: its point nearest the foot of the origin on the plane, h n
    t = np.where(parallel, np.einsum("ij,ij->i", h * n[None, :] - p0, d), t)
    return p0 + t[:, None] * d
