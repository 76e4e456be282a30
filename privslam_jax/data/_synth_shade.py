"""Materials and lighting of the synthetic street world (private helper).

Static surfaces: asphalt road with lane markings, zebra crossings and parking bays; paved
sidewalks with granite kerb stones; façades split into 9 m houses (brick or plaster, window
grids with frames, mullions and curtains, shop fronts with sign boards, doors, cornices).
Objects: skin-coloured heads with eyes, brows and mouth (the "face region"), clothes, car bodies
with licence plates (white, blue EU band, seven dark 3×5 dot-matrix glyphs), lights and glass
cabins, wheels, buses, trucks.

Lighting: Lambert sun + sky ambient, faked ambient occlusion at the wall base and along kerbs, and
exponential distance fog towards the horizon colour.  All patterns are box-filtered by the pixel
footprint (see ``_synth_textures``) so far detail fades to its mean instead of aliasing.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from privslam_jax.data import _synth_objects as so
from privslam_jax.data._synth_textures import (
    band, cscale, current_channel, cwhere, fade, grey, grid_lines, mix, palette, rand3, rand_bytes, rgb, shared, value_noise,
)

_SUN = tuple(float(v) for v in np.array([0.5, -0.75, 0.42]) / np.linalg.norm([0.5, -0.75, 0.42]))
HORIZON = (0.80, 0.86, 0.92)
_WALLS = [
    [0.78, 0.72, 0.62], [0.86, 0.80, 0.66], [0.70, 0.55, 0.45], [0.62, 0.66, 0.70], [0.90, 0.88, 0.84],
    [0.74, 0.78, 0.66], [0.83, 0.68, 0.55], [0.58, 0.56, 0.54],
]
_BRICKS = [[0.62, 0.28, 0.20], [0.55, 0.35, 0.25], [0.72, 0.58, 0.40], [0.45, 0.25, 0.20]]
_SIGNS = [[0.80, 0.10, 0.10], [0.10, 0.30, 0.70], [0.10, 0.45, 0.25], [0.15, 0.15, 0.15], [0.90, 0.70, 0.10]]

# Vectors are planar too: a tuple (x, y, z) of pixel-grid arrays.


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a):
    return jnp.sqrt(_dot(a, a))


def _unit(a):
    n = jnp.maximum(_norm(a), 1e-12)
    return tuple(ai / n for ai in a)


def footprint(dist, fx, view, normal, axis):
    """World length covered by one pixel along the unit surface axis ``axis`` (metres).

    On a plane with normal ``n`` seen along ``v̂`` from distance ``ℓ``, a pixel (angle ``1/f_x``) covers
    ``ℓ/f_x`` across the view and ``ℓ/(f_x |n·v̂|)`` along it: ``ℓ/f_x · sqrt(1 + (v̂·e)²/(n·v̂)²)``.
    """
    nv = _dot(normal, view)
    ve = view[axis]
    return dist / fx * jnp.sqrt(1.0 + ve * ve / jnp.maximum(nv * nv, 0.02))


def lighting(col, normal, view, dist):
    """Sun + sky ambient shading and distance fog."""
    diff = jnp.maximum(_dot(normal, _SUN), 0.0)
    sky = 0.5 - 0.5 * normal[1]
    shade = shared(0.42 + 0.55 * diff + 0.18 * sky)
    fog = shared(1.0 - jnp.exp(-dist / 320.0))
    return mix(cscale(col, shade), rgb(*HORIZON), fog)


def cloud_coords(d):
    """Direction-anchored sky coordinates (clouds at infinity: consistent across views)."""
    n = _unit(d)
    up = jnp.clip(-n[1], 0.0, 1.0)
    k = 1.0 / (up + 0.08)
    return n[0] * k, n[2] * k, up


def sky_color(up, noise):
    """Sky gradient with clouds (``noise``: value noise at two scales of the cloud coordinates)."""
    col = mix(rgb(*HORIZON), rgb(0.36, 0.56, 0.86), jnp.clip(up * 2.5, 0.0, 1.0))
    cloud = 0.6 * noise[0] + 0.4 * noise[1]
    cov = jnp.clip((cloud - 0.52) * 4.0, 0.0, 1.0) * jnp.clip(up * 6.0, 0.0, 1.0)
    return mix(col, rgb(0.95, 0.96, 0.97), cov * 0.85)


def road_color(x, z, layout, fw, noise):
    P, R = layout.period, layout.road_half_width
    latx = x - jnp.round(x / P) * P
    latz = z - jnp.round(z / P) * P
    road_z = jnp.abs(latx) < jnp.abs(latz)  # inside the street running along z
    lat = jnp.where(road_z, latx, latz)
    lon = jnp.where(road_z, z, x)
    dcross = jnp.where(road_z, jnp.abs(latz), jnp.abs(latx))
    alat = jnp.abs(lat)
    in_street = dcross > R
    g1, g2, g3, patch = noise
    base = 0.30 + 0.08 * (g1 - 0.5) + 0.10 * (g2 - 0.5) * fade(fw, 0.31) + 0.10 * (g3 - 0.5) * fade(fw, 0.07)
    base = base * (1.0 - 0.18 * band(patch, 0.70, 2.0, 0.02 + fw * 0.1))
    base = base * (0.78 + 0.22 * jnp.clip((R - alat) / 0.6, 0.0, 1.0))  # gutter
    dash = band(jnp.mod(lon, 8.0), 0.3, 3.8, fw)
    dash = 0.44 + (dash - 0.44) * fade(fw, 8.0)
    centre = band(lat, -0.075, 0.075, fw) * dash * (dcross > R + 4.0)
    lane = band(alat, R - 2.06, R - 1.94, fw) * (dcross > R + 4.0)
    bays = band(alat, R - 2.0, R - 0.1, fw) * grid_lines(lon, 6.0, 0.06, fw) * (dcross > R + 4.0)
    zebra = band(dcross, R + 0.7, R + 3.7, fw) * band(alat, 0.0, R - 0.4, fw)
    zebra = zebra * (0.5 + (band(jnp.mod(lat + 0.25, 1.0), 0.0, 0.5, fw) - 0.5) * fade(fw, 1.0))
    stop = band(dcross, R + 4.0, R + 4.35, fw) * band(alat, 0.0, R - 2.0, fw)
    paint = jnp.clip((centre + lane + bays + zebra + stop) * in_street, 0.0, 1.0) * (0.8 + 0.2 * g2)
    g = base + (0.86 - base) * paint
    return grey(g, (0.98, 0.99, 1.02))


def sidewalk_color(x, z, cx, cz, layout, fw, salt, noise):
    P, R = layout.period, layout.road_half_width
    x0, x1 = cx * P + R, (cx + 1) * P - R
    z0, z1 = cz * P + R, (cz + 1) * P - R
    dedge = jnp.minimum(jnp.minimum(x - x0, x1 - x), jnp.minimum(z - z0, z1 - z))
    tile = rand3(jnp.floor(x / 0.5).astype(jnp.int32), jnp.floor(z / 0.5).astype(jnp.int32), salt + 21)
    grout = jnp.maximum(grid_lines(x, 0.5, 0.012, fw), grid_lines(z, 0.5, 0.012, fw))
    g = 0.60 + 0.12 * (tile - 0.5) * fade(fw, 0.5)
    g = g * (1.0 - 0.45 * grout) * (0.9 + 0.1 * noise[0])
    kerb_joint = jnp.maximum(grid_lines(x, 1.0, 0.01, fw), grid_lines(z, 1.0, 0.01, fw))
    kerb = (0.72 + 0.06 * noise[1]) * (1.0 - 0.4 * kerb_joint)
    g = jnp.where(dedge < 0.3, kerb, g)
    return grey(g, (1.0, 0.97, 0.93))


def wall_color(a, h, key, bh, fwa, fwh, salt, noise):
    """Façade colour at along-wall coordinate ``a`` and height ``h`` (metres) of the block ``key``."""
    seg = jnp.floor(a / 9.0)
    la = shared(a - seg * 9.0)
    seg_i = shared(seg.astype(jnp.int32))
    r = rand_bytes(key, seg_i, salt + 100) + rand_bytes(key, seg_i, salt + 101)
    brick = r[1] < 0.35
    base = cwhere(brick, palette(jnp.floor(r[0] * 4).astype(jnp.int32), _BRICKS),
                  palette(jnp.floor(r[0] * 8).astype(jnp.int32), _WALLS))
    # bricks: 0.24 × 0.075 m, rows offset by half a brick
    row = jnp.floor(h / 0.075)
    bx = a / 0.24 + 0.5 * jnp.mod(row, 2.0)
    bvar = rand3(jnp.floor(bx).astype(jnp.int32), row.astype(jnp.int32), salt + 31)
    mortar = jnp.maximum(grid_lines(h, 0.075, 0.006, fwh), grid_lines(bx * 0.24, 0.24, 0.006, fwa))
    bshade = 0.85 + 0.3 * (bvar - 0.5) * fade(jnp.maximum(fwa, fwh), 0.15)
    stain = noise[0]
    shade = jnp.where(brick, bshade, 0.9 + 0.14 * stain)
    col = mix(cscale(base, shade), rgb(0.78, 0.76, 0.72), 0.8 * mortar * brick)
    # pilasters at house borders, plinth, cornice, string courses
    pil = 1.0 - band(la, 0.35, 8.65, jnp.maximum(fwa, 0.02))
    col = cscale(col, 1.0 - 0.18 * pil)
    gfh = 3.9
    fh = 2.9 + 0.5 * r[2]
    course = band(jnp.mod(h - gfh, fh), 0.0, 0.15, fwh) * (h > gfh - 0.1)
    col = mix(col, rgb(0.88, 0.86, 0.82), course * 0.9)
    col = mix(col, rgb(0.35, 0.34, 0.33), band(h, -1.0, 0.45, fwh))
    col = mix(col, col * 0.55 + 0.1, band(h, bh - 0.6, bh + 1.0, fwh))
    # window grid: n windows per house, evenly spaced
    nwin = jnp.floor(8.3 / (2.2 + 1.0 * r[3]))
    wsp = 8.3 / nwin
    fa = shared(jnp.mod(la - 0.35, wsp) - 0.5 * wsp)
    wcol = jnp.floor((la - 0.35) / wsp)
    fl = shared(jnp.floor((h - gfh) / fh))
    fy = shared(h - gfh - fl * fh)
    ww = wsp * (0.38 + 0.22 * r[4])
    wh = 1.3 + 0.4 * r[5]
    top_ok = gfh + fl * fh + 0.8 + wh < bh - 0.8
    upper = (h > gfh) & top_ok & (la > 0.35) & (la < 8.65)
    frame = band(fa, -ww / 2 - 0.09, ww / 2 + 0.09, fwa) * band(fy, 0.7, 0.8 + wh + 0.09, fwh) * upper
    glass = band(fa, -ww / 2, ww / 2, fwa) * band(fy, 0.8, 0.8 + wh, fwh) * upper
    wr = rand3(key * 4096 + seg_i, (wcol + 64 * fl).astype(jnp.int32), salt + 41)
    gcol = mix(rgb(0.16, 0.20, 0.27), rgb(0.45, 0.52, 0.60), jnp.clip((fy - 0.8) / wh, 0.0, 1.0) * 0.6 + 0.25 * wr)
    curtain = (wr > 0.62) & (fy < 0.8 + 0.55 * wh)
    gcol = cwhere(curtain, rgb(0.82, 0.76, 0.62), gcol)
    gcol = cwhere(wr < 0.08, rgb(0.95, 0.85, 0.55), gcol)
    mull = band(fa, -0.03, 0.03, fwa) + band(fy, 0.8 + 0.62 * wh, 0.86 + 0.62 * wh, fwh)
    gcol = mix(gcol, rgb(0.92, 0.92, 0.90), jnp.clip(mull, 0.0, 1.0) * (r[6] > 0.3))
    fcol = cwhere(r[6] > 0.5, rgb(0.93, 0.93, 0.91), rgb(0.20, 0.18, 0.16))
    col = mix(col, fcol, frame)
    col = mix(col, gcol, glass)
    # ground floor: shop front with sign, or door + windows
    shop = r[7] < 0.6
    door0 = 1.0 + 5.5 * r[3]
    door = band(la, door0, door0 + 1.3, fwa) * band(h, 0.0, 2.4, fwh)
    doorcol = palette(jnp.floor(r[5] * 4).astype(jnp.int32), [[0.35, 0.20, 0.12], [0.10, 0.25, 0.15], [0.15, 0.15, 0.18], [0.55, 0.10, 0.10]])
    shopwin = band(la, 0.8, 8.2, fwa) * band(h, 0.55, 3.0, fwh) * shop
    shopglass = mix(rgb(0.12, 0.14, 0.17), rgb(0.55, 0.50, 0.42), noise[1] * 0.7)
    col = mix(col, rgb(0.15, 0.15, 0.16), band(la, 0.7, 8.3, fwa) * band(h, 0.45, 3.1, fwh) * shop)
    col = mix(col, shopglass, shopwin)
    sign = band(la, 0.7, 8.3, fwa) * band(h, 3.15, 3.75, fwh) * shop
    scol = palette(jnp.floor(r[4] * 5).astype(jnp.int32), _SIGNS)
    glyph = rand3(jnp.floor(la / 0.28).astype(jnp.int32) + 97 * seg_i, jnp.floor(h / 0.12).astype(jnp.int32) + key, salt + 43)
    letters = band(la, 1.5, 7.5, fwa) * band(h, 3.28, 3.62, fwh) * (glyph > 0.45) * fade(jnp.maximum(fwa, fwh), 0.12)
    scol = mix(scol, rgb(0.97, 0.97, 0.95), letters)
    col = mix(col, scol, sign)
    resid_win = band(jnp.abs(la - 4.5 - 1.5 * (r[3] > 0.5)), 1.6, 2.9, fwa) * band(h, 1.0, 2.5, fwh) * (~shop)
    col = mix(col, rgb(0.2, 0.24, 0.3), resid_win)
    return mix(col, doorcol, door)


def static_fields(p, d, hit, layout, fx, salt):
    """Channel-independent fields of the static world at hit points ``p`` (``hit``: dict from trace)."""
    kind = hit["s_kind"]
    t = hit["t_static"]
    dist = t * _norm(d)
    view = _unit(d)
    x, y, z = p
    side = hit["s_side"]
    xface = hit["s_xface"]
    zero = jnp.zeros_like(x)
    nx = -jnp.sign(d[0])
    nz = -jnp.sign(d[2])
    vertical = (kind >= 2) & side
    normal = (jnp.where(vertical & xface, nx, zero), jnp.where(vertical, zero, -1.0),
              jnp.where(vertical & ~xface, nz, zero))
    fw_x = footprint(dist, fx, view, normal, 0)
    fw_y = footprint(dist, fx, view, normal, 1)
    fw_z = footprint(dist, fx, view, normal, 2)
    a = jnp.where(xface, z, x)
    h = -y
    face = jnp.where(xface, 0, 2) + (jnp.where(xface, nx, nz) > 0)
    # four value-noise fields shared by all materials, on each material's surface coordinates
    ccx, ccz, up = cloud_coords(d)
    sky = kind == 0
    su = jnp.where(sky, ccx, jnp.where(vertical, a, x))
    sv = jnp.where(sky, ccz, jnp.where(vertical, h, z))
    scales = {1: (2.3, 0.31, 0.07, 6.0), 2: (3.0, 0.4, 1.0, 1.0), 3: (1.7, 0.8, 1.0, 1.0), 0: (1 / 1.5, 0.25, 1.0, 1.0)}
    noise = []
    for k in range(4):
        inv = jnp.full(kind.shape, 1.0, jnp.float32)
        for m, sc in scales.items():
            inv = jnp.where(kind == m, 1.0 / sc[k], inv)
        noise.append(value_noise(su * inv, sv * inv, salt + 11 + k))
    return {
        "kind": kind, "side": side, "vertical": vertical, "normal": normal, "view": view, "dist": dist,
        "x": x, "z": z, "a": a, "h": h, "up": up, "noise": noise,
        "fw_ground": jnp.maximum(fw_x, fw_z), "fwa": jnp.where(xface, fw_z, fw_x), "fw_y": fw_y,
        "key": (hit["s_cx"].astype(jnp.int32) * 4 + face) * 7919 + hit["s_cz"].astype(jnp.int32),
        "cx": hit["s_cx"], "cz": hit["s_cz"], "bh": hit["s_bh"],
    }


def static_wall(f, salt):
    """One channel of the façade colour (run in its own channel loop, see ``synthetic._view``)."""
    return wall_color(f["a"], f["h"], f["key"], f["bh"], f["fwa"], f["fw_y"], salt, f["noise"])


def static_color(f, layout, salt, wall):
    """One channel of the static world's colour from :func:`static_fields` and the façade channel ``wall``."""
    kind, side, vertical = f["kind"], f["side"], f["vertical"]
    road = road_color(f["x"], f["z"], layout, f["fw_ground"], f["noise"])
    walk = sidewalk_color(f["x"], f["z"], f["cx"], f["cz"], layout, f["fw_ground"], salt, f["noise"])
    kerb = grey(0.66 * (1.0 - 0.4 * grid_lines(f["a"], 1.0, 0.01, f["fwa"])), (1.0, 0.98, 0.95))
    col = cwhere(kind == 1, road, walk)
    col = cwhere((kind == 2) & side, kerb, col)
    col = cwhere(kind == 3, cwhere(side, wall, rgb(0.32, 0.30, 0.30)), col)
    # fake ambient occlusion at the foot of walls
    ao = jnp.where(vertical & (kind == 3), 0.72 + 0.28 * jnp.clip((f["h"] - 0.15) / 1.5, 0.0, 1.0), 1.0)
    lit = lighting(cscale(col, ao), f["normal"], f["view"], f["dist"])
    return cwhere(kind == 0, sky_color(f["up"], f["noise"]), lit)


