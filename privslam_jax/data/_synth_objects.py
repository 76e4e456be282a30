"""Privacy objects of the synthetic street world: templates, placement, motion (private, host numpy).

Each object is a union of at most ``NB`` yawed boxes ("prisms": vertical extrusions of a rotated
rectangle) and ``NE`` arbitrarily rotated ellipsoids, given in the object's local frame (``y`` down,
base on ``y = 0``, forward ``+z``).  Walking people swing legs and arms about hip/shoulder pivots
(rotation about the local ``x`` axis).  Per frame, :func:`frame_primitives` poses the ``K`` nearest
objects inside the view frustum and packs their primitives into fixed-size float32 tables
(unused rows have ``valid = 0``), which is what the jitted renderer consumes.

Primitive row layout (``F = 24`` floats): ``0:3`` centre (city frame), ``3:6`` half sizes,
``6:15`` world→local rotation (row-major), ``15:18`` colour, ``18:21`` second colour,
``21`` part code, ``22`` instance id, ``23`` valid.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from privslam_jax.data._synth_path import CityLayout, StreetPath, repeated_legs, right_of

NB = 4
NE = 6
F = 24

# part codes (shading programs in _synth_render)
PLAIN, HEAD, CLOTH, CAR_BODY, CAR_CABIN, WHEEL, BUS, TRUCK_CAB, TRUCK_BOX, PLATE = range(10)

PERSON, BICYCLE, CAR, MOTORCYCLE, BUS_CLS, TRUCK = 0, 1, 2, 3, 5, 7
"""COCO class ids."""

_RADIUS = {PERSON: 1.1, BICYCLE: 1.1, CAR: 2.6, MOTORCYCLE: 1.3, BUS_CLS: 6.5, TRUCK: 4.6}

_SKIN = np.array([[0.96, 0.80, 0.69], [0.87, 0.67, 0.52], [0.76, 0.57, 0.42], [0.55, 0.38, 0.26], [0.38, 0.26, 0.18]])
_HAIR = np.array([[0.08, 0.06, 0.05], [0.30, 0.18, 0.09], [0.80, 0.66, 0.38], [0.55, 0.55, 0.55], [0.45, 0.15, 0.06]])
_CLOTH = np.array(
    [
        [0.80, 0.12, 0.12], [0.12, 0.25, 0.65], [0.15, 0.50, 0.20], [0.90, 0.75, 0.15], [0.92, 0.92, 0.90],
        [0.10, 0.10, 0.12], [0.55, 0.30, 0.60], [0.95, 0.50, 0.10], [0.35, 0.60, 0.85], [0.50, 0.35, 0.22],
    ]
)
_TROUSERS = np.array([[0.10, 0.14, 0.30], [0.12, 0.12, 0.13], [0.45, 0.40, 0.32], [0.30, 0.30, 0.33], [0.20, 0.28, 0.45]])
_PAINT = np.array(
    [
        [0.93, 0.93, 0.92], [0.68, 0.70, 0.72], [0.07, 0.07, 0.08], [0.30, 0.32, 0.35], [0.75, 0.08, 0.08],
        [0.10, 0.22, 0.55], [0.10, 0.32, 0.20], [0.95, 0.78, 0.10], [0.55, 0.10, 0.12], [0.85, 0.85, 0.78],
    ]
)


@dataclasses.dataclass
class ObjectSpec:
    """One privacy object: shape in its local frame and its motion."""

    class_id: int
    prisms: np.ndarray  # (NB, 13): centre 3, half 3, colour 3, colour2 3, part 1 (part < 0: unused)
    ellipsoids: np.ndarray  # (NE, 17): centre 3, half 3, pivot 3, colour 3, colour2 3, part, swing amp
    motion: int  # 0 static, 1 linear (walk), 2 along the path (s0 + v t), 3 lead car
    p0: np.ndarray  # (2,) xz position (static/linear)
    vel: np.ndarray  # (2,) xz velocity (linear)
    yaw: float  # heading (static/linear); along-path objects add the path tangent
    base_y: float  # 0 on the road, -kerb on the sidewalk
    s0: float = 0.0
    speed: float = 0.0
    lateral: float = 0.0
    gait: float = 0.0  # rad/s of the limb swing (walkers)
    phase: float = 0.0


def _empty():
    pr = np.zeros((NB, 13))
    pr[:, 12] = -1
    el = np.zeros((NE, 17))
    el[:, 15] = -1
    return pr, el


def _prism(pr, i, c, h, col, part, col2=(0, 0, 0)):
    pr[i] = [*c, *h, *col, *col2, part]


def _ell(el, i, c, h, col, part, col2=(0, 0, 0), pivot=None, amp=0.0):
    pivot = c if pivot is None else pivot
    el[i] = [*c, *h, *pivot, *col, *col2, part, amp]


def person(rng: np.random.Generator, walking: bool):
    s = rng.uniform(0.9, 1.08)
    skin = _SKIN[rng.integers(len(_SKIN))]
    hair = _HAIR[rng.integers(len(_HAIR))]
    shirt = _CLOTH[rng.integers(len(_CLOTH))]
    trousers = _TROUSERS[rng.integers(len(_TROUSERS))]
    arms = skin if rng.random() < 0.3 else shirt
    pr, el = _empty()
    amp_leg = 0.42 if walking else 0.0
    amp_arm = 0.3 if walking else 0.0
    _ell(el, 0, (0, -1.63 * s, 0.01), (0.095 * s, 0.12 * s, 0.105 * s), skin, HEAD, hair)
    _ell(el, 1, (0, -1.19 * s, 0), (0.2 * s, 0.31 * s, 0.125 * s), shirt, CLOTH)
    for i, side in ((2, -1), (3, 1)):
        _ell(el, i, (0.1 * side * s, -0.46 * s, 0), (0.082 * s, 0.48 * s, 0.092 * s), trousers, CLOTH,
             pivot=(0.1 * side * s, -0.92 * s, 0), amp=amp_leg * side)
    for i, side in ((4, -1), (5, 1)):
        _ell(el, i, (0.255 * side * s, -1.15 * s, 0), (0.057 * s, 0.31 * s, 0.062 * s), arms, CLOTH,
             pivot=(0.25 * side * s, -1.43 * s, 0), amp=-amp_arm * side)
    _prism(pr, 0, (0, -0.93 * s, 0), (0.17 * s, 0.09 * s, 0.1 * s), trousers, CLOTH)
    return pr, el


def car(rng: np.random.Generator):
    L = rng.uniform(3.9, 4.7)
    W = rng.uniform(0.85, 0.95)
    paint = _PAINT[rng.integers(len(_PAINT))]
    pr, el = _empty()
    _prism(pr, 0, (0, -0.62, 0), (W, 0.34, L / 2), paint, CAR_BODY)
    _prism(pr, 1, (0, -1.2, -0.05 * L), (W - 0.1, 0.25, 0.26 * L), paint, CAR_CABIN)
    k = 0
    for sx in (-1, 1):
        for sz in (-1, 1):
            _ell(el, k, (sx * (W - 0.08), -0.32, sz * 0.31 * L), (0.12, 0.32, 0.32), (0.06, 0.06, 0.06), WHEEL)
            k += 1
    return pr, el, L


def bus(rng: np.random.Generator):
    L = rng.uniform(10.5, 12.0)
    paint = [np.array([0.85, 0.15, 0.12]), np.array([0.95, 0.8, 0.15]), np.array([0.15, 0.45, 0.75])][rng.integers(3)]
    pr, el = _empty()
    _prism(pr, 0, (0, -1.75, 0), (1.25, 1.42, L / 2), paint, BUS, (0.95, 0.95, 0.95))
    k = 0
    for sx in (-1, 1):
        for sz in (-1, 1):
            _ell(el, k, (sx * 1.12, -0.5, sz * 0.3 * L), (0.16, 0.5, 0.5), (0.06, 0.06, 0.06), WHEEL)
            k += 1
    return pr, el, L


def truck(rng: np.random.Generator):
    paint = _PAINT[rng.integers(len(_PAINT))]
    box = np.array([0.9, 0.9, 0.88]) if rng.random() < 0.6 else _CLOTH[rng.integers(len(_CLOTH))]
    pr, el = _empty()
    _prism(pr, 0, (0, -1.6, 2.65), (1.2, 1.15, 0.9), paint, TRUCK_CAB)
    _prism(pr, 1, (0, -2.1, -1.0), (1.25, 1.5, 2.65), box, TRUCK_BOX, paint)
    _prism(pr, 2, (0, -0.72, 0.0), (0.95, 0.22, 3.5), (0.12, 0.12, 0.12), PLAIN)
    k = 0
    for sx in (-1, 1):
        for sz in (2.6, -2.3):
            _ell(el, k, (sx * 1.05, -0.5, sz), (0.18, 0.5, 0.5), (0.06, 0.06, 0.06), WHEEL)
            k += 1
    return pr, el, 7.2


def bicycle(rng: np.random.Generator):
    frame = _CLOTH[rng.integers(len(_CLOTH))]
    pr, el = _empty()
    _prism(pr, 0, (0, -0.78, 0.06), (0.022, 0.025, 0.33), frame, PLAIN)
    _prism(pr, 1, (0, -0.6, -0.24), (0.022, 0.2, 0.022), frame, PLAIN)
    _prism(pr, 2, (0, -0.62, 0.45), (0.022, 0.32, 0.022), frame, PLAIN)
    _prism(pr, 3, (0, -0.96, 0.43), (0.27, 0.018, 0.018), (0.1, 0.1, 0.1), PLAIN)
    _ell(el, 0, (0, -0.34, 0.52), (0.025, 0.34, 0.34), (0.06, 0.06, 0.06), WHEEL)
    _ell(el, 1, (0, -0.34, -0.52), (0.025, 0.34, 0.34), (0.06, 0.06, 0.06), WHEEL)
    _ell(el, 2, (0, -0.84, -0.25), (0.07, 0.035, 0.13), (0.08, 0.08, 0.08), PLAIN)
    return pr, el


def motorcycle(rng: np.random.Generator):
    paint = _PAINT[rng.integers(len(_PAINT))]
    pr, el = _empty()
    _prism(pr, 0, (0, -0.87, -0.35), (0.15, 0.05, 0.3), (0.05, 0.05, 0.05), PLAIN)
    _prism(pr, 1, (0, -1.08, 0.6), (0.36, 0.02, 0.02), (0.1, 0.1, 0.1), PLAIN)
    _prism(pr, 2, (0, -0.75, 0.63), (0.04, 0.3, 0.04), (0.6, 0.6, 0.62), PLAIN)
    _prism(pr, 3, (0, -0.62, -0.8), (0.11, 0.075, 0.012), (1, 1, 1), PLATE)
    _ell(el, 0, (0, -0.31, 0.7), (0.07, 0.31, 0.31), (0.06, 0.06, 0.06), WHEEL)
    _ell(el, 1, (0, -0.31, -0.7), (0.07, 0.31, 0.31), (0.06, 0.06, 0.06), WHEEL)
    _ell(el, 2, (0, -0.88, 0.2), (0.17, 0.14, 0.32), paint, PLAIN)
    _ell(el, 3, (0, -0.52, 0.0), (0.2, 0.18, 0.3), (0.25, 0.25, 0.27), PLAIN)
    return pr, el


def _vehicle(rng, kind):
    if kind == CAR:
        return car(rng)
    if kind == BUS_CLS:
        return bus(rng)
    if kind == TRUCK:
        return truck(rng)
    pr, el = motorcycle(rng)
    return pr, el, 2.1


def place_objects(
    rng: np.random.Generator,
    path: StreetPath,
    layout: CityLayout,
    s_cam0: float,
    speed: float,
    duration: float,
    density: float,
) -> list[ObjectSpec]:
    """Populate the streets the path traverses (parked and driving vehicles, people, bicycles)."""
    objs: list[ObjectSpec] = []
    R, S, kerb = layout.road_half_width, layout.sidewalk_width, layout.kerb_height
    if density <= 0:
        return objs
    nodes = path.nodes
    repeated = repeated_legs(path)
    for k in range(len(nodes) - 1):
        if repeated[k]:  # a later lap of a loop route: its street is populated already
            continue
        a = path.leg_dirs[k]
        rgt = right_of(a)
        leg_len = float(np.linalg.norm(nodes[k + 1] - nodes[k]))
        lo = 0.0 if k == 0 else R + S + 1.0
        hi = leg_len - (R + S + 1.0)
        yaw_a = float(np.arctan2(a[0], a[1]))
        for side in (1.0, -1.0):
            # parked vehicles in the parking lane
            u = lo + rng.uniform(0, 6) / density
            while True:
                r = rng.random()
                kind = CAR if r < 0.78 else TRUCK if r < 0.85 else BUS_CLS if r < 0.9 else MOTORCYCLE
                pr, el, L = _vehicle(rng, kind)
                if u + L > hi:
                    break
                centre = u + L / 2
                lat = side * (layout.parking_offset - (0.3 if kind == BUS_CLS else 0.0) + (0.4 if kind == MOTORCYCLE else 0.0))
                pos = nodes[k] + centre * a + lat * rgt
                yaw = yaw_a + (0.0 if side > 0 else np.pi) + rng.normal(0, 0.03)
                if kind == MOTORCYCLE:
                    yaw += side * rng.uniform(0.3, 0.7)
                objs.append(ObjectSpec(kind, pr, el, 0, pos, np.zeros(2), yaw, 0.0))
                u += L + rng.uniform(0.8, 9.0) / density
            # people on the sidewalk
            n_people = rng.poisson(max(hi - lo, 0) / 9.0 * density)
            for _ in range(n_people):
                walking = rng.random() < 0.55
                pr, el = person(rng, walking)
                along = rng.uniform(lo, hi)
                lat = side * rng.uniform(R + 0.8, R + S - 0.5)
                pos = nodes[k] + along * a + lat * rgt
                if walking:
                    direction = 1.0 if rng.random() < 0.5 else -1.0
                    v = rng.uniform(1.0, 1.6)
                    yaw = yaw_a + (0.0 if direction > 0 else np.pi)
                    objs.append(ObjectSpec(PERSON, pr, el, 1, pos, direction * v * a, yaw, -kerb,
                                           gait=v / 0.75 * np.pi, phase=rng.uniform(0, 2 * np.pi)))
                else:
                    yaw = rng.uniform(-np.pi, np.pi)
                    objs.append(ObjectSpec(PERSON, pr, el, 0, pos, np.zeros(2), yaw, -kerb))
            # parked bicycles near the kerb
            for _ in range(rng.poisson(max(hi - lo, 0) / 35.0 * density)):
                pr, el = bicycle(rng)
                along = rng.uniform(lo, hi)
                pos = nodes[k] + along * a + side * (R + 0.55) * rgt
                yaw = yaw_a + rng.choice([0.0, np.pi]) + rng.normal(0, 0.15)
                objs.append(ObjectSpec(BICYCLE, pr, el, 0, pos, np.zeros(2), yaw, -kerb))
    # oncoming traffic in the left lane of the path (meets the camera at random times)
    v_on = 8.0
    n_on = rng.poisson(duration * 0.12 * density + 0.5 * density)
    t_meet = np.sort(rng.uniform(0.5, duration + 4.0, n_on))
    last = -10.0
    for tm in t_meet:
        if tm - last < 1.6:
            continue
        last = tm
        r = rng.random()
        kind = CAR if r < 0.85 else BUS_CLS if r < 0.92 else TRUCK
        pr, el, _ = _vehicle(rng, kind)
        s_meet = s_cam0 + speed * tm
        objs.append(ObjectSpec(kind, pr, el, 2, np.zeros(2), np.zeros(2), np.pi, 0.0,
                               s0=s_meet + v_on * tm, speed=-v_on, lateral=-layout.lane_offset))
    # a lead car ahead in the ego lane
    if rng.random() < min(0.6 * density, 1.0):
        pr, el, L = car(rng)
        objs.append(ObjectSpec(CAR, pr, el, 3, np.zeros(2), np.zeros(2), 0.0, 0.0,
                               s0=rng.uniform(16.0, 26.0), speed=0.0, lateral=layout.lane_offset,
                               phase=rng.uniform(0, 2 * np.pi)))
    return objs


class ObjectTable:
    """The objects of a sequence as stacked arrays (vectorised per-frame posing)."""

    def __init__(self, objs: list[ObjectSpec]):
        n = len(objs)
        self.n = n
        self.classes = np.array([o.class_id for o in objs], np.int32)
        self.motion = np.array([o.motion for o in objs], np.int32)
        self.p0 = np.array([o.p0 for o in objs], np.float64).reshape(n, 2)
        self.vel = np.array([o.vel for o in objs], np.float64).reshape(n, 2)
        self.yaw = np.array([o.yaw for o in objs], np.float64)
        self.base = np.array([o.base_y for o in objs], np.float64)
        self.s0 = np.array([o.s0 for o in objs], np.float64)
        self.speed = np.array([o.speed for o in objs], np.float64)
        self.lateral = np.array([o.lateral for o in objs], np.float64)
        self.gait = np.array([o.gait for o in objs], np.float64)
        self.phase = np.array([o.phase for o in objs], np.float64)
        self.prisms = np.array([o.prisms for o in objs], np.float64).reshape(n, NB, 13)
        self.ellipsoids = np.array([o.ellipsoids for o in objs], np.float64).reshape(n, NE, 17)


def object_poses(tab: ObjectTable, path: StreetPath, t: float, s_cam: float):
    """Positions ``(N, 2)``, yaws ``(N,)``, base heights ``(N,)`` of all objects at time ``t``.

    Motion: 0 static, 1 linear ``p0 + v t``, 2 along the path ``s0 + speed·t`` at ``lateral``,
    3 lead car ``s_cam + s0 + 4 sin(0.25 t + phase)``; path-following yaw = tangent heading + ``yaw``.
    """
    pos = tab.p0 + tab.vel * t
    yaw = tab.yaw.copy()
    on_path = tab.motion >= 2
    if on_path.any():
        s = np.where(tab.motion == 2, tab.s0 + tab.speed * t, s_cam + tab.s0 + 4.0 * np.sin(0.25 * t + tab.phase))[on_path]
        p, tan = path.evaluate(s, tab.lateral[on_path])
        pos[on_path] = p
        yaw[on_path] = np.arctan2(tan[:, 0], tan[:, 1]) + tab.yaw[on_path]
    return pos, yaw, tab.base.copy()


def _rot_y(yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def select_visible(pos, base, classes, cam_xz, cam_yaw, tan_half: float, max_range: float, k: int, margin: float):
    """Indices of at most ``k`` objects whose bounding circle meets the horizontal view wedge, nearest first."""
    fwd = np.array([np.sin(cam_yaw), np.cos(cam_yaw)])
    rgt = np.array([np.cos(cam_yaw), -np.sin(cam_yaw)])
    rel = pos - cam_xz[None, :]
    z = rel @ fwd
    x = rel @ rgt
    rad = np.array([_RADIUS[c] for c in classes]) if len(classes) else np.zeros(0)
    ok = (z > -rad) & (z < max_range) & (np.abs(x) - margin <= (z + rad) * tan_half + rad * 1.5)
    idx = np.nonzero(ok)[0]
    idx = idx[np.argsort(z[idx], kind="stable")]
    return idx[:k]


def frame_primitives(tab: ObjectTable, sel: np.ndarray, pos, yaw, base, t: float, k: int):
    """Pack the primitives of the selected objects into ``(k·NB, F)`` prism and ``(k·NE, F)`` ellipsoid tables."""
    prisms = np.zeros((k, NB, F), np.float64)
    ells = np.zeros((k, NE, F), np.float64)
    ells[:, :, 3:6] = 1.0  # unused rows: a harmless unit sphere at the origin, valid = 0
    ells[:, :, 6:15] = np.eye(3).reshape(9)
    prisms[:, :, 6:15] = np.eye(3).reshape(9)
    ids = np.zeros(k, np.int32)
    m = len(sel)
    if m == 0:
        return prisms.reshape(k * NB, F).astype(np.float32), ells.reshape(k * NE, F).astype(np.float32), ids
    Ry = _rot_y(yaw[sel])  # (m, 3, 3)
    p = np.stack([pos[sel, 0], base[sel], pos[sel, 1]], axis=1)  # (m, 3)
    ids[:m] = sel + 1
    pr = tab.prisms[sel]
    prisms[:m, :, 0:3] = p[:, None, :] + np.einsum("mij,mnj->mni", Ry, pr[:, :, 0:3])
    prisms[:m, :, 3:6] = pr[:, :, 3:6]
    prisms[:m, :, 6:15] = np.transpose(Ry, (0, 2, 1)).reshape(m, 1, 9)
    prisms[:m, :, 15:21] = pr[:, :, 6:12]
    prisms[:m, :, 21] = pr[:, :, 12]
    prisms[:m, :, 22] = (sel + 1)[:, None]
    prisms[:m, :, 23] = pr[:, :, 12] >= 0
    el = tab.ellipsoids[sel]
    used = el[:, :, 15] >= 0
    theta = el[:, :, 16] * np.sin(tab.gait[sel] * t + tab.phase[sel])[:, None]
    Rx = _rot_x(theta)  # (m, NE, 3, 3)
    c_local = el[:, :, 6:9] + np.einsum("mnij,mnj->mni", Rx, el[:, :, 0:3] - el[:, :, 6:9])
    Rw = np.einsum("mij,mnjk->mnik", Ry, Rx)
    ells[:m, :, 0:3] = p[:, None, :] + np.einsum("mij,mnj->mni", Ry, c_local)
    ells[:m, :, 3:6] = np.where(used[..., None], el[:, :, 3:6], 1.0)
    ells[:m, :, 6:15] = np.transpose(Rw, (0, 1, 3, 2)).reshape(m, NE, 9)
    ells[:m, :, 15:21] = el[:, :, 9:15]
    ells[:m, :, 21] = el[:, :, 15]
    ells[:m, :, 22] = (sel + 1)[:, None]
    ells[:m, :, 23] = used
    return prisms.reshape(k * NB, F).astype(np.float32), ells.reshape(k * NE, F).astype(np.float32), ids
