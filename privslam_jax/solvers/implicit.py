"""Derivatives of a minimiser by the implicit-function theorem (forward and reverse mode).

Let ``x*(θ) = argmin_x F(x, θ)`` on a manifold with retraction ``x ⊞ ξ`` (``exp(ξ)·T`` for poses,
``X + δ`` for points).  At a minimum the tangent gradient vanishes,
``G(ξ, θ) = ∇_ξ F(x* ⊞ ξ, θ)|_{ξ=0} = 0``, and differentiating that identity gives

    H ξ̇ = −(∂G/∂θ) θ̇,     H = ∂G/∂ξ (the exact Hessian of F in the tangent space at x*),
    ẋ = ∂(x* ⊞ ξ)/∂ξ · ξ̇

(Krantz & Parks, *The Implicit Function Theorem*, 2002; Blondel et al., *Efficient and Modular
Implicit Differentiation*, NeurIPS 2022).  The rule is a ``jax.custom_jvp``: the solver's loop is never
differentiated, and because every step after ``H`` is linear in ``θ̇`` JAX transposes it for reverse
mode, so ``jax.jvp``/``jacfwd`` and ``jax.grad``/``jacrev`` both work, under ``jit`` too; one extra
linear solve with ``H`` per derivative.  ``H`` is the exact Hessian (forward-over-reverse), not the
Gauss–Newton matrix, so the derivative is exact for non-zero residuals and robust losses as well.

Caveats, made explicit rather than silent:

* the derivative is that of the *converged* minimiser: when the solve did not converge
  (``converged(aux)`` false) or ``H`` is singular (a gauge left free, e.g. monocular BA's scale),
  every tangent of ``x`` is NaN;
* rows of ``H`` that are exactly zero (variables the cost does not see: fixed cameras, padded points)
  get an identity row, so their derivative is zero;
* the initial guess ``x0`` and ``const`` get no derivative (their tangents are ignored), and the auxiliary outputs (costs, masks,
  counters) are treated as constants (zero tangents), like ``stop_gradient``;
* ``H`` is dense (``n × n`` for ``n`` tangent dimensions): meant for pose refinement and small BA
  problems; :func:`implicit_argmin` refuses ``n > max_dim``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

__all__ = ["implicit_argmin"]


def _zero_tangent(a: Any) -> Any:
    a = jnp.asarray(a)
    if jnp.issubdtype(a.dtype, jnp.inexact):
        return jnp.zeros_like(a)
    return np.zeros(a.shape, dtype=jax.dtypes.float0)


def implicit_argmin(
    solve: Callable[[Any, Any, Any], tuple[Any, Any]],
    objective: Callable[[Any, Any, Any, Any], jax.Array],
    retract: Callable[[Any, Any, Any], Any],
    zero_tangent: Callable[[Any], Any],
    converged: Callable[[Any], jax.Array],
    max_dim: int = 4096,
) -> Callable[[Any, Any, Any], tuple[Any, Any]]:
    """Make ``solve`` differentiable in ``θ`` by the implicit-function theorem.

    Args:
      solve: ``(x0, θ, const) -> (x*, aux)``, any solver (not differentiated).
      objective: ``(x, θ, const, aux) -> F``, the scalar cost ``x*`` minimises (``aux`` may select
        e.g. the inlier set the last round used).
      retract: ``(x, ξ, const) -> x ⊞ ξ`` (``const`` may mask fixed variables).
      zero_tangent: ``x -> 0`` in the tangent space (any pytree).
      converged: ``aux -> bool``, whether the derivative of this solve is meaningful.
      max_dim: largest tangent dimension accepted (``H`` is built densely).

    Returns ``f(x0, θ, const) -> (x*, aux)`` with the same values as ``solve`` and derivatives in ``θ``,
    jitted (one compilation per shape, also for eager callers and for ``jacfwd``/``jacrev``/``grad``
    outside ``jit``).  ``θ`` must hold only floating-point arrays; every leaf of ``x0``, ``θ`` and
    ``const`` is traced.
    """

    aux_tree: list[Any] = []  # the auxiliary outputs cross the custom_jvp as a flat tuple of leaves

    def solve_flat(x0: Any, theta: Any, const: Any) -> tuple[Any, tuple[Any, ...], Any]:
        x, aux = solve(x0, theta, const)
        leaves, tree = jax.tree.flatten(aux)
        aux_tree[:] = [tree]
        return x, tuple(leaves), aux

    # ``const`` crosses as a flat tuple of leaves, a differentiable argument whose tangent is ignored:
    # as a ``nondiff_argnums`` argument its arrays would be closed-over constants, which breaks
    # ``grad`` of a ``jit``-ed caller (a tracer cannot be a constant), and as a pytree of the caller's
    # own (type-checked) classes its float0 tangents would have to pass their annotations.
    @functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
    def f(const_tree: Any, x0: Any, theta: Any, const_leaves: tuple[Any, ...]) -> tuple[Any, tuple[Any, ...]]:
        x, leaves, _ = solve_flat(x0, theta, jax.tree.unflatten(const_tree, const_leaves))
        return x, leaves

    @f.defjvp
    def f_jvp(const_tree: Any, primals: tuple[Any, Any, Any], tangents: tuple[Any, Any, Any]) -> tuple[Any, Any]:
        x0, theta, const_leaves = primals
        const = jax.tree.unflatten(const_tree, const_leaves)
        theta_dot = tangents[1]
        x, leaves, aux = solve_flat(x0, theta, const)
        flat0, unravel = ravel_pytree(zero_tangent(x))
        n = flat0.shape[0]
        if n > max_dim:
            raise ValueError(f"implicit derivative of a problem with {n} tangent dimensions: the dense Hessian is "
                             f"limited to {max_dim} (max_dim); differentiate a smaller problem")

        def grad_tangent(flat: jax.Array, th: Any) -> jax.Array:
            g = jax.grad(lambda t: objective(retract(x, unravel(t), const), th, const, aux))(flat)
            return g

        H = jax.jacfwd(grad_tangent)(flat0, theta)
        H = 0.5 * (H + H.T)
        dead = jnp.all(H == 0, axis=1)
        H = H + jnp.diag(dead.astype(H.dtype))
        # singular or not, judged in units of the variables' own curvature (Jacobi scaling
        # D^-1/2 H D^-1/2): metres against radians must not look like a free gauge
        d = jnp.sqrt(jnp.abs(jnp.diag(H)))
        d = jnp.where(d > 0, d, 1.0)
        eig = jnp.abs(jnp.linalg.eigvalsh(H / jnp.outer(d, d)))
        well_posed = jnp.min(eig) > 1e3 * jnp.finfo(H.dtype).eps * jnp.max(eig)
        scale = jnp.where(converged(aux) & well_posed, 1.0, jnp.nan).astype(H.dtype)
        _, rhs = jax.jvp(lambda th: grad_tangent(flat0, th), (theta,), (theta_dot,))
        xi_dot = -jnp.linalg.solve(H, rhs) * scale
        _, x_dot = jax.jvp(lambda t: retract(x, unravel(t), const), (flat0,), (xi_dot,))
        return (x, leaves), (x_dot, tuple(_zero_tangent(a) for a in leaves))

    def call(x0: Any, theta: Any, const: Any) -> tuple[Any, Any]:
        const_leaves, const_tree = jax.tree.flatten(const)
        x, leaves = f(const_tree, x0, theta, tuple(const_leaves))
        return x, jax.tree.unflatten(aux_tree[0], leaves)

    return jax.jit(call)