def _plate(u, v, inst):
    """Licence plate in plate coordinates ``u, v ∈ [0, 1]`` (white, blue band, 7 glyphs)."""
    col = cwhere(u < 0.09, rgb(0.1, 0.2, 0.65), rgb(0.96, 0.96, 0.93))
    ci = jnp.floor((u - 0.12) / 0.115)
    cu = (u - 0.12) / 0.115 - ci
    gx = jnp.floor((cu - 0.12) / 0.76 * 3.0)
    gy = jnp.floor((v - 0.15) / 0.7 * 5.0)
    inside = (ci >= 0) & (ci < 7) & (gx >= 0) & (gx < 3) & (gy >= 0) & (gy < 5)
    bit = rand3(inst * 8 + ci.astype(jnp.int32), (gx + 3 * gy).astype(jnp.int32), 5) < 0.55
    col = cwhere(inside & bit, rgb(0.05, 0.05, 0.06), col)
    border = (u < 0.02) | (u > 0.98) | (v < 0.06) | (v > 0.94)
    return cwhere(border, rgb(0.1, 0.1, 0.1), col)


def object_color(p, d, t, row, table, fx):
    """One channel of the colour of object hits (``row`` indexes the packed primitive ``table``)."""
    f = [shared(jnp.take(table[:, k], row, axis=0)) for k in range(23)]
    c, h = f[0:3], f[3:6]
    Rm = f[6:15]
    ch = current_channel()
    col = jnp.take(table[:, 15 + ch], row, axis=0)
    col2 = jnp.take(table[:, 18 + ch], row, axis=0)
    part = jnp.round(f[21]).astype(jnp.int32)
    inst = jnp.round(f[22]).astype(jnp.int32)
    is_ell = row >= table.shape[0] - so.NE * (table.shape[0] // (so.NB + so.NE))
    rel = tuple(p[i] - c[i] for i in range(3))
    pl = tuple(shared(Rm[3 * r] * rel[0] + Rm[3 * r + 1] * rel[1] + Rm[3 * r + 2] * rel[2]) for r in range(3))
    q = tuple(pl[i] / h[i] for i in range(3))
    aq = tuple(jnp.abs(v) for v in q)
    # prism normal: the dominant local axis; ellipsoid: gradient of the quadric
    fxa = (aq[0] >= aq[1]) & (aq[0] >= aq[2])
    fya = (~fxa) & (aq[1] >= aq[2])
    fza = ~(fxa | fya)
    n_box = (fxa * jnp.sign(q[0]), fya * jnp.sign(q[1]), fza * jnp.sign(q[2]))
    n_loc = _unit(tuple(jnp.where(is_ell, q[i] / h[i], n_box[i]) for i in range(3)))
    normal = tuple(shared(Rm[i] * n_loc[0] + Rm[3 + i] * n_loc[1] + Rm[6 + i] * n_loc[2]) for i in range(3))
    dist = shared(t * _norm(d))
    view = tuple(shared(v) for v in _unit(d))
    fw = dist / fx
    X, Y, Z = pl
    hx, hy, hz = h
    # head: skin, hair, eyes, brows, mouth (face on local +z)
    nx, ny, nz = q
    hair = (ny < -0.45) | ((nz < -0.1) & (ny < 0.55))
    eye = (nz > 0.5) & (jnp.abs(jnp.abs(nx) - 0.38) < 0.13) & (jnp.abs(ny + 0.1) < 0.1)
    brow = (nz > 0.45) & (jnp.abs(jnp.abs(nx) - 0.38) < 0.2) & (jnp.abs(ny + 0.3) < 0.05)
    mouth = (nz > 0.5) & (jnp.abs(nx) < 0.3) & (jnp.abs(ny - 0.45) < 0.07)
    head = cwhere(hair, col2, col)
    head = cwhere(eye | brow, rgb(0.05, 0.04, 0.04), head)
    head = cwhere(mouth, rgb(0.6, 0.15, 0.15), head)
    # car body: plates front/back, lights, bumpers, door gaps
    front = fza & (q[2] > 0)
    back = fza & (q[2] < 0)
    pu = 0.5 - X * jnp.sign(q[2]) / 0.52
    pv = (Y - 0.105) / 0.11
    on_plate = fza & (pu >= 0) & (pu <= 1) & (pv >= 0) & (pv <= 1)
    light = fza & (jnp.abs(X) > hx - 0.38) & (jnp.abs(X) < hx - 0.06) & (Y > -0.2) & (Y < -0.05)
    body = cwhere(Y > hy - 0.1, rgb(0.12, 0.12, 0.12), col)
    body = cwhere(fxa & (jnp.abs(Z - 0.1 * hz) < 0.012 + 0.5 * fw), cscale(col, 0.4), body)
    body = cwhere(light & front, rgb(1.0, 0.97, 0.85), body)
    body = cwhere(light & back, rgb(0.75, 0.05, 0.05), body)
    # one plate evaluation serves cars (pv), buses/truck cabs (bpv) and truck boxes (tpv)
    bpv = (Y - (hy - 0.55)) / 0.11
    tpv = (Y - (hy - 0.5)) / 0.11
    ppv = jnp.where(part == so.CAR_BODY, pv, jnp.where(part == so.TRUCK_BOX, tpv, bpv))
    ppu = jnp.where(part == so.PLATE, 0.5 - X / (2 * hx) * jnp.sign(q[2]), pu)
    ppv = jnp.where(part == so.PLATE, (Y + hy) / (2 * hy), ppv)
    plate_here = fza & (ppu >= 0) & (ppu <= 1) & (ppv >= 0) & (ppv <= 1)
    plate = _plate(ppu, ppv, inst)
    body = cwhere(on_plate, plate, body)
    # cabin: glass with pillars, roof in paint
    glasscol = mix(rgb(0.10, 0.13, 0.18), rgb(0.40, 0.46, 0.55), jnp.clip(-Y / hy * 0.5 + 0.5, 0.0, 1.0))
    pillar = (fxa & ((jnp.abs(Z) > hz - 0.13) | (jnp.abs(Z + 0.05 * hz) < 0.05))) | (fza & (jnp.abs(X) > hx - 0.1)) | (Y > hy - 0.05)
    cabin = cwhere(fya | pillar, col, glasscol)
    # wheels: dark tyre, light hub
    rho = jnp.sqrt(q[1] ** 2 + q[2] ** 2)
    thin = hx < 0.05
    hub = jnp.where(thin, rho < 0.86, rho < 0.55)
    wheel = cwhere(hub, cwhere(thin, rgb(0.55, 0.55, 0.57), rgb(0.68, 0.68, 0.70)), rgb(0.07, 0.07, 0.08))
    # bus: window band, windscreen, white stripe, plates
    bwin = (fxa & (Y > -hy + 0.35) & (Y < -hy + 1.25) & (jnp.abs(jnp.mod(Z, 1.3) - 0.65) > 0.07)) | (
        front & (Y > -hy + 0.25) & (Y < 0.15) & (jnp.abs(X) < hx - 0.08))
    busc = cwhere((Y > 0.25) & (Y < 0.45), col2, col)
    busc = cwhere(bwin, glasscol, busc)
    busc = cwhere(plate_here, plate, busc)
    # truck cab: windscreen + side windows, plate at the bottom of the front
    cwin = (Y < -0.05) & (Y > -hy + 0.15) & ((front & (jnp.abs(X) < hx - 0.1)) | (fxa & (Z > -0.1)))
    cab = cwhere(cwin, glasscol, col)
    cab = cwhere(plate_here, plate, cab)
    # truck box: stripe in the second colour; rear plate near the bottom
    tbox = cwhere(fxa & (jnp.abs(Y) < 0.2), col2, col)
    tbox = cwhere((Y > hy - 0.3) & back, rgb(0.15, 0.15, 0.15), tbox)
    tbox = cwhere(plate_here & back, plate, tbox)
    mplate = cwhere(fza, plate, col)
    cloth = cscale(col, 0.92 + 0.08 * jnp.sin(Y * 40.0))
    out = col
    for code, val in ((so.HEAD, head), (so.CLOTH, cloth), (so.CAR_BODY, body), (so.CAR_CABIN, cabin),
                      (so.WHEEL, wheel), (so.BUS, busc), (so.TRUCK_CAB, cab), (so.TRUCK_BOX, tbox),
                      (so.PLATE, mplate)):
        out = cwhere(part == code, val, out)
    return lighting(out, normal, view, dist)
