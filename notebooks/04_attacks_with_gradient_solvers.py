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
# # 04 · Attacking a line cloud: Line2Point and a gradient solver
#
# A map of 3D points reveals the scene it was built from. A **line cloud** hides the points: every
# map point `P_i` is *lifted* to a line through it with a random direction `d_i`, published in
# Plücker coordinates `(d_i, m_i = P_i × d_i)` (`privslam_jax.privacy.lift`). A single line says
# nothing about where on it the point was. But the points of a real map lie on surfaces, so the
# lines of neighbouring points pass close to each other *near the points*: an attack recovers
# `R_i = a_i + t_i d_i` (`a_i = d_i × m_i`, the line's closest point to the origin) by choosing the
# offset `t_i` where the neighbouring lines crowd together.
#
# This notebook
#
# 1. builds a realistic map by back-projecting depth pixels of the synthetic street world,
# 2. lifts it (`random_lift`; `paired_lift` puts two points on every line),
# 3. attacks it with **Line2Point** (Chelani et al., CVPR 2021: peaks of the closest-approach offsets
#    along each line) and the **gradient attack** (a robust consistency energy minimised with
#    optimistix's nonlinear CG), against a no-attack baseline,
# 4. compares per-point errors `‖R_i − P_i‖` (table, histograms, a 3D view), shows the solver's
#    result object, and differentiates the attack with `jax.grad`.
#
# Set `PRIVSLAM_NB_TINY=1` for a short run on a small image and 400 points (the test suite does).

# %%
import os

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import optimistix as optx

from privslam_jax.attacks import (
    GradientAttackConfig,
    Line2PointConfig,
    gradient_attack,
    gradient_attack_core,
    line2point,
    num_coarse_neighbours,
)
from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.metrics.privacy import baseline_points, point_recovery_metrics
from privslam_jax.privacy.lift import fixed_key, paired_lift, random_lift
from privslam_jax.types import LineCloud

TINY = os.environ.get("PRIVSLAM_NB_TINY", "0") == "1"
synth = SynthConfig(width=160, height=48, num_frames=2) if TINY else SynthConfig(num_frames=10)
frame_ids = [0, 1] if TINY else [0, 3, 6, 9]
num_points = 400 if TINY else 3000
max_depth = 40.0  # metres: a SLAM map's far points
print(("tiny run" if TINY else "full run")
      + f": {num_points} points from {len(frame_ids)} frames of {synth.width}x{synth.height}")

# %% [markdown]
# ## A map from the synthetic world
#
# `SynthFrame.depth` is the z-depth of every pixel (0 = sky). A pixel `(u, v)` with depth `z` is the
# camera-frame point `((u − cx) z / fx, (v − cy) z / fy, z)`, and the frame's pose `T_w_c` maps it to
# the world frame (the first camera; x right, y down, z forward). A random subset of the valid pixels
# of a few frames stands in for a SLAM map.

# %%
seq = make_sequence(synth)
cam = seq.camera
rng = np.random.default_rng(0)
world, pixels = [], []
for i in frame_ids:
    f = seq[i]
    v, u = np.nonzero((f.depth > 0) & (f.depth < max_depth))
    z = f.depth[v, u].astype(np.float64)
    p_c = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], axis=1)
    world.append(p_c @ f.T_w_c[:3, :3].T + f.T_w_c[:3, 3])
    pixels.append(np.stack([np.full_like(u, i), u, v], axis=1))
world, pixels = np.concatenate(world), np.concatenate(pixels)
pick = np.sort(rng.choice(len(world), num_points, replace=False))
points = world[pick].astype(np.float32)
print(f"{len(world)} valid depth pixels (< {max_depth:.0f} m); map of {len(points)} points, "
      f"median distance to the first camera {np.median(np.linalg.norm(points, axis=1)):.1f} m")

