"""Street-network layout and the camera's path through it (private helper, host-side numpy).

City frame ("c" below, internal): ``y`` down with the ground at ``y = 0``; road centre lines run
along ``x = i·P`` and ``z = j·P`` (``P`` = block period).  Blocks fill the squares between them.

The path is a monotone "staircase" through the grid: legs along ``+z`` alternate with legs along
``±x``, so it turns left and right but never revisits a street (objects placed along one leg never
collide with another leg).  The loop route (:func:`make_loop_path`) drives laps around a rectangle of
blocks instead, so the camera comes back to where it started (loop closing); its repeated legs get
no objects of their own.  Every 90° corner is rounded by a circular arc of radius ``r``: for
incoming direction ``a`` and outgoing ``b`` at node ``N`` the arc runs from ``N − r·a`` to
``N + r·b`` around the centre ``N − r·a + r·b``, ``p(φ) = C + r(−b cos φ + a sin φ)``, with unit
tangent ``a cos φ + b sin φ``.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class CityLayout:
    """Fixed dimensions of the street grid (metres)."""

    period: float = 48.0
    """Distance between parallel road centre lines (block size + road width)."""
    road_half_width: float = 6.0
    """Half the carriageway width: two 2 m driving lanes + a 2 m parking lane each side."""
    sidewalk_width: float = 3.5
    """Sidewalk between kerb and façade."""
    kerb_height: float = 0.15
    """Height of the raised sidewalk slab."""
    min_height: float = 8.0
    """Lowest building (blocks draw heights uniformly in [min_height, max_height])."""
    max_height: float = 26.0
    """Tallest building."""
    lane_offset: float = 2.0
    """Lateral offset of the driving lane centre from the road centre line (right-hand traffic)."""
    parking_offset: float = 5.0
    """Lateral offset of parked vehicles from the centre line."""
    corner_radius: float = 10.0
    """Radius of the centre line's rounded 90° turns."""


def right_of(t: np.ndarray) -> np.ndarray:
    """Right-hand unit vector in the ``xz`` plane of a heading ``(tx, tz)`` (y down): ``(tz, −tx)``."""
    return np.stack([t[..., 1], -t[..., 0]], axis=-1)


