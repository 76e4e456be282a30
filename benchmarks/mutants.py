"""Mutation score of the test suite on the core numerical modules (issue 22, item 3).

Each mutant below is one plausible bug (an off-by-one, a sign flip, a transpose, a dropped term, a
wrong constant) written as an exact source snippet and its replacement. For every mutant the script
copies the working tree (tracked and untracked-but-not-ignored files, so uncommitted tests count; no
``.git``, no ``runs/``) into a temporary folder, applies the replacement there, and runs the mutant's
tests with ``python -m pytest -x -q -p no:cacheprovider`` in that copy, with ``../shared`` hidden
(``PRIVSLAM_SHARED`` points to a folder that does not exist, so the tests that need it skip).
``/work/main``'s files are never modified.

* **killed**: pytest failed (exit 1: a test failed; 2: collection error or interruption; 3: internal
  error); **timeout**: the run exceeded ``--timeout`` (counted as killed, marked);
* **survived**: every selected test passed or skipped (exit 0);
* **error**: pytest exit 4 or 5 (usage error, no test collected): a broken entry of the list, not
  a kill (counted against the score).

Before the mutants, a sanity run checks the set-up: ``import privslam_jax`` in the copy must import
the copy (not the editable install), and the union of the selected tests must pass unmutated.
The list checks itself: every ``original`` snippet must occur exactly once in its file and every
replacement must still compile, else the script stops (so the list stays true as the code changes).

Not part of CI (too slow: 15 min for the whole list with ``--jobs 2`` on the 2-core machine, docs/testing.md). Command::

    python benchmarks/mutants.py                              # all mutants, one at a time
    python benchmarks/mutants.py --out results/mutants.md     # also write the table (atomically)
    python benchmarks/mutants.py --only ba-schur-drop-XT,psnr-R-not-squared
    python benchmarks/mutants.py --list                       # check and print the list, run nothing
    python benchmarks/mutants.py --shared ../shared --only ID # the same with ../shared visible

The score and the command are recorded in ``docs/testing.md``.
"""

from __future__ import annotations

import argparse
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    """One stated bug: ``original`` (exactly once in ``file``) becomes ``replacement``."""

    id: str
    file: str
    original: str
    replacement: str
    description: str
    tests: tuple[str, ...]


# Test selections (fast, discriminating files first: pytest runs with -x).
ALIGN = ("tests/test_align.py", "tests/test_trajectory_metrics.py")
PROJ = ("tests/test_projection.py", "tests/test_refine.py", "tests/test_ba.py")
PLUCKER = ("tests/test_lift.py::test_plucker_helpers_against_numpy", "tests/test_gradient_attack.py")
BA = ("tests/test_ba.py", "tests/test_ba_step.py", "tests/test_degenerate_solvers.py")
REFINE = ("tests/test_refine.py", "tests/test_degenerate_solvers.py")
LIFT = ("tests/test_lift.py",)
L2P = ("tests/test_line2point.py",)
GRAD = ("tests/test_gradient_attack.py", "tests/test_degenerate_solvers.py")
DECODE = (
    "tests/test_detect_predict.py",
    "tests/test_yolov8_model.py::test_output_shapes_and_decode",
    "tests/test_detect_embedded.py",
    "tests/test_yolov8_loss.py",
)
NMS = ("tests/test_detect_predict.py", "tests/test_temporal.py")
LOSS = ("tests/test_yolov8_loss.py",)
IMAGE = ("tests/test_image_metrics.py", "tests/test_image_inputs.py")
TRAJ = ("tests/test_trajectory_metrics.py",)
PRIV = ("tests/test_privacy_metrics.py",)
LOC = ("tests/test_localize.py",)
PLANE = ("tests/test_plane_attack.py", "tests/test_road_parallel.py")
TPF = ("tests/test_two_peaks.py",)
CENTRED = ("tests/test_centred_attack.py",)
ROAD = ("tests/test_road_parallel.py", "tests/test_lines_cli.py")
INPAINT_INFERENCE = ("tests/test_inpaint_inference.py",)
REDETECTION = ("tests/test_pareto_tradeoff.py::test_count_refound_on_a_hand_built_case",)

_AL = "privslam_jax/geometry/align.py"
_PR = "privslam_jax/geometry/projection.py"
_PL = "privslam_jax/geometry/plucker.py"
_BA = "privslam_jax/slam/ba.py"
_RF = "privslam_jax/slam/refine.py"
_SC = "privslam_jax/solvers/schur.py"
_RB = "privslam_jax/solvers/robust.py"
_LN = "privslam_jax/solvers/linear.py"
_LI = "privslam_jax/privacy/lift.py"
_LP = "privslam_jax/attacks/line2point.py"
_GR = "privslam_jax/attacks/gradient.py"
_DE = "privslam_jax/detect/decode.py"
_LO = "privslam_jax/detect/loss.py"
_IM = "privslam_jax/metrics/image.py"
_TR = "privslam_jax/metrics/trajectory.py"
_PM = "privslam_jax/metrics/privacy.py"
_LC = "privslam_jax/privacy/localize.py"
_PA = "privslam_jax/attacks/plane.py"
_TP = "privslam_jax/attacks/two_peaks.py"
_CE = "privslam_jax/attacks/centred.py"
_RD = "privslam_jax/privacy/road.py"