# %%
f0 = seq[frame_ids[0]]
mine = pixels[pick][pixels[pick][:, 0] == frame_ids[0]]
fig, axes = plt.subplots(1, 2, figsize=(14, 14 * synth.height / synth.width / 2 + 0.8))
axes[0].imshow(f0.image)
axes[0].scatter(mine[:, 1], mine[:, 2], s=4, c="yellow")
axes[0].set_title(f"frame {frame_ids[0]}: the {len(mine)} sampled pixels of this frame")
d = np.where(f0.depth > 0, f0.depth, np.nan)
axes[1].imshow(d, cmap="magma_r", vmin=0, vmax=max_depth)
axes[1].set_title("z-depth (m)")
for ax in axes:
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## Lift the map to a line cloud
#
# `random_lift` draws each direction uniformly on the sphere from the key. A published cloud must
# use a secret key (the default draws one from OS entropy); `fixed_key` is for reproducible
# experiments only. `paired_lift` (Lee et al., CVPR 2023) instead pairs the points at random and
# lifts each pair to the line through both, so a density peak on a line no longer marks one point.

# %%
lines = random_lift(points, fixed_key(0))
print(f"random lift: {len(lines)} lines, |d·m| ≤ {float(jnp.max(jnp.abs(jnp.sum(lines.directions * lines.moments, -1)))):.1e}")

# %% [markdown]
# ## Three guesses of the points
#
# * **no attack**: `baseline_points(lines, "closest")`, each line's closest point to the origin;
# * **Line2Point**: `k = int(min(500, 0.05 N))` nearest lines per line, the peak of their
#   closest-approach offsets, then refinement rounds on the estimated points;
# * **gradient attack**: minimise `E(t) = Σ_i Σ_{j∈𝒩(i)} σ² log(1 + ‖x_i − x_j‖²/σ²)` over the offsets
#   (`𝒩(i)`: the `num_neighbours` nearest lines), started at the median closest-approach offset.

# %%
l2p_config = Line2PointConfig()
ga_config = GradientAttackConfig(max_steps=3000, rtol=1e-4, atol=1e-4)
print(f"Line2Point: k = {num_coarse_neighbours(len(lines), l2p_config)} coarse neighbours per line, "
      f"{l2p_config.num_refine_iterations} refinement rounds; gradient attack: {ga_config.num_neighbours} neighbours, "
      f"sigma = {ga_config.sigma} m")
recovered = {"no attack": baseline_points(lines, "closest")}
recovered["Line2Point"] = np.asarray(line2point(lines, l2p_config)[0])
ga = gradient_attack(lines, ga_config, throw=False)
recovered["gradient"] = np.asarray(ga.points)

# %% [markdown]
# ## The solver's result object
#
# `gradient_attack` returns a `GradientAttackResult` pytree: the points, the offsets `t`, the
# optimistix result code and the number of NonlinearCG steps; `.successful` compares the code with
# `optimistix.RESULTS.successful` and `.message()` is optimistix's explanation. With the default
# `throw=True` an unsuccessful solve raises `RuntimeError`; `throw=False` returns the last iterate
# and the code says why it stopped. Below: the solve used above, and one cut off after 20 steps.


