"""Fine-tune the EdgeConnect filter for privacy and SLAM accuracy at once (issue 18 item 2).

For a pair of frames ``(x_r, x_t)`` of a synthetic world (reference ``r``, target ``t = r + gap``)
with their objects' masks ``M_r``, ``M_t`` and the filter ``y = f_φ(x, M)``
(:func:`~privslam_jax.inpaint.differentiable.apply_filter`), one step lowers

    L(φ) = L_fid(y_t, b_t, M_t) + λ_p · L_priv(y_t, M_t) + λ_a · L_acc(y_t, y_r)

(:mod:`privslam_jax.tradeoff.objectives`: ``b_t`` the object-free render, ``L_priv`` the frozen
detector's privacy-class confidence inside the masks, ``L_acc`` the geodesic error of direct
photometric alignment of the two filtered frames against the ground-truth relative pose) with
Optax's Adam. The filter is run once per frame with :func:`jax.vjp`; the three losses give the
cotangents of the filtered frames; one pull-back gives ``∂L/∂φ``. When the alignment did not converge
its gradient is NaN by design (:mod:`privslam_jax.solvers.implicit`): that step then drops the
accuracy term (counted in the log as ``acc_skipped``) instead of writing NaN into the weights.

Only the generators' ``nnx.Param`` leaves are trained; the spectral-norm vectors stay as loaded
(eval mode). Masks are padded to ``rows`` objects so that the whole step is one compiled function.
The weights ``(λ_p, λ_a)`` are an argument of that function, not constants in it: a sweep over the
trade-off compiles one step (per process, and once for all processes through the compilation cache);
only whether the alignment runs at all (``λ_a ≠ 0``) is part of the program.
Checkpoints (orbax) hold the parameters, the optimiser state and the step; a rerun of
:func:`train_tradeoff` with the same ``workdir`` resumes from the latest one.

**Batches and devices.**  ``batch_size`` pairs per step (default 1): the gradient and the losses are
the means over the pairs, each pair's accuracy term dropped on its own when its alignment did not
converge. ``devices > 1`` runs the step data-parallel as the other trainers do
(:mod:`privslam_jax.sharding`): the batch split across a ``("data",)`` mesh, the parameters, Adam's
state and the detector replicated, and XLA inserting the mean's all-reduce, so ``k`` steps on ``n``
devices compute ``k`` steps on one with the same global batch up to the order of the sums.  In a
multi-process run (:func:`~privslam_jax.sharding.initialize_distributed` first) every process makes
only its own rows of each batch (:func:`synthetic_batches`), process 0 writes the log, and orbax
writes the shared checkpoints, which resume under another process or device count.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, Bool, Float, PyTree

from privslam_jax.data.files import trim_log
from privslam_jax.inpaint.differentiable import (
    FilterConstants,
    FilterGeometry,
    FilterModel,
    apply_filter,
    filter_constants,
    filter_geometry,
)
from privslam_jax.inpaint.filter import Inpainter
from privslam_jax.sharding import data_mesh, local_rows, replicate, shard_batch, to_host
from privslam_jax.tradeoff.objectives import DetectorModel, accuracy_loss, fidelity_loss, privacy_loss
from privslam_jax.tradeoff.photometric import PhotometricConfig

__all__ = ["TradeoffConfig", "TradeoffSample", "loss_weights", "pair_gradients", "sample_of", "stack_samples",
           "synthetic_batches", "synthetic_pairs", "tradeoff_step", "train_tradeoff"]


@dataclasses.dataclass(frozen=True)
class TradeoffConfig:
    """Weights, optimiser and data of :func:`train_tradeoff`."""

    privacy_weight: float = 1.0
    """λ_p."""
    accuracy_weight: float = 1.0
    """λ_a (``L_acc`` is in metres for ``rotation_scale = 1 m/rad``)."""
    learning_rate: float = 1e-4
    steps: int = 400
    world_seeds: tuple[int, ...] = tuple(range(1000, 1010))
    """Synthetic worlds sampled from (keep them apart from evaluation worlds)."""
    frames_per_world: int = 60
    gap: int = 1
    """Target frame = reference frame + ``gap`` (0.8 m ahead at the world's default speed; at 1.6 m
    the alignment falls into wrong minima more often)."""
    width: int = 320
    height: int = 96
    dilation: int = 2
    """Mask dilation in pixels (``privslam filter`` uses 4 at 640 px wide)."""
    rows: int = 16
    """Objects per frame, at most (more are dropped: the farthest, i.e. the smallest masks)."""
    detector_input_hw: tuple[int, int] | None = (192, 640)
    """Size the frame is resized to for the detector (``None``: as it is)."""
    privacy_temperature: float = 0.01
    """τ of the privacy loss's soft maximum."""
    alignment: PhotometricConfig = PhotometricConfig(function_tolerance=1e-6, step_tolerance=1e-6)
    """Tolerances a float32 solve reaches (the default 1e-10 is float64's: in float32 the solver then
    ends at its iteration limit more often, and its gradient is flagged NaN)."""
    checkpoint_every: int = 50
    seed: int = 0
    batch_size: int = 1
    """Pairs per step (module docstring); a multiple of ``devices`` and of the process count."""
    devices: int = 1
    """Data-parallel over this many devices (in a multi-process run: all of every process's)."""


