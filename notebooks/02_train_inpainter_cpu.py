# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 02 · Training the EdgeConnect inpainter on the CPU
#
# The privacy filter hides each person or vehicle and fills the hole. The learned fill is
# EdgeConnect (Nazeri et al., ICCVW 2019), re-implemented in Flax NNX (`privslam_jax.inpaint`,
# `docs/inpainting.md`). It has two stages:
#
# * the **edge generator G1** sees the grey image, its Canny edges and the mask, and draws the
#   edges that continue into the hole;
# * the **image generator G2** sees the masked RGB crop (the hole prefilled with white, or with
#   Telea's fill for the real-frame checkpoint) plus G1's completed edge map, and paints the hole.
#
# Both work on square crops around each object, resized to the model resolution (64² for the
# shipped checkpoints) and pasted back under the mask. The **CPU preset** is the official topology
# with every channel count divided by four (width 16 instead of 64, 8 residual blocks). The filter
# is **leak-free**: nothing inside the hole is ever read — the hidden pixels are zeroed and filled
# from the outside before any Canny smoothing, edges in a band around the hole are erased and
# redrawn by G1, so every output is a function of the outside pixels and the mask only.
#
# The two shipped checkpoints (`Inpainter.embedded("synthetic")`, `Inpainter.embedded("real")`)
# were trained by `train/inpaint.py` for over an hour each; the exact commands are in
# `docs/model_card_inpainter.md` and `docs/model_card_inpainter_real.md`. This notebook
#
# 1. builds a small crop dataset from the synthetic world (`CropBank`),
# 2. trains the library trainer (`privslam_jax.inpaint.train.train`) for a few steps with the shipped
#    recipe — an edge stage, then `edge_inpaint` (G1 frozen, G2 on G1's edges, L1 only) — and shows
#    the loss curves and the same held-out crops before and after,
# 3. fills a held-out synthetic frame with the embedded checkpoints and Telea and scores each inside
#    the hole against the object-free render,
# 4. fills a real KITTI frame from `../shared` with masks from the embedded real-frame detector
#    (skipped when `../shared` is absent).
#
# Set `PRIVSLAM_NB_TINY=1` for a short run (the test suite does): a tiny network (width 4, one
# residual block, 32² crops) trained for a few dozen steps.

# %%
import os
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from privslam_jax._shared import shared_dir
from privslam_jax.data.images import read_rgb8
from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.detect.predict import Detector
from privslam_jax.inpaint.data import CropBank
from privslam_jax.inpaint.filter import Inpainter, filter_frame
from privslam_jax.inpaint.masks import boxes_to_masks, instance_masks
from privslam_jax.inpaint.train import InpaintTrainer, TrainConfig, prepare_batch, train
from privslam_jax.metrics.image import psnr

TINY = os.environ.get("PRIVSLAM_NB_TINY", "0") == "1"
# The shipped recipe (docs/model_card_inpainter.md) at a notebook's budget: the edge GAN, then G2 on
# the frozen G1's edges with the L1 loss alone (no discriminator D2), Adam lr 3e-4, beta1 0.5, cosine.
recipe = {"inpaint_adv_weight": 0.0, "inpaint_lr": 3e-4, "inpaint_beta1": 0.5, "inpaint_lr_final": 1e-5,
          "checkpoint_every": 10_000, "sample_every": 0}
if TINY:  # a width-4 network with one residual block on 32² crops of 3 frames; a higher G2 lr
    synth, frame_stride = SynthConfig(num_frames=3, seed=0), 1
    config = TrainConfig(width=4, num_residual_blocks=1, size=32, batch_size=4,
                         stages=(("edge", 20), ("edge_inpaint", 40)), **(recipe | {"inpaint_lr": 1e-3}))
else:  # the CPU preset (width 16, 8 blocks, 64² crops) on every 5th frame of a 100-frame drive
    synth, frame_stride = SynthConfig(num_frames=100, seed=0), 5
    config = TrainConfig(batch_size=8, stages=(("edge", 200), ("edge_inpaint", 600)), **recipe)
schedule = ", ".join(f"{stage}:{steps}" for stage, steps in config.stages)
print(("tiny run" if TINY else "full run") + f": {config.size}x{config.size} crops, width {config.width}, "
      f"{config.num_residual_blocks} residual block(s), batch {config.batch_size}, stages {schedule}")

