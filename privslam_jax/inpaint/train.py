"""EdgeConnect training (edge → inpaint → joint) with one jit per generator / discriminator step.

Library entry point :func:`train` (``train/inpaint.py`` is a thin CLI over it). Data comes from a
callable ``data(step, batch_size) -> (images (B, S, S, 3) float32 [0, 1], holes (B, S, S) bool)``
that is a pure function of the step (see :mod:`privslam_jax.inpaint.data`), so a run killed and
resumed from its last orbax checkpoint continues bit-identically (tested).

Per step (official ``src/edge_connect.py`` / ``models.py`` flow):

* ``edge`` stage: G1 step (adversarial + FM × 10 against D1 on ``[grey, edges]``), then the D1 step on
  the same (pre-update) fake edges.
* ``inpaint`` stage: G2 on the *ground-truth* edge map, G2 step (L1 / mean mask, adversarial
  × 0.1, optional perceptual × 0.1 and style × 250), then D2 step.
* ``edge_inpaint`` (official ``MODEL: 3``): G1 frozen, G2 (and D2) trained on G1's composited
  edges ``ê`` — G2 learns on the edges it will see at inference, at about half a joint step's cost.
* ``joint`` (official ``MODEL: 4``): both, G2 fed G1's composited edges ``ê`` (gradient stopped at
  ê — the official joint model also keeps the two optimisers separate).

Edge inputs are the leak-free ones of :func:`~privslam_jax.inpaint.masks.safe_canny`; the edge
targets are the Canny edges of the full target image.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from tqdm import tqdm

from privslam_jax.data.files import trim_log
from privslam_jax.sharding import data_mesh, local_part, local_rows, replicate, shard_batch, to_host
from privslam_jax.inpaint import baselines
from privslam_jax.inpaint import losses as L
from privslam_jax.inpaint.edgeconnect import CPU_WIDTH, Discriminator, EdgeGenerator, InpaintGenerator
from privslam_jax.inpaint.filter import PREFILLS, Inpainter, InpainterConfig, hole_distance, residual_output
from privslam_jax.inpaint.masks import safe_canny, to_grey
from privslam_jax.inpaint.widen import widen_inpaint_generator

__all__ = ["DataFn", "InpaintTrainer", "TrainConfig", "check_init", "prepare_batch", "train"]

DataFn = Callable[[int, int], tuple[np.ndarray, np.ndarray]]
STAGES = ("edge", "inpaint", "edge_inpaint", "joint")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """EdgeConnect training settings; every loss weight is pinned here.

    Paper (Nazeri et al. 2019, §3.1–3.3, §4) vs official ``config.yml.example``: the loss weights
    agree (λ_adv,1 = 1, λ_FM = 10; λ_ℓ1 = 1, λ_adv,2 = λ_p = 0.1, λ_s = 250), as do Adam
    (β = (0, 0.9)), lr 1e-4 and the discriminator/generator lr ratio 0.1. They disagree on:
    the schedule (paper: lr 1e-4 until the losses plateau, then 1e-5, then end-to-end fine-tuning
    at 1e-6 *without D1*; the code keeps lr 1e-4 and D1 throughout, which is what we do); the
    L1 normalisation (paper: plain ℓ1; code: ℓ1 over the whole image ÷ mean mask, used here);
    the style loss (paper: on the output; code: on output·M vs target·M, used here); the
    discriminator output (paper/edge: sigmoid; code: sigmoid for nsgan in both, reference npz:
    raw logits for the inpaint D — we compute the BCE on logits, identical to sigmoid + BCE).
    Perceptual and style losses need a frozen VGG-19 (ImageNet); none is available offline, so
    they are **disabled** unless a ``feature_fn`` is passed to :func:`train` (weights below apply).
    """

    width: int = CPU_WIDTH
    """Channel width of all four networks (official 64)."""
    inpaint_width: int = 0
    """Channel width of the image generator and its discriminator (0: :attr:`width`)."""
    num_residual_blocks: int = 8
    """Residual blocks per generator (official 8)."""
    size: int = 64
    """Training resolution S (official 256)."""
    batch_size: int = 8
    """Batch size (official 8)."""
    stages: tuple[tuple[str, int], ...] = (("edge", 2000), ("inpaint", 2000), ("joint", 1000))
    """(stage, steps) in order; stages among "edge", "inpaint", "edge_inpaint", "joint"."""
    lr: float = 1e-4
    """Generator Adam learning rate (paper and code)."""
    d2g_lr: float = 0.1
    """Discriminator lr = ``lr · d2g_lr`` (paper and code)."""
    beta1: float = 0.0
    """Adam β1 (paper and code)."""
    beta2: float = 0.9
    """Adam β2 (paper and code)."""
    inpaint_lr: float | None = None
    """G2's own Adam lr (None: ``lr``); not in the paper — a PSNR-oriented L1 run may go faster."""
    inpaint_beta1: float | None = None
    """G2's own Adam β1 (None: ``beta1``)."""
    inpaint_lr_final: float | None = None
    """If set, G2's lr follows a cosine from its initial value down to this over all G2 updates
    (None: constant, as the official code)."""
    edge_adv_weight: float = 1.0
    """λ_adv,1 for G1 (paper; code implicit 1)."""
    fm_weight: float = 10.0
    """λ_FM feature matching for G1."""
    l1_weight: float = 1.0
    """λ_ℓ1 for G2 (÷ mean mask, code)."""
    inpaint_adv_weight: float = 0.1
    """λ_adv,2 for G2 (0: G2 is trained on the L1 term alone and the D2 step is skipped)."""
    perceptual_weight: float = 0.1
    """λ_p (used only with a feature_fn)."""
    style_weight: float = 250.0
    """λ_s (used only with a feature_fn)."""
    sigma: float = 2.0
    """Canny σ."""
    prefill: str = "white"
    """What G2 sees in the hole (:attr:`~privslam_jax.inpaint.filter.InpainterConfig.prefill`; official "white")."""
    hole_loss: str = "l1"
    """G2's reconstruction term: ``"l1"`` (official: ``mean|out − y| / mean(mask)`` over the whole
    crop), ``"l1_hole"`` or ``"l2_hole"`` (:func:`~privslam_jax.inpaint.losses.masked_hole_loss`:
    inside the hole only; L2 is what PSNR measures), or ``"l2_blend"``: the squared error inside the hole
    of the blend the filter makes, ``w · out + (1 − w) · fill`` with the network's share ``w = 1 −
    exp(−d / blend_distance)`` at distance ``d`` (model pixels) from the nearest visible pixel
    (:func:`~privslam_jax.inpaint.filter.network_share` with ``prefill_blend_unit="model"``; the crop's
    prefill stands in for the frame's full-resolution one). Weighted by ``l1_weight``."""
    blend_distance: float = 3.0
    """τ of ``hole_loss="l2_blend"``, in model pixels."""
    residual: bool = False
    """G2 predicts a correction of the prefill (:attr:`~privslam_jax.inpaint.filter.InpainterConfig.residual`)."""
    seed: int = 0
    """Model-initialisation seed (the data seed belongs to the data source)."""
    checkpoint_every: int = 500
    """Steps between orbax checkpoints (and at the end)."""
    sample_every: int = 500
    """Steps between PNG sample grids (0: never)."""
    devices: int = 1
    """Data parallelism: each batch is split across this many devices, the four networks and their
    optimisers replicated (:mod:`privslam_jax.sharding`); ``batch_size`` must be a multiple of it."""

    @property
    def g2_width(self) -> int:
        """The image generator's channel width."""
        return self.inpaint_width or self.width

    def __post_init__(self):
        for stage, steps in self.stages:
            if stage not in STAGES or steps < 0:
                raise ValueError(f"bad stage {(stage, steps)}; stages are {STAGES} with steps >= 0")
        if self.size % 4:
            raise ValueError(f"size must be a multiple of 4, got {self.size}")
        for name in ("width", "num_residual_blocks", "size", "batch_size", "checkpoint_every", "devices"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.inpaint_width < 0:
            raise ValueError(f"inpaint_width must be >= 0 (0: width), got {self.inpaint_width}")
        if self.sample_every < 0:
            raise ValueError(f"sample_every must be >= 0, got {self.sample_every}")
        if self.batch_size % self.devices:
            raise ValueError(f"batch_size {self.batch_size} must be a multiple of devices {self.devices}")
        if self.hole_loss not in ("l1", "l1_hole", "l2_hole", "l2_blend"):
            raise ValueError(f"hole_loss must be l1, l1_hole, l2_hole or l2_blend, got {self.hole_loss!r}")
        if not 0.0 < self.blend_distance < float("inf"):
            raise ValueError(f"blend_distance must be > 0 and finite, got {self.blend_distance}")
        if self.prefill not in PREFILLS:
            raise ValueError(f"prefill must be one of {PREFILLS}, got {self.prefill!r}")

    @property
    def g2_steps(self) -> int:
        """Number of G2 updates in the schedule."""
        return sum(s for st, s in self.stages if st != "edge")

    @property
    def total_steps(self) -> int:
        return sum(s for _, s in self.stages)

    def stage_at(self, step: int) -> str:
        """Stage of the 0-based global ``step``."""
        acc = 0
        for stage, steps in self.stages:
            acc += steps
            if step < acc:
                return stage
        raise ValueError(f"step {step} beyond the schedule ({acc} steps)")


def prepare_batch(images: np.ndarray, holes: np.ndarray, sigma: float = 2.0, prefill: str = "white",
                  blend_distance: float = 0.0) -> dict[str, np.ndarray]:
    """Host-side inputs: rgb, grey, true edges, leak-free input edges, hole, edge hole, and G2's
    hole fill (``prefill``: a :mod:`~privslam_jax.inpaint.baselines` fill of the image with the hole
    zeroed; "white" = 1 as the official code) (B,S,S,·); with ``blend_distance`` τ > 0 also ``share``,
    ``1 − exp(−d / τ)`` of each pixel's distance ``d`` to the nearest visible pixel (``hole_loss="l2_blend"``)."""
    if images.ndim != 4 or images.shape[-1] != 3 or holes.shape != images.shape[:3]:
        raise ValueError(f"need images (B, S, S, 3) and holes (B, S, S), got {images.shape}, {holes.shape}")
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("grey", "edges_true", "edges_in", "edge_hole")}
    empty = np.zeros(images.shape[1:3], bool)
    for img, hole in zip(images, holes, strict=True):
        g = to_grey(img)
        out["grey"].append(g)
        out["edges_true"].append(safe_canny(g, empty, sigma=sigma)[0])
        e, eh = safe_canny(g, hole, sigma=sigma)
        out["edges_in"].append(e)
        out["edge_hole"].append(eh.astype(np.float32))
    batch = {k: np.stack(v)[..., None].astype(np.float32) for k, v in out.items()}
    batch["rgb"] = images.astype(np.float32)
    batch["hole"] = holes[..., None].astype(np.float32)
    batch["fill"] = np.stack([baselines.fill(np.where(h[..., None], np.float32(0), img), h, prefill)
                              for img, h in zip(batch["rgb"], holes.astype(bool), strict=True)])
    if blend_distance > 0.0:
        batch["share"] = np.stack([-np.expm1(-hole_distance(h) / blend_distance) for h in holes.astype(bool)]
                                  )[..., None].astype(np.float32)
    return batch