MUTANTS: tuple[Mutant, ...] = (
    # ---- alignment (Umeyama) -----------------------------------------------------------------
    Mutant("align-scale-trD", _AL,
           "c = (d * s_diag).sum() / sigma_x2",
           "c = d.sum() / sigma_x2",
           "Sim(3) scale tr(D)/σ² instead of tr(DS)/σ² (eq. 42): wrong on reflected covariances",
           ALIGN),
    Mutant("align-no-reflection-fix", _AL,
           "sign = xp.where(xp.linalg.det(u) * xp.linalg.det(vt) < 0.0, -1.0, 1.0)",
           "sign = xp.where(xp.linalg.det(u) * xp.linalg.det(vt) < 0.0, 1.0, 1.0)",
           "S = I always: a reflection is returned when det U det V < 0 (eq. 43 dropped)",
           ALIGN),
    Mutant("align-rotation-transposed", _AL,
           "R = (u * s_diag[None, :]) @ vt",
           "R = ((u * s_diag[None, :]) @ vt).T",
           "rotation transposed (R = V S Uᵀ): aligns the wrong way round",
           ALIGN),
    Mutant("align-cov-transposed", _AL,
           "cov = yc.T @ xc / n",
           "cov = xc.T @ yc / n",
           "covariance Σ_xy transposed (source and target swapped in eq. 38)",
           ALIGN),
    Mutant("align-translation-unscaled", _AL,
           "t = mu_y - c * (R @ mu_x)",
           "t = mu_y - R @ mu_x",
           "translation forgets the scale: t = μ_y − R μ_x (eq. 41)",
           ALIGN),
    Mutant("align-variance-n-1", _AL,
           "sigma_x2 = (xc * xc).sum() / n",
           "sigma_x2 = (xc * xc).sum() / (n - 1)",
           "sample variance (n − 1) where eq. 36 has the population variance (n): scale off by (n−1)/n",
           ALIGN),
    Mutant("align-apply-rotation-transposed", _AL,
           "out[:, :3, 3] = float(c) * out[:, :3, 3] @ R.T + np.asarray(t, np.float64)[None, :]",
           "out[:, :3, 3] = float(c) * out[:, :3, 3] @ R + np.asarray(t, np.float64)[None, :]",
           "apply_similarity rotates the positions by Rᵀ instead of R (row-vector convention slip)",
           ALIGN),
    # ---- projection / Plücker helpers -------------------------------------------------------
    Mutant("proj-rotation-jacobian-sign", _PR,
           "J_pose = jnp.stack([jnp.concatenate([P, jnp.cross(p_c, P)], -1) for P in rows], -2)",
           "J_pose = jnp.stack([jnp.concatenate([P, jnp.cross(P, p_c)], -1) for P in rows], -2)",
           "∂r/∂ω row (P × p_c) instead of (p_c × P): +[p_c]× instead of −[p_c]× (left-perturbation sign)",
           PROJ),
    Mutant("proj-stereo-jacobian-sign", _PR,
           "return _chain([Pu, Pv, Pu + jnp.stack([zero, zero, bf * inv_z * inv_z], -1)], p_c, R_c_w)",
           "return _chain([Pu, Pv, Pu + jnp.stack([zero, zero, -bf * inv_z * inv_z], -1)], p_c, R_c_w)",
           "∂u_r/∂z: +bf/z² term with the wrong sign",
           PROJ),
    Mutant("proj-stereo-disparity-sign", _PR,
           "return _xp(p_c).stack([u, fy * p_c[..., 1] * inv_z + cy, u - bf * inv_z], axis=-1)",
           "return _xp(p_c).stack([u, fy * p_c[..., 1] * inv_z + cy, u + bf * inv_z], axis=-1)",
           "right-image u_r = u + bf/z (disparity sign)",
           PROJ),
    Mutant("plucker-closest-approach-sign", _PL,
           "t1 = jnp.where(parallel, 0.0, (b * dw2 - dw1) / safe)",
           "t1 = jnp.where(parallel, 0.0, (dw1 - b * dw2) / safe)",
           "closest-approach parameter t₁ with the sign flipped",
           PLUCKER),
    # ---- bundle adjustment ------------------------------------------------------------------
    Mutant("ba-schur-drop-XT", _SC,
           "S = block_diag(Ud) - X_off - X_off.T",
           "S = block_diag(Ud) - X_off",
           "Schur complement without the − Xᵀ term (only one triangle of the off-diagonal blocks)",
           BA),
    Mutant("ba-schur-drop-diag", _SC,
           "Ud = lin.U + (lam * dU)[:, :, None] * eye6[None] - S_diag",
           "Ud = lin.U + (lam * dU)[:, :, None] * eye6[None]",
           "Schur complement without the diagonal blocks Σ Y_o W_oᵀ",
           BA),
    Mutant("ba-rhs-sign", _SC,
           "rc = -lin.gc + jax.ops.segment_sum(",
           "rc = -lin.gc - jax.ops.segment_sum(",
           "reduced right-hand side −g_c − Σ Y g_p (sign of the eliminated point gradient)",
           BA),
    Mutant("ba-backsubstitution-sign", _SC,
           "rp = -lin.gp - jax.ops.segment_sum(",
           "rp = -lin.gp + jax.ops.segment_sum(",
           "point back-substitution δ = V⁻¹(−g_p + Wᵀξ) (sign)",
           BA),
    Mutant("ba-sym3-cofactor", _SC,
           "c01 = c * f - b * i",
           "c01 = b * i - c * f",
           "3×3 adjugate inverse: cofactor (0,1) with the wrong sign",
           BA),
    Mutant("ba-jacobian-cross-order", _BA,
           "return stereo_jacobians(p_c, R, K[:, 0], K[:, 1], K[:, 0] * K[:, 4])",
           "return stereo_jacobians(p_c, R, K[:, 0], K[:, 1], K[:, 4])",
           "BA's stereo Jacobians with the baseline in metres instead of bf = fx·b (the kernels are shared: proj-*)",
           BA),
    Mutant("ba-huber-weight", _BA,
           "w = jnp.where(front, obs.isg * huber_weight(s, delta), 0.0)",
           "w = jnp.where(front, obs.isg * huber_weight(s, delta) ** 2, 0.0)",
           "IRLS weight ρ'(s)² instead of ρ'(s) in the BA normal equations",
           BA),
    Mutant("ba-stereo-chi2-swapped", _BA,
           "(config.huber_delta, config.chi2),\n                                                  (config.huber_delta_stereo, config.chi2_stereo)",
           "(config.huber_delta, config.chi2_stereo),\n                                                  (config.huber_delta_stereo, config.chi2)",
           "χ² thresholds of stereo (3 dof) and monocular (2 dof) rows swapped",
           BA),
    Mutant("ba-pairs-off-by-one", _SC,
           "second_pos = first_pos + 1 + offs",
           "second_pos = first_pos + offs",
           "Schur pair list starts at (o, o) instead of (o, o+1): off by one",
           BA),
    Mutant("ba-stereo-baseline-not-bf", _BA,
           "return p_c, pinhole_stereo(p_c, K[:, 0], K[:, 1], K[:, 2], K[:, 3], K[:, 0] * K[:, 4])",
           "return p_c, pinhole_stereo(p_c, K[:, 0], K[:, 1], K[:, 2], K[:, 3], K[:, 4])",
           "stereo projection u_r = u − b/z (baseline in metres instead of bf = fx·b)",
           BA),
    Mutant("ba-cost-not-halved", _BA,
           "return Rm, p_c, e, s, front, 0.5 * jnp.sum(c)",
           "return Rm, p_c, e, s, front, jnp.sum(c)",
           "cost Σρ instead of ½Σρ (inconsistent with the gain ratio and the documented cost)",
           BA),
    # ---- pose refinement --------------------------------------------------------------------
    Mutant("refine-huber-rho-offset", _RB,
           "return jnp.where(s <= delta * delta, s, 2.0 * delta * jnp.sqrt(safe) - delta * delta)",
           "return jnp.where(s <= delta * delta, s, 2.0 * delta * jnp.sqrt(safe))",
           "Huber ρ(s) = 2δ√s without − δ² (discontinuous at δ²; shared with BA)",
           REFINE),
    Mutant("refine-huber-weight", _RB,
           "return jnp.where(s <= delta * delta, 1.0, delta / jnp.sqrt(safe))",
           "return jnp.where(s <= delta * delta, 1.0, delta / safe)",
           "IRLS weight δ/s instead of δ/√s",
           REFINE),
    Mutant("refine-step-sign", _LN,
           "step = jax.scipy.linalg.cho_solve((L, True), -system.g)",
           "step = jax.scipy.linalg.cho_solve((L, True), system.g)",
           "LM step solves (H + λD)ξ = +g (uphill)",
           REFINE),
    Mutant("refine-right-update", _RF,
           "retract=lambda T, xi: jaxlie.SE3.exp(xi) @ T,",
           "retract=lambda T, xi: T @ jaxlie.SE3.exp(xi),",
           "right update T·exp(ξ) with Jacobians of the left perturbation",
           REFINE),
    Mutant("refine-huber-delta-swapped", _RF,
           "obs, stereo, delta, chi2 = observation_rows(uv, u_right, (config.huber_mono, config.chi2_mono),\n"
           "                                                (config.huber_stereo, config.chi2_stereo), dtype)",
           "obs, stereo, delta, chi2 = observation_rows(uv, u_right, (config.huber_stereo, config.chi2_mono),\n"
           "                                                (config.huber_mono, config.chi2_stereo), dtype)",
           "Huber thresholds of stereo and monocular observations swapped",
           REFINE),
    Mutant("refine-information-dropped", _RF,
           "w = jnp.where(mask & front, huber_weight(s, delta) * inv_sigma2, 0.0)",
           "w = jnp.where(mask & front, huber_weight(s, delta), 0.0)",
           "normal equations ignore the information 1/σ² (the cost keeps it)",
           REFINE),
    Mutant("refine-pad-depth-zero", _RF,
           "pts[n:, 2] = 1.0",
           "pts[n:, 2] = 0.0",
           "padded rows at z = 0 (inf/NaN through the masked rows) instead of z = 1",
           REFINE),
    # ---- least-squares core -----------------------------------------------------------------
    Mutant("implicit-derivative-sign", "privslam_jax/solvers/implicit.py",
           "xi_dot = -jnp.linalg.solve(H, rhs) * scale",
           "xi_dot = jnp.linalg.solve(H, rhs) * scale",
           "implicit-function-theorem tangent ξ̇ = +H⁻¹(∂G/∂θ)θ̇ (sign)",
           ("tests/test_solvers.py",)),
    Mutant("implicit-dead-rows-left-singular", "privslam_jax/solvers/implicit.py",
           "H = H + jnp.diag(dead.astype(H.dtype))",
           "H = H",
           "rows of H the cost does not see (fixed cameras, padded points) left singular",
           ("tests/test_solvers.py",)),
    Mutant("lm-stalled-not-reported", "privslam_jax/solvers/lm.py",
           "jnp.where(lam > 1e32, _STALLED, _RUNNING)",
           "jnp.where(lam > 1e32, _CONVERGED, _RUNNING)",
           "a solve that no step could improve reported as converged",
           ("tests/test_solvers.py",)),
    # ---- lifts ------------------------------------------------------------------------------
    Mutant("lift-directions-in-cube", _LI,
           "n = jax.random.normal(key, like.shape, like.dtype)",
           "n = jax.random.uniform(key, like.shape, like.dtype, -1.0, 1.0)",
           "random directions normalised from a cube (not uniform on the sphere)",
           LIFT),
    Mutant("lift-paired-sign-fixed", _LI,
           "sign = np.where(np.asarray(jax.random.bernoulli(k_sign, 0.5, (n, 1))), 1.0, -1.0)[rep]",
           "sign = np.ones((n, 1))[rep]",
           "paired lift: direction always from the lower to the higher index (random sign dropped)",
           LIFT),
    Mutant("lift-moment-sign", _LI,
           "return _lines(d, np.cross(p, d), dtype)",
           "return _lines(d, np.cross(d, p), dtype)",
           "random lift moment d × p instead of p × d (line through −p)",
           LIFT),
    Mutant("lift-pairing-drops-last-pair", _LI,
           "a, b = perm[0 : n - n % 2 : 2], perm[1 : n - n % 2 : 2]",
           "a, b = perm[0 : n - 1 : 2], perm[1 : n - 1 : 2]",
           "pairing off by one: with an even count the last pair is left unpaired",
           LIFT),
    Mutant("lift-copies-own-direction", _LI,
           "d = d[inverse]  # repeated points share one line (module docstring)",
           "d = _directions(key, len(p)) if ids is None else d[inverse]",
           "repeated points get distinct lines again (they meet at the secret point; issue 15 item 5)",
           LIFT),
    # ---- Line2Point -------------------------------------------------------------------------
    Mutant("l2p-trim-bound", _LP,
           "return (end - start > 5) & (kv > config.kuiper_threshold) & shrunk",
           "return (end - start >= 5) & (kv > config.kuiper_threshold) & shrunk",
           "peak search continues with 5 offsets left (> 5 → ≥ 5)",
           L2P),
    Mutant("l2p-kmin-range", _LP,
           "kmin = jnp.argmin(diff[: int(0.9 * nb)])",
           "kmin = jnp.argmin(diff[:nb])",
           "k₋ searched over all bin edges instead of the first 90 %",
           L2P),
    Mutant("l2p-kuiper-no-uniform", _LP,
           "kv = hist_cs[kmax] + uni[kmin] - hist_cs[kmin] - uni[kmax]",
           "kv = hist_cs[kmax] - hist_cs[kmin]",
           "Kuiper statistic without the uniform CDF terms",
           L2P),
    Mutant("l2p-median-upper", _LP,
           "return (s[a + (m - 1) // 2] + s[a + m // 2]) / 2",
           "return (s[a + m // 2] + s[a + m // 2]) / 2",
           "median of an even count takes the upper middle only",
           L2P),
    Mutant("l2p-estimate-sign", _LP,
           "return jnp.sum((a_j - a_i) * n2, axis=-1) / (jnp.sum(d_i * n2, axis=-1) + _EPS)",
           "return jnp.sum((a_i - a_j) * n2, axis=-1) / (jnp.sum(d_i * n2, axis=-1) + _EPS)",
           "closest-approach offset with a_i − a_j (sign flipped)",
           L2P),
    Mutant("l2p-neighbours-plus-one", _LP,
           "return max(1, min(n, int(min(config.max_neighbours, config.neighbour_fraction * n))))",
           "return max(1, min(n, int(min(config.max_neighbours, config.neighbour_fraction * n)) + 1))",
           "coarse neighbour count k off by one",
           L2P),
    Mutant("l2p-intersection-swapped", _LP,
           "use = jnp.where(jnp.sum(member.astype(jnp.int32)) > config.min_intersection, member, True)",
           "use = jnp.where(jnp.sum(member.astype(jnp.int32)) > config.min_intersection, True, member)",
           "refinement uses the l2p set when the intersection is large and the intersection when small",
           L2P),
    Mutant("l2p-anchor-sign", _LP,
           "a = jnp.cross(d, jnp.asarray(lines.moments, d.dtype))",
           "a = jnp.cross(jnp.asarray(lines.moments, d.dtype), d)",
           "anchor m × d = −(d × m): the mirror of the closest point",
           L2P),
    Mutant("l2p-distance-unnormalised", _LP,
           "return jnp.abs(num) / (jnp.sqrt(cx * cx + cy * cy + cz * cz) + _EPS)",
           "return jnp.abs(num)",
           "line–line distance not divided by ‖d_i × d_j‖ (ranks by the triple product)",
           L2P),
    # ---- gradient attack --------------------------------------------------------------------
    Mutant("grad-self-neighbour", _GR,
           "return select_smallest(jnp.where(jnp.arange(n) == i, jnp.inf, dist), k)",
           "return select_smallest(dist, k)",
           "neighbour graph includes the line itself (distance 0)",
           GRAD),
    Mutant("grad-point-sign", _GR,
           "x = anchors + t[:, None] * directions",
           "x = anchors - t[:, None] * directions",
           "energy evaluates a − t·d while the result is a + t·d",
           GRAD),
    Mutant("grad-cauchy-scale", _GR,
           "return jnp.sum(sigma**2 * jnp.log1p(s / sigma**2))",
           "return jnp.sum(sigma**2 * jnp.log1p(s / sigma))",
           "Cauchy loss scaled by σ instead of σ² inside the log",
           GRAD),
    # ---- detection decode / NMS -------------------------------------------------------------
    Mutant("decode-dfl-bins", _DE,
           "return prob @ jnp.arange(reg_max, dtype=box_logits.dtype)",
           "return prob @ jnp.arange(1, reg_max + 1, dtype=box_logits.dtype)",
           "DFL expectation over bins 1..16 instead of 0..15",
           DECODE),
    Mutant("decode-anchor-offset", _DE,
           "strides: tuple[int, ...], offset: float = 0.5",
           "strides: tuple[int, ...], offset: float = 0.0",
           "anchors at cell corners instead of cell centres",
           DECODE),
    Mutant("decode-anchor-xy-swapped", _DE,
           "points.append(jnp.stack([sx, sy], axis=-1).reshape(-1, 2))",
           "points.append(jnp.stack([sy, sx], axis=-1).reshape(-1, 2))",
           "anchor points (y, x) instead of (x, y)",
           DECODE),
    Mutant("decode-corner-not-centre", _DE,
           "xywh = jnp.concatenate([(x1y1 + x2y2) / 2, x2y2 - x1y1], axis=-1) * stride[None]",
           "xywh = jnp.concatenate([x1y1, x2y2 - x1y1], axis=-1) * stride[None]",
           "decoded box position is the top-left corner instead of the centre",
           DECODE),
    Mutant("nms-iou-without-intersection", _DE,
           "iou = inter / (areas[i] + areas[rest] - inter)",
           "iou = inter / (areas[i] + areas[rest])",
           "NMS IoU denominator without − intersection",
           NMS),
    Mutant("nms-class-agnostic", _DE,
           "offset = 0.0 if agnostic else cls[:, None].astype(np.float32) * MAX_WH",
           "offset = 0.0",
           "class-aware NMS lost: boxes of different classes suppress each other",
           NMS),
    Mutant("box-iou-union", _DE,
           "return inter / (area_a[:, None] + area_b[None, :] - inter + 1e-7)",
           "return inter / (area_a[:, None] + area_b[None, :] + 1e-7)",
           "box_iou denominator without − intersection",
           NMS),
    # ---- detection loss ---------------------------------------------------------------------
    Mutant("ciou-4-over-pi", _LO,
           "v = (4 / math.pi**2) *",
           "v = (4 / math.pi) *",
           "CIoU aspect term 4/π instead of 4/π²",
           LOSS),
    Mutant("ciou-alpha-sign", _LO,
           "alpha = jax.lax.stop_gradient(v / (v - iou + (1 + eps)))",
           "alpha = jax.lax.stop_gradient(v / (v + iou + (1 + eps)))",
           "CIoU trade-off α = v/(v + IoU + 1) instead of v/(v − IoU + 1)",
           LOSS),
    Mutant("ciou-centre-distance", _LO,
           "b1[..., 1] - b1[..., 3]) ** 2) / 4",
           "b1[..., 1] - b1[..., 3]) ** 2) / 2",
           "CIoU centre distance ρ² divided by 2 instead of 4",
           LOSS),
    Mutant("dfl-ce-weights-swapped", _LO,
           "return -lp_l * wl - lp_r * (1 - wl)",
           "return -lp_l * (1 - wl) - lp_r * wl",
           "DFL: left/right bin weights swapped",
           LOSS),
    Mutant("assign-candidate-any-side", _LO,
           "in_gts = (deltas.min(-1) > eps).astype(pd_scores.dtype) * m",
           "in_gts = (deltas.max(-1) > eps).astype(pd_scores.dtype) * m",
           "assigner candidates: anchor inside on any side (max) instead of all four (min)",
           LOSS),
    Mutant("bce-target-term", _LO,
           "bce = (1 - y) * x - jax.nn.log_sigmoid(x)",
           "bce = -y * x - jax.nn.log_sigmoid(x)",
           "BCE with logits written (−y)·x − log σ(x) instead of (1 − y)·x − log σ(x)",
           LOSS),
    Mutant("loss-dfl-bins", _LO,
           "dist = jax.nn.softmax(dist_logits, axis=-1) @ jnp.arange(r, dtype=box_logits.dtype)",
           "dist = jax.nn.softmax(dist_logits, axis=-1) @ jnp.arange(1, r + 1, dtype=box_logits.dtype)",
           "loss decodes predicted distances over bins 1..16",
           LOSS),
    # ---- image metrics ----------------------------------------------------------------------
    Mutant("psnr-R-not-squared", _IM,
           "return 10.0 * jnp.log10(data_range**2 / mse)",
           "return 10.0 * jnp.log10(data_range / mse)",
           "PSNR with R instead of R²",
           IMAGE),
    Mutant("ssim-constants-unscaled", _IM,
           "c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2",
           "c1, c2 = 0.01 * data_range**2, 0.03 * data_range**2",
           "SSIM C1 = K1·R², C2 = K2·R² instead of (K1·R)², (K2·R)²",
           IMAGE),
    Mutant("ssim-covariance-no-mean", _IM,
           "sab = _filter_valid(a * b, g) - mu_a * mu_b",
           "sab = _filter_valid(a * b, g)",
           "SSIM cross-covariance without − μ_a μ_b",
           IMAGE),
    Mutant("ssim-gauss-sigma", _IM,
           "g = np.exp(-(r**2) / (2 * sigma**2))",
           "g = np.exp(-(r**2) / (sigma**2))",
           "Gaussian window exp(−r²/σ²) (σ effectively 1.06 instead of 1.5)",
           IMAGE),
    Mutant("masked-mean-all-pixels", _IM,
           "return jnp.sum(x * w) / jnp.maximum(jnp.sum(w), 1.0)",
           "return jnp.sum(x * w) / x.size",
           "masked mean divides by all pixels instead of the masked ones",
           IMAGE),
    Mutant("uint8-scale-256", _IM,
           "return x.astype(jnp.float32) * jnp.float32(data_range / jnp.iinfo(x.dtype).max)",
           "return x.astype(jnp.float32) * jnp.float32(data_range / (jnp.iinfo(x.dtype).max + 1))",
           "integer images scaled by 1/256 instead of 1/255",
           IMAGE),
    Mutant("edge-recall-over-predicted", _IM,
           "recall = jnp.where(ntrue > 0, tp / jnp.maximum(ntrue, 1.0), 1.0)",
           "recall = jnp.where(ntrue > 0, tp / jnp.maximum(npred, 1.0), 1.0)",
           "edge recall divided by the predicted count (copy of precision)",
           IMAGE),
    # ---- trajectory metrics -----------------------------------------------------------------
    Mutant("rpe-world-frame-motion", _TR,
           "rel_e = np.linalg.inv(T_e[i]) @ T_e[j]",
           "rel_e = T_e[j] @ np.linalg.inv(T_e[i])",
           "estimated relative motion in the world frame instead of the camera frame",
           TRAJ),
    Mutant("rpe-all-pairs-off-by-one", _TR,
           "i = np.arange(n - delta) if all_pairs else np.arange(0, n, delta)[:-1]",
           "i = np.arange(n - delta - 1) if all_pairs else np.arange(0, n, delta)[:-1]",
           "all_pairs drops the last pair",
           TRAJ),
    Mutant("rotation-angle-sin-not-halved", _TR,
           "sin = 0.5 * np.linalg.norm(w, axis=-1)",
           "sin = np.linalg.norm(w, axis=-1)",
           "rotation angle with ‖vee(R − Rᵀ)‖ instead of half of it",
           TRAJ),
    Mutant("ate-se3-with-scale", _TR,
           'R, t, c = umeyama_np(T_est[:, :3, 3], T_ref[:, :3, 3], with_scale=align == "sim3")',
           'R, t, c = umeyama_np(T_est[:, :3, 3], T_ref[:, :3, 3], with_scale=align != "none")',
           "SE(3) alignment also fits a scale",
           TRAJ),
    Mutant("stats-std-ddof", _TR,
           "std=float(np.std(e)),",
           "std=float(np.std(e, ddof=1)),",
           "sample standard deviation where evo reports the population one",
           TRAJ),
    # ---- privacy metrics --------------------------------------------------------------------
    Mutant("chamfer-not-halved", _PM,
           '"chamfer": float(0.5 * (o2r.mean() + r2o.mean())),',
           '"chamfer": float(o2r.mean() + r2o.mean()),',
           "symmetric Chamfer distance without the ½",
           PRIV),
    Mutant("nn-direction-swapped", _PM,
           "o2r = nn_distances(p, r)",
           "o2r = nn_distances(r, p)",
           "nn_mean measured from recovered to original points (the paper's metric is the other way)",
           PRIV),
    Mutant("within-threshold-copy-paste", _PM,
           '"within_1.0": float(100.0 * np.mean(e < 1.0)),',
           '"within_1.0": float(100.0 * np.mean(e < 0.1)),',
           "within_1.0 computed with the 0.1 m threshold (copy-paste)",
           PRIV),
    Mutant("baseline-anchor-sign", _PM,
           "c = np.cross(d, np.asarray(lines.moments, np.float64))",
           "c = np.cross(np.asarray(lines.moments, np.float64), d)",
           "no-attack baseline m × d: mirror of the closest point",
           PRIV),
    Mutant("baseline-chord-min", _PM,
           "tmin = np.where(d != 0, np.minimum(t1, t2), -np.inf).max(1)",
           "tmin = np.where(d != 0, np.minimum(t1, t2), -np.inf).min(1)",
           "uniform baseline chord entry parameter min over axes instead of max (leaves the box)",
           PRIV),
    # ---- localisation against line clouds ------------------------------------------------------
    Mutant("loc-pixel-line-Kinv-transposed", _LC,
           "return mc @ jnp.linalg.inv(K)  # l_px = K^-T m_c, as rows",
           "return mc @ jnp.linalg.inv(K).T  # l_px = K^-T m_c, as rows",
           "refinement's image line K⁻¹ m_c instead of l = K⁻ᵀ m_c (rows m_c K⁻ᵀ): principal point in the wrong place",
           LOC),
    Mutant("loc-point-line-t-unrotated", _LC,
           "Xw = (X - t) @ R  # Rᵀ (X − t), row-wise",
           "Xw = X @ R - t  # Rᵀ (X − t), row-wise",
           "point_line_errors maps the query points to the world as Rᵀ X − t instead of Rᵀ (X − t)",
           LOC),
    Mutant("loc-ray-origins-ahead", _LC,
           "origins = a - far * d",
           "origins = a + far * d",
           "far-back ray origins a + L d: every map point lies behind its ray (PoseLib's cheirality)",
           LOC),
    Mutant("loc-depth-as-range", _LC,
           "X = rays * depth[:, None]  # the keypoints in the query camera (z = depth)",
           "X = rays / np.linalg.norm(rays, axis=1, keepdims=True) * depth[:, None]",
           "depth taken as the range along the ray instead of z: X = depth · K⁻¹u / ‖K⁻¹u‖",
           LOC),
    Mutant("loc-depth-scale-without-z", _LC,
           "np.concatenate([f / depth, np.zeros(pad)])",
           "np.concatenate([np.full(len(depth), f), np.zeros(pad)])",
           "depth refinement scales the offsets by f instead of f / z: far points weigh z² more than in pixels",
           LOC),
    Mutant("loc-prior-trace-untransposed", _LC,
           "if (np.trace(T[:3, :3] @ R_prior.T) - 1) / 2 >= cos_max]",
           "if (np.trace(T[:3, :3] @ R_prior) - 1) / 2 >= cos_max]",
           "rotation prior angle from tr(R R_prior) instead of tr(R R_priorᵀ)",
           LOC),
    Mutant("loc-axial-largest-eigenvector", _LC,
           "u = np.linalg.eigh(d.T @ d)[1][:, 0]",
           "u = np.linalg.eigh(d.T @ d)[1][:, -1]",
           "axial check takes the direction most aligned with the lines (largest eigenvalue) as the axis",
           LOC),
    Mutant("loc-keypoint-depths-clip-hw", _LC,
           "0, [w - 1, h - 1])",
           "0, [h - 1, w - 1])",
           "keypoint_depths clips (u, v) to (h − 1, w − 1): columns past the image height read the wrong pixel",
           LOC),
    Mutant("loc-match-order-by-row", _LC,
           'return pairs[np.argsort(pairs[:, 0], kind="stable")]',
           'return pairs[np.argsort(pairs[:, 1], kind="stable")]',
           "match_to_map ordered by map row instead of keypoint",
           LOC),
    # ---- ground-plane / road-surface attacks ---------------------------------------------------
    Mutant("plane-offset-not-normalised", _PA,
           "h = float(offset) / np.linalg.norm(n)",
           "h = float(offset)",
           "n·x = h with n normalised but h not: the plane moves when ‖n‖ ≠ 1",
           PLANE),
    Mutant("road-planes-rotation-transposed", _PA,
           "n = T[:, :3, :3] @ (dn / np.linalg.norm(dn))",
           "n = np.swapaxes(T[:, :3, :3], 1, 2) @ (dn / np.linalg.norm(dn))",
           "road normal R_c_w · down instead of R_w_c · down (pitch sign flipped)",
           PLANE),
    # ---- two-peak finding ----------------------------------------------------------------------
    Mutant("tpf-pair-copy-neighbour", _TP,
           "dist[cn[..., 0] < 1e-12] = np.inf",
           "dist[np.arange(len(rows)), rows] = np.inf",
           "only the line itself excluded: its pair's bit-identical copy (no closest approach) votes offset 0",
           TPF),
    Mutant("tpf-kde-sigma-in-metres", _TP,
           'density = gaussian_filter1d(counts, h / width, mode="constant")',
           'density = gaussian_filter1d(counts, h, mode="constant")',
           "KDE smoothing σ = h bins instead of h / bin width (bandwidth in metres used as bins)",
           TPF),
    Mutant("tpf-oracle-copy-paste", _TP,
           "swap = err(result.second[i], i) + err(result.first[j], j) < keep",
           "swap = err(result.second[i], i) + err(result.second[j], j) < keep",
           "oracle's swapped cost uses second[j] (copy-paste) instead of first[j]",
           TPF),
    # ---- ray-cloud attack ----------------------------------------------------------------------
    Mutant("centred-vote-counts-offsets", _CE,
           "score += (hits > 0) + 1e-6 * hits",
           "score += hits",
           "a candidate scores the number of offsets within δ, not the number of centres agreeing",
           CENTRED),
    Mutant("centred-distance-unnormalised", _CE,
           "dist = np.where(ok, np.abs(np.sum((a - a[i]) * c, axis=1)) / s, np.inf)",
           "dist = np.where(ok, np.abs(np.sum((a - a[i]) * c, axis=1)), np.inf)",
           "line–line distance not divided by ‖d_i × d_j‖: voters chosen by the triple product",
           CENTRED),
    # ---- road-parallel defence / keyframe up axis ----------------------------------------------
    Mutant("road-up-sign", _RD,
           "up = -n.mean(axis=0)",
           "up = n.mean(axis=0)",
           "keyframe_up returns the mean down axis (R_w_c · down) instead of up",
           ROAD),
    Mutant("road-near-one-sided", _RD,
           'near = np.abs(np.einsum("ik,ik->i", p - feet[nearest], nk)) < within',
           'near = np.einsum("ik,ik->i", p - feet[nearest], nk) < within',
           "near-road test without abs(): every point above the road (negative along down) is laid flat",
           ROAD),
    # recall-first propagation on real frames (issue 13 item 3)
    Mutant("runs-keep-non-increasing", "privslam_jax/detect/temporal.py",
           "cuts = [0] + [i + 1 for i, d in enumerate(steps) if d != step] + [len(ids)]",
           "cuts = [0] + [i + 1 for i, d in enumerate(steps) if d > step] + [len(ids)]",
           "a repeated or backwards frame number does not end a run (boxes carried across it)",
           ("tests/test_temporal.py",)),
    Mutant("runs-unit-step", "privslam_jax/detect/temporal.py",
           "step = min((d for d in steps if d > 0), default=1)",
           "step = 1",
           "runs assume a step of one frame: a sequence kept at every third frame is cut into single frames "
           "(propagation silently off)",
           ("tests/test_temporal.py",)),
    Mutant("real-frames-default-per-frame", "privslam_jax/inpaint/sequence.py",
           "propagate = 0 if synthetic else REAL_FRAME_PROPAGATION",
           "propagate = 0",
           "real frames filtered per frame by default (the recall-first default lost)",
           ("tests/test_detector_domain.py",)),
    # ---- real-frame inpainter inference (flip average, blend with the prefill by distance) ------------
    Mutant("flip-fill-not-unmirrored", "privslam_jax/inpaint/filter.py",
           "        return m(out)\n",
           "        return out\n",
           "flip average: the mirrored crop's fill is not mirrored back before averaging (the two fills disagree "
           "left to right)",
           INPAINT_INFERENCE),
    Mutant("share-complement-dropped", "privslam_jax/inpaint/filter.py",
           "return (a * -np.expm1(-blend_distance(masks, config) / tau)).astype(np.float32)",
           "return (a * np.exp(-blend_distance(masks, config) / tau)).astype(np.float32)",
           "network share a·exp(−d/τ) instead of a·(1 − exp(−d/τ)): the network fills the hole's rim and Telea "
           "its centre",
           INPAINT_INFERENCE),
    Mutant("model-pixels-inverse-factor", "privslam_jax/inpaint/filter.py",
           "total[m] += max(box.height, box.width) / config.size",
           "total[m] += config.size / max(box.height, box.width)",
           "distance in model pixels multiplied by the crop's resize factor instead of divided by it",
           INPAINT_INFERENCE),
    Mutant("model-pixels-short-side", "privslam_jax/inpaint/filter.py",
           "total[m] += max(box.height, box.width) / config.size",
           "total[m] += min(box.height, box.width) / config.size",
           "resize factor from the crop's shorter side (the crop is resized by its longer side)",
           INPAINT_INFERENCE),
    Mutant("hole-distance-inverted", "privslam_jax/inpaint/filter.py",
           "return ndimage.distance_transform_edt(hidden).astype(np.float32)",
           "return ndimage.distance_transform_edt(~hidden).astype(np.float32)",
           "distance to the nearest hidden pixel instead of the nearest visible one (0 inside every hole)",
           INPAINT_INFERENCE),
    Mutant("prefill-blend-swapped", "privslam_jax/inpaint/differentiable.py",
           "blend = a * blend + (1.0 - a) * jax.lax.stop_gradient(cast(constants.frame_fill))",
           "blend = (1.0 - a) * blend + a * jax.lax.stop_gradient(cast(constants.frame_fill))",
           "the network's share a given to the prefill and 1 − a to the network",
           INPAINT_INFERENCE),
    Mutant("paste-overlaps-summed", "privslam_jax/inpaint/differentiable.py",
           "blend = acc / jnp.maximum(count, 1.0)[..., None]",
           "blend = acc",
           "pixels covered by two crops take the sum of their fills instead of the mean",
           INPAINT_INFERENCE),
    # ---- re-detection count (Table 2, the Pareto front's privacy axis) ------------------------------
    Mutant("refound-counts-detections", "privslam_jax/metrics/redetection.py",
           "return int(np.any((box_iou(bo, bf) >= iou) & same, axis=1).sum())",
           "return int(np.any((box_iou(bo, bf) >= iou) & same, axis=0).sum())",
           "re-detection counts the filtered detections that match some object, not the objects matched",
           REDETECTION),
    Mutant("refound-class-ignored", "privslam_jax/metrics/redetection.py",
           "same = co[:, None] == cf[None, :]",
           "same = np.ones((len(co), len(cf)), bool)",
           "a filtered detection of another class counts as re-detecting the object",
           REDETECTION),
)


