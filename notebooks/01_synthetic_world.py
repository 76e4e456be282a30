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
# # 01 · The synthetic street world and the KITTI reader
#
# privslam_jax renders its own street world (`privslam_jax.data.synthetic`): every frame comes
# with depth, a per-pixel instance mask of the privacy objects (people, cars, …), their boxes,
# the same frame rendered *without* them, and the ground-truth camera pose. This notebook
#
# 1. renders a short sequence and shows frames, masks, depth and the object-free background,
# 2. plots the camera path,
# 3. writes the sequence in the KITTI odometry layout (what `privslam synth` does) and reads it
#    back with `KittiSequence`,
# 4. reads the real KITTI sequence in `../shared` when it is present.
#
# Set `PRIVSLAM_NB_TINY=1` for a seconds-long run on tiny images (the test suite does).

# %%
import os
import tempfile

import matplotlib.pyplot as plt
import numpy as np

from privslam_jax._shared import shared_dir
from privslam_jax.data.kitti_write import COCO_NAMES, summarize_sequence, write_kitti_sequence
from privslam_jax.data.kitti import KittiSequence
from privslam_jax.data.synthetic import SynthConfig, make_sequence

TINY = os.environ.get("PRIVSLAM_NB_TINY", "0") == "1"
config = SynthConfig(width=160, height=48, num_frames=3, stereo=True) if TINY else SynthConfig(num_frames=60, stereo=True)
print("tiny run" if TINY else "full run", config)

# %% [markdown]
# ## Render frames

# %%
seq = make_sequence(config)
show = [0, len(seq) - 1] if TINY else [0, 20, 40, 59]
frames = {i: seq[i] for i in show}
print(f"{len(seq)} frames of {seq.camera.width}x{seq.camera.height}, fx = {seq.camera.fx:.1f} px")

# %%
fig, axes = plt.subplots(len(show), 4, figsize=(16, 1.1 * len(show) * 16 / 4 * config.height / config.width + 1), squeeze=False)
for row, i in enumerate(show):
    f = frames[i]
    axes[row, 0].imshow(f.image)
    for (x1, y1, x2, y2), c in zip(f.boxes, f.class_ids):
        axes[row, 0].add_patch(plt.Rectangle((x1 - 0.5, y1 - 0.5), x2 - x1, y2 - y1, fill=False, color="yellow", lw=0.8))
    axes[row, 1].imshow(f.background)
    axes[row, 2].imshow(np.where(f.instance_ids > 0, f.instance_ids % 20 + 1, 0), cmap="tab20", interpolation="nearest")
    d = np.where(f.depth > 0, f.depth, np.nan)
    axes[row, 3].imshow(d, cmap="magma_r", vmin=0, vmax=np.nanpercentile(d, 95))
    axes[row, 0].set_ylabel(f"frame {i}")
for ax, title in zip(axes[0], ["image + boxes", "without privacy objects", "instance mask", "depth"]):
    ax.set_title(title)
for ax in axes.ravel():
    ax.set_xticks([])
    ax.set_yticks([])
fig.tight_layout()
plt.show()

# %% [markdown]
# The stereo pair (right camera `baseline` metres to the right):

# %%
f = frames[show[0]]
fig, axes = plt.subplots(1, 2, figsize=(12, 2.5))
axes[0].imshow(f.image)
axes[0].set_title("left")
axes[1].imshow(f.image_right)
axes[1].set_title(f"right (baseline {config.baseline} m)")
for ax in axes:
    ax.axis("off")
plt.show()

# %% [markdown]
# ## Camera path (bird's eye view, x–z plane; KITTI convention y down)

# %%
pos = np.asarray(seq.poses)[:, :3, 3]
fig, ax = plt.subplots(figsize=(5, 5))
ax.plot(pos[:, 0], pos[:, 2], "-o", ms=2)
ax.plot(pos[0, 0], pos[0, 2], "gs", label="start")
ax.set_xlabel("x [m]")
ax.set_ylabel("z [m]")
ax.set_aspect("equal", adjustable="datalim")
ax.legend()
plt.show()

# %% [markdown]
# ## Write the KITTI layout and read it back

# %%
out = tempfile.mkdtemp(prefix="privslam_nb_")
seq_dir = write_kitti_sequence(seq, out, name="synth", progress=False)
kitti = KittiSequence(seq_dir, stereo=True)
print(kitti)
g = kitti[show[0]]
err = np.abs(g.image - frames[show[0]].image).max()
print(f"max |image difference| after the 8-bit PNG round trip: {err:.4f} (≤ 1/510 expected)")
assert err <= 1 / 510 + 1e-6
np.testing.assert_allclose(g.T_w_c, frames[show[0]].T_w_c, atol=1e-12)
print(summarize_sequence(kitti, title="read back"))
print("classes present:", sorted({COCO_NAMES[int(c)] for c in g.class_ids}))

# %% [markdown]
# ## Real KITTI frames from `../shared` (skipped when absent)

# %%
shared = shared_dir()
kitti_root = None if shared is None else shared / "data/kitti_odometry"
if kitti_root is not None and (kitti_root / "sequences/seq1").is_dir():
    real = KittiSequence.from_root(kitti_root, "seq1")
    print(real)
    fig, axes = plt.subplots(1, 2, figsize=(16, 3), gridspec_kw={"width_ratios": [3, 1]})
    axes[0].imshow(real[0].image)
    axes[0].set_title("KITTI seq1, frame 0 (grey, repeated to RGB)")
    axes[0].axis("off")
    p = real.poses[:, :3, 3]
    axes[1].plot(p[:, 0], p[:, 2], "-")
    axes[1].set_title(f"ground-truth path, {np.linalg.norm(np.diff(p, axis=0), axis=1).sum():.1f} m")
    axes[1].set_aspect("equal", adjustable="datalim")
    plt.show()
else:
    print("../shared is absent: skipping the real KITTI sequence")