@functools.lru_cache(maxsize=None)
def _adam(lr: float, b1: float, b2: float, lr_final: float | None = None, steps: int = 0
          ) -> optax.GradientTransformation:
    """One optax object per setting: the optimiser is static in the jitted steps' cache key.

    With ``lr_final``: cosine decay from ``lr`` to ``lr_final`` over ``steps`` updates."""
    if lr_final is None:
        return optax.adam(lr, b1=b1, b2=b2)
    sched = optax.cosine_decay_schedule(lr, max(steps, 1), alpha=lr_final / lr)
    return optax.adam(sched, b1=b1, b2=b2)


def _edge_inputs(b: dict[str, jax.Array]) -> jax.Array:
    eh = b["edge_hole"]
    return jnp.concatenate([b["grey"] * (1 - eh) + eh, b["edges_in"] * (1 - eh), eh], axis=-1)


# Module-level jitted steps (config / feature_fn static) so every trainer with the same config
# and shapes shares the compiled programs.
@nnx.jit(static_argnums=(0,))
def _edge_g_step(c: TrainConfig, g, d, opt, b):
    def loss_fn(g, d):
        e = g(_edge_inputs(b))
        _, fake_feats = d(jnp.concatenate([b["grey"], e], axis=-1))
        _, real_feats = d(jnp.concatenate([b["grey"], b["edges_true"]], axis=-1))
        adv = L.generator_adversarial_loss(fake_feats[-1])
        fm = L.feature_matching_loss(real_feats, fake_feats)
        return c.edge_adv_weight * adv + c.fm_weight * fm, (e, adv, fm)

    (loss, (e, adv, fm)), grads = nnx.value_and_grad(loss_fn, has_aux=True)(g, d)
    opt.update(g, grads)
    return e, {"e_g": loss, "e_adv": adv, "e_fm": fm}


