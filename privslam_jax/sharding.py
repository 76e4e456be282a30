"""Data parallelism over a device mesh: batch sharded, parameters and optimiser state replicated.

As Flax's and big_vision's data-parallel examples do with ``jax.sharding``: a one-axis
:class:`~jax.sharding.Mesh` named ``"data"`` over the devices, every training batch placed with
``NamedSharding(mesh, P("data"))`` (its leading axis split across devices) and the training state
with ``NamedSharding(mesh, P())`` (a full copy on each).  The trainers' jitted steps are unchanged:
XLA's SPMD partitioner compiles them for these shardings and inserts the all-reduces — the gradient
mean over the global batch, and batch-norm statistics over the global batch as well — so ``k`` steps
on ``n`` devices compute what ``k`` steps on one device compute with the same global batch, up to the
order of the floating-point sums.

On a CPU host, ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before JAX starts) gives
``N`` devices to test with.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = ["data_mesh", "devices_problem", "replicate", "shard_batch"]


def devices_problem(devices: int, batch_size: int) -> str | None:
    """Why ``devices`` cannot run a data-parallel batch of ``batch_size`` here (``None``: it can);
    for the training scripts' argument checks."""
    if batch_size % devices:
        return f"the batch ({batch_size}) must be a multiple of --devices ({devices})"
    if devices > 1 and devices > jax.device_count():
        return (f"{devices} devices asked for, {jax.device_count()} available (on a CPU host set "
                f"XLA_FLAGS=--xla_force_host_platform_device_count={devices} before starting)")
    return None


def data_mesh(devices: int | None = None) -> Mesh | None:
    """A ``("data",)`` mesh over the first ``devices`` devices (``None``: all); ``None`` for one device,
    where the trainers skip placement altogether (the single-device program is unchanged)."""
    available = jax.devices()
    n = len(available) if devices is None else int(devices)
    if n < 1:
        raise ValueError(f"devices must be at least 1, got {devices}")
    if n > len(available):
        raise ValueError(f"{n} devices asked for, {len(available)} available ({jax.default_backend()}); on a CPU "
                         f"host set XLA_FLAGS=--xla_force_host_platform_device_count={n} before starting")
    return None if n == 1 else Mesh(np.asarray(available[:n]), ("data",))


def replicate(tree: Any, mesh: Mesh | None) -> Any:
    """Every leaf of ``tree`` copied onto each device of ``mesh`` (unchanged without a mesh)."""
    return tree if mesh is None else jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def shard_batch(tree: Any, mesh: Mesh | None) -> Any:
    """Every leaf of ``tree`` split along its leading (batch) axis across ``mesh``'s devices.

    Raises ``ValueError`` when a batch does not divide evenly (choose a batch size that is a multiple
    of the device count).
    """
    if mesh is None:
        return tree
    n = mesh.devices.size
    for leaf in jax.tree.leaves(tree):
        if np.ndim(leaf) == 0 or np.shape(leaf)[0] % n:
            raise ValueError(f"a batch of shape {np.shape(leaf)} cannot be split across {n} devices: "
                             f"the batch size must be a multiple of the device count")
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec("data")))
