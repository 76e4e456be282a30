r"""Pose-graph optimisation on the least-squares core: ORB-SLAM's essential graph after a loop closure.

Nodes are camera-from-world poses :math:`S_i` (:class:`~privslam_jax.geometry.sim3.Sim3`; rigid poses
are the case :math:`s = 1`).  An edge :math:`(i, j)` measures the relative pose
:math:`Z_{ij} \approx S_i S_j^{-1}` (camera :math:`j` to camera :math:`i`) — an odometry or covisibility
edge from the map before the loop, or the loop edge from the Sim(3) between the two matched
keyframes.  As in ORB-SLAM's ``Optimizer::OptimizeEssentialGraph`` (Mur-Artal & Tardós, *ORB-SLAM2*,
T-RO 2017, §VI-D; the g2o edge ``EdgeSim3``) the error of an edge is

.. math:: e_{ij} = \phi\!\left(Z_{ij}\, S_j\, S_i^{-1}\right) \in \mathbb R^7,

zero when the edge is satisfied, with the chart :math:`\phi` = :meth:`Sim3.log_chart` (the rotation
log, the translation and the log scale; see :mod:`privslam_jax.geometry.sim3`).  The cost is

.. math:: F = \tfrac12 \sum_{(i,j)} \rho\!\left(e_{ij}^\top \Omega_{ij} e_{ij}\right)

with a diagonal information :math:`\Omega_{ij}` (ORB-SLAM: identity) and :math:`\rho` the Huber loss
(``huber_delta``; ``inf``: squared, ORB-SLAM's choice).  It is minimised by
:func:`~privslam_jax.solvers.lm.levenberg_marquardt` over the retraction :meth:`Sim3.retract` of every
free node, with dense normal equations (:math:`7N` unknowns; the essential graph of a few hundred
keyframes).  ``with_scale=False`` (stereo / RGB-D: SE(3)) freezes every node's scale.  The gauge is
fixed by ``fixed`` nodes (ORB-SLAM: the map's first keyframe, or the loop keyframe's side).

Each edge's two 7×7 Jacobian blocks are computed by forward-mode AD of :math:`e_{ij}` with respect to
the two nodes' retraction increments at zero, so the residual is written once.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from privslam_jax.geometry.sim3 import Sim3
from privslam_jax.solvers.linear import DenseSystem, dense_damped_solve
from privslam_jax.solvers.lm import LMParams, SolveSummary, levenberg_marquardt
from privslam_jax.solvers.robust import huber_rho, huber_weight

__all__ = ["PoseGraphResult", "edge_errors", "optimize_pose_graph"]

DOF = 7


@struct.dataclass
class PoseGraphResult:
    poses: Sim3
    """``(N,)`` optimised camera-from-world poses."""
    summary: SolveSummary
    edge_errors: Float[Array, " E"]
    """``√(eᵀΩe)`` of each edge at the solution (a loop edge that stays large was probably wrong)."""


def edge_errors(poses: Sim3, edges: Int[Array, "E 2"], measurements: Sim3) -> Float[Array, "E 7"]:
    """``e_ij = φ(Z_ij S_j S_i⁻¹)`` for every edge (see the module docstring)."""
    S_i = poses[edges[:, 0]]
    S_j = poses[edges[:, 1]]
    return (measurements @ S_j @ S_i.inverse()).log_chart()


def _edge_error(S_i: Sim3, S_j: Sim3, Z: Sim3) -> Float[Array, " 7"]:
    return (Z @ S_j @ S_i.inverse()).log_chart()


@partial(jax.jit, static_argnames=("with_scale",))
def _solve(
    poses: Sim3,
    edges: Int[Array, "E 2"],
    measurements: Sim3,
    information: Float[Array, "E 7"],
    fixed: Bool[Array, " N"],
    huber_delta: Float[Array, ""],
    lm: LMParams,
    with_scale: bool,
) -> PoseGraphResult:
    n = fixed.shape[0]
    ei, ej = edges[:, 0], edges[:, 1]
    free = jnp.broadcast_to(~fixed[:, None], (n, DOF))
    if not with_scale:
        free = free.at[:, 6].set(False)
    free = free.reshape(-1)

    def whitened(x: Sim3) -> tuple[Float[Array, "E 7"], Float[Array, " E"]]:
        e = edge_errors(x, edges, measurements)
        return e, jnp.sum(information * e * e, axis=-1)

    def cost(x: Sim3) -> Float[Array, ""]:
        _, s = whitened(x)
        return 0.5 * jnp.sum(huber_rho(s, huber_delta))

    def jacobians(S_i: Sim3, S_j: Sim3, Z: Sim3) -> tuple[Float[Array, "7 7"], Float[Array, "7 7"]]:
        zero = jnp.zeros(DOF, S_i.translation.dtype)
        f = lambda di, dj: _edge_error(S_i.retract(di), S_j.retract(dj), Z)  # noqa: E731
        return jax.jacfwd(f, argnums=(0, 1))(zero, zero)

    def linearise(x: Sim3) -> DenseSystem:
        e, s = whitened(x)
        Ji, Jj = jax.vmap(jacobians)(x[ei], x[ej], measurements)
        w = huber_weight(s, huber_delta)[:, None] * information  # (E, 7): IRLS weight × Ω
        block = lambda A, B: jnp.einsum("ek,eka,ekb->eab", w, A, B)  # noqa: E731
        H4 = jnp.zeros((n, n, DOF, DOF), e.dtype)
        H4 = H4.at[ei, ei].add(block(Ji, Ji)).at[ej, ej].add(block(Jj, Jj))
        H4 = H4.at[ei, ej].add(block(Ji, Jj)).at[ej, ei].add(block(Jj, Ji))
        g2 = jnp.zeros((n, DOF), e.dtype)
        g2 = g2.at[ei].add(jnp.einsum("ek,eka,ek->ea", w, Ji, e)).at[ej].add(jnp.einsum("ek,eka,ek->ea", w, Jj, e))
        H = H4.transpose(0, 2, 1, 3).reshape(n * DOF, n * DOF)
        keep = free[:, None] & free[None, :]
        H = jnp.where(keep, H, 0.0) + jnp.diag(jnp.where(free, 0.0, 1.0).astype(e.dtype))
        g = jnp.where(free, g2.reshape(-1), 0.0)
        return DenseSystem(H=H, g=g, cost=0.5 * jnp.sum(huber_rho(s, huber_delta)))

    def retract(x: Sim3, delta: Float[Array, " n"]) -> Sim3:
        return x.retract(jnp.where(free, delta, 0.0).reshape(n, DOF))

    x, _, summary = levenberg_marquardt(poses, linearise, dense_damped_solve, cost, retract, lm)
    _, s = whitened(x)
    return PoseGraphResult(poses=x, summary=summary, edge_errors=jnp.sqrt(s))


def optimize_pose_graph(
    poses: Sim3,
    edges: Int[Array, "E 2"] | np.ndarray,
    measurements: Sim3,
    *,
    fixed: Bool[Array, " N"] | np.ndarray | None = None,
    information: Float[Array, "E 7"] | np.ndarray | None = None,
    with_scale: bool = True,
    huber_delta: float = float("inf"),
    max_iterations: int = 20,
    function_tolerance: float = 1e-12,
    parameter_tolerance: float = 1e-10,
) -> PoseGraphResult:
    """Minimise the pose-graph cost of the module docstring from ``poses`` (``(N,)`` :class:`Sim3`).

    ``edges``: ``(E, 2)`` node indices ``(i, j)`` with ``measurements[k] ≈ S_i S_j⁻¹``; ``fixed``:
    ``(N,)`` nodes held constant (default: node 0); ``information``: ``(E, 7)`` diagonal weights in the
    order (rotation, translation, log scale), default ones; ``with_scale=False`` keeps every scale as
    given (SE(3) graphs).  Inputs are checked here, on the host; the solve is jitted (one compile per
    number of nodes and edges) and returns why it stopped in ``summary``.
    """
    n = int(poses.log_scale.shape[0]) if poses.log_scale.ndim == 1 else -1
    if n < 1:
        raise ValueError(f"poses must be a (N,) batch of Sim3, got log_scale shape {poses.log_scale.shape}")
    edges = np.asarray(edges)
    if edges.ndim != 2 or edges.shape[1] != 2 or edges.shape[0] < 1 or not np.issubdtype(edges.dtype, np.integer):
        raise ValueError(f"edges must be a non-empty (E, 2) integer array, got {edges.dtype} {edges.shape}")
    if edges.min() < 0 or edges.max() >= n or np.any(edges[:, 0] == edges[:, 1]):
        raise ValueError(f"edges must join two different nodes in [0, {n}), got {edges.min()}..{edges.max()}")
    if measurements.log_scale.shape != (edges.shape[0],):
        raise ValueError(f"measurements must be a ({edges.shape[0]},) batch of Sim3, got {measurements.log_scale.shape}")
    dtype = poses.translation.dtype
    fixed = np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool)
    if fixed.shape != (n,):
        raise ValueError(f"fixed must have shape ({n},), got {fixed.shape}")
    if not fixed.any():
        fixed = fixed.copy()
        fixed[0] = True
    info = np.ones((edges.shape[0], DOF)) if information is None else np.asarray(information, np.float64)
    if info.shape != (edges.shape[0], DOF) or not np.all(np.isfinite(info)) or np.any(info < 0):
        raise ValueError(f"information must be ({edges.shape[0]}, 7), finite and >= 0, got {info.shape}")
    for name, leaf in (("poses", poses), ("measurements", measurements)):
        if not all(bool(jnp.all(jnp.isfinite(a))) for a in jax.tree.leaves(leaf)):
            raise ValueError(f"{name} contain NaN or inf")
    lm = LMParams.of(dtype, max_iterations, 1e-4, function_tolerance, parameter_tolerance=parameter_tolerance)
    measurements = jax.tree.map(lambda a: jnp.asarray(a, dtype), measurements)
    return _solve(poses, jnp.asarray(edges, jnp.int32), measurements, jnp.asarray(info, dtype), jnp.asarray(fixed),
                  jnp.asarray(huber_delta, dtype), lm, with_scale)