@nnx.jit
def _edge_forward(g, b):
    return g(_edge_inputs(b))


@nnx.jit
def _edge_d_step(d, opt, b, fake):
    def loss_fn(d):
        _, rf = d(jnp.concatenate([b["grey"], b["edges_true"]], axis=-1))
        _, ff = d(jnp.concatenate([b["grey"], jax.lax.stop_gradient(fake)], axis=-1))
        return L.discriminator_loss(rf[-1], ff[-1])

    loss, grads = nnx.value_and_grad(loss_fn)(d)
    opt.update(d, grads)
    return {"e_d": loss}


@nnx.jit(static_argnums=(0, 1))
def _inpaint_g_step(c: TrainConfig, feature_fn, g, d, opt, b, edges):
    m, y = b["hole"], b["rgb"]

    def loss_fn(g, d):
        out = g(jnp.concatenate([y * (1 - m) + b["fill"] * m, edges], axis=-1))
        if c.residual:
            out = residual_output(out, b["fill"])
        if c.inpaint_adv_weight:
            _, ff = d(out)
            adv = L.generator_adversarial_loss(ff[-1])
        else:  # L1-only G2: the discriminator is not evaluated at all
            adv = jnp.zeros(())
        if c.hole_loss == "l1":
            l1 = L.l1_hole_loss(out, y, m)
        elif c.hole_loss == "l2_blend":
            l1 = L.masked_hole_loss(b["share"] * out + (1 - b["share"]) * b["fill"], y, m, power=2)
        else:
            l1 = L.masked_hole_loss(out, y, m, power=2 if c.hole_loss == "l2_hole" else 1)
        loss = c.inpaint_adv_weight * adv + c.l1_weight * l1
        if feature_fn is not None:
            loss = loss + c.perceptual_weight * L.perceptual_loss(feature_fn(out), feature_fn(y))
            loss = loss + c.style_weight * L.style_loss(feature_fn(out * m), feature_fn(y * m))
        return loss, (out, adv, l1)

    (loss, (out, adv, l1)), grads = nnx.value_and_grad(loss_fn, has_aux=True)(g, d)
    opt.update(g, grads)
    return out, {"i_g": loss, "i_adv": adv, "i_l1": l1}


