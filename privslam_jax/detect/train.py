"""Train YOLOv8 with Optax on a YOLO-format dataset (ultralytics recipe, CPU scale), resumable.

Recipe (ultralytics ``engine/trainer.py`` defaults; ``cfg/default.yaml``):

* SGD (``optimizer="sgd"``), Nesterov momentum 0.937, ``lr0 = 0.01``, final factor ``lrf = 0.01`` with a linear
  (default) or cosine schedule per epoch; three parameter groups — conv kernels with weight
  decay ``5e-4 · batch / 64``, BatchNorm scales and all biases without; warmup over
  ``max(3 epochs, 100)`` steps: lr from 0 (biases from 0.1) and momentum from 0.8 to their
  scheduled values. Optax: ``multi_transform`` of ``inject_hyperparams(sgd)`` per group.
  ``optimizer="adamw"`` is what ultralytics' ``optimizer=auto`` picks for runs under 10,000
  iterations (``trainer.build_optimizer``): AdamW, ``b1`` = momentum (0.9), ``b2 = 0.999``,
  decoupled weight decay on the conv kernels only, ``lr0 = 0.002 · 5 / (4 + nc)`` suggested.
* Loss: :func:`privslam_jax.detect.loss.detection_loss`, back-propagated as
  ``(box + cls + dfl) · batch``; BatchNorm batch statistics in training mode.
* Weight EMA (ultralytics ``ModelEMA``): ``decay_t = 0.9999 · (1 − exp(−t / 2000))`` over all
  parameters and BatchNorm statistics; the EMA is the model that is evaluated and exported.
* Augmentation (numpy/OpenCV, reproducible from ``(seed, epoch, index)``): letterbox to
  ``imgsz²`` (or, with ``imgh`` set, "rect" training: letterbox to an ``imgh × imgsz`` canvas,
  e.g. 192×640 for KITTI-shaped frames — 3.3× less compute than 640² for the same pixels), random scale (±50 %) and translation (±10 %) with grey fill, HSV jitter
  (h 0.015, s 0.7, v 0.4), left-right flip (0.5); boxes transformed, clipped and filtered as
  ultralytics ``box_candidates`` (w, h > 2 px, area kept > 10 %, aspect < 100).
* Optional Fourier domain adaptation towards real frames (``style``, ``style_frames``; applied after
  the HSV jitter), photometric domain randomisation (``domain_rand``,
  :mod:`privslam_jax.detect.domain_rand`) and fine-tuning from a checkpoint (``init_weights``).
* Checkpoints: orbax ``CheckpointManager`` every ``ckpt_every`` steps (params, batch stats,
  optimiser state, EMA, step); ``train`` resumes from the latest one in ``ckpt_dir``. Data order
  and augmentation depend only on ``(seed, epoch, index)``, so a run killed and resumed ends with
  the same weights as an uninterrupted one.

Departures: no mosaic/mixup (mosaic of 3.3:1 frames on a 3.3:1 canvas would halve object
sizes; the scale augmentation covers sizes instead), no gradient accumulation to the nominal batch 64, no AMP.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from tqdm import tqdm

from privslam_jax.detect.domain_rand import fourier_style, randomize_photometric
from privslam_jax.detect.loss import LossConfig, detection_loss
from privslam_jax.detect.predict import Letterboxed, letterbox
from privslam_jax.detect.yolov8 import YOLOv8, YOLOv8Config, init_yolov8

__all__ = ["TrainConfig", "train", "load_batch", "augment", "style_bank", "TrainResult"]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Training settings (ultralytics defaults unless noted)."""

    data: str
    """YOLO dataset root (``images/<split>``, ``labels/<split>``)."""
    num_classes: int
    """Number of classes of the detector."""
    split: str = "train"
    """Training split."""
    scale: str = "n"
    """Model scale (``n``, ``s``, … or the test-only ``tiny``)."""
    imgsz: int = 640
    """Square training size (multiple of 32); the canvas width when ``imgh`` is set."""
    imgh: int | None = None
    """Canvas height for "rect" training (multiple of 32, ≤ ``imgsz``); ``None``: square ``imgsz²``."""
    optimizer: str = "sgd"
    """``"sgd"`` (Nesterov) or ``"adamw"`` (ultralytics ``auto`` for short runs)."""
    batch_size: int = 16
    """Images per step."""
    epochs: int = 100
    """Epochs."""
    lr0: float = 0.01
    """Initial learning rate."""
    lrf: float = 0.01
    """Final learning rate factor."""
    cos_lr: bool = False
    """Cosine instead of linear schedule."""
    momentum: float = 0.937
    """SGD momentum (Nesterov)."""
    weight_decay: float = 5e-4
    """Weight decay at the nominal batch 64 (scaled by ``batch / 64``)."""
    warmup_epochs: float = 3.0
    """Warmup epochs (at least 100 steps)."""
    warmup_momentum: float = 0.8
    """Momentum at the start of warmup."""
    warmup_bias_lr: float = 0.1
    """Bias learning rate at the start of warmup."""
    ema_decay: float = 0.9999
    """EMA decay (ramped with ``tau = 2000``)."""
    fliplr: float = 0.5
    """Left-right flip probability."""
    hsv: tuple[float, float, float] = (0.015, 0.7, 0.4)
    """HSV gains (hue, saturation, value)."""
    scale_aug: float = 0.5
    """Random scale ± this fraction."""
    translate: float = 0.1
    """Random translation ± this fraction of the size."""
    domain_rand: float = 0.0
    """Probability of a photometric domain-randomisation draw per image
    (:func:`privslam_jax.detect.domain_rand.randomize_photometric`; 0: off)."""
    style: float = 0.0
    """Probability per image of taking a real frame's low-frequency amplitude spectrum
    (:func:`privslam_jax.detect.domain_rand.fourier_style`, before the domain randomisation; 0: off)."""
    style_frames: tuple[str, ...] = ()
    """Real frames (image files or folders) whose spectra ``style`` draws from, each resized to the canvas."""
    style_beta: float = 0.05
    """FDA window ``β`` of :func:`~privslam_jax.detect.domain_rand.fourier_style`."""
    init_weights: str | None = None
    """Start from this detector checkpoint (our ``.npz``; same scale and classes) instead of a random init."""
    max_boxes: int = 64
    """Ground-truth boxes per image kept (padding size)."""
    seed: int = 0
    """Seed of initialisation, data order and augmentation."""
    ckpt_dir: str | None = None
    """Orbax checkpoint folder (``None``: no checkpoints, no resume)."""
    ckpt_every: int = 100
    """Checkpoint every this many steps (and at the end)."""
    max_steps: int | None = None
    """Stop after this many total steps (e.g. to simulate a kill); ``None``: all epochs."""
    devices: int = 1
    """Data parallelism: the batch is split across this many devices, the state replicated
    (:mod:`privslam_jax.sharding`); ``batch_size`` must be a multiple of it."""

    def __post_init__(self) -> None:
        bad_h = self.imgh is not None and (self.imgh % 32 or not 0 < self.imgh <= self.imgsz)
        if self.imgsz <= 0 or self.imgsz % 32 or bad_h:
            raise ValueError(f"imgsz and imgh must be positive multiples of 32 with imgh <= imgsz, got {self.imgsz}, {self.imgh}")
        for name in ("num_classes", "batch_size", "epochs", "ckpt_every", "devices"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if not (0.0 <= self.style <= 1.0 and 0.0 <= self.style_beta < 0.5):
            raise ValueError(f"style must be in [0, 1] and style_beta in [0, 0.5), got {self.style}, {self.style_beta}")
        if self.style and not self.style_frames:
            raise ValueError("style > 0 needs style_frames (real frames to take the spectra from)")
        if self.optimizer not in ("sgd", "adamw"):
            raise ValueError(f"optimizer must be 'sgd' or 'adamw', got {self.optimizer!r}")
        if self.batch_size % self.devices:
            raise ValueError(f"batch_size {self.batch_size} must be a multiple of devices {self.devices}")

    @property
    def canvas(self) -> tuple[int, int]:
        """Training image size ``(H, W)``."""
        return (self.imgh or self.imgsz, self.imgsz)


@dataclasses.dataclass
class TrainResult:
    """The trained network (EMA weights, eval mode) and the per-step losses of this run."""

    model: YOLOv8
    losses: np.ndarray
    step: int


def augment(image: np.ndarray, boxes: np.ndarray, cfg: TrainConfig, rng: np.random.Generator,
            styles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Letterbox + random affine + HSV (+ Fourier style, domain randomisation) + flip of one float RGB
    image with ``xyxy`` pixel boxes. ``styles``: the ``(N, H, W, 3)`` uint8 frames of :func:`style_bank`
    (needed when ``cfg.style > 0``).

    Returns the ``(H, W, 3)`` image (:attr:`TrainConfig.canvas`), the kept boxes and the indices
    of the kept boxes.
    """
    hh, ww = cfg.canvas
    if cfg.imgh is None:
        lb = letterbox(image, cfg.imgsz, "square")
    else:  # rect: fit into the H×W canvas (never upscale beyond it), grey padding centred
        img0 = np.asarray(image, np.float32)
        h0, w0 = img0.shape[:2]
        r = min(hh / h0, ww / w0)
        nw, nh = round(w0 * r), round(h0 * r)
        if (nw, nh) != (w0, h0):
            img0 = cv2.resize(img0, (nw, nh), interpolation=cv2.INTER_LINEAR)
        left, top = (ww - nw) // 2, (hh - nh) // 2
        img0 = cv2.copyMakeBorder(img0, top, hh - nh - top, left, ww - nw - left, cv2.BORDER_CONSTANT,
                                  value=(114 / 255,) * 3)
        lb = Letterboxed(image=img0, orig_hw=(h0, w0), gains=(nh / h0, nw / w0), pad=(left, top))
    (gy, gx), (left, top) = lb.gains, lb.pad
    b = np.asarray(boxes, np.float64).reshape(-1, 4) * np.array([gx, gy, gx, gy]) + np.array([left, top, left, top])
    s = ww
    sc = rng.uniform(1 - cfg.scale_aug, 1 + cfg.scale_aug)
    tx = rng.uniform(0.5 - cfg.translate, 0.5 + cfg.translate) * ww
    ty = rng.uniform(0.5 - cfg.translate, 0.5 + cfg.translate) * hh
    M = np.array([[sc, 0, tx - sc * ww / 2], [0, sc, ty - sc * hh / 2]])
    img = cv2.warpAffine(lb.image, M, (ww, hh), flags=cv2.INTER_LINEAR, borderValue=(114 / 255,) * 3)
    nb = b * sc + np.array([M[0, 2], M[1, 2], M[0, 2], M[1, 2]])
    clipped = nb.copy()
    clipped[:, [0, 2]] = clipped[:, [0, 2]].clip(0, ww)
    clipped[:, [1, 3]] = clipped[:, [1, 3]].clip(0, hh)
    w0, h0 = (nb[:, 2] - nb[:, 0]), (nb[:, 3] - nb[:, 1])
    w1, h1 = (clipped[:, 2] - clipped[:, 0]), (clipped[:, 3] - clipped[:, 1])
    ar = np.maximum(w1 / (h1 + 1e-16), h1 / (w1 + 1e-16))
    keep = (w1 > 2) & (h1 > 2) & (w1 * h1 / (w0 * h0 + 1e-16) > 0.1) & (ar < 100)
    hg = rng.uniform(-1, 1, 3) * np.asarray(cfg.hsv) + 1
    hsv = cv2.cvtColor(img.astype(np.float32), cv2.COLOR_RGB2HSV)
    hsv[..., 0] = (hsv[..., 0] * hg[0]) % 360
    hsv[..., 1] = np.clip(hsv[..., 1] * hg[1], 0, 1)
    hsv[..., 2] = np.clip(hsv[..., 2] * hg[2], 0, 1)
    img = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    if cfg.style and rng.random() < cfg.style:
        if styles is None or not len(styles):
            raise ValueError("cfg.style > 0 needs the frames of style_bank(cfg)")
        img = fourier_style(img, styles[rng.integers(len(styles))].astype(np.float32) / 255, cfg.style_beta)
    if cfg.domain_rand and rng.random() < cfg.domain_rand:
        img = randomize_photometric(img, rng)
    out = clipped[keep]
    if rng.random() < cfg.fliplr:
        img = img[:, ::-1]
        out = np.stack([s - out[:, 2], out[:, 1], s - out[:, 0], out[:, 3]], axis=1) if len(out) else out
    return np.ascontiguousarray(img, np.float32), out.astype(np.float32), np.nonzero(keep)[0]


def style_bank(cfg: TrainConfig) -> np.ndarray | None:
    """The ``(N, H, W, 3)`` uint8 frames of ``cfg.style_frames`` resized to the training canvas (``None`` when
    ``cfg.style`` is 0)."""
    if not cfg.style:
        return None
    from privslam_jax.data.images import read_rgb8
    from privslam_jax.inpaint.data import image_paths

    hh, ww = cfg.canvas
    return np.stack([cv2.resize(read_rgb8(p), (ww, hh), interpolation=cv2.INTER_AREA) for p in image_paths(*cfg.style_frames)])


def load_batch(dataset, indices: np.ndarray, cfg: TrainConfig, epoch: int,
               styles: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Augmented batch: images ``(B, H, W, 3)``, labels ``(B, M)``, boxes ``(B, M, 4)``, mask ``(B, M)``."""
    n = len(indices)
    images = np.zeros((n, *cfg.canvas, 3), np.float32)
    labels = np.zeros((n, cfg.max_boxes), np.int32)
    boxes = np.zeros((n, cfg.max_boxes, 4), np.float32)
    mask = np.zeros((n, cfg.max_boxes), bool)
    for j, i in enumerate(indices):
        sample = dataset[int(i)]
        rng = np.random.default_rng((cfg.seed, epoch, int(i)))
        img, b, keep = augment(sample.image, sample.boxes, cfg, rng, styles)
        k = min(len(b), cfg.max_boxes)
        images[j], boxes[j, :k], labels[j, :k], mask[j, :k] = img, b[:k], np.asarray(sample.class_ids)[keep][:k], True
    return images, labels, boxes, mask


def _labels(params: dict) -> dict:
    def label(path, _):
        names = [str(getattr(p, "key", p)) for p in path]
        if names[-1] == "kernel":
            return "decay"
        return "bias" if names[-1] == "bias" else "no_decay"

    return jax.tree_util.tree_map_with_path(label, params)


def _make_tx(params, wd: float, optimizer: str = "sgd"):
    if optimizer == "adamw":  # torch AdamW: decoupled decay p -= lr·wd·p on the conv kernels only
        adam = lambda w: optax.inject_hyperparams(optax.adamw)(learning_rate=0.0, b1=0.9, b2=0.999, eps=1e-8,  # noqa: E731
                                                              weight_decay=w)
        return optax.multi_transform({"decay": adam(wd), "no_decay": adam(0.0), "bias": adam(0.0)}, _labels(params))
    sgd = lambda: optax.inject_hyperparams(optax.sgd)(learning_rate=0.0, momentum=0.9, nesterov=True)  # noqa: E731
    return optax.multi_transform(
        {"decay": optax.chain(optax.add_decayed_weights(wd), sgd()), "no_decay": sgd(), "bias": sgd()},
        _labels(params),
    )


def _set_hparams(opt_state, lrs: dict[str, float], momentum: float):
    inner = dict(opt_state.inner_states)
    for group, lr in lrs.items():
        st = inner[group].inner_state
        hp = st.hyperparams if hasattr(st, "hyperparams") else st[1].hyperparams
        hp["learning_rate"] = jnp.asarray(lr, jnp.float32)
        hp["b1" if "b1" in hp else "momentum"] = jnp.asarray(momentum, jnp.float32)
    return opt_state


def _schedule(cfg: TrainConfig, step: int, steps_per_epoch: int) -> tuple[dict[str, float], float]:
    epoch = step // steps_per_epoch
    x = epoch / cfg.epochs
    lf = ((1 - math.cos(x * math.pi)) / 2) * (cfg.lrf - 1) + 1 if cfg.cos_lr else (1 - x) * (1 - cfg.lrf) + cfg.lrf
    lr = cfg.lr0 * lf
    nw = max(round(cfg.warmup_epochs * steps_per_epoch), 100)
    if step <= nw:
        f = step / nw
        lrs = {"decay": f * lr, "no_decay": f * lr, "bias": cfg.warmup_bias_lr + f * (lr - cfg.warmup_bias_lr)}
        return lrs, cfg.warmup_momentum + f * (cfg.momentum - cfg.warmup_momentum)
    return {"decay": lr, "no_decay": lr, "bias": lr}, cfg.momentum


def _strong(tree):
    """Strongly typed copies of every leaf, so a restored state hits the same compiled step."""
    return jax.tree.map(lambda x: jnp.array(np.asarray(x), dtype=np.asarray(x).dtype), tree)


_STEP_CACHE: dict = {}
"""Jitted train steps by (graph, weight decay, shapes, EMA decay): a resumed run reuses the compiled step."""


def _build_step(graphdef, params, stats, tx, feat_shapes, loss_cfg: LossConfig, ema_decay: float):
    def step_fn(state, images, labels, boxes, mask):
        def loss_fn(p):
            pst, sst = jax.tree.map(lambda x: x, params), jax.tree.map(lambda x: x, stats)
            nnx.replace_by_pure_dict(pst, p)
            nnx.replace_by_pure_dict(sst, state["stats"])
            m = nnx.merge(graphdef, pst, sst)
            feats = m(images)
            b = images.shape[0]
            flat = jnp.concatenate([f.reshape(b, -1, f.shape[-1]) for f in feats], axis=1)
            r4 = 4 * loss_cfg.reg_max
            losses, _ = detection_loss(flat[..., :r4], flat[..., r4:], labels, boxes, mask, feat_shapes, loss_cfg)
            new_stats = nnx.to_pure_dict(nnx.state(m, nnx.BatchStat))
            return losses.sum() * b, (losses, new_stats)

        (_, (losses, new_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state["params"])
        updates, opt = tx.update(grads, state["opt"], state["params"])
        new_params = optax.apply_updates(state["params"], updates)
        t = state["step"] + 1
        d = ema_decay * (1 - jnp.exp(-t.astype(jnp.float32) / 2000))
        ema = lambda e, x: d * e + (1 - d) * x  # noqa: E731
        return {"params": new_params, "stats": new_stats, "opt": opt,
                "ema_params": jax.tree.map(ema, state["ema_params"], new_params),
                "ema_stats": jax.tree.map(ema, state["ema_stats"], new_stats), "step": t}, losses

    return jax.jit(step_fn, donate_argnums=0)


def train(cfg: TrainConfig, progress: bool = True) -> TrainResult:
    """Train (or resume training) a YOLOv8; returns the EMA model in eval mode.

    With ``cfg.devices > 1`` every step runs data-parallel (:mod:`privslam_jax.sharding`); a
    checkpoint written with one device count resumes with another.  In a multi-process run
    (:func:`~privslam_jax.sharding.initialize_distributed` first, ``cfg.devices`` counting every
    process's devices) each process calls this with the same ``cfg``, loads only its own rows of each
    batch, and gets the same model back; the checkpoints are written once (orbax coordinates the
    processes).
    """
    from privslam_jax.data.yolo import YoloDataset
    from privslam_jax.sharding import data_mesh, local_rows, replicate, shard_batch, to_host

    mesh = data_mesh(cfg.devices)
    dataset = YoloDataset(cfg.data, cfg.split)
    styles = style_bank(cfg)
    n = len(dataset)
    if cfg.batch_size > n:
        raise ValueError(f"batch_size {cfg.batch_size} exceeds the {n} images of {cfg.data}/{cfg.split}")
    steps_per_epoch = n // cfg.batch_size
    total_steps = steps_per_epoch * cfg.epochs if cfg.max_steps is None else min(cfg.max_steps, steps_per_epoch * cfg.epochs)

    model = init_yolov8(YOLOv8Config(num_classes=cfg.num_classes, scale=cfg.scale), seed=cfg.seed)
    if cfg.init_weights is not None:
        from privslam_jax.detect.weights import load_detector

        init, _ = load_detector(cfg.init_weights)
        if init.config != model.config:
            raise ValueError(f"init_weights {cfg.init_weights} is a {init.config}, the run trains a {model.config}")
        model = init
    model.train()
    graphdef, params, stats = nnx.split(model, nnx.Param, ...)
    tx = _make_tx(nnx.to_pure_dict(params), cfg.weight_decay * cfg.batch_size / 64, cfg.optimizer)
    state = {"params": nnx.to_pure_dict(params), "stats": nnx.to_pure_dict(stats), "opt": tx.init(nnx.to_pure_dict(params)),
             "ema_params": jax.tree.map(jnp.copy, nnx.to_pure_dict(params)),
             "ema_stats": jax.tree.map(jnp.copy, nnx.to_pure_dict(stats)), "step": jnp.asarray(0, jnp.int32)}
    state = _strong(state)
    feat_shapes = tuple((cfg.canvas[0] // s, cfg.canvas[1] // s) for s in (8, 16, 32))
    loss_cfg = LossConfig()

    mngr = None
    if cfg.ckpt_dir is not None:
        import orbax.checkpoint as ocp

        mngr = ocp.CheckpointManager(Path(cfg.ckpt_dir).resolve(), options=ocp.CheckpointManagerOptions(max_to_keep=2))
        if mngr.latest_step() is not None:
            state = _strong(mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state)))
    state = replicate(state, mesh)

    key = (graphdef, cfg.weight_decay * cfg.batch_size / 64, feat_shapes, cfg.ema_decay, cfg.optimizer)
    if key not in _STEP_CACHE:
        _STEP_CACHE[key] = _build_step(graphdef, params, stats, tx, feat_shapes, loss_cfg, cfg.ema_decay)
    step_jit = _STEP_CACHE[key]
    start = int(to_host(state["step"]))
    history = []
    bar = tqdm(total=total_steps, initial=start, desc="train", unit="step", disable=not progress)
    rows = local_rows(cfg.batch_size)  # this process's rows of every global batch (all of them in one process)

    def batch_of(step: int) -> tuple[np.ndarray, ...]:
        epoch, k = divmod(step, steps_per_epoch)
        order = np.random.default_rng((cfg.seed, epoch)).permutation(n)
        return load_batch(dataset, order[k * cfg.batch_size : (k + 1) * cfg.batch_size][rows], cfg, epoch, styles)

    batch = batch_of(start) if start < total_steps else None
    for step in range(start, total_steps):
        epoch = step // steps_per_epoch
        lrs, mom = _schedule(cfg, step, steps_per_epoch)
        state["opt"] = _set_hparams(state["opt"], lrs, mom)
        state, losses = step_jit(state, *shard_batch(tuple(map(jnp.asarray, batch)), mesh))
        if step + 1 < total_steps:  # prepare the next batch while the (asynchronous) step runs
            batch = batch_of(step + 1)
        losses = to_host(losses)
        history.append(losses)
        bar.set_postfix(box=f"{losses[0]:.3f}", cls=f"{losses[1]:.3f}", dfl=f"{losses[2]:.3f}", epoch=epoch)
        bar.update(1)
        if mngr is not None and ((step + 1) % cfg.ckpt_every == 0 or step + 1 == total_steps):
            import orbax.checkpoint as ocp

            mngr.save(step + 1, args=ocp.args.StandardSave(state))
    bar.close()
    if mngr is not None:
        mngr.wait_until_finished()
    if jax.process_count() > 1:  # replicated across processes: this process's copy
        state = jax.tree.map(jnp.asarray, to_host(state))
    nnx.replace_by_pure_dict(params, state["ema_params"])
    nnx.replace_by_pure_dict(stats, state["ema_stats"])
    out = nnx.merge(graphdef, params, stats)
    out.eval()
    return TrainResult(model=out, losses=np.asarray(history).reshape(-1, 3), step=int(state["step"]))