# %% [markdown]
# ## A crop dataset from the synthetic world
#
# `CropBank.from_synthetic` renders a drive and cuts one square crop around every privacy object of
# at least 64 px: the target is the object-free render (`frame.background`), the hole the union of
# all dilated instance masks reaching the crop. The trainer asks the bank for batch `step`, a pure
# function of the step (so a killed run resumes bit-identically). `prepare_batch` computes what the
# networks see: the leak-free input edges (nothing drawn within 8 px of the hole), the true edges
# (G1's target) and G2's masked input.

# %%
bank = CropBank.from_synthetic(synth, config.size, frame_stride=frame_stride, progress=False)
print(f"{len(bank)} object crops of {config.size}x{config.size} from {len(range(0, synth.num_frames, frame_stride))} "
      f"frames of world {synth.seed} ({synth.width}x{synth.height})")
batch = prepare_batch(*bank(0, 4), config.sigma, config.prefill)
print(f"hole share of the first batch: {100 * batch['hole'].mean():.1f}% of the crop pixels")

# %%
cols = {"masked input (G2)": batch["fill"], "input edges (G1)": batch["edges_in"][..., 0],
        "edge band (G1 mask)": batch["edge_hole"][..., 0], "true edges (G1 target)": batch["edges_true"][..., 0],
        "target (G2)": batch["rgb"]}