@nnx.jit
def _inpaint_d_step(d, opt, b, fake):
    def loss_fn(d):
        _, rf = d(b["rgb"])
        _, ff = d(jax.lax.stop_gradient(fake))
        return L.discriminator_loss(rf[-1], ff[-1])

    loss, grads = nnx.value_and_grad(loss_fn)(d)
    opt.update(d, grads)
    return {"i_d": loss}


class InpaintTrainer:
    """The four networks, their optimisers and the jitted steps."""

    def __init__(self, config: TrainConfig, feature_fn: Callable | None = None):
        c = self.config = config
        rngs = nnx.Rngs(c.seed)
        self.edge_g = EdgeGenerator(num_residual_blocks=c.num_residual_blocks, width=c.width, rngs=rngs)
        self.inpaint_g = InpaintGenerator(num_residual_blocks=c.num_residual_blocks, width=c.g2_width, rngs=rngs)
        self.edge_d = Discriminator(2, use_sigmoid=True, width=c.width, rngs=rngs)
        self.inpaint_d = Discriminator(3, use_sigmoid=False, width=c.g2_width, rngs=rngs)
        g_tx = _adam(c.lr, c.beta1, c.beta2)
        d_tx = _adam(c.lr * c.d2g_lr, c.beta1, c.beta2)
        g2_tx = _adam(c.lr if c.inpaint_lr is None else c.inpaint_lr,
                      c.beta1 if c.inpaint_beta1 is None else c.inpaint_beta1, c.beta2,
                      c.inpaint_lr_final, c.g2_steps)
        self.opt = {
            "edge_g": nnx.Optimizer(self.edge_g, g_tx, wrt=nnx.Param),
            "edge_d": nnx.Optimizer(self.edge_d, d_tx, wrt=nnx.Param),
            "inpaint_g": nnx.Optimizer(self.inpaint_g, g2_tx, wrt=nnx.Param),
            "inpaint_d": nnx.Optimizer(self.inpaint_d, d_tx, wrt=nnx.Param),
        }
        self.feature_fn = feature_fn
        self.mesh = data_mesh(c.devices)
        self._replicate()

    def _replicate(self) -> None:
        """Every network's and optimiser's state onto each device of the mesh (nothing on one device)."""
        if self.mesh is not None:
            for obj in self._objects().values():
                nnx.update(obj, replicate(nnx.state(obj), self.mesh))

    def step(self, stage: str, batch: dict[str, np.ndarray]) -> tuple[dict[str, float], dict[str, jax.Array]]:
        """One training step of ``stage``; returns (losses, outputs for sample grids)."""
        b = shard_batch({k: jnp.asarray(v) for k, v in batch.items()}, self.mesh)
        logs: dict[str, jax.Array] = {}
        outs: dict[str, jax.Array] = {}
        if stage in ("edge", "joint"):
            e, lg = _edge_g_step(self.config, self.edge_g, self.edge_d, self.opt["edge_g"], b)
            logs |= lg
            logs |= _edge_d_step(self.edge_d, self.opt["edge_d"], b, e)
            outs["edges"] = e
        if stage == "edge_inpaint":  # G1 frozen (its spectral-norm vectors too: eval mode)
            self.edge_g.eval()
            outs["edges"] = _edge_forward(self.edge_g, b)
            self.edge_g.train()
        if stage in ("inpaint", "edge_inpaint", "joint"):
            if stage in ("edge_inpaint", "joint"):
                eh = b["edge_hole"]
                edges = jax.lax.stop_gradient(outs["edges"]) * eh + b["edges_in"] * (1 - eh)
            else:
                edges = b["edges_true"]
            out, lg = _inpaint_g_step(self.config, self.feature_fn, self.inpaint_g, self.inpaint_d, self.opt["inpaint_g"], b, edges)
            logs |= lg
            if self.config.inpaint_adv_weight:
                logs |= _inpaint_d_step(self.inpaint_d, self.opt["inpaint_d"], b, out)
            outs["image"] = out * b["hole"] + b["rgb"] * (1 - b["hole"])
        return {k: float(to_host(v)) for k, v in logs.items()}, outs

    # ---------------------------------------------------------------- state / checkpoints
    def _objects(self) -> dict[str, nnx.Module | nnx.Optimizer]:
        return {"edge_g": self.edge_g, "edge_d": self.edge_d, "inpaint_g": self.inpaint_g,
                "inpaint_d": self.inpaint_d} | {f"opt_{k}": v for k, v in self.opt.items()}

    def state_dict(self) -> dict:
        """All trainable and non-trainable state (params, spectral u/v, optimiser moments)."""
        return {k: nnx.to_pure_dict(nnx.state(v)) for k, v in self._objects().items()}

    def load_state_dict(self, pure: dict) -> None:
        for k, obj in self._objects().items():
            st = nnx.state(obj)
            nnx.replace_by_pure_dict(st, pure[k])
            nnx.update(obj, st)
        self._replicate()

    def inpainter(self, size: int | None = None) -> Inpainter:
        """An :class:`Inpainter` on copies of the current generators."""
        c = self.config
        cfg = InpainterConfig(width=c.width, inpaint_width=c.inpaint_width, num_residual_blocks=c.num_residual_blocks,
                              size=size or c.size, sigma=c.sigma, prefill=c.prefill, residual=c.residual)
        eg, ig = nnx.clone(self.edge_g), nnx.clone(self.inpaint_g)
        if self.mesh is not None:  # replicated over the mesh (several processes too): one plain copy
            for m in (eg, ig):
                nnx.update(m, jax.tree.map(jnp.asarray, to_host(nnx.state(m))))
        return Inpainter(eg, ig, cfg)