class TradeoffSample(NamedTuple):
    """One training pair, every array of a fixed shape."""

    target: Float[np.ndarray, "H W 3"]
    reference: Float[np.ndarray, "H W 3"]
    background: Float[np.ndarray, "H W 3"]
    """The target's object-free render."""
    reference_depth: Float[np.ndarray, "H W"]
    T_t_r: Float[np.ndarray, " 7"]
    """Ground-truth reference → target pose, jaxlie ``wxyz_xyz``."""
    intrinsics: Float[np.ndarray, " 4"]
    masks_t: Bool[np.ndarray, "K H W"]
    geometry_t: FilterGeometry
    constants_t: FilterConstants
    geometry_r: FilterGeometry
    constants_r: FilterConstants


def _masks(frame: Any, rows: int, dilation: int) -> np.ndarray:
    from privslam_jax.inpaint.masks import instance_masks

    m = instance_masks(frame.instance_ids, None, dilation)
    m = m[np.argsort(-m.sum(axis=(1, 2)), kind="stable")[:rows]]  # the largest objects first
    out = np.zeros((rows,) + frame.instance_ids.shape, bool)
    out[:len(m)] = m
    return out


def _padded(image: np.ndarray, masks: np.ndarray, model: FilterModel, rows: int) -> tuple[FilterGeometry, FilterConstants]:
    c = filter_constants(image, masks, model.config)
    k = len(c.edges)
    pad = ((0, rows - k),)
    return (filter_geometry(masks, model.config, rows),
            c._replace(edges=np.pad(c.edges, pad + ((0, 0),) * 2), fill=np.pad(c.fill, pad + ((0, 0),) * 3)))


def sample_of(ref: Any, tgt: Any, camera: Any, model: FilterModel, rows: int, dilation: int) -> TradeoffSample:
    """The :class:`TradeoffSample` of two rendered frames (``SynthFrame``) of one world."""
    m_r, m_t = _masks(ref, rows, dilation), _masks(tgt, rows, dilation)
    x_r, x_t = (np.asarray(f.image, np.float32) for f in (ref, tgt))
    T = np.linalg.inv(tgt.T_w_c) @ ref.T_w_c
    g_t, c_t = _padded(x_t, m_t, model, rows)
    g_r, c_r = _padded(x_r, m_r, model, rows)
    return TradeoffSample(
        target=x_t, reference=x_r, background=np.asarray(tgt.background, np.float32),
        reference_depth=np.asarray(ref.depth, np.float32),
        T_t_r=np.asarray(jaxlie.SE3.from_matrix(T).wxyz_xyz, np.float32),
        intrinsics=np.array([camera.fx, camera.fy, camera.cx, camera.cy], np.float32),
        masks_t=m_t, geometry_t=g_t, constants_t=c_t, geometry_r=g_r, constants_r=c_r,
    )