# %%
CODES = ("successful", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite", "nonfinite_input")


def describe(res) -> str:
    name = next((c for c in CODES if bool(res.result == getattr(optx.RESULTS, c))), "other")
    return (f"{type(res).__name__}(points={tuple(res.points.shape)}, offsets={tuple(res.offsets.shape)}, "
            f"result={name}, num_steps={int(res.num_steps)})")


short_config = GradientAttackConfig(max_steps=20, rtol=ga_config.rtol, atol=ga_config.atol)
short = gradient_attack(lines, short_config, throw=False)
for label, res in [("used", ga), ("max_steps=20", short)]:
    print(f"{label:<12} {describe(res)} successful={bool(res.successful)}")
print(f"message of the cut-off solve: {short.message()[:56]!r}")
try:
    gradient_attack(lines, short_config)  # throw=True
except RuntimeError as err:
    print(f"with throw=True: RuntimeError({str(err)[:62]!r}…)")

# %% [markdown]
# ## Point-recovery metrics
#
# `point_recovery_metrics` knows the correspondence (line `i` came from point `i`): the median of
# `‖R_i − P_i‖` and the share of points recovered within 0.5 m.

# %%
metrics = {name: point_recovery_metrics(points, r) for name, r in recovered.items()}
print(f"{'method':<20} {'median (m)':>10} {'within 0.5 m (%)':>17}")
for name, m in metrics.items():
    print(f"{name:<20} {m['per_point_median']:10.3f} {m['within_0.5']:17.1f}")

# %%
errors = {name: np.linalg.norm(r - points, axis=1) for name, r in recovered.items()}
bins = np.logspace(-3, np.log10(max(e.max() for e in errors.values()) * 1.01), 40)
fig, ax = plt.subplots(figsize=(7, 3.5))
for name, e in errors.items():
    ax.hist(e, bins=bins, histtype="step", lw=1.5, label=f"{name} (median {np.median(e):.2f} m)")
ax.axvline(0.5, color="k", ls=":", lw=1)
ax.set_xscale("log")
ax.set_xlabel("per-point error ‖R_i − P_i‖ (m)")
ax.set_ylabel("points")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## Original vs recovered in 3D
#
# Grey: the map; coloured: the recovered points, coloured by their error (clipped at 2 m). Plotted
# with the camera's "up" (−y) upwards; recovered points outside the map's bounding box (+2 m) are
# left out of the view.

# %%
def up(p):
    return p[:, 0], p[:, 2], -p[:, 1]


lo, hi = points.min(0) - 2, points.max(0) + 2
fig = plt.figure(figsize=(13, 5.5))
for k, name in enumerate(["Line2Point", "gradient"]):
    ax = fig.add_subplot(1, 2, k + 1, projection="3d")
    r, e = recovered[name], errors[name]
    inside = np.all((r >= lo) & (r <= hi), axis=1)
    ax.scatter(*up(points), s=2, c="0.6", label="original")
    sc = ax.scatter(*up(r[inside]), s=4, c=np.minimum(e[inside], 2.0), cmap="viridis_r", vmin=0, vmax=2.0,
                    label="recovered")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[2], hi[2])
    ax.set_zlim(-hi[1], -lo[1])
    ax.set_box_aspect((hi - lo)[[0, 2, 1]])  # metres to scale
    ax.view_init(elev=25, azim=-75)  # from behind and above the first camera
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_zlabel("up (m)")
    ax.set_title(f"{name}: {int((~inside).sum())} of {len(r)} outside the view", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
fig.colorbar(sc, ax=fig.axes, shrink=0.6, label="error (m, clipped at 2)")
plt.show()

# %% [markdown]
# ## Paired lifting
#
# The same map lifted with `paired_lift`: every line holds two map points, so an attack that finds
# one density peak per line can recover at most one of them.

# %%
paired = paired_lift(points, fixed_key(0))
for name, r in [("Line2Point", line2point(paired, l2p_config)[0]),
                ("gradient", gradient_attack(paired, ga_config, throw=False).points)]:
    m = point_recovery_metrics(points, np.asarray(r))
    print(f"{name + ' (paired)':<20} {m['per_point_median']:10.3f} {m['within_0.5']:17.1f}")

# %% [markdown]
# ## Differentiating the attack
#
# `gradient_attack_core` is the same attack as a pure function: jit-able, differentiable in the
# lines by the implicit function theorem at the minimiser (optimistix `ImplicitAdjoint`; the
# neighbour graph and the start are constants). Here: the gradient of the attacker's mean squared
# error with respect to the published moments, the quantity a defence could push up. It is only
# meaningful when the solve succeeded, which the result object reports alongside.
# (`line2point_core` is the differentiable Line2Point.)

# %%
target = jnp.asarray(points)


def attack_error(moments):
    res = gradient_attack_core(LineCloud(directions=lines.directions, moments=moments), ga_config)
    return jnp.mean(jnp.sum((res.points - target) ** 2, axis=-1)), res.successful


grad, ok = jax.jit(jax.grad(attack_error, has_aux=True))(jnp.asarray(lines.moments))
g = np.linalg.norm(np.asarray(grad), axis=1)
print(f"d(mean squared error)/d(moments): shape {tuple(grad.shape)}, finite {bool(np.isfinite(g).all())}, "
      f"solve successful {bool(ok)}; 10% of the lines carry {100 * np.sort(g)[::-1][: len(g) // 10].sum() / g.sum():.0f}% of the gradient norm")
