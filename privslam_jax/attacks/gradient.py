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

**Entry points.**  :func:`gradient_attack` is the host entry point: it checks the lines (shape,
NaN/inf, zero directions) and the start with ``ValueError``, solves, and by default
(``throw=True``) raises ``RuntimeError`` when the solve did not succeed (e.g. ``max_steps``
reached).  :func:`gradient_attack_core` is the same computation as a pure function without host
checks: jit-able and differentiable in the line cloud; it never raises and reports the optimistix
result code and step count in its :class:`GradientAttackResult` for the caller to check.

**Gradients.**  The minimiser ``t*(a, d)`` is differentiated by the implicit function theorem
(``optimistix.ImplicitAdjoint``, optimistix's default: ``∂t*/∂θ = −(∇²_t E)⁻¹ ∂(∇_t E)/∂θ``,
no unrolled iterations).  Held constant: the neighbour graph ``𝒩`` (discrete, chosen on
``lax.stop_gradient`` copies of the lines) and the start ``t⁰`` (a converged minimiser does not
depend on it).  The Hessian ``∇²_t E`` is materialised (``N × N``, LU): memory ``O(N²)``, time
``O(N³)``, so gradients are for clouds of up to a few thousand lines.  They are only meaningful
where the solve converged (``result == optimistix.RESULTS.successful``) to a strict minimum.
``tests/test_attack_gradients.py`` checks ``jax.jit(jax.grad(...))`` against central finite
differences.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from flax import struct
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from privslam_jax.attacks.line2point import (
    _anchors,
    _estimates,
    _line_line_dist,
    select_smallest,
)
from privslam_jax.types import LineCloud

__all__ = [
    "GradientAttackConfig",
    "GradientAttackResult",
    "gradient_attack",
    "gradient_attack_core",
    "consistency_energy",
    "line_neighbours",
]


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


@struct.dataclass
class GradientAttackResult:
    """What the gradient attack returns (a pytree: it can leave ``jit``)."""

    points: Float[Array, "N 3"]
    """Recovered points ``a + t·d``."""
    offsets: Float[Array, " N"]
    """Offsets ``t`` along the lines from their anchors ``a = d × m``."""
    result: optx.RESULTS
    """The optimistix result code (``optimistix.RESULTS.successful`` when the solve converged)."""
    num_steps: Int[Array, ""]
    """NonlinearCG iterations run (at most ``max_steps``)."""

    @property
    def successful(self) -> Bool[Array, ""]:
        """``result == optimistix.RESULTS.successful``."""
        return self.result == optx.RESULTS.successful

    def message(self) -> str:
        """optimistix's explanation of :attr:`result` (``""`` for success; host side)."""
        return optx.RESULTS[self.result]


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


def _energy(t, args, sigma: float):
    anchors, directions, neighbours = args
    return consistency_energy(t, anchors, directions, neighbours, sigma)


@partial(jax.jit, static_argnames=("config",))
def _minimise(t0, anchors, directions, neighbours, config: GradientAttackConfig):
    """NonlinearCG on ``E`` from ``t0``: ``(t, optimistix result, steps)``; never raises
    (``throw=False``), differentiable in the lines through ``optimistix.ImplicitAdjoint``."""
    solver = optx.NonlinearCG(rtol=config.rtol, atol=config.atol)
    sol = optx.minimise(
        partial(_energy, sigma=config.sigma), solver, t0, (anchors, directions, neighbours),
        max_steps=config.max_steps, adjoint=optx.ImplicitAdjoint(), throw=False,
    )
    return sol.value, sol.result, sol.stats["num_steps"]


@jax.jit
def _median_start(anchors, directions, neighbours):
    est = jax.vmap(lambda a, d, nb: _estimates(a, d, anchors[nb], directions[nb]))(anchors, directions, neighbours)
    return jnp.median(est, axis=1)


def _attack(a, d, config: GradientAttackConfig, t0) -> GradientAttackResult:
    """The attack on anchors and unit directions (no checks; jit-able, never raises)."""
    a0, d0 = lax.stop_gradient(a), lax.stop_gradient(d)
    nb = line_neighbours(a0, d0, k=config.num_neighbours, chunk_size=config.chunk_size)
    start = _median_start(a0, d0, nb) if t0 is None else lax.stop_gradient(jnp.asarray(t0, d.dtype))
    t, result, steps = _minimise(start, a, d, nb, config)
    return GradientAttackResult(points=a + t[:, None] * d, offsets=t, result=result, num_steps=steps)


def gradient_attack_core(
    lines: LineCloud, config: GradientAttackConfig = GradientAttackConfig(), t0: Float[Array, " N"] | None = None
) -> GradientAttackResult:
    """:func:`gradient_attack` as a pure function: jit-able and differentiable in ``lines``.

    No input checks and no exception: the solve runs with optimistix ``throw=False`` and the
    caller checks ``result.successful`` (or ``result.result``) and ``result.num_steps``.
    Gradients: implicit function theorem at the returned minimiser, with the neighbour graph and
    the start held constant (module docstring); they are meaningless unless the solve succeeded.
    Needs ``N > num_neighbours`` lines (``lax.top_k`` fails at trace time otherwise).
    """
    a, d = _anchors(lines)
    return _attack(a, d, config, t0)


def gradient_attack(
    lines: LineCloud,
    config: GradientAttackConfig = GradientAttackConfig(),
    t0: Float[Array, " N"] | None = None,
    *,
    throw: bool = True,
) -> GradientAttackResult:
    """Recover one point per line by minimising ``E``.

    Returns a :class:`GradientAttackResult` (points, offsets, the optimistix result code and the
    step count).  Host entry point: ``ValueError`` for fewer than
    ``num_neighbours + 1`` lines, a wrong shape, NaN/inf or zero directions, or a bad ``t0``.
    With ``throw=True`` (default) a solve that did not succeed (``max_steps`` reached, divergence,
    non-finite values) raises ``RuntimeError``; ``throw=False`` returns the last iterate and its
    result code instead.  Not traceable; under ``jit``/``grad`` use :func:`gradient_attack_core`.
    """
    d = jnp.asarray(lines.directions)
    if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] <= config.num_neighbours:
        raise ValueError(
            f"gradient attack needs more than {config.num_neighbours} lines of shape (N, 3), got {tuple(d.shape)}"
        )
    if tuple(np.shape(lines.moments)) != tuple(d.shape):
        raise ValueError(f"line moments must have the shape of the directions {tuple(d.shape)}, got {tuple(np.shape(lines.moments))}")
    a, d = _anchors(lines)
    if not bool(jnp.all(jnp.isfinite(a)) & jnp.all(jnp.isfinite(d))):
        raise ValueError("line cloud contains NaN/inf or zero directions")
    if t0 is not None:
        if tuple(np.shape(t0)) != (d.shape[0],):
            raise ValueError(f"t0 must have shape ({d.shape[0]},) (one offset per line), got {tuple(np.shape(t0))}")
        if not bool(np.all(np.isfinite(np.asarray(t0)))):
            raise ValueError("t0 contains NaN or inf")
    res = _attack(a, d, config, t0)
    if throw and not bool(res.successful):
        raise RuntimeError(
            f"gradient attack: the solve did not succeed after {int(res.num_steps)} of max_steps={config.max_steps} "
            f"NonlinearCG steps: {res.message()} Pass throw=False to take the last iterate (the result "
            "says why it stopped), or raise max_steps / loosen rtol, atol."
        )
    return res