fig, axes = plt.subplots(4, len(cols), figsize=(2.2 * len(cols), 2.2 * 4))
for j, (title, x) in enumerate(cols.items()):
    axes[0, j].set_title(title, fontsize=9)
    for i in range(4):
        axes[i, j].imshow(np.clip(x[i], 0, 1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
for ax in axes.ravel():
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## A few training steps
#
# `train` builds the four networks (`InpaintTrainer`: G1, G2 and their PatchGAN discriminators D1,
# D2), runs the schedule with one jitted step per network, and writes an orbax checkpoint, PNG sample
# grids (off here) and the per-step losses to `workdir/log.csv`. Edge stage: G1's non-saturating GAN
# loss `e_adv` plus 10 × feature matching `e_fm` (`e_g` is their sum), D1's loss `e_d`.
# `edge_inpaint` stage: G2's L1 inside the crop ÷ mean mask, `i_l1`. The first step of each stage
# compiles its programs; the rest take milliseconds at the tiny size (about 0.8 s at the CPU preset).
#
# The *initial* generators are those of `InpaintTrainer(config)` (same seed as the trainer's start).

# %%
before = InpaintTrainer(config).inpainter()
workdir = Path(tempfile.mkdtemp(prefix="privslam_nb_")) / "inpaint"
t0 = time.perf_counter()
trainer = train(config, bank, workdir, progress=False)
seconds = time.perf_counter() - t0
after = trainer.inpainter()

# log.csv rows: step, stage, seconds, "name=value;name=value;..."
rows = [r.split(",", 3) for r in (workdir / "log.csv").read_text().splitlines()[1:]]
log = [(int(step), stage, {k: float(v) for k, v in (kv.split("=") for kv in losses.split(";"))})
       for step, stage, _, losses in rows]
edge_log = [(s, v) for s, st, v in log if st == "edge"]
g2_log = [(s, v) for s, st, v in log if st == "edge_inpaint"]
print(f"trained {len(log)} steps in {seconds:.0f} s: G1 e_g {edge_log[0][1]['e_g']:.3f} -> {edge_log[-1][1]['e_g']:.3f}, "
      f"G2 i_l1 {g2_log[0][1]['i_l1']:.3f} -> {g2_log[-1][1]['i_l1']:.3f}")


# %%
def smooth(x, k=5):
    """Running mean over ``k`` steps (the losses of single small batches are noisy)."""
    x = np.asarray(x, float)
    k = min(k, len(x))
    return np.convolve(x, np.ones(k) / k, mode="valid")


fig, axes = plt.subplots(1, 2, figsize=(12, 3.2))
steps = np.array([s for s, _ in edge_log])
for key in ("e_adv", "e_fm", "e_d"):
    y = [v[key] for _, v in edge_log]
    line, = axes[0].plot(steps, y, alpha=0.35)
    axes[0].plot(steps[len(steps) - len(smooth(y)):], smooth(y), color=line.get_color(), label=key)
axes[0].set_title("edge stage: G1 / D1")
steps = np.array([s for s, _ in g2_log])
y = [v["i_l1"] for _, v in g2_log]
axes[1].plot(steps, y, alpha=0.35, color="C3")
axes[1].plot(steps[len(steps) - len(smooth(y)):], smooth(y), color="C3", label="i_l1 (running mean)")
axes[1].set_title("edge_inpaint stage: G2 hole L1")
for ax in axes:
    ax.set_xlabel("step")
    ax.legend(fontsize=8)
fig.tight_layout()
plt.show()

# %% [markdown]
# ## Before and after, on crops of a world the trainer never saw
#
# Crops of frame 1 of world 902 (held out from every shipped model too; the first four whose holes
# cover 10–60 % of the crop), filled by the initial and the trained generators through
# `Inpainter.inpaint_crop` — the call the frame filter makes for every object.

# %%
heldout = make_sequence(SynthConfig(width=synth.width, height=synth.height, num_frames=2, seed=902))[1]
test_bank = CropBank.from_frames([heldout], config.size)
share = test_bank.holes.mean(axis=(1, 2))
pick = np.flatnonzero((share > 0.1) & (share < 0.6))[:4]
n = len(pick)
grid = {"masked input": [], "before": [], "after": [], "target": []}
for img, hole in zip(test_bank.images[pick].astype(np.float32) / 255, test_bank.holes[pick], strict=True):
    masked = np.where(hole[..., None], np.float32(0), img)
    grid["masked input"].append(np.where(hole[..., None], np.float32(1), img))
    grid["before"].append(before.inpaint_crop(masked, hole))
    grid["after"].append(after.inpaint_crop(masked, hole))
    grid["target"].append(img)
l1 = {k: float(np.mean([np.abs(o - t)[h].mean() for o, t, h in zip(grid[k], grid["target"], test_bank.holes[pick], strict=True)]))
      for k in ("before", "after")}
print(f"{n} held-out crops, mean |error| inside the hole: before {l1['before']:.3f}, after {l1['after']:.3f}")

fig, axes = plt.subplots(n, 4, figsize=(9, 2.3 * n), squeeze=False)
for j, (title, xs) in enumerate(grid.items()):
    axes[0, j].set_title(title + (f" ({len(log)} steps)" if title == "after" else ""), fontsize=9)
    for i, x in enumerate(xs):
        axes[i, j].imshow(np.clip(x, 0, 1), interpolation="nearest")
for ax in axes.ravel():
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# In the tiny run, a few dozen steps of a width-4 network replace the initial noise by roughly the
# colours around the hole, little more; the shipped checkpoint took 4,800 steps of the width-16
# preset on 12,160 crops of 60 worlds (76 min). Next, the embedded checkpoints on a whole frame.
#
# ## The embedded checkpoints on a held-out synthetic frame
#
# `filter_frame(image, masks, method)` crops around every mask, fills and pastes back; the masks
# here are the renderer's instance masks dilated by 4 px. The object-free render is the ground
# truth, so each fill can be scored by its PSNR inside the hole (`metrics.image.psnr`). Telea is
# OpenCV's fast-marching inpainting, the strongest of the source paper's baselines.

# %%
masks = instance_masks(heldout.instance_ids, dilation=4)
hidden = masks.any(axis=0)
fills = {
    "telea": filter_frame(heldout.image, masks, "telea"),
    "edgeconnect (just trained)": filter_frame(heldout.image, masks, "edgeconnect", inpainter=after),
    "edgeconnect (synthetic)": filter_frame(heldout.image, masks, "edgeconnect", inpainter=Inpainter.embedded("synthetic")),
    "edgeconnect (real)": filter_frame(heldout.image, masks, "edgeconnect", inpainter=Inpainter.embedded("real")),
}
scores = {name: float(psnr(out, heldout.background, hidden)) for name, out in fills.items()}
print(f"world 902, frame {heldout.index}: {len(masks)} objects, {100 * hidden.mean():.1f}% of the pixels hidden")
print(f"{'method':<28} {'PSNR in the hole (dB)':>22}")
for name, value in scores.items():
    print(f"{name:<28} {value:22.2f}")

# %%
panels = {"frame": heldout.image, "object-free render (truth)": heldout.background} | fills
fig, axes = plt.subplots(3, 2, figsize=(14, 3 * 7 * synth.height / synth.width + 1))
for ax, (title, x) in zip(axes.ravel(), panels.items(), strict=True):
    ax.imshow(np.clip(x, 0, 1))
    if title in scores:
        title += f": {scores[title]:.2f} dB"
    elif title == "frame":
        ax.contour(hidden, levels=[0.5], colors="yellow", linewidths=0.6)
    ax.set_title(title, fontsize=9)
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## A real KITTI frame from `../shared` (skipped when absent)
#
# A colour frame of `kitti_raw_a` (frame 220, in the validation run the real-frame recipe was chosen
# on, not trained on; the grey KITTI `seq1` frame 0 stands in when only that is present). The boxes
# come from the embedded real-frame detector (`Detector.embedded(domain="real")`, the privacy preset:
# person, bicycle, car, motorcycle, bus, truck at confidence 0.4), turned into masks by
# `boxes_to_masks` (dilated by 4 px) — what `privslam filter --masks detect` does. With no detection a
# fixed box on the road stands in. There is no ground truth behind real objects, so this is for the
# eye (scores on real holes with a known answer: `results/inpaint_real.md`). The real-frame
# checkpoint starts from Telea's fill and adds a learned correction (`prefill="telea"`,
# `residual=True`), so the two differ by that correction only.

# %%
shared = shared_dir()
candidates = [] if shared is None else [shared / "data/real/kitti_raw_a/frames/0000000220.png",
                                        shared / "data/kitti_odometry/sequences/seq1/image_0/000000.png"]
real_path = next((p for p in candidates if p.is_file()), None)
if real_path is not None:
    frame = read_rgb8(real_path)
    h, w = frame.shape[:2]
    detector = Detector.embedded(domain="real")
    dets = detector.detect([frame])[0].compact()
    boxes = np.asarray(dets.boxes, np.float32).reshape(-1, 4)
    if len(boxes):
        names = ", ".join(f"{detector.names[int(c)]} {s:.2f}" for c, s in zip(dets.class_ids, dets.scores, strict=True))
        print(f"real frame {real_path.parent.parent.name}/{real_path.parent.name}/{real_path.name}: {w}x{h}, "
              f"{len(boxes)} detections ({names})")
    else:
        boxes = np.array([[0.45 * w, 0.55 * h, 0.55 * w, 0.8 * h]], np.float32)
        print(f"real frame {real_path.parent.parent.name}/{real_path.parent.name}/{real_path.name}: {w}x{h}, "
              "no detection: a fixed box on the road")
    real_masks = boxes_to_masks(boxes, h, w, dilation=4)
    real_hidden = real_masks.any(axis=0)
    real_fills = {"original": frame,
                  "mask": np.where(real_hidden[..., None], np.array([255, 0, 0], np.uint8), frame),
                  "Telea": filter_frame(frame, real_masks, "telea"),
                  "EdgeConnect (real checkpoint)": filter_frame(frame, real_masks, "edgeconnect",
                                                                inpainter=Inpainter.embedded("real"))}
    diff = np.abs(real_fills["EdgeConnect (real checkpoint)"].astype(np.float32)
                  - real_fills["Telea"].astype(np.float32))[real_hidden].mean() / 255
    print(f"{100 * real_hidden.mean():.1f}% of the frame hidden; mean |EdgeConnect − Telea| in the hole: {diff:.3f}")

    # zoom: the boxes' union with context, 2:1 like the panels below the frame
    x0, y0 = boxes[:, :2].min(axis=0)
    x1, y1 = boxes[:, 2:].max(axis=0)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half_h = min(max(0.8 * (y1 - y0), 0.6 * (x1 - x0) / 2, 40), h / 2)
    half_w = min(2 * half_h, w / 2)
    zu0, zv0 = int(np.clip(cx - half_w, 0, w - 2 * half_w)), int(np.clip(cy - half_h, 0, h - 2 * half_h))
    zu1, zv1 = zu0 + int(2 * half_w), zv0 + int(2 * half_h)
    fig, axes = plt.subplot_mosaic([["frame"] * 4, list(real_fills)], figsize=(20, 9),
                                   gridspec_kw={"height_ratios": [4 * h / w, 0.5]})
    axes["frame"].imshow(frame)
    for (bx0, by0, bx1, by1), c in zip(boxes, dets.class_ids if len(dets.boxes) else [-1], strict=True):
        axes["frame"].add_patch(plt.Rectangle((bx0, by0), bx1 - bx0, by1 - by0, fill=False, color="red", lw=1))
        axes["frame"].text(bx0, by0 - 3, detector.names.get(int(c), "fixed box"), color="red", fontsize=8)
    axes["frame"].add_patch(plt.Rectangle((zu0, zv0), zu1 - zu0, zv1 - zv0, fill=False, color="yellow", lw=1.2, ls="--"))
    axes["frame"].set_title(f"{real_path.name}: detections of the real-frame detector, zoomed region (dashed)")
    for title, x in real_fills.items():
        axes[title].imshow(x[zv0:zv1, zu0:zu1], interpolation="nearest")
        axes[title].set_title(title, fontsize=11)
    for ax in axes.values():
        ax.axis("off")
    fig.tight_layout()
    plt.show()
else:
    print("../shared is absent: skipping the real KITTI frame")
