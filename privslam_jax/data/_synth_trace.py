"""Column ray casting for the synthetic street world (private helper, jitted from synthetic.py).

The camera is level (no roll, no pitch) and everything in the world is either a vertical prism
(axis-aligned city blocks, kerb slabs, yawed boxes of objects), the ground plane or an ellipsoid.
For a level camera all rays of one image column lie in one vertical plane, with the ray
``d(u, v) = (d_xz(u), y_c(v))`` (unnormalised, ``z``-component 1 in the camera frame, so the ray
parameter ``t`` *is* the z-depth).  Hence the expensive part is done once per column
("2.5-D casting", as in Wolfenstein-style renderers):

* **Prism** with footprint rectangle ``R`` and vertical extent ``[y_lo, y_hi]``: the column ray meets
  ``R`` for ``t ∈ [t_a, t_b]`` (2-D slab test per column); a pixel ray meets the prism for
  ``t ∈ [t_a, t_b] ∩ {t : y_lo ≤ o_y + t y_c ≤ y_hi}``, so per pixel only a 1-D interval test is left.
* **Ellipsoid** ``(p − c)ᵀ M (p − c) = 1``: substituting ``p = o + t (d_h + y_c e_y)`` gives
  ``a t² + 2 b t + γ = 0`` with ``a = α₀ + y_c (α₁ + y_c M_yy)``, ``b = β₀ + y_c β₁``; the ``α, β`` are
  per column, so a pixel costs a handful of flops.
* The static city is a regular grid: a 2-D DDA (Amanatides & Woo 1987) per column visits
  ``n_steps`` cells, each holding one sidewalk slab and one building prism.
* Objects are culled per column: only the ``MB`` prisms and ``ME`` ellipsoids whose footprint
  the column meets, nearest first, are tested per pixel.

Inputs are shaped ``(R, C)`` per ray and ``(C,)`` per column; every array broadcast is explicit
(rank promotion is an error in this project).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from privslam_jax.data._synth_textures import rand3

NEAR = 1e-3
INF = jnp.inf


def static_columns(o, dxz, salt, layout, n_steps: int):
    """Per column: the cells visited by the DDA and the 2-D entry/exit of their slab and building.

    Returns a dict of ``(C, 2·n_steps)`` arrays ordered slab, building, slab, building, … along the
    ray: ``ta, tb`` (footprint interval), ``xface`` (entered through an x-facing side), ``ylo, yhi``
    (vertical extent, y down), ``cx, cz`` (cell indices), ``bh`` (the cell's building height).
    """
    P = layout.period
    R, S = layout.road_half_width, layout.sidewalk_width
    dx, dz = dxz[:, 0], dxz[:, 1]
    dx = jnp.where(jnp.abs(dx) < 1e-9, 1e-9, dx)
    dz = jnp.where(jnp.abs(dz) < 1e-9, 1e-9, dz)
    ox, oz = o[0], o[2]
    ix = jnp.zeros_like(dx) + jnp.floor(ox / P)
    iz = jnp.zeros_like(dz) + jnp.floor(oz / P)
    sx = jnp.where(dx > 0, 1.0, -1.0)
    sz = jnp.where(dz > 0, 1.0, -1.0)
    tmx = ((ix + (dx > 0)) * P - ox) / dx
    tmz = ((iz + (dz > 0)) * P - oz) / dz
    tdx = P / jnp.abs(dx)
    tdz = P / jnp.abs(dz)
    cxs, czs = [], []
    for _ in range(n_steps):
        cxs.append(ix)
        czs.append(iz)
        stepx = tmx < tmz
        ix = jnp.where(stepx, ix + sx, ix)
        tmx = jnp.where(stepx, tmx + tdx, tmx)
        iz = jnp.where(stepx, iz, iz + sz)
        tmz = jnp.where(stepx, tmz, tmz + tdz)
    cx = jnp.stack(cxs, axis=1)
    cz = jnp.stack(czs, axis=1)
    bh = layout.min_height + (layout.max_height - layout.min_height) * rand3(cx.astype(jnp.int32), cz.astype(jnp.int32), salt)
    out = {k: [] for k in ("ta", "tb", "xface", "ylo", "yhi")}
    dxc, dzc = dx[:, None], dz[:, None]
    for inset, ylo, yhi in ((R, -layout.kerb_height, 0.0), (R + S, -bh, -layout.kerb_height + 1e-3)):
        x0, x1 = cx * P + inset, (cx + 1) * P - inset
        z0, z1 = cz * P + inset, (cz + 1) * P - inset
        t1x, t2x = (x0 - ox) / dxc, (x1 - ox) / dxc
        t1z, t2z = (z0 - oz) / dzc, (z1 - oz) / dzc
        tnx, tfx = jnp.minimum(t1x, t2x), jnp.maximum(t1x, t2x)
        tnz, tfz = jnp.minimum(t1z, t2z), jnp.maximum(t1z, t2z)
        out["ta"].append(jnp.maximum(tnx, tnz))
        out["tb"].append(jnp.minimum(tfx, tfz))
        out["xface"].append(tnx > tnz)
        out["ylo"].append(jnp.broadcast_to(jnp.asarray(ylo, jnp.float32), cx.shape))
        out["yhi"].append(jnp.broadcast_to(jnp.asarray(yhi, jnp.float32), cx.shape))
    res = {k: jnp.stack(v, axis=2).reshape(cx.shape[0], 2 * n_steps) for k, v in out.items()}
    res["cx"] = jnp.repeat(cx, 2, axis=1)
    res["cz"] = jnp.repeat(cz, 2, axis=1)
    res["bh"] = jnp.repeat(bh, 2, axis=1)
    return res


def prism_pixels(oy, inv_yc, ta, tb, ylo, yhi):
    """Nearest hit ``t`` (``inf`` if none) and index over a list of column prisms, per pixel.

    ``ta, tb, ylo, yhi`` are ``(C, K)``; ``inv_yc`` is ``(R, C)``.  Returns ``(best_t, best_k)``.
    A ``lax.scan`` over ``k`` (rather than an unrolled loop) keeps the per-column tables
    materialised: XLA would otherwise fuse their computation into the per-pixel loop.
    """

    def body(carry, xs):
        best, bidx = carry
        k, ta_k, tb_k, ylo_k, yhi_k = xs
        t1 = (ylo_k[None, :] - oy) * inv_yc
        t2 = (yhi_k[None, :] - oy) * inv_yc
        tn = jnp.maximum(ta_k[None, :], jnp.minimum(t1, t2))
        tf = jnp.minimum(tb_k[None, :], jnp.maximum(t1, t2))
        t = jnp.where((tn <= tf) & (tn > NEAR), tn, INF)
        better = t < best
        return (jnp.where(better, t, best), jnp.where(better, k, bidx)), None

    init = (jnp.full(inv_yc.shape, INF, jnp.float32), jnp.zeros(inv_yc.shape, jnp.int32))
    xs = (jnp.arange(ta.shape[1], dtype=jnp.int32), ta.T, tb.T, ylo.T, yhi.T)
    (best, bidx), _ = jax.lax.scan(body, init, xs)
    return best, bidx


def take_cols(a, idx):
    """``out[r, c] = a[c, idx[r, c]]`` for a ``(C, K)`` table and ``(R, C)`` indices (one flat gather)."""
    C, K = a.shape
    flat = jnp.arange(C, dtype=jnp.int32)[None, :] * K + idx
    return jnp.take(a.reshape(C * K), flat.reshape(-1), axis=0).reshape(idx.shape)


def object_prism_columns(o, dxz, prisms, mb: int):
    """Per column, the ``mb`` nearest object prisms the column's vertical plane meets."""
    c = prisms[:, 0:3]
    h = prisms[:, 3:6]
    Rm = prisms[:, 6:15]
    valid = prisms[:, 23] > 0.5
    dx, dz = dxz[:, 0:1], dxz[:, 1:2]
    # local 2-D frame of each yawed box: rows 0 and 2 of the world→local rotation
    dlx = Rm[None, :, 0] * dx + Rm[None, :, 2] * dz
    dlz = Rm[None, :, 6] * dx + Rm[None, :, 8] * dz
    rx, rz = o[0] - c[:, 0], o[2] - c[:, 2]
    olx = (Rm[:, 0] * rx + Rm[:, 2] * rz)[None, :]
    olz = (Rm[:, 6] * rx + Rm[:, 8] * rz)[None, :]
    dlx = jnp.where(jnp.abs(dlx) < 1e-9, 1e-9, dlx)
    dlz = jnp.where(jnp.abs(dlz) < 1e-9, 1e-9, dlz)
    hx, hz = h[None, :, 0], h[None, :, 2]
    t1x, t2x = (-hx - olx) / dlx, (hx - olx) / dlx
    t1z, t2z = (-hz - olz) / dlz, (hz - olz) / dlz
    ta = jnp.maximum(jnp.minimum(t1x, t2x), jnp.minimum(t1z, t2z))
    tb = jnp.minimum(jnp.maximum(t1x, t2x), jnp.maximum(t1z, t2z))
    ok = valid[None, :] & (ta <= tb) & (tb > NEAR)
    key = jnp.where(ok, ta, INF)
    neg, sel = jax.lax.top_k(-key, mb)
    ok_sel = jnp.isfinite(neg)
    ta_s = jnp.take_along_axis(ta, sel, axis=1)
    tb_s = jnp.where(ok_sel, jnp.take_along_axis(tb, sel, axis=1), -INF)
    ylo = (c[:, 1] - h[:, 1])[sel]
    yhi = (c[:, 1] + h[:, 1])[sel]
    return ta_s, tb_s, ylo, yhi, sel


def ellipsoid_quadrics(ells):
    """World quadric matrices ``M = Rᵀ diag(1/h²) R`` of the ellipsoids, ``(E, 3, 3)``."""
    h = ells[:, 3:6]
    Rm = ells[:, 6:15].reshape(-1, 3, 3)
    return jnp.einsum("eki,ek,ekj->eij", Rm, 1.0 / (h * h), Rm)


def object_ellipsoid_columns(o, dxz, ells, me: int):
    """Per column, the coefficients of the ``me`` nearest ellipsoids whose bounding circle it meets."""
    c = ells[:, 0:3]
    h = ells[:, 3:6]
    valid = ells[:, 23] > 0.5
    M = ellipsoid_quadrics(ells)
    delta = o[None, :] - c  # (E, 3)
    Md = jnp.einsum("eij,ej->ei", M, delta)
    gamma = jnp.sum(Md * delta, axis=1) - 1.0
    dh = jnp.stack([dxz[:, 0], jnp.zeros_like(dxz[:, 0]), dxz[:, 1]], axis=1)  # (C, 3)
    Mdh = jnp.einsum("eij,cj->cei", M, dh)  # (C, E, 3)
    alpha0 = jnp.sum(Mdh * dh[:, None, :], axis=2)
    alpha1 = 2.0 * Mdh[:, :, 1]
    beta0 = jnp.einsum("ei,ci->ce", Md, dh)
    # cull with the bounding circle of the footprint
    rad = jnp.max(h, axis=1)
    rel = c[:, 0::2] - o[0::2][None, :]  # (E, 2)
    n2 = jnp.sum(dxz * dxz, axis=1, keepdims=True)  # (C, 1)
    proj = (dxz @ rel.T) / n2  # (C, E) in t units
    perp2 = jnp.sum(rel * rel, axis=1)[None, :] - proj * proj * n2
    rt = rad[None, :] / jnp.sqrt(n2)
    ok = valid[None, :] & (perp2 <= (rad * rad)[None, :]) & (proj + rt > NEAR)
    key = jnp.where(ok, proj - rt, INF)
    neg, sel = jax.lax.top_k(-key, me)
    ok_sel = jnp.isfinite(neg)
    a0 = jnp.take_along_axis(alpha0, sel, axis=1)
    a1 = jnp.take_along_axis(alpha1, sel, axis=1)
    b0 = jnp.take_along_axis(beta0, sel, axis=1)
    a2 = M[:, 1, 1][sel]
    b1 = Md[:, 1][sel]
    g = jnp.where(ok_sel, gamma[sel], INF)
    return a0, a1, a2, b0, b1, g, sel


def ellipsoid_pixels(yc, a0, a1, a2, b0, b1, g):
    """Nearest ellipsoid hit per pixel among the column's selected ellipsoids (``lax.scan`` over them)."""

    def body(carry, xs):
        best, bidx = carry
        k, a0k, a1k, a2k, b0k, b1k, gk = xs
        a = a0k[None, :] + yc * (a1k[None, :] + yc * a2k[None, :])
        b = b0k[None, :] + yc * b1k[None, :]
        disc = b * b - a * gk[None, :]
        t = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / a
        t = jnp.where((disc >= 0.0) & (t > NEAR), t, INF)
        better = t < best
        return (jnp.where(better, t, best), jnp.where(better, k, bidx)), None

    init = (jnp.full(yc.shape, INF, jnp.float32), jnp.zeros(yc.shape, jnp.int32))
    xs = (jnp.arange(a0.shape[1], dtype=jnp.int32), a0.T, a1.T, a2.T, b0.T, b1.T, g.T)
    (best, bidx), _ = jax.lax.scan(body, init, xs)
    return best, bidx


def trace(o, dxz, yc, prisms, ells, salt, layout, n_steps: int, mb: int, me: int):
    """Cast the rays ``o + t·(d_xz[c], y_c[r, c])``; returns per-ray static and object hits.

    Keys: ``t_static, t_obj`` (``inf`` = none), static hit description (``s_kind``: 0 sky,
    1 ground, 2 slab, 3 building; ``s_side``, ``s_xface``, ``s_cx``, ``s_cz``, ``s_bh``) and the
    object primitive row ``o_row`` (index into the concatenated prism+ellipsoid table),
    ``o_is_prism``.
    """
    oy = o[1]
    inv_yc = 1.0 / yc
    # static: ground + the DDA cells
    col = static_columns(o, dxz, salt, layout, n_steps)
    t_ground = jnp.where(yc > 0, -oy * inv_yc, INF)
    t_box, k_box = prism_pixels(oy, inv_yc, col["ta"], col["tb"], col["ylo"], col["yhi"])
    box_wins = t_box < t_ground
    t_static = jnp.minimum(t_box, t_ground)
    side = take_cols(col["ta"], k_box) >= t_box
    s_kind = jnp.where(box_wins, 2 + (k_box % 2), jnp.where(jnp.isfinite(t_ground), 1, 0))
    # objects
    ta, tb, ylo, yhi, psel = object_prism_columns(o, dxz, prisms, mb)
    t_p, k_p = prism_pixels(oy, inv_yc, ta, tb, ylo, yhi)
    a0, a1, a2, b0, b1, g, esel = object_ellipsoid_columns(o, dxz, ells, me)
    t_e, k_e = ellipsoid_pixels(yc, a0, a1, a2, b0, b1, g)
    is_prism = t_p < t_e
    row = jnp.where(is_prism, take_cols(psel, k_p), prisms.shape[0] + take_cols(esel, k_e))
    return {
        "t_static": t_static,
        "s_kind": s_kind,
        "s_side": side,
        "s_xface": take_cols(col["xface"], k_box),
        "s_cx": take_cols(col["cx"], k_box),
        "s_cz": take_cols(col["cz"], k_box),
        "s_bh": take_cols(col["bh"], k_box),
        "t_obj": jnp.minimum(t_p, t_e),
        "o_row": row,
        "o_is_prism": is_prism,
    }