def synthetic_batches(config: TradeoffConfig, model: FilterModel, rows: slice = slice(None),
                      start: int = 0) -> Iterator[list[TradeoffSample]]:
    """An endless, reproducible stream of training batches of ``config.batch_size`` pairs, each a
    random world of ``config.world_seeds`` (rendered when first needed, then kept), a random
    reference frame and the target ``gap`` frames later; only the pairs of ``rows`` are made (a
    process's share, :func:`~privslam_jax.sharding.local_rows`), from batch ``start`` on (the earlier
    batches' draws are skipped, not made). The draws are pair after pair, so the stream of pairs does
    not depend on the batch size."""
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    rng = np.random.default_rng(config.seed)
    worlds: dict[int, Any] = {}
    keep = range(config.batch_size)[rows]
    for batch in itertools.count():
        draws = [(int(rng.choice(config.world_seeds)), int(rng.integers(0, config.frames_per_world - config.gap)))
                 for _ in range(config.batch_size)]  # (rng.choice then rng.integers, pair after pair)
        if batch < start:
            continue
        out = []
        for s, r in (draws[i] for i in keep):
            if s not in worlds:
                worlds[s] = make_sequence(SynthConfig(width=config.width, height=config.height,
                                                      num_frames=config.frames_per_world, seed=s))
            seq = worlds[s]
            out.append(sample_of(seq[r], seq[r + config.gap], seq.camera, model, config.rows, config.dilation))
        yield out


def synthetic_pairs(config: TradeoffConfig, model: FilterModel) -> Iterator[TradeoffSample]:
    """The pairs of :func:`synthetic_batches`, one after the other."""
    return itertools.chain.from_iterable(synthetic_batches(dataclasses.replace(config, batch_size=1), model))


def stack_samples(samples: list[TradeoffSample]) -> TradeoffSample:
    """One batch of pairs: every array with a leading batch axis."""
    return jax.tree.map(lambda *xs: np.stack(xs), *samples)


def loss_weights(config: TradeoffConfig) -> Float[np.ndarray, " 2"]:
    """``(λ_p, λ_a)`` of ``config``, the ``weights`` argument of :func:`tradeoff_step`."""
    return np.array([config.privacy_weight, config.accuracy_weight], np.float32)


def pair_gradients(
    params: PyTree, rest: PyTree, sample: TradeoffSample, detector_params: PyTree, weights: Float[Array, " 2"], *,
    model: FilterModel, detector: DetectorModel, config: TradeoffConfig,
) -> tuple[PyTree, dict[str, Array]]:
    """``∂L/∂φ`` and the losses of one pair (module docstring; arguments as :func:`tradeoff_step`)."""
    s = sample
    w_priv, w_acc = weights[0], weights[1]

    def filt(p: PyTree) -> tuple[Array, Array]:
        state = nnx.merge_state(p, rest)
        return (apply_filter(state, s.target, s.geometry_t, model, s.constants_t),
                apply_filter(state, s.reference, s.geometry_r, model, s.constants_r))

    (y_t, y_r), pull = jax.vjp(filt, params)
    l_fid, g_fid = jax.value_and_grad(fidelity_loss)(y_t, s.background, s.masks_t)
    l_priv, g_priv = jax.value_and_grad(
        lambda y: privacy_loss(detector_params, y, s.masks_t, detector, temperature=config.privacy_temperature,
                               input_hw=config.detector_input_hw))(y_t)
    if config.accuracy_weight:
        T_gt = jaxlie.SE3(s.T_t_r)
        l_acc, (g_acc_t, g_acc_r) = jax.value_and_grad(
            lambda yt, yr: accuracy_loss(yt, yr, s.reference_depth, s.intrinsics, T_gt, config=config.alignment),
            argnums=(0, 1))(y_t, y_r)
        ok = jnp.isfinite(l_acc) & jnp.all(jnp.isfinite(g_acc_t)) & jnp.all(jnp.isfinite(g_acc_r))
    else:  # λ_a = 0: no alignment at all
        l_acc, g_acc_t, g_acc_r, ok = jnp.zeros((), y_t.dtype), jnp.zeros_like(y_t), jnp.zeros_like(y_r), jnp.asarray(True)
    w_acc = jnp.where(ok, w_acc, 0.0)
    cot_t = g_fid + w_priv * g_priv + w_acc * jnp.where(ok, g_acc_t, 0.0)
    cot_r = w_acc * jnp.where(ok, g_acc_r, 0.0)
    (grads,) = pull((cot_t, cot_r))
    total = l_fid + w_priv * l_priv + w_acc * jnp.where(ok, l_acc, 0.0)
    return grads, {"loss": total, "fidelity": l_fid, "privacy": l_priv, "accuracy": l_acc,
                   "acc_skipped": (~ok).astype(jnp.float32)}


