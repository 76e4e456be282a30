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

Several processes (hosts) — :func:`initialize_distributed` first — form one mesh over every process's
devices, as in JAX's multi-controller model: each process runs the same program, loads only its own
rows of every global batch (:func:`local_rows`; :func:`shard_batch` assembles the global array from
them with ``jax.make_array_from_process_local_data``), and reads replicated results back with
:func:`to_host`.  On CPU the cross-process collectives run over gloo.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from privslam_jax.argtypes import nonnegative_int, positive_int

__all__ = ["add_parallel_arguments", "data_mesh", "devices_problem", "initialize_distributed", "local_part",
           "local_rows", "replicate", "shard_batch", "start_parallel", "to_host"]


def initialize_distributed(coordinator: str | None = None, num_processes: int | None = None,
                           process_id: int | None = None) -> None:
    """Join a multi-process run (``jax.distributed.initialize``) before JAX does anything else.

    Arguments default to the environment: ``JAX_COORDINATOR_ADDRESS`` (``host:port`` of process 0),
    ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``; left unset there too, JAX detects a cluster it knows
    (SLURM, Open MPI, …).  On CPU the collectives run over gloo.
    """
    env = os.environ
    coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS")
    if num_processes is None and env.get("JAX_NUM_PROCESSES"):
        num_processes = int(env["JAX_NUM_PROCESSES"])
    if process_id is None and env.get("JAX_PROCESS_ID"):
        process_id = int(env["JAX_PROCESS_ID"])
    if num_processes is not None and process_id is not None and not 0 <= process_id < num_processes:
        raise ValueError(f"process id {process_id} is not in [0, {num_processes})")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes, process_id=process_id)


def local_rows(batch_size: int) -> slice:
    """The rows of a global batch of ``batch_size`` that this process loads (all of them in a
    single-process run): process ``p`` of ``P`` holds the ``p``-th contiguous block, the rows its
    devices hold in :func:`data_mesh`'s mesh."""
    n, p = jax.process_count(), jax.process_index()
    if batch_size % n:
        raise ValueError(f"a batch of {batch_size} cannot be split across {n} processes")
    k = batch_size // n
    return slice(p * k, (p + 1) * k)


def to_host(tree: Any) -> Any:
    """numpy copies of every leaf; a replicated array of a multi-process run is read from this
    process's own copy (``np.asarray`` refuses arrays with shards on other processes)."""

    def get(x: Any) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            if not x.sharding.is_fully_replicated:
                raise ValueError(f"an array of shape {x.shape} is split across processes: gather it first")
            return np.asarray(x.addressable_data(0))
        return np.asarray(x)

    return jax.tree.map(get, tree)


def local_part(tree: Any) -> Any:
    """numpy copies of this process's rows of every batch-sharded leaf (the whole leaf in a
    single-process run), in batch order: what :func:`local_rows` loaded, after the step."""

    def get(x: Any) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            shards = {s.index[0].start or 0: s for s in x.addressable_shards}  # replicas hold the same rows
            return np.concatenate([np.asarray(shards[k].data) for k in sorted(shards)])
        return np.asarray(x)

    return jax.tree.map(get, tree)


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
    """Every leaf of ``tree`` copied onto each device of ``mesh`` (unchanged without a mesh); in a
    multi-process run every process passes the same values."""
    if mesh is None:
        return tree
    sharding = NamedSharding(mesh, PartitionSpec())
    if jax.process_count() == 1:
        return jax.device_put(tree, sharding)
    return jax.tree.map(lambda x: jax.make_array_from_process_local_data(sharding, np.asarray(x)), tree)


def shard_batch(tree: Any, mesh: Mesh | None) -> Any:
    """Every leaf of ``tree`` split along its leading (batch) axis across ``mesh``'s devices.

    In a multi-process run ``tree`` holds this process's rows only (:func:`local_rows`) and the
    result is the global batch.  Raises ``ValueError`` when a batch does not divide evenly (choose
    a batch size that is a multiple of the device count).
    """
    if mesh is None:
        return tree
    local = jax.process_count() > 1
    n = sum(d.process_index == jax.process_index() for d in mesh.devices.flat) if local else mesh.devices.size
    for leaf in jax.tree.leaves(tree):
        if np.ndim(leaf) == 0 or np.shape(leaf)[0] % n:
            raise ValueError(f"a batch of shape {np.shape(leaf)} cannot be split across {n} devices: "
                             f"the batch size must be a multiple of the device count")
    sharding = NamedSharding(mesh, PartitionSpec("data"))
    if local:
        return jax.tree.map(lambda x: jax.make_array_from_process_local_data(sharding, np.asarray(x)), tree)
    return jax.device_put(tree, sharding)


# ---- the training scripts' options ----------------------------------------------------------------


def add_parallel_arguments(parser: argparse.ArgumentParser) -> None:
    """``--devices``, ``--distributed``, ``--coordinator``, ``--num-processes``, ``--process-id``."""
    parser.add_argument("--devices", type=positive_int, default=None,
                        help="data-parallel over this many devices (the batch split, the state replicated; default 1, "
                             "with --distributed every process's devices; on a CPU host "
                             "XLA_FLAGS=--xla_force_host_platform_device_count=N gives N)")
    parser.add_argument("--distributed", action="store_true",
                        help="one of several processes (jax.distributed): start each with the same arguments and "
                             "its --process-id (docs/training.md)")
    parser.add_argument("--coordinator", default=None,
                        help="with --distributed: host:port of process 0 (default $JAX_COORDINATOR_ADDRESS)")
    parser.add_argument("--num-processes", type=positive_int, default=None,
                        help="with --distributed: the process count (default $JAX_NUM_PROCESSES)")
    parser.add_argument("--process-id", type=nonnegative_int, default=None,
                        help="with --distributed: this process's id (default $JAX_PROCESS_ID)")


def start_parallel(parser: argparse.ArgumentParser, args: argparse.Namespace, batch_size: int) -> bool:
    """Check the options of :func:`add_parallel_arguments` (``parser.error`` on a bad one), join the
    multi-process run when ``--distributed``, fill in ``args.devices``; returns whether this is
    process 0, the one that writes the outputs."""
    if not args.distributed and (args.coordinator or args.num_processes or args.process_id is not None):
        parser.error("--coordinator, --num-processes and --process-id need --distributed")
    if args.distributed:
        try:
            initialize_distributed(args.coordinator, args.num_processes, args.process_id)
        except ValueError as e:
            parser.error(f"argument --distributed: {e}")
    if args.devices is None:
        args.devices = jax.device_count() if args.distributed else 1
    if problem := devices_problem(args.devices, batch_size):
        parser.error(f"argument --devices: {problem}")
    return jax.process_index() == 0
