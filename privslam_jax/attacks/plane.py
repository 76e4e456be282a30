"""Scene-prior attacks on every line cloud: intersect each line with the ground plane, or with the road
under the camera path, or take its point nearest the camera path.

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

A real road is not one plane (KITTI seq1 climbs 1.2 m over 60 m, enough to put its road points metres
off along their lines).  :func:`road_surface_attack` uses the keyframe poses that a SLAM map keeps
beside its points (ORB-SLAM's Atlas saves them; the edge server that localises against the map holds
them): the road under keyframe ``c`` is the plane through its foot ``F_c = C_c + h n_c``, with normal
``n_c = R_w_c · down`` (the camera's down axis, ``down = (0, 1, 0)`` in KITTI's and the synthetic
world's camera frames, and ``h`` the camera height), and each line takes its intersection with the
plane of the keyframe whose foot is nearest to that intersection — the road surface the vehicle
drove over, one tangent plane per keyframe.  With one shared plane this is :func:`ground_plane_attack`.

:func:`path_attack` uses the keyframes' camera centres alone: a street map's points were seen from the
path, most of them a few metres from it (the road, parked cars, kerbs), so each line's point nearest
any keyframe centre is a guess that needs no road model.  It is the prior an attacker has left against
an axial cloud (:func:`~privslam_jax.privacy.lift.axial_lift`), whose lines say nothing about a point's
distance from the axis.
"""

from __future__ import annotations

import numpy as np

from privslam_jax.types import LineCloud

__all__ = ["ground_plane_attack", "path_attack", "road_planes", "road_surface_attack"]


def ground_plane_attack(lines: LineCloud, normal: np.ndarray | tuple | list, offset: float) -> np.ndarray:
    """``(N, 3)`` float64: where each line of ``lines`` meets the plane ``normal · x = offset`` (module
    docstring); ``normal``: ``(3,)``, need not be unit length."""
    n = np.asarray(normal, np.float64)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0 or not np.isfinite(offset):
        raise ValueError(f"the plane needs a finite non-zero normal (3,) and a finite offset, got {n} and {offset}")
    h = float(offset) / np.linalg.norm(n)
    n = n / np.linalg.norm(n)
    d, p0 = _lines(lines)
    return _meet(p0, d, n[None, :], h * n[None, :])[:, 0]


def road_surface_attack(lines: LineCloud, T_w_c: np.ndarray, height: float,
                        down: np.ndarray | tuple | list = (0.0, 1.0, 0.0), chunk: int = 4096) -> np.ndarray:
    """``(N, 3)`` float64: where each line of ``lines`` meets the road under the keyframes ``T_w_c``
    ``(M, 4, 4)`` (camera to map), ``height`` above it along the camera's ``down`` axis ``(3,)`` (module
    docstring): of the ``M`` intersections, the one nearest its keyframe's foot.  ``chunk`` lines at a time
    (memory ``chunk × M``)."""
    n, feet = road_planes(T_w_c, height, down)
    d, p0 = _lines(lines)
    out = np.empty_like(p0)
    for i in range(0, len(p0), chunk):
        x = _meet(p0[i:i + chunk], d[i:i + chunk], n, feet)  # (c, M, 3)
        best = np.argmin(np.linalg.norm(x - feet[None], axis=2), axis=1)
        out[i:i + chunk] = x[np.arange(len(x)), best]
    return out


def path_attack(lines: LineCloud, T_w_c: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """``(N, 3)`` float64: each line's point nearest any of the keyframes' camera centres (``T_w_c``
    ``(M, 4, 4)``, camera to map; module docstring).  ``chunk`` lines at a time (memory ``chunk × M``)."""
    centres = _keyframes(T_w_c)[:, :3, 3]
    d, p0 = _lines(lines)
    out = np.empty_like(p0)
    for i in range(0, len(p0), chunk):
        t = d[i:i + chunk] @ centres.T - np.einsum("ik,ik->i", p0[i:i + chunk], d[i:i + chunk])[:, None]  # (c, M)
        x = p0[i:i + chunk, None, :] + t[..., None] * d[i:i + chunk, None, :]
        best = np.argmin(np.linalg.norm(x - centres[None], axis=2), axis=1)
        out[i:i + chunk] = x[np.arange(len(x)), best]
    return out


def road_planes(T_w_c: np.ndarray, height: float, down: np.ndarray | tuple | list = (0.0, 1.0, 0.0)
                ) -> tuple[np.ndarray, np.ndarray]:
    """The road under each keyframe (module docstring): ``(normals, feet)``, both ``(M, 3)`` float64, the
    plane of keyframe ``c`` being ``n_c · x = n_c · F_c`` with unit ``n_c`` pointing down."""
    T = _keyframes(T_w_c)
    dn = np.asarray(down, np.float64)
    if dn.shape != (3,) or not np.all(np.isfinite(dn)) or np.linalg.norm(dn) == 0:
        raise ValueError(f"down must be a finite non-zero (3,) vector in the camera frame, got {dn}")
    if not (np.isfinite(height) and height > 0):
        raise ValueError(f"height (the camera above the road, metres) must be finite and > 0, got {height}")
    n = T[:, :3, :3] @ (dn / np.linalg.norm(dn))  # (M, 3) each keyframe's down axis in the map
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return n, T[:, :3, 3] + float(height) * n


def _keyframes(T_w_c: np.ndarray) -> np.ndarray:
    """``T_w_c`` as float64 ``(M, 4, 4)``, ``M ≥ 1``, finite; a ``ValueError`` otherwise."""
    T = np.asarray(T_w_c, np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0 or not np.all(np.isfinite(T)):
        raise ValueError(f"T_w_c must be finite keyframe poses (M, 4, 4) with M >= 1, got shape {T.shape}")
    return T


def _lines(lines: LineCloud) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions and each line's point nearest the origin, ``(N, 3)`` float64."""
    d = np.asarray(lines.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return d, np.cross(d, np.asarray(lines.moments, np.float64))


def _meet(p0: np.ndarray, d: np.ndarray, n: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(N, M, 3)``: line ``i`` (``p0 + t d``) met with the plane ``n_j · x = n_j · q_j`` (unit ``n``); a
    line parallel to a plane (``|n·d| ≤ 1e-9``) gives its point nearest ``q_j``."""
    nd = d @ n.T  # (N, M)
    parallel = np.abs(nd) <= 1e-9
    gap = np.einsum("mk,mk->m", n, q)[None, :] - p0 @ n.T
    t = np.where(parallel, (q @ d.T).T - np.einsum("ik,ik->i", p0, d)[:, None], gap / np.where(parallel, 1.0, nd))
    return p0[:, None, :] + t[..., None] * d[:, None, :]
