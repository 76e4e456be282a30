"""A lift whose directions are optimised against the gradient attack (issue 19 item 5).

Every point ``p_i`` gets a line ``(d_i, p_i × d_i)`` as in the random lift, but the directions are
then moved by gradient descent to *maximise* the error of the differentiable gradient attack
(:func:`~privslam_jax.attacks.gradient.gradient_attack_core`, differentiated by the implicit function
theorem), while a conditioning term keeps each line usable for localisation::

    d_i = θ_i / ‖θ_i‖,      θ⁰_i ~ N(0, I₃)  (the random lift's draw for the key)

    L(θ) = − 1/|B| Σ_{i ∈ B} c · tanh(‖x̂_i(θ) − p_i‖ / c)  +  w · 1/|B| Σ_{i ∈ B} (d_i · v_i)²

``x̂(θ)`` is the attack's estimate on the lines of a patch ``B`` (the ``patch_size`` points nearest a
random point of the map: the attack's neighbour graph is local, so a patch sees what the whole-map
attack sees away from its border, and the implicit gradient's ``|B|×|B|`` Hessian stays small);
``c`` caps the reward for pushing an estimate far away (an error of ``c`` is as good as any larger one).
``v_i`` is the unit direction in which ``p_i`` is seen (a SLAM map point's viewing normal, the mean
bearing from its observing cameras): a line along the viewing ray projects to a single pixel and tells a
localiser nothing, so ``(d_i · v_i)²`` penalises directions near the ray (the degeneracy Speciale et al.
note).  Without viewing directions ``w`` is ignored.
Adam (Optax) on ``θ``, one step per patch; the patch's loss and gradient are one jitted program per patch
size, whatever the size of the map.

**What it is and is not.**  The optimisation is white-box against one attack; the lift is judged by
the attacks that took no part in it (Line2Point, two-peak finding), as ``experiments/table_map_privacy.py``
does.  The directions depend on the points through the optimisation (unlike the random lift's), which an
attacker who knows the algorithm might exploit; nothing here measures that.  The key seeds the start
and the patches; as for every lift, a published cloud needs a secret key.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, ArrayLike, Float

from privslam_jax.attacks.gradient import GradientAttackConfig, gradient_attack_core
from privslam_jax.geometry.plucker import lines_from_points_directions
from privslam_jax.privacy.lift import _as_points, _directions, _lines, entropy_key, unique_points
from privslam_jax.types import LineCloud

__all__ = ["OptimisedLiftConfig", "optimised_lift", "lift_loss"]


@dataclasses.dataclass(frozen=True)
class OptimisedLiftConfig:
    """Settings of :func:`optimised_lift`."""

    passes: float = 100.0
    """Adam steps (one patch each) = ``passes · N / patch_size``: how often each point is optimised, on average."""
    learning_rate: float = 0.1
    """Adam step size on the unnormalised directions ``θ`` (unit length at the start)."""
    patch_size: int = 256
    """Points per patch (the nearest ones to a random point)."""
    cap: float = 2.0
    """``c``: errors beyond a few ``c`` metres earn nothing more (module docstring)."""
    conditioning_weight: float = 1.0
    """``w``: weight of the viewing-ray term (ignored without viewing directions)."""
    attack: GradientAttackConfig = GradientAttackConfig(max_steps=100)
    """The attack optimised against (fewer steps than its default: the gradient needs a minimiser, the
    loss only its neighbourhood)."""


def lift_loss(theta: Float[Array, "B 3"], points: Float[Array, "B 3"], bearings: Float[Array, "B 3"],
              config: OptimisedLiftConfig) -> tuple[Float[Array, ""], Float[Array, " B"]]:
    """``L`` of the module docstring on one patch, and the attack's per-point errors."""
    d = theta / jnp.linalg.norm(theta, axis=-1, keepdims=True)
    res = gradient_attack_core(lines_from_points_directions(points, d), config.attack)
    err = jnp.linalg.norm(res.points - points, axis=-1)
    privacy = -jnp.mean(config.cap * jnp.tanh(err / config.cap))
    conditioning = jnp.mean(jnp.sum(d * bearings, axis=-1) ** 2)
    return privacy + config.conditioning_weight * conditioning, err