def tradeoff_step(
    params: PyTree, rest: PyTree, opt_state: PyTree, sample: TradeoffSample, detector_params: PyTree,
    weights: Float[Array, " 2"], *, model: FilterModel, detector: DetectorModel,
    optimizer: optax.GradientTransformation, config: TradeoffConfig,
) -> tuple[PyTree, PyTree, dict[str, Array]]:
    """One optimiser step on ``L`` (module docstring); returns new params, optimiser state and the losses.

    ``params``: the generators' ``nnx.Param`` leaves; ``rest``: the other state (spectral-norm
    vectors), held fixed; ``sample``: one pair, or a batch (:func:`stack_samples`: every array with a
    leading batch axis), whose gradient and losses are the means over its pairs; ``weights``:
    ``(λ_p, λ_a)`` (:func:`loss_weights`). ``config`` gives the rest, and ``config.accuracy_weight == 0``
    leaves the alignment out of the program (the accuracy term is then 0 whatever ``weights[1]``).
    Pure: jit it with the keyword arguments bound."""
    grad_fn = functools.partial(pair_gradients, model=model, detector=detector, config=config)
    if sample.target.ndim == 4:  # a batch: the pairs side by side, then their mean
        per_pair = jax.vmap(grad_fn, in_axes=(None, None, 0, None, None))
        grads, logs = per_pair(params, rest, sample, detector_params, weights)
        grads = jax.tree.map(lambda g: jnp.mean(g, axis=0), grads)
        logs = {k: jnp.mean(v) for k, v in logs.items()}  # (in the single pair's order: the log's columns)
    else:
        grads, logs = grad_fn(params, rest, sample, detector_params, weights)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, logs


def _compiled_step(model: FilterModel, detector: DetectorModel, config: TradeoffConfig) -> tuple[Any, Any]:
    """Adam and the jitted :func:`tradeoff_step`, once per program in a process: configs that differ
    only in the weights' values, the data or the schedule share it."""
    program = TradeoffConfig(privacy_weight=0.0, accuracy_weight=float(config.accuracy_weight != 0),
                             learning_rate=config.learning_rate, privacy_temperature=config.privacy_temperature,
                             detector_input_hw=config.detector_input_hw, alignment=config.alignment)
    return _step_program(model, detector, program)


@functools.lru_cache(maxsize=8)
def _step_program(model: FilterModel, detector: DetectorModel, config: TradeoffConfig) -> tuple[Any, Any]:
    optimizer = optax.adam(config.learning_rate)
    return optimizer, jax.jit(lambda p, r, o, smp, dp, w: tradeoff_step(
        p, r, o, smp, dp, w, model=model, detector=detector, optimizer=optimizer, config=config))


def _batches_of(data: Iterator[TradeoffSample], size: int, rows: slice) -> Iterator[list[TradeoffSample]]:
    """``rows`` of each ``size`` consecutive pairs of ``data``."""
    while True:
        pairs = list(itertools.islice(data, size))
        if len(pairs) < size:
            raise ValueError(f"the training data ended: {len(pairs)} pairs left for a batch of {size}")
        yield pairs[rows]


