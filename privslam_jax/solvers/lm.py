"""Levenberg–Marquardt with Nielsen's damping rule: the one loop under pose refinement and BA.

A problem is given by four pure functions over a pytree ``x`` (poses as ``jaxlie.SE3``, points as
arrays):

* ``linearise(x) -> system``: the normal equations at ``x`` (any pytree with a ``cost`` field,
  ``F(x) = ½ Σ ρ(s)``), e.g. :class:`~privslam_jax.solvers.linear.DenseSystem`;
* ``solve(system, λ) -> (δ, predicted decrease)``: the damped step ``(H + λ D) δ = −g`` with
  ``D = diag(H)`` clamped to [1e-6, 1e32] (Marquardt; the clamp as in Ceres) and the decrease the
  quadratic model predicts, ``½ δᵀ(λ D δ − g)``;
* ``cost(x) -> F``: the cost alone (a rejected step costs one evaluation, not a linearisation);
* ``retract(x, δ) -> x'``: the update on the manifold (``T ← exp(ξ) T``, ``X ← X + δ``).

Damping (Nielsen 1999; Madsen, Nielsen & Tingleff, *Methods for Non-Linear Least Squares
Problems*, 2004, §3.2): a step is accepted when the cost drops; then
``λ ← λ·max(⅓, 1 − (2ϱ − 1)³)``, ``ν ← 2`` with the gain ratio ``ϱ = (F − F_new)/predicted``;
otherwise ``λ ← λν``, ``ν ← 2ν``.

Stopping (as Ceres): an accepted step lowers the cost by at most ``function_tolerance·F``; or
``‖δ‖ ≤ step_tolerance + parameter_tolerance·(‖x‖ + parameter_tolerance)``; or ``F ≤ target_cost``;
or ``λ > 1e32`` (no step lowers the cost: *stalled*); or ``max_iterations``.  Why it stopped is
returned as a value, :class:`SolveSummary`, never printed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
from flax import struct
from jaxtyping import Array, Bool, Float, Int

__all__ = ["LMParams", "SolveSummary", "STATUS_NAMES", "levenberg_marquardt", "tree_norm"]

X = TypeVar("X")
S = TypeVar("S")

STATUS_NAMES: tuple[str, ...] = ("converged", "max_steps", "stalled", "non_finite")
""":attr:`SolveSummary.status` codes: 0 a tolerance or the target cost was reached; 1 the iteration
limit ended the solve; 2 no step lowered the cost (``λ > 1e32``); 3 the initial or final cost is NaN/inf."""
_RUNNING, _CONVERGED, _MAX_STEPS, _STALLED, _NON_FINITE = -1, 0, 1, 2, 3


class LMParams(struct.PyTreeNode):
    """The numeric settings of :func:`levenberg_marquardt`, as traced values (changing them does not recompile)."""

    max_iterations: Int[Array, ""]
    initial_damping: Float[Array, ""]
    """Initial λ relative to ``diag(H)`` (Ceres' initial trust radius 1e4 ⇒ 1e-4)."""
    function_tolerance: Float[Array, ""]
    step_tolerance: Float[Array, ""]
    """Absolute step-norm tolerance."""
    parameter_tolerance: Float[Array, ""]
    """Step-norm tolerance relative to ``‖x‖`` (Ceres' ``parameter_tolerance``)."""
    target_cost: Float[Array, ""]
    """Stop as soon as the cost is at or below this (0: only an exact zero)."""

    @staticmethod
    def of(
        dtype: Any,
        max_iterations: int,
        initial_damping: float,
        function_tolerance: float,
        step_tolerance: float = 0.0,
        parameter_tolerance: float = 0.0,
        target_cost: float = 0.0,
    ) -> "LMParams":
        f = lambda v: jnp.asarray(v, dtype)  # noqa: E731
        return LMParams(
            max_iterations=jnp.asarray(max_iterations, jnp.int32),
            initial_damping=f(initial_damping),
            function_tolerance=f(function_tolerance),
            step_tolerance=f(step_tolerance),
            parameter_tolerance=f(parameter_tolerance),
            target_cost=f(target_cost),
        )


@struct.dataclass
class SolveSummary:
    """Why and where a least-squares solve stopped (a value: jit-able, batchable)."""

    status: Int[Array, "*b"]
    """Index into :data:`STATUS_NAMES`."""
    iterations: Int[Array, "*b"]
    """LM iterations run (accepted and rejected steps)."""
    initial_cost: Float[Array, "*b"]
    cost: Float[Array, "*b"]
    """Final ``½ Σ ρ(s)``."""

    @property
    def converged(self) -> Bool[Array, "*b"]:
        """True where a tolerance or the target cost ended the solve (implicit gradients are valid there)."""
        return self.status == _CONVERGED

    def describe(self) -> str:
        """One line for people (host side, unbatched summaries only)."""
        name = STATUS_NAMES[int(self.status)]
        return f"{name} after {int(self.iterations)} iterations, cost {float(self.initial_cost):.6g} -> {float(self.cost):.6g}"


def tree_norm(tree: Any) -> Float[Array, ""]:
    """Euclidean norm over every leaf of a pytree (``jaxlie`` groups count by their parameters)."""
    return jnp.sqrt(sum(jnp.sum(leaf * leaf) for leaf in jax.tree.leaves(tree)))


def _all_finite(tree: Any) -> Bool[Array, ""]:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves(tree)]))