# ------------------------------------------------------------------------------------------------


def check_list(mutants: tuple[Mutant, ...], root: Path) -> None:
    """Every id unique, every snippet exactly once, every mutated file compiles, every test path exists."""
    ids = [m.id for m in mutants]
    dup = {i for i in ids if ids.count(i) > 1}
    if dup:
        raise SystemExit(f"duplicate mutant ids: {sorted(dup)}")
    for m in mutants:
        src = (root / m.file).read_text()
        count = src.count(m.original)
        if count != 1:
            raise SystemExit(f"{m.id}: the original snippet occurs {count} times in {m.file} (must be once):\n  {m.original}")
        if m.replacement == m.original:
            raise SystemExit(f"{m.id}: replacement equals the original")
        try:
            compile(src.replace(m.original, m.replacement), m.file, "exec")
        except SyntaxError as err:
            raise SystemExit(f"{m.id}: the mutated {m.file} does not compile: {err}") from err
        for t in m.tests:
            if not (root / t.split("::")[0]).is_file():
                raise SystemExit(f"{m.id}: test file {t.split('::')[0]} does not exist")


def working_tree_files(root: Path) -> list[str]:
    """Tracked and untracked-but-not-ignored files of the working tree (deleted ones left out), no ``runs/``."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=root, check=True, capture_output=True,
    ).stdout.decode()
    files = sorted({f for f in out.split("\0") if f})
    return [f for f in files if not f.startswith("runs/") and (root / f).is_file()]


def make_copy(root: Path, files: list[str], dest: Path) -> Path:
    for f in files:
        target = dest / f
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / f, target)
    return dest


def test_env(copy: Path, shared: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(copy)  # the copy before the editable install of /work/main
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # no stale .pyc between a mutant and the restored file
    env["PRIVSLAM_SHARED"] = str(shared)  # by default a folder that does not exist: tests needing ../shared skip
    return env


def run_pytest(copy: Path, env: dict[str, str], tests: tuple[str, ...], timeout: float) -> tuple[int | None, float, str]:
    """``(exit code or None on timeout, seconds, the first failing test or else the last lines of the output)``."""
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=copy, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
        code: int | None = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the pytest process group this function started
        out, _ = proc.communicate()
        code = None
    lines = out.decode(errors="replace").strip().splitlines()
    # first failing test of pytest's short summary (-ra): "FAILED tests/x.py::test_y - ..." / "ERROR ..."
    first = next((ln.split(" - ")[0].split(" ", 1)[1] for ln in lines if ln.startswith(("FAILED ", "ERROR "))), "")
    return code, time.monotonic() - t0, first or "\n".join(lines[-3:])


def classify(code: int | None) -> str:
    if code is None:
        return "timeout"
    if code == 0:
        return "survived"
    if code in (1, 2, 3):
        return "killed"
    return "error"


def git_state(root: Path) -> str:
    def git(*cmd: str) -> str:
        return subprocess.run(["git", *cmd], cwd=root, check=True, capture_output=True, text=True).stdout

    head = git("rev-parse", "--short", "HEAD").strip()
    status = git("status", "--porcelain", "--", "privslam_jax", "tests").splitlines()
    if not status:
        return f"commit {head}, clean working tree (privslam_jax/, tests/)"
    return f"commit {head} + working tree ({len(status)} uncommitted in privslam_jax/, tests/: " + ", ".join(
        s[3:] for s in status) + ")"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="comma-separated mutant ids")
    ap.add_argument("--jobs", type=int, default=1, help="mutants run concurrently (one repo copy each)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run (timeout = killed, marked)")
    ap.add_argument("--out", default="", help="also write the markdown table here (atomically)")
    ap.add_argument("--list", action="store_true", help="check the list and print it; run nothing")
    ap.add_argument("--no-baseline", action="store_true", help="skip the unmutated sanity run")
    ap.add_argument("--shared", default="", help="run with this ../shared folder visible (default: hidden)")
    args = ap.parse_args()

    check_list(MUTANTS, REPO)
    selected = list(MUTANTS)
    if args.only:
        want = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = sorted(set(want) - {m.id for m in MUTANTS})
        if unknown:
            raise SystemExit(f"unknown mutant ids: {unknown}")
        selected = [m for m in MUTANTS if m.id in want]
    if args.list:
        for m in selected:
            print(f"{m.id:32s} {m.file:38s} {m.description}")
        print(f"{len(selected)} mutants, list checked against {REPO}")
        return 0

    if args.shared and not Path(args.shared).is_dir():
        raise SystemExit(f"--shared {args.shared}: no such folder")
    state = git_state(REPO)
    shared_note = f"`../shared` = {args.shared}" if args.shared else "`../shared` hidden"
    print(f"mutants: {len(selected)} of {len(MUTANTS)}; {state}; {shared_note}", flush=True)
    start = time.monotonic()
    files = working_tree_files(REPO)
    tmp = Path(tempfile.mkdtemp(prefix="privslam-mutants-"))
    shared = Path(args.shared).resolve() if args.shared else tmp / "no-shared"  # the latter never exists
    results: dict[str, tuple[str, float, str]] = {}
    try:
        copies: queue.Queue[Path] = queue.Queue()
        for k in range(max(1, args.jobs)):
            copies.put(make_copy(REPO, files, tmp / f"w{k}" / "main"))
        check_list(tuple(selected), tmp / "w0" / "main")  # the copy holds the same snippets

        if not args.no_baseline:
            copy = tmp / "w0" / "main"
            env = test_env(copy, shared)
            where = subprocess.run([sys.executable, "-c", "import privslam_jax; print(privslam_jax.__file__)"],
                                   cwd=copy, env=env, capture_output=True, text=True, check=True).stdout.strip()
            if not Path(where).resolve().is_relative_to(copy.resolve()):
                raise SystemExit(f"sanity: the copy imports privslam_jax from {where}, not from {copy}")
            print(f"sanity: privslam_jax imported from the copy ({where})", flush=True)
            union = tuple(dict.fromkeys(t for m in selected for t in m.tests))
            code, secs, tail = run_pytest(copy, env, union, args.timeout * 2)
            if code != 0:
                raise SystemExit(f"sanity: the unmutated tests do not pass (exit {code}, {secs:.0f} s):\n{tail}")
            print(f"sanity: unmutated tests pass ({secs:.0f} s): {tail.splitlines()[-1] if tail else ''}", flush=True)

        lock = threading.Lock()
        done = [0]

        def run_one(m: Mutant) -> None:
            copy = copies.get()
            path = copy / m.file
            original = path.read_text()
            try:
                path.write_text(original.replace(m.original, m.replacement))
                code, secs, tail = run_pytest(copy, test_env(copy, shared), m.tests, args.timeout)
            finally:
                path.write_text(original)
                copies.put(copy)
            result = classify(code)
            with lock:
                results[m.id] = (result, secs, tail)
                done[0] += 1
                print(f"[{done[0]}/{len(selected)}] {m.id}: {result} ({secs:.0f} s) {tail if result != 'survived' else ''}",
                      flush=True)

        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            list(pool.map(run_one, selected))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    rows = ["| id | module | bug | result | first failing test | s |", "|---|---|---|---|---|---:|"]
    for m in selected:
        result, secs, info = results[m.id]
        mark = "**survived**" if result == "survived" else result
        module = m.file.removeprefix("privslam_jax/")
        by = info.removeprefix("tests/") if result == "killed" and "\n" not in info else ""
        rows.append(f"| {m.id} | {module} | {m.description} | {mark} | {by} | {secs:.0f} |")
    killed = sum(results[m.id][0] in ("killed", "timeout") for m in selected)
    timeouts = sum(results[m.id][0] == "timeout" for m in selected)
    survivors = [m.id for m in selected if results[m.id][0] != "killed" and results[m.id][0] != "timeout"]
    score = (f"score: {killed}/{len(selected)} killed ({100.0 * killed / len(selected):.1f} %)"
             + (f", {timeouts} of them by timeout" if timeouts else "")
             + (f"; not killed: {', '.join(survivors)}" if survivors else ""))
    table = "\n".join(rows)
    print()
    print(table)
    print()
    print(score)
    print(f"total: {(time.monotonic() - start) / 60:.0f} min")
    if args.out:
        from privslam_jax.data.files import write_atomic

        cmd = "python benchmarks/mutants.py " + " ".join(sys.argv[1:])
        write_atomic(args.out, f"# Mutation score\n\n`{cmd.strip()}` on {state}, {shared_note}.\n\n"
                               f"{table}\n\n{score}\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