class StreetPath:
    """Arc-length parametrised centre line: straight legs joined by quarter-circle arcs."""

    def __init__(self, nodes: np.ndarray, radius: float):
        nodes = np.asarray(nodes, np.float64)
        dirs = np.diff(nodes, axis=0)
        lengths = np.linalg.norm(dirs, axis=1)
        dirs = dirs / lengths[:, None]
        self.nodes = nodes
        self.leg_dirs = dirs
        segs = []  # (kind, s0, length, p0(2), a(2), b(2), centre(2))
        s = 0.0
        start = nodes[0]
        for k in range(len(dirs)):
            end_cut = radius if k + 1 < len(dirs) else 0.0
            end = nodes[k + 1] - end_cut * dirs[k]
            seg_len = float(np.linalg.norm(end - start))
            segs.append((0, s, seg_len, start, dirs[k], dirs[k], start))
            s += seg_len
            if k + 1 < len(dirs):
                a, b = dirs[k], dirs[k + 1]
                centre = nodes[k + 1] - radius * a + radius * b
                arc_len = radius * np.pi / 2
                segs.append((1, s, arc_len, end, a, b, centre))
                s += arc_len
                start = nodes[k + 1] + radius * b
        self.radius = radius
        self.length = s
        self._kind = np.array([g[0] for g in segs])
        self._s0 = np.array([g[1] for g in segs])
        self._p0 = np.array([g[3] for g in segs])
        self._a = np.array([g[4] for g in segs])
        self._b = np.array([g[5] for g in segs])
        self._c = np.array([g[6] for g in segs])

    def evaluate(self, s: np.ndarray, lateral: float | np.ndarray = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(…, 2)`` (``xz``) at arc length ``s`` offset ``lateral`` to the right, and unit tangents."""
        s = np.asarray(s, np.float64)
        idx = np.clip(np.searchsorted(self._s0, s, side="right") - 1, 0, len(self._s0) - 1)
        ds = s - self._s0[idx]
        kind = self._kind[idx]
        a, b = self._a[idx], self._b[idx]
        phi = ds / self.radius
        cos, sin = np.cos(phi)[..., None], np.sin(phi)[..., None]
        p_arc = self._c[idx] + self.radius * (-b * cos + a * sin)
        t_arc = a * cos + b * sin
        line = (kind == 0)[..., None]
        p = np.where(line, self._p0[idx] + ds[..., None] * a, p_arc)
        t = np.where(line, a, t_arc)
        return p + np.asarray(lateral)[..., None] * right_of(t), t


def make_path(rng: np.random.Generator, layout: CityLayout, min_length: float) -> StreetPath:
    """A random staircase route of at least ``min_length`` metres, starting mid-block heading ``+z``."""
    P = layout.period
    nodes = [np.array([0.0, 0.35 * P])]
    pos = np.array([0.0, 0.0])
    heading_z = True
    total = 0.0
    first = True
    while total < min_length + 2 * P:
        nblocks = int(rng.integers(1, 3)) if not first else int(rng.integers(2, 4))
        first = False
        if heading_z:
            step = np.array([0.0, nblocks * P])
        else:
            step = np.array([P * nblocks * (1.0 if rng.random() < 0.5 else -1.0), 0.0])
        pos = pos + step
        nodes.append(pos.copy())
        total += float(np.linalg.norm(nodes[-1] - nodes[-2]))
        heading_z = not heading_z
    return StreetPath(np.asarray(nodes), layout.corner_radius)


LOOP_BLOCKS: tuple[int, int] = (3, 2)
"""Blocks of the loop route's rectangle along ``x`` and ``z``: ``2·(3 + 2)·P`` = 480 m of streets, 463 m
a lap along the rounded centre line (the camera, 2 m to its right, drives 451–476 m)."""


def make_loop_path(rng: np.random.Generator, layout: CityLayout, min_length: float,
                   blocks: tuple[int, int] = LOOP_BLOCKS) -> StreetPath:
    """Laps around a rectangle of ``blocks`` blocks (along ``x``, ``z``), at least ``min_length`` metres.

    Starts mid-block heading ``+z`` like :func:`make_path`, turns all left or all right (drawn from
    ``rng``), and passes its start again after one lap (about 58–60 s at the default 8 m/s).
    """
    P = layout.period
    w, h = blocks
    side = 1.0 if rng.random() < 0.5 else -1.0
    corners = [np.array([0.0, h * P]), np.array([side * w * P, h * P]), np.array([side * w * P, 0.0]), np.array([0.0, 0.0])]
    nodes = [np.array([0.0, 0.35 * P])]
    total = 0.0
    k = 0
    while total < min_length + 2 * P:
        nodes.append(corners[k % 4])
        total += float(np.linalg.norm(nodes[-1] - nodes[-2]))
        k += 1
    return StreetPath(np.asarray(nodes), layout.corner_radius)


def repeated_legs(path: StreetPath) -> np.ndarray:
    """``(L,)`` True for a leg that lies on the street of an earlier leg (a later lap of a loop)."""
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    out = []
    for k in range(len(path.nodes) - 1):
        a, b = path.nodes[k], path.nodes[k + 1]
        d = path.leg_dirs[k]
        rep = False
        for a0, b0 in seen:
            d0 = (b0 - a0) / np.linalg.norm(b0 - a0)
            collinear = abs(d0[0] * d[1] - d0[1] * d[0]) < 1e-9 and abs(d0[0] * (a - a0)[1] - d0[1] * (a - a0)[0]) < 1e-6
            if collinear:
                lo0, hi0 = sorted([0.0, float(d0 @ (b0 - a0))])
                lo, hi = sorted([float(d0 @ (a - a0)), float(d0 @ (b - a0))])
                rep |= min(hi, hi0) - max(lo, lo0) > 1e-6
        seen.append((a, b))
        out.append(rep)
    return np.asarray(out, bool)
