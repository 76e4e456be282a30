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
# # 03 · The privacy/accuracy trade-off, end to end
#
# A privacy filter hides people and vehicles; SLAM on the filtered frames should lose as little
# accuracy as possible. privslam_jax states both goals as differentiable functions of the filter's
# output (`privslam_jax.tradeoff`, `docs/tradeoff.md`):
#
# * **privacy** `L_priv`: a frozen YOLOv8's privacy-class confidence inside each mask (a soft maximum
#   over the anchors whose predicted boxes lie in the mask);
# * **accuracy** `L_acc`: the pose error (m) of direct photometric alignment of two filtered frames
#   against the ground-truth relative pose, differentiated through the least-squares solve by the
#   implicit-function theorem;
# * **fidelity** `L_fid`: mean absolute error inside the masks against the object-free render.
#
# This notebook
#
# 1. evaluates the three objectives on one pair of frames for the unfiltered frame and four filters,
# 2. takes a few optimisation steps of `L = L_fid + λ_p L_priv + λ_a L_acc` on the EdgeConnect filter
#    (`train/tradeoff.py` runs the same loop for real),
# 3. shows the Pareto front of `experiments/pareto_tradeoff.py` from its results file.
#
# Set `PRIVSLAM_NB_TINY=1` for a short run (the test suite does): a smaller world, two steps of a
# width-4 network instead of the embedded one, a one-level alignment and the detector at the frames' size.

# %%
import dataclasses
import json
import os
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import matplotlib.pyplot as plt
import numpy as np

from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.detect.predict import EMBEDDED_WEIGHTS
from privslam_jax.detect.weights import load_detector
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig, filter_frame
from privslam_jax.inpaint.masks import instance_masks
from privslam_jax.tradeoff import DetectorModel, accuracy_loss, fidelity_loss, privacy_loss
from privslam_jax.tradeoff.train import TradeoffConfig, train_tradeoff

TINY = os.environ.get("PRIVSLAM_NB_TINY", "0") == "1"
config = TradeoffConfig(steps=2 if TINY else 20, frames_per_world=8 if TINY else 60, world_seeds=(1000,),
                        checkpoint_every=1000)
if TINY:  # the alignment on one pyramid level instead of three and the detector at the frames' size: smaller programs
    config = dataclasses.replace(config, alignment=dataclasses.replace(config.alignment, levels=1),
                                 detector_input_hw=(config.height, config.width))
print(("tiny run" if TINY else "full run") + f": {config.width}x{config.height} frames, {config.steps} steps")

# %% [markdown]
# ## One pair of frames and its masks
#
# The reference frame `r` and the target `t = r + 1` of a synthetic world (0.8 m apart), at the
# training size. The masks are the renderer's instance masks, dilated by 2 px.

# %%
seq = make_sequence(SynthConfig(width=config.width, height=config.height, num_frames=config.frames_per_world,
                                seed=config.world_seeds[0]))
r = config.frames_per_world - 3 if TINY else 20
ref, tgt = seq[r], seq[r + config.gap]
masks_t = instance_masks(tgt.instance_ids, None, config.dilation)
masks_r = instance_masks(ref.instance_ids, None, config.dilation)
cam = seq.camera
K = jnp.asarray([cam.fx, cam.fy, cam.cx, cam.cy], jnp.float32)
T_gt = jaxlie.SE3.from_matrix(jnp.asarray(np.linalg.inv(tgt.T_w_c) @ ref.T_w_c, jnp.float32))
print(f"pair ({r}, {r + config.gap}): {len(masks_t)} objects in the target, "
      f"{100 * np.any(masks_t, axis=0).mean():.1f}% of its pixels hidden")

# %% [markdown]
# ## The three objectives per filter
#
# Each filter is applied to both frames (frame `i` with seed `i`); `none` is the unfiltered pair,
# whose privacy loss is what the detector sees when nothing is hidden. The privacy loss has a
# floor of `τ log(A·C)` (0.096 at 640×192 input): the soft maximum of all-zero confidences.

# %%
inpainter = Inpainter.embedded("synthetic")
detector, detector_params = DetectorModel.split(load_detector(EMBEDDED_WEIGHTS)[0])
filters = ["none", "edgeconnect", "black", "telea", "blur"]


