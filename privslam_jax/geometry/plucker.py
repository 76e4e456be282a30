"""3D lines in Plücker coordinates ``(d, m)``: construction, closest points, distances.

A line through point ``p`` with unit direction ``d`` has moment ``m = p × d`` (orthogonal to
``d``); every point of the line gives the same ``m``.  Its point closest to the origin is
``c = d × m``.  Formulas (Pottmann & Wallner, *Computational Line Geometry*, §2.1):

* point–line distance: ``‖x × d − m‖`` (for unit ``d``);
* line–line distance of non-parallel lines: ``|d₁·m₂ + d₂·m₁| / ‖d₁ × d₂‖`` (the reciprocal
  product over the sine of the angle); of parallel lines: ``‖d₁ × (c₂ − c₁)‖``;
* closest approach of ``x = p₁ + t₁d₁`` and ``y = p₂ + t₂d₂``: with ``w = p₁ − p₂``,
  ``b = d₁·d₂``, ``t₁ = (b (d₂·w) − d₁·w)/(1 − b²)``, ``t₂ = ((d₂·w) − b (d₁·w))/(1 − b²)``.

All functions work on one line (or pair) and broadcast over leading batch axes.  They are pure
JAX (no host checks): jit-able and differentiable.  Norms go through :func:`safe_norm`, whose
gradient at zero is 0 instead of ``jnp.linalg.norm``'s NaN, so a distance that is exactly zero
(a point on its line, intersecting lines) does not turn a gradient into NaN.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from privslam_jax.types import LineCloud

__all__ = [
    "lines_from_points_directions",
    "closest_point_to_origin",
    "point_line_distance",
    "line_line_distance",
    "closest_approach",
    "safe_norm",
]

_PARALLEL_EPS = 1e-12


def safe_norm(x: Float[Array, "*b n"], keepdims: bool = False) -> Float[Array, "*b"] | Float[Array, "*b 1"]:
    """``‖x‖`` over the last axis, equal in value to ``jnp.linalg.norm(x, axis=-1)``, with the
    subgradient 0 at ``x = 0`` (``jnp.linalg.norm`` gives NaN there, and NaN survives ``where``)."""
    sq = jnp.sum(x * x, axis=-1, keepdims=keepdims)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def lines_from_points_directions(points: Float[Array, "N 3"], directions: Float[Array, "N 3"]) -> LineCloud:
    """Lines through ``points`` along ``directions`` (normalised here): ``d = u/‖u‖``, ``m = p × d``."""
    d = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
    return LineCloud(directions=d, moments=jnp.cross(points, d))


def closest_point_to_origin(d: Float[Array, "*b 3"], m: Float[Array, "*b 3"]) -> Float[Array, "*b 3"]:
    """``c = d × m`` (unit ``d``): the point of the line closest to the origin."""
    return jnp.cross(d, m)


def point_line_distance(x: Float[Array, "*b 3"], d: Float[Array, "*b 3"], m: Float[Array, "*b 3"]) -> Float[Array, "*b"]:
    """Distance ``‖x × d − m‖`` from point ``x`` to the line ``(d, m)`` (unit ``d``)."""
    return safe_norm(jnp.cross(x, d) - m)


def line_line_distance(
    d1: Float[Array, "*b 3"], m1: Float[Array, "*b 3"], d2: Float[Array, "*b 3"], m2: Float[Array, "*b 3"]
) -> Float[Array, "*b"]:
    """Shortest distance between two lines (unit directions), parallel lines included."""
    cr = jnp.cross(d1, d2)
    s2 = jnp.sum(cr * cr, axis=-1)
    parallel = s2 < _PARALLEL_EPS
    recip = jnp.abs(jnp.sum(d1 * m2, axis=-1) + jnp.sum(d2 * m1, axis=-1))
    skew = recip / jnp.sqrt(jnp.where(parallel, 1.0, s2))
    c1, c2 = jnp.cross(d1, m1), jnp.cross(d2, m2)
    par = safe_norm(jnp.cross(d1, c2 - c1))
    return jnp.where(parallel, par, skew)


def closest_approach(
    p1: Float[Array, "*b 3"], d1: Float[Array, "*b 3"], p2: Float[Array, "*b 3"], d2: Float[Array, "*b 3"]
) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """Parameters ``(t₁, t₂)`` of the closest points ``p₁ + t₁d₁`` and ``p₂ + t₂d₂`` (unit directions).

    Parallel lines have no unique answer; they return ``t₁ = 0`` and ``t₂`` = the foot of ``p₁``.
    """
    w = p1 - p2
    b = jnp.sum(d1 * d2, axis=-1)
    dw1 = jnp.sum(d1 * w, axis=-1)
    dw2 = jnp.sum(d2 * w, axis=-1)
    den = 1.0 - b * b
    parallel = den < _PARALLEL_EPS
    safe = jnp.where(parallel, 1.0, den)
    t1 = jnp.where(parallel, 0.0, (b * dw2 - dw1) / safe)
    t2 = jnp.where(parallel, dw2, (dw2 - b * dw1) / safe)
    return t1, t2