def _grid(batch: dict[str, np.ndarray], outs: dict[str, np.ndarray], rows: int = 4) -> np.ndarray:
    """PNG grid: masked input | input edges | predicted edges | output | target, one row each."""
    m = batch["hole"]
    masked = batch["fill"]  # the image with G2's hole fill (white for the official prefill)
    cols = [masked, np.repeat(batch["edges_in"], 3, -1)]
    if "edges" in outs:
        cols.append(np.repeat(np.asarray(outs["edges"]), 3, -1))
    if "image" in outs:
        cols.append(np.asarray(outs["image"]))
    cols.append(batch["rgb"])
    n = min(rows, len(m))
    img = np.concatenate([np.concatenate([c[i] for c in cols], axis=1) for i in range(n)], axis=0)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def check_init(init: InpainterConfig, config: TrainConfig) -> None:
    """Raise ``ValueError`` unless an inpainter of config ``init`` can start ``config``'s training: the
    same edge-generator width and residual blocks, and an image generator of the same width or up to
    twice as wide (widened by :func:`~privslam_jax.inpaint.widen.widen_inpaint_generator`)."""
    w2 = config.g2_width
    if ((init.width, init.num_residual_blocks) != (config.width, config.num_residual_blocks)
            or not init.g2_width <= w2 <= 2 * init.g2_width):
        raise ValueError(f"the init inpainter has width {init.width} (image generator {init.g2_width}) and "
                         f"{init.num_residual_blocks} residual blocks, the training config {config.width} (image "
                         f"generator {w2}) and {config.num_residual_blocks}: widths and blocks must match, except "
                         "that the image generator may widen to at most twice its width")