@jax.jit  # one program for the three objectives, called once per filter (data as arguments, not constants)
def objectives(y_t, y_r, masks, background, depth):
    return (privacy_loss(detector_params, y_t, masks, detector, input_hw=config.detector_input_hw),
            fidelity_loss(y_t, background, masks),
            accuracy_loss(y_t, y_r, depth, K, T_gt, config=config.alignment))


filtered, rows = {}, []
for name in filters:
    pair = [f.image if name == "none" else filter_frame(f.image, m, name, inpainter=inpainter, seed=f.index)
            for f, m in ((ref, masks_r), (tgt, masks_t))]
    filtered[name] = pair
    y_r, y_t = (jnp.asarray(x, jnp.float32) for x in pair)
    values = objectives(y_t, y_r, masks_t, jnp.asarray(tgt.background, jnp.float32), jnp.asarray(ref.depth, jnp.float32))
    rows.append((name, *(float(v) for v in values)))
print(f"{'filter':<12} {'L_priv':>8} {'L_fid':>8} {'L_acc (m)':>10}")
for name, lp, lf, la in rows:
    print(f"{name:<12} {lp:8.4f} {lf:8.4f} {la:10.4f}")

# %%
fig, axes = plt.subplots(len(filters) + 1, 1, figsize=(8, 1.6 * (len(filters) + 1)))
axes[0].imshow(tgt.background)
axes[0].set_title("object-free render (the fidelity target)", fontsize=9)
for ax, name in zip(axes[1:], filters, strict=True):
    ax.imshow(np.clip(filtered[name][1], 0, 1))
    ax.set_title(name, fontsize=9)
for ax in axes:
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## A few optimisation steps
#
# `train_tradeoff` fine-tunes the EdgeConnect generators with Adam on `L`, one jitted step per pair
# (the filter run once per frame, one pull-back of the three losses' cotangents). A step whose
# alignment did not converge drops the accuracy term (`acc_skipped`). The log is `workdir/log.csv`.

# %%
workdir = Path(tempfile.mkdtemp()) / "tradeoff"
start = Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1)) if TINY else inpainter  # tiny: a width-4 net
trained = train_tradeoff(config, start, detector_params, detector, workdir, progress=False)
log = np.genfromtxt(workdir / "log.csv", delimiter=",", names=True)
log = np.atleast_1d(log)
print(f"trained {len(log)} steps: loss {log['loss'][0]:.4f} -> {log['loss'][-1]:.4f} "
      f"(accuracy term dropped in {int(log['acc_skipped'].sum())})")

# %%
fig, ax = plt.subplots(figsize=(6, 3))
for key in ("loss", "fidelity", "accuracy", "privacy"):
    ax.plot(log["step"], log[key], marker="o", label=key)
ax.set_xlabel("step")
ax.set_yscale("log")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## The front
#
# `python experiments/pareto_tradeoff.py` measures every fixed filter and the trained points on
# unseen worlds with independent judges (a detector that took no part in training) and real SLAM:
# re-detection rate against the monocular ATE change. Its summary is `results/pareto_tradeoff.json`.

# %%
results = Path.cwd().parent / "results" / "pareto_tradeoff.json"
if results.is_file():
    front = json.loads(results.read_text())
    points = [p for p in front["synthetic"] if p["filter"] != "none" and None not in (p["redetection_pct"], p["mono_dATE_pct"])]
    fig, ax = plt.subplots(figsize=(6, 4))
    for p in points:
        trained_point = p["filter"] in front.get("trained", {})
        ax.scatter(p["redetection_pct"], p["mono_dATE_pct"], c="C3" if trained_point else "C0")
        ax.annotate(p["filter"], (p["redetection_pct"], p["mono_dATE_pct"]), fontsize=8)
    ax.set_xlabel("re-detection by the judge (%)")
    ax.set_ylabel("monocular ATE change (%)")
    plt.show()
    print(f"front of {len(points)} filters from {results.name}")
else:
    print(f"{results.name} not found: run experiments/pareto_tradeoff.py first")