def levenberg_marquardt(
    x0: X,
    linearise: Callable[[X], S],
    solve: Callable[[S, Array], tuple[Any, Array]],
    cost: Callable[[X], Array],
    retract: Callable[[X, Any], X],
    params: LMParams,
    system0: S | None = None,
) -> tuple[X, S, SolveSummary]:
    """Minimise ``F`` from ``x0`` (jit-able; see the module docstring for the functions' contracts).

    ``system0``: the linearisation at ``x0`` if the caller already has it.  Returns the solution, its
    linearisation (whose ``cost`` is the final cost) and the :class:`SolveSummary`.
    """
    sys0 = linearise(x0) if system0 is None else system0
    dtype = jnp.asarray(sys0.cost).dtype
    one = jnp.asarray(1.0, dtype)
    init = (x0, sys0, one * params.initial_damping, 2.0 * one, jnp.asarray(0), jnp.asarray(_RUNNING))

    def cond(st):
        _, system, _, _, it, reason = st
        return (it < params.max_iterations) & (reason == _RUNNING) & (system.cost > params.target_cost)

    def body(st):
        x, system, lam, nu, it, _ = st
        step, predicted = solve(system, lam)
        x_new = retract(x, step)
        cost_new = cost(x_new)
        ok = jnp.isfinite(cost_new) & _all_finite(step)
        accept = ok & (cost_new < system.cost)
        # re-linearise only after an accepted step
        system_new = jax.lax.cond(accept, lambda: linearise(x_new), lambda: system)
        gain = (system.cost - cost_new) / jnp.maximum(predicted, jnp.finfo(dtype).tiny)
        lam_accepted = lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        tol = params.step_tolerance + params.parameter_tolerance * (tree_norm(x) + params.parameter_tolerance)
        small_step = ok & (tree_norm(step) <= tol)
        small_decrease = accept & ((system.cost - cost_new) <= params.function_tolerance * system.cost)
        reason = jnp.where(small_step | small_decrease, _CONVERGED, jnp.where(lam > 1e32, _STALLED, _RUNNING))
        pick = lambda a, b: jax.tree.map(lambda u, v: jnp.where(accept, u, v), a, b)  # noqa: E731
        return (
            pick(x_new, x),
            system_new,
            jnp.where(accept, lam_accepted, lam * nu),
            jnp.where(accept, 2.0 * one, nu * 2.0),
            it + 1,
            reason,
        )

    x_f, sys_f, _, _, it_f, reason = jax.lax.while_loop(cond, body, init)
    finite = jnp.isfinite(sys0.cost) & jnp.isfinite(sys_f.cost)
    reached = (reason == _CONVERGED) | (sys_f.cost <= params.target_cost)
    status = jnp.where(~finite, _NON_FINITE, jnp.where(reached, _CONVERGED, jnp.where(reason == _STALLED, _STALLED, _MAX_STEPS)))
    return x_f, sys_f, SolveSummary(status=status, iterations=it_f, initial_cost=sys0.cost, cost=sys_f.cost)