def train(
    config: TrainConfig,
    data: DataFn,
    workdir: str | Path,
    *,
    max_steps: int | None = None,
    feature_fn: Callable | None = None,
    init: Inpainter | None = None,
    progress: bool = True,
) -> InpaintTrainer:
    """Train (or resume from ``workdir/checkpoints``) up to ``max_steps`` or the schedule's end.

    ``init`` (fine-tuning): start both generators from this inpainter's weights instead of the
    random initialisation (discriminators and optimiser moments start fresh); ignored when a
    checkpoint is resumed, which already holds the fine-tuned weights. A residual config started
    from a non-residual inpainter gets G2's last layer zeroed, so it starts at its prefill exactly.
    A config whose image generator is wider than ``init``'s (:attr:`TrainConfig.inpaint_width`, up to
    twice) starts from the widened copy that computes the same fill
    (:func:`~privslam_jax.inpaint.widen.widen_inpaint_generator`, seeded by ``config.seed``).

    Writes ``workdir/checkpoints/<step>`` (orbax), ``workdir/samples/step_<n>.png`` and
    ``workdir/log.csv`` (step, stage, seconds, losses). ``max_steps`` stops early (e.g. to
    simulate a kill); rerunning the same call resumes from the latest checkpoint.  In a
    multi-process run (:func:`~privslam_jax.sharding.initialize_distributed` first) every process
    calls this with the same arguments and prepares only its rows of each batch; process 0 writes
    the log and the samples, orbax the shared checkpoints.
    """
    import orbax.checkpoint as ocp

    workdir = Path(workdir).resolve()
    (workdir / "samples").mkdir(parents=True, exist_ok=True)
    trainer = InpaintTrainer(config, feature_fn)
    mngr = ocp.CheckpointManager(
        workdir / "checkpoints",
        options=ocp.CheckpointManagerOptions(max_to_keep=2, enable_async_checkpointing=False),
    )
    start = 0
    if mngr.latest_step() is not None:
        start = int(mngr.latest_step())
        restored = mngr.restore(start, args=ocp.args.StandardRestore(trainer.state_dict()))
        # orbax returns arrays committed to the device, fresh ones are not: uncommitted copies keep
        # the jitted steps' cache (in memory and on disk) valid instead of compiling all four anew
        trainer.load_state_dict(jax.tree.map(lambda x: jnp.array(to_host(x)), restored))
    elif init is not None:
        check_init(init.config, config)
        eg, ig = init.modules
        if config.g2_width != init.config.g2_width:  # Net2Net, from the model seed
            ig = widen_inpaint_generator(ig, config.g2_width, seed=config.seed)
        nnx.update(trainer.edge_g, nnx.state(eg))
        nnx.update(trainer.inpaint_g, nnx.state(ig))
        if config.residual and not init.config.residual:
            last = trainer.inpaint_g.dec3
            last.kernel[...] = jnp.zeros_like(last.kernel[...])
            last.bias[...] = jnp.zeros_like(last.bias[...])
        trainer._replicate()
    end = config.total_steps if max_steps is None else min(max_steps, config.total_steps)
    log_path = workdir / "log.csv"
    primary = jax.process_index() == 0  # writes the log and the samples
    if primary:
        trim_log(log_path, start)  # drop rows logged after the checkpoint we resume from, and a row cut short
    rows = local_rows(config.batch_size)  # this process's rows of every global batch (all of them in one process)
    bar = tqdm(range(start, end), initial=start, total=config.total_steps, disable=not (progress and primary),
               desc="inpaint")
    for step in bar:
        stage = config.stage_at(step)
        images, holes = data(step, config.batch_size)
        batch = prepare_batch(images[rows], holes[rows], config.sigma, config.prefill,
                              config.blend_distance if config.hole_loss == "l2_blend" else 0.0)
        t0 = time.perf_counter()
        logs, outs = trainer.step(stage, batch)
        dt = time.perf_counter() - t0
        bar.set_postfix({"stage": stage} | {k: f"{v:.3f}" for k, v in logs.items()})
        done = step + 1
        if primary:
            with log_path.open("a") as f:
                if f.tell() == 0:
                    f.write("step,stage,seconds,losses\n")
                f.write(f"{done},{stage},{dt:.4f}," + ";".join(f"{k}={v:.5f}" for k, v in logs.items()) + "\n")
            if config.sample_every and (done % config.sample_every == 0 or done == end):
                cv2.imwrite(str(workdir / "samples" / f"step_{done:07d}.png"),
                            cv2.cvtColor(_grid(batch, local_part(outs)), cv2.COLOR_RGB2BGR))
        if done % config.checkpoint_every == 0 or done == end:
            mngr.save(done, args=ocp.args.StandardSave(trainer.state_dict()))
    mngr.wait_until_finished()
    mngr.close()
    return trainer
