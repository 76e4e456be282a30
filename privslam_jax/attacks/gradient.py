"""Gradient-based point recovery from a line cloud (a second attack next to Line2Point).

Unknowns: one offset ``t_i`` per line, the recovered point ``x_i = a_i + t_i d_i`` (``a_i = d_i × m_i``
the line's closest point to the origin).  Points of a real map lie on surfaces, so the lines of
nearby points pass close to each other near the points themselves.  The attack minimises the
robust (Cauchy / Lorentzian) consistency energy over a fixed neighbour graph ``𝒩``::

    E(t) = Σ_i Σ_{j ∈ 𝒩(i)} σ² · log(1 + ‖x_i(t_i) − x_j(t_j)‖² / σ²)

where ``𝒩(i)`` are the ``k`` lines nearest line ``i`` by line–line distance (Line2Point's
distance, line ``i`` excluded).  Each term pulls both points towards the closest approach of the
two lines; the log caps the pull of pairs that are far apart (lines that only pass close
somewhere else), so ``E`` rewards *local density*.  Start: ``t_i⁰`` = median over ``𝒩(i)`` of the
closest-approach offsets along line ``i`` (a one-shot version of Line2Point's coarse step), or a
given start (e.g. Line2Point's output).  Solver: ``optimistix.NonlinearCG`` (Polak–Ribière,
backtracking Armijo), jitted; ``N`` unknowns, so no dense Hessian.

For σ → ∞ and a pair of lines the energy is ``‖x₁ − x₂‖²`` and the minimiser is the pair's
closest approach (the closed form the tests check).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import optimistix as optx
from jax import lax
from jaxtyping import Array, Float, Int

from privslam_jax.attacks.line2point import _estimates, _line_line_dist, select_smallest
from privslam_jax.types import LineCloud

__all__ = ["GradientAttackConfig", "gradient_attack", "consistency_energy", "line_neighbours"]


@dataclass(frozen=True)
class GradientAttackConfig:
    """Parameters of the gradient attack."""

    num_neighbours: int = 16
    """``k``: neighbours per line in the energy."""
    sigma: float = 0.5
    """Scale of the Cauchy loss, metres."""
    max_steps: int = 300
    """Nonlinear CG iterations at most."""
    rtol: float = 1e-5
    """Relative tolerance of the solver."""
    atol: float = 1e-5
    """Absolute tolerance of the solver."""
    chunk_size: int = 128
    """Rows per vectorised block of the neighbour search."""


@partial(jax.jit, static_argnames=("k", "chunk_size"))
def line_neighbours(
    anchors: Float[Array, "N 3"], directions: Float[Array, "N 3"], *, k: int, chunk_size: int = 128
) -> Int[Array, "N k"]:
    """The ``k`` nearest lines of every line (itself excluded), chunked: memory ``O(chunk·N)``."""
    aT, dT = anchors.T, directions.T
    n = anchors.shape[0]

    def one(i):
        dist = _line_line_dist(anchors[i], directions[i], aT, dT)
        return select_smallest(jnp.where(jnp.arange(n) == i, jnp.inf, dist), k)

    return lax.map(one, jnp.arange(n), batch_size=chunk_size)


def consistency_energy(
    t: Float[Array, " N"], anchors: Float[Array, "N 3"], directions: Float[Array, "N 3"],
    neighbours: Int[Array, "N k"], sigma: float,
) -> Float[Array, ""]:
    """``E(t)`` of the module docstring."""
    x = anchors + t[:, None] * directions
    diff = x[:, None, :] - x[neighbours]
    s = jnp.sum(diff * diff, axis=-1)
    return jnp.sum(sigma**2 * jnp.log1p(s / sigma**2))


@partial(jax.jit, static_argnames=("config",))
def _solve(t0, anchors, directions, neighbours, config: GradientAttackConfig):
    def fn(t, args):
        return consistency_energy(t, anchors, directions, neighbours, config.sigma)

    solver = optx.NonlinearCG(rtol=config.rtol, atol=config.atol)
    sol = optx.minimise(fn, solver, t0, max_steps=config.max_steps, throw=False)
    return sol.value, sol.stats["num_steps"]


@jax.jit
def _median_start(anchors, directions, neighbours):
    est = jax.vmap(lambda a, d, nb: _estimates(a, d, anchors[nb], directions[nb]))(anchors, directions, neighbours)
    return jnp.median(est, axis=1)


def gradient_attack(
    lines: LineCloud, config: GradientAttackConfig = GradientAttackConfig(), t0: Float[Array, " N"] | None = None
) -> tuple[Float[Array, "N 3"], Float[Array, " N"]]:
    """Recover one point per line by minimising ``E``; returns ``(points, offsets)``."""
    d = jnp.asarray(lines.directions)
    if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] <= config.num_neighbours:
        raise ValueError(
            f"gradient attack needs more than {config.num_neighbours} lines of shape (N, 3), got {tuple(d.shape)}"
        )
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    a = jnp.cross(d, jnp.asarray(lines.moments, d.dtype))
    if not bool(jnp.all(jnp.isfinite(a)) & jnp.all(jnp.isfinite(d))):
        raise ValueError("line cloud contains NaN/inf or zero directions")
    nb = line_neighbours(a, d, k=config.num_neighbours, chunk_size=config.chunk_size)
    start = _median_start(a, d, nb) if t0 is None else jnp.asarray(t0, d.dtype)
    t, _ = _solve(start, a, d, nb, config)
    return a + t[:, None] * d, t