def train_tradeoff(
    config: TradeoffConfig, inpainter: Inpainter, detector_params: PyTree, detector: DetectorModel,
    workdir: str | Path, *, data: Iterator[TradeoffSample] | None = None, max_steps: int | None = None,
    progress: bool = True,
) -> Inpainter:
    """Fine-tune ``inpainter`` for ``config.steps`` steps (or resume from ``workdir/checkpoints``).

    Writes ``workdir/checkpoints/<step>`` (orbax: parameters, Adam state) every
    ``config.checkpoint_every`` steps and at the end, and ``workdir/log.csv`` (step, seconds, losses).
    ``max_steps`` stops early (a killed run); rerunning resumes. ``data``: a stream of pairs, taken
    ``config.batch_size`` at a time (in a multi-process run every process reads the whole stream and
    keeps its rows); default :func:`synthetic_batches`, which makes only this process's rows. A resumed
    run skips the pairs the finished steps used, so that it continues on the same stream. Returns the
    fine-tuned :class:`Inpainter`.
    """
    import orbax.checkpoint as ocp
    from tqdm import tqdm

    if config.batch_size < 1 or config.batch_size % config.devices:
        raise ValueError(f"the batch size ({config.batch_size}) must be a positive multiple of the devices "
                         f"({config.devices})")
    model, state = FilterModel.split(inpainter)
    params, rest = nnx.split_state(state, nnx.Param, ...)
    optimizer, step_fn = _compiled_step(model, detector, config)
    weights = loss_weights(config)
    opt_state = optimizer.init(params)
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    mngr = ocp.CheckpointManager(workdir / "checkpoints",
                                 options=ocp.CheckpointManagerOptions(max_to_keep=2, enable_async_checkpointing=False))
    leaves, treedef = jax.tree.flatten((params, opt_state))
    start = 0
    if mngr.latest_step() is not None:
        start = int(mngr.latest_step())
        target = {str(i): np.asarray(a) for i, a in enumerate(leaves)}  # host copies: any device or process count
        restored = mngr.restore(start, args=ocp.args.StandardRestore(target))
        params, opt_state = jax.tree.unflatten(treedef, [jnp.array(np.asarray(restored[str(i)]))
                                                        for i in range(len(leaves))])
    mesh = data_mesh(config.devices)
    params, rest, opt_state, detector_params, weights = replicate(
        (params, rest, opt_state, detector_params, weights), mesh)
    b = config.batch_size
    rows = local_rows(b)  # this process's rows of every batch (all of them in one process)
    if data is None:
        batches = synthetic_batches(config, model, rows, start)
    else:
        for _ in range(start * b):
            next(data)
        batches = _batches_of(data, b, rows)
    end = config.steps if max_steps is None else min(max_steps, config.steps)
    log_path = workdir / "log.csv"
    primary = jax.process_index() == 0  # writes the log
    if primary:
        trim_log(log_path, start)  # drop rows logged after the checkpoint we resume from, and a row cut short
    bar = tqdm(range(start, end), initial=start, total=config.steps, disable=not (progress and primary),
               desc="tradeoff")
    for step in bar:
        pairs = next(batches)
        sample = pairs[0] if b == 1 else shard_batch(stack_samples(pairs), mesh)
        t0 = time.perf_counter()
        params, opt_state, logs = step_fn(params, rest, opt_state, sample, detector_params, weights)
        logs = {k: float(v) for k, v in to_host(logs).items()}
        dt = time.perf_counter() - t0
        if not all(np.isfinite(v) for k, v in logs.items() if k != "accuracy"):
            raise FloatingPointError(f"step {step + 1}: non-finite loss {logs}; the last checkpoint is step {start}")
        bar.set_postfix({k: f"{v:.4f}" for k, v in logs.items() if k != "acc_skipped"})
        if primary:
            with log_path.open("a") as f:
                if f.tell() == 0:
                    f.write("step,seconds," + ",".join(logs) + "\n")
                f.write(f"{step + 1},{dt:.3f}," + ",".join(f"{v:.6f}" for v in logs.values()) + "\n")
        done = step + 1
        if done % config.checkpoint_every == 0 or done == end:
            leaves = jax.tree.leaves((params, opt_state))  # replicated: orbax writes each array once
            mngr.save(done, args=ocp.args.StandardSave({str(i): a for i, a in enumerate(leaves)}))
            start = done
    mngr.wait_until_finished()
    mngr.close()
    params, rest = jax.tree.map(jnp.asarray, to_host((params, rest)))
    eg, ig = nnx.merge(model.graphdef, nnx.merge_state(params, rest))
    return Inpainter(eg, ig, model.config, model.use_edge_model)