@partial(jax.jit, static_argnames=("config",))
def _patch_gradient(theta, points, bearings, config: OptimisedLiftConfig):
    """Loss, gradient and the attack's share within 0.5 m on one patch: one compiled program per patch size."""
    (loss, err), g = jax.value_and_grad(lift_loss, has_aux=True)(theta, points, bearings, config)
    return loss, jnp.where(jnp.isfinite(g), g, 0.0), jnp.mean(err < 0.5)


@partial(jax.jit, static_argnames=("optimiser",))
def _apply(theta, opt_state, idx, g, optimiser):
    updates, opt_state = optimiser.update(jnp.zeros_like(theta).at[idx].set(g), opt_state, theta)
    return optax.apply_updates(theta, updates), opt_state


def optimised_lift(points: ArrayLike, key: jax.Array | None = None,
                   viewing_directions: Float[ArrayLike, "N 3"] | None = None,
                   config: OptimisedLiftConfig = OptimisedLiftConfig(), progress: bool = False) -> LineCloud:
    """Lift each point to a line through it whose direction was optimised against the gradient attack.

    Args:
      points: ``(N, 3)`` points, ``N > config.patch_size``.
      key: ``jax.random`` key (start directions and patches); ``None`` draws one from OS entropy.
      viewing_directions: ``(N, 3)`` direction in which each point is seen (e.g. ``PointCloud.normals`` of a
        SLAM map; normalised here), for the localisation-conditioning term; ``None`` drops the term.
      progress: print the loss and the attack's share within 0.5 m of the patch every 200 steps.

    Host entry point with the lifts' rules (input checks, repeated points share one line, the input's
    precision); the optimisation runs in float32.
    """
    from scipy.spatial import cKDTree

    p, dtype = _as_points(points)
    first, inverse = unique_points(p)
    q = p[first]
    if len(q) <= config.patch_size:
        raise ValueError(f"the optimised lift needs more than patch_size={config.patch_size} distinct points, got {len(q)}")
    if viewing_directions is None:
        bearings = np.zeros_like(q)
        config = dataclasses.replace(config, conditioning_weight=0.0)
    else:
        v = np.asarray(viewing_directions, np.float64)
        if v.shape != p.shape or not np.all(np.isfinite(v)):
            raise ValueError(f"viewing directions must be finite and of the points' shape {p.shape}, got {v.shape}")
        bearings = v[first] / np.maximum(np.linalg.norm(v[first], axis=1, keepdims=True), 1e-12)
    key = entropy_key() if key is None else key
    k_dir, k_patch = jax.random.split(key)
    theta = jnp.asarray(_directions(k_dir, len(q)), jnp.float32)
    optimiser = optax.adam(config.learning_rate)
    opt_state = optimiser.init(theta)
    tree = cKDTree(q)
    rng = np.random.default_rng(np.asarray(jax.random.key_data(k_patch)).ravel())
    qj, bj = jnp.asarray(q, jnp.float32), jnp.asarray(bearings, jnp.float32)
    steps = max(1, int(np.ceil(config.passes * len(q) / config.patch_size)))
    for step in range(steps):
        _, idx = tree.query(q[rng.integers(len(q))], k=config.patch_size)
        idx = jnp.asarray(idx)
        loss, g, within = _patch_gradient(theta[idx], qj[idx], bj[idx], config)
        theta, opt_state = _apply(theta, opt_state, idx, g, optimiser)
        if progress and (step % 200 == 0 or step == steps - 1):
            print(f"optimised lift: step {step}: loss {float(loss):.3f}, attack within 0.5 m {100 * float(within):.1f} %",
                  flush=True)
    d = np.asarray(theta, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    d = d[inverse]
    return _lines(d, np.cross(p, d), dtype)
