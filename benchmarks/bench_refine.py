"""Pose-only refinement benchmark: privslam_jax's jitted 6×6 LM vs optimistix LM vs OpenCV.

One synthetic KITTI-like frame (1226×370, fx = 707): ``N`` 2D–3D matches (default 2,000) with 1 px
noise and 10 % gross outliers, initial pose off by ~3 cm / 0.6°.  Rows:

* ``refine_pose`` with the ORB-SLAM schedule (4 rounds × 10 iterations, Huber, χ² re-classification);
* ``refine_pose`` one round of squared-loss LM (the problem optimistix and OpenCV solve);
* ``optimistix.LevenbergMarquardt`` on the same squared-loss residual (jitted, its default QR solve);
* ``cv2.solvePnPRefineLM`` (squared loss, C++).

Command::

    python benchmarks/bench_refine.py            # 20 timed runs per row (~1 min idle)
    python benchmarks/bench_refine.py --n 500 --runs 5

Times are per call after compilation (median); compile time separately; translation error of the
result against the true pose (the squared-loss rows are pulled by the outliers).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import jaxlie  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

from privslam_jax.slam.refine import RefineConfig, refine_pose  # noqa: E402
from privslam_jax.types import Camera  # noqa: E402

CAM = Camera(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, width=1226, height=370)


def _frame(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(4, 50, n)
    uv_true = np.stack([rng.uniform(0, CAM.width, n), rng.uniform(0, CAM.height, n)], 1)
    p_c = np.c_[(uv_true - [CAM.cx, CAM.cy]) / CAM.fx * z[:, None], z]
    T_true = jaxlie.SE3.exp(jnp.asarray([0.3, -0.1, 1.2, 0.02, -0.05, 0.01]))
    M = np.asarray(T_true.as_matrix())
    p_w = (p_c - M[:3, 3]) @ M[:3, :3]
    uv = uv_true + rng.normal(0, 1, (n, 2))
    n_out = n // 10
    uv[:n_out] += rng.uniform(20, 80, (n_out, 2)) * rng.choice([-1, 1], (n_out, 2))
    T0 = jaxlie.SE3.exp(jnp.asarray([0.02, -0.02, 0.02, 0.01, 0.0, -0.005])) @ T_true
    return T_true, T0, p_w, uv


def _timed(fn, runs: int):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return out, first - med, med


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="matches per frame")
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args()
    T_true, T0, p_w, uv = _frame(args.n)
    t_true = np.asarray(T_true.translation())
    rows = []

    def err(T: jaxlie.SE3) -> float:
        return float(np.linalg.norm(np.asarray(T.translation()) - t_true))

    for name, cfg in (("refine_pose, ORB-SLAM schedule (4×10, Huber)", RefineConfig()),
                      ("refine_pose, 1 round, squared loss", RefineConfig(rounds=1, max_iterations=20, robust=False))):
        pw32, uv32 = p_w.astype(np.float32), uv.astype(np.float32)

        def call(cfg=cfg):
            r = refine_pose(T0, pw32, uv32, None, CAM, cfg)
            jax.block_until_ready(r.T_c_w.wxyz_xyz)
            return r

        r, comp, med = _timed(call, args.runs)
        rows.append((name, comp, med, int(r.iterations), err(r.T_c_w)))

    pw_j, uv_j = jnp.asarray(p_w, jnp.float32), jnp.asarray(uv, jnp.float32)

    def resid(xi, _):
        T = jaxlie.SE3.exp(xi) @ T0
        p_c = pw_j @ T.rotation().as_matrix().T + T.translation()[None, :]
        pred = jnp.stack([CAM.fx * p_c[:, 0] / p_c[:, 2] + CAM.cx, CAM.fy * p_c[:, 1] / p_c[:, 2] + CAM.cy], 1)
        return (pred - uv_j).reshape(-1)

    solver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)
    @jax.jit
    def opt():
        sol = optx.least_squares(resid, solver, jnp.zeros(6, jnp.float32), max_steps=50, throw=False)
        return sol.value, sol.stats["num_steps"]

    def call_optx():
        out = opt()
        jax.block_until_ready(out)
        return out

    (xi, steps), comp, med = _timed(call_optx, args.runs)
    rows.append(("optimistix LevenbergMarquardt (squared loss)", comp, med, int(steps), err(jaxlie.SE3.exp(xi) @ T0)))

    M0 = np.asarray(T0.as_matrix())
    K = np.asarray(CAM.K, np.float64)

    def call_cv():
        rvec, _ = cv2.Rodrigues(M0[:3, :3])
        tvec = M0[:3, 3].copy()
        return cv2.solvePnPRefineLM(p_w.astype(np.float64), uv.astype(np.float64), K, None, rvec, tvec)

    (rv, tv), comp, med = _timed(call_cv, args.runs)
    rows.append(("cv2.solvePnPRefineLM (squared loss)", 0.0, med, -1, float(np.linalg.norm(tv.ravel() - t_true))))

    print(f"{args.n} matches (10 % outliers), {args.runs} timed runs per row, load average {os.getloadavg()[0]:.1f}\n")
    print("| method | compile (s) | median per call (ms) | iterations | translation error (m) |")
    print("|---|---|---|---|---|")
    for name, comp, med, it, e in rows:
        print(f"| {name} | {comp:.2f} | {med * 1e3:.2f} | {it if it >= 0 else '–'} | {e:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
