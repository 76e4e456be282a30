"""Procedural, world-anchored textures of the synthetic street world (private helper).

Every texture is a function of the 3-D hit point (through surface coordinates such as ``(x, z)`` on
the ground or ``(along, height)`` on a façade) and of the pixel footprint, so the same surface point
has the same colour in every view (multi-view consistency) while detail finer than a pixel fades to
its mean instead of aliasing (analytic box filtering, as in Inigo Quilez's "filterable procedurals").

All inputs are float32 arrays of one common shape; the integer hash is the "lowbias32" mixer of
Chris Wellons (hash-prospector), computed in ``uint32`` arithmetic.
"""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)
_GOLD = np.uint32(0x9E3779B1)


def hash_u32(x):
    """lowbias32 integer mixer (uint32 → uint32)."""
    x = jnp.asarray(x).astype(jnp.uint32)
    x = x ^ (x >> 16)
    x = x * _M1
    x = x ^ (x >> 15)
    x = x * _M2
    return x ^ (x >> 16)


def hash3(i, j, k):
    """Hash of three integer lattice coordinates (any int dtype, wrapped to uint32)."""
    h = hash_u32(jnp.asarray(i).astype(jnp.int32).astype(jnp.uint32) * _GOLD ^ jnp.asarray(k).astype(jnp.uint32))
    return hash_u32(h ^ jnp.asarray(j).astype(jnp.int32).astype(jnp.uint32) * _M2)


def unit(h):
    """uint32 hash → float32 uniform in [0, 1)."""
    return (h >> 8).astype(jnp.float32) * np.float32(1.0 / 16777216.0)


def rand3(i, j, k):
    """Uniform [0, 1) per integer lattice cell."""
    return shared(unit(hash3(i, j, k)))


def hash_fast(i, j, k):
    """A cheaper 2-D lattice hash (two multiply–xorshift rounds) for value noise."""
    h = (jnp.asarray(i).astype(jnp.uint32) * np.uint32(0x8DA6B343)) ^ (jnp.asarray(j).astype(jnp.uint32) * np.uint32(0xD8163841))
    h = (h ^ jnp.asarray(k).astype(jnp.uint32)) * np.uint32(0x2C1B3C6D)
    h = (h ^ (h >> 15)) * np.uint32(0x297A2D39)
    return h ^ (h >> 15)


def rand_bytes(i, j, k):
    """Four independent uniforms in [0, 1) (8 bits each) from one lattice hash."""
    h = shared(hash3(i, j, k))
    return [((h >> (8 * b)) & np.uint32(0xFF)).astype(jnp.float32) * np.float32(1.0 / 256.0) for b in range(4)]


def value_noise(x, y, salt):
    """2-D value noise in [0, 1] with smoothstep interpolation (one octave, lattice spacing 1)."""
    xi = jnp.floor(x)
    yi = jnp.floor(y)
    fx = x - xi
    fy = y - yi
    xi = xi.astype(jnp.int32)
    yi = yi.astype(jnp.int32)
    a = unit(hash_fast(xi, yi, salt))
    b = unit(hash_fast(xi + 1, yi, salt))
    c = unit(hash_fast(xi, yi + 1, salt))
    d = unit(hash_fast(xi + 1, yi + 1, salt))
    sx = fx * fx * (3.0 - 2.0 * fx)
    sy = fy * fy * (3.0 - 2.0 * fy)
    return shared((a + (b - a) * sx) * (1.0 - sy) + (c + (d - c) * sx) * sy)


def fade(fw, size):
    """Weight in [0, 1] of detail of world size ``size`` seen with footprint ``fw`` (1 = sharp)."""
    return jnp.clip(1.5 - 2.0 * fw / size, 0.0, 1.0)


def band(coord, lo, hi, fw):
    """Box-filtered indicator of ``lo <= coord <= hi`` for a pixel footprint ``fw`` (metres)."""
    w = jnp.maximum(fw, 1e-4)
    return jnp.clip((coord - lo) / w + 0.5, 0.0, 1.0) * jnp.clip((hi - coord) / w + 0.5, 0.0, 1.0)


def grid_lines(coord, period, half_width, fw):
    """Box-filtered periodic lines of half-width ``half_width`` every ``period`` (value in [0, 1]).

    Far away (footprint ≳ period) the pattern tends to its mean coverage ``2·half_width/period``.
    """
    d = jnp.abs(coord / period - jnp.floor(coord / period + 0.5)) * period
    w = jnp.maximum(fw, 1e-4)
    m = jnp.clip((half_width - d) / w + 0.5, 0.0, 1.0)
    mean = 2.0 * half_width / period
    return mean + (m - mean) * fade(fw, period)


# Colours are computed one channel at a time: the shading program runs in a ``lax.map`` over the
# three channels (see ``channel``), so a "colour" is a single planar array and ``rgb(r, g, b)`` picks
# the current channel's value.  XLA on CPU duplicates shared elementwise work into every output
# fusion and runs (H, W, 3) layouts unvectorised; one channel per loop iteration avoids both and
# compiles the shading program once instead of three times.
_CHANNEL: list = []


@contextlib.contextmanager
def channel(c):
    """Trace the enclosed shading code for channel ``c`` (a traced int: 0 = R, 1 = G, 2 = B)."""
    _CHANNEL.append(c)
    try:
        yield
    finally:
        _CHANNEL.pop()


_SHARED: list = []


@contextlib.contextmanager
def sharing(mode: str, values: list | None = None):
    """Record (``mode="record"``) or replay (``"replay"``) the channel-independent fields of a shading pass.

    The shading program is traced twice: once outside the per-channel ``lax.map`` in record mode,
    where every :func:`shared` value (hashes, noise, geometry) is collected, and once inside it in
    replay mode, where :func:`shared` returns the recorded arrays in the same order.  Loop operands
    are materialised, so the expensive channel-independent work runs once instead of three times.
    """
    state = {"mode": mode, "values": [] if values is None else values, "i": 0}
    _SHARED.append(state)
    try:
        yield state["values"]
    finally:
        _SHARED.pop()


def shared(x):
    """Mark a channel-independent value (see :func:`sharing`); identity outside a sharing block."""
    if not _SHARED:
        return x
    state = _SHARED[-1]
    if state["mode"] == "record":
        state["values"].append(x)
        return x
    v = state["values"][state["i"]]
    state["i"] += 1
    return v


def current_channel():
    """The traced channel index of the enclosing :func:`channel` block."""
    return _CHANNEL[-1]


def rgb(r, g, b):
    """A constant colour (its value in the current channel)."""
    return jnp.asarray([r, g, b], jnp.float32)[_CHANNEL[-1]]


def mix(a, b, t):
    """Linear interpolation ``a + (b − a)·t``."""
    return a + (b - a) * t


def cwhere(m, a, b):
    """``where(m, a, b)`` for colours."""
    return jnp.where(m, a, b)


def cscale(a, s):
    """Colour times a scalar field."""
    return a * s


def grey(v, tint=(1.0, 1.0, 1.0)):
    """A tinted grey level."""
    return v * rgb(*tint)


def palette(idx, table):
    """Pick colours of a small (n, 3) table by an integer index array (select chain, no gather)."""
    table = np.asarray(table, np.float32)
    col = jnp.asarray(table)[:, _CHANNEL[-1]]
    v = jnp.full(idx.shape, col[0], jnp.float32)
    for k in range(1, table.shape[0]):
        v = jnp.where(idx == k, col[k], v)
    return v
