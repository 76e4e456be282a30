"""Bundle-adjustment benchmark on the real KITTI ``seq1`` BAL problem (51 cameras, 15,698 points).

Goal (issue 5, item 3): wall time for :func:`privslam_jax.slam.bundle_adjust` to reach cost
``≤ 13,300 px²`` (``½Σ‖r‖²``, squared loss, intrinsics fixed, camera 0 fixed) from the perturbed start
(26.26 M px²), compile time separately, against Ceres (through pycolmap, when installed) in the same run.

Command::

    python benchmarks/bench_ba.py            # 20 timed runs per row (≈ 3-4 min on an idle 2-core machine)
    python benchmarks/bench_ba.py --runs 3   # quick look

Every timed call is the whole host entry point (checks, Schur-structure analysis, padding, the jitted
LM, unpadding); the final cost is re-evaluated in float64 with the BAL-convention residual
(:func:`privslam_jax.data.bal.bal_cost`), so the float32 rows are judged by the exact cost.
Ceres: pycolmap's default bundle adjuster (LM, Schur, 2 threads, squared loss, fixed intrinsics, its
own gauge fixing), timed in ``solve()`` on a fresh copy of the problem each run.

``OPENBLAS_NUM_THREADS`` defaults to 1 here: XLA's CPU Cholesky calls LAPACK from scipy's OpenBLAS,
whose spinning worker threads made a 306×306 float64 factorisation take 20-500 ms instead of ~1 ms on
this 2-core machine when other processes run (measured; see docs/slam_solvers.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import jaxlie  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.data.bal import BALProblem, bal_cost, bal_to_opencv, opencv_to_bal_cameras, read_bal  # noqa: E402
from privslam_jax.slam.ba import BAConfig, analyze, bundle_adjust  # noqa: E402

TARGET = 13_300.0


def _jax_rows(problem: BALProblem, runs: int) -> list[dict]:
    T, intr, uv = bal_to_opencv(problem)
    wxyz = np.c_[Rotation.from_matrix(T[:, :3, :3]).as_quat(scalar_first=True), T[:, :3, 3]]
    fixed = np.zeros(problem.n_cameras, bool)
    fixed[0] = True
    rows, seen = [], set()
    for dtype, stop in (("float64", "target"), ("float32", "target"), ("float64", "converged"), ("float32", "converged")):
        cfg = BAConfig(huber_delta=None, max_iterations=100, target_cost=TARGET if stop == "target" else 0.0)
        with jax.enable_x64(dtype == "float64"):
            pts = problem.points.astype(dtype)

            def call():
                r = bundle_adjust(jaxlie.SE3(jnp.asarray(wxyz, dtype)), pts, problem.obs_cam, problem.obs_pt, uv.astype(dtype),
                                  None, fixed, intr, cfg, pad=False)
                jax.block_until_ready(r)
                return r

            t0, c0 = time.perf_counter(), time.process_time()
            res = call()
            first, first_cpu = time.perf_counter() - t0, time.process_time() - c0
            times, cpus = [], []
            for _ in range(runs):
                t0, c0 = time.perf_counter(), time.process_time()
                res = call()
                times.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
        med = statistics.median(times)
        q = np.asarray(res.T_c_w.wxyz_xyz, np.float64)
        Tm = np.tile(np.eye(4), (q.shape[0], 1, 1))
        Tm[:, :3, :3] = Rotation.from_quat(q[:, :4], scalar_first=True).as_matrix()
        Tm[:, :3, 3] = q[:, 4:]
        cost = bal_cost(problem, opencv_to_bal_cameras(Tm, intr), np.asarray(res.points, np.float64))
        # the numeric BAConfig fields are traced values: only the first row of each dtype compiles
        compiled = dtype not in seen
        seen.add(dtype)
        rows.append(dict(solver=f"privslam_jax ({dtype})", stop=stop, compile=(first - med) if compiled else None, median=med,
                         compile_cpu=(first_cpu - statistics.median(cpus)) if compiled else None, cpu=statistics.median(cpus),
                         spread=(min(times), max(times)), iterations=int(res.iterations), cost=cost))
    return rows


def _ceres_rows(problem: BALProblem, runs: int) -> list[dict]:
    try:
        import pycolmap as pc
    except ImportError:
        return []
    T, intr, uv = bal_to_opencv(problem)
    kp_index = np.zeros(problem.n_observations, np.int64)
    for c in range(problem.n_cameras):
        sel = np.flatnonzero(problem.obs_cam == c)
        kp_index[sel] = np.arange(sel.size)
    order = np.argsort(problem.obs_pt, kind="stable")
    bounds = np.searchsorted(problem.obs_pt[order], np.arange(problem.n_points + 1))

    def build():
        rec = pc.Reconstruction()
        cam = pc.Camera(model="SIMPLE_PINHOLE", width=1226, height=370, params=[float(intr[0, 0]), 0.0, 0.0], camera_id=1)
        rec.add_camera_with_trivial_rig(cam)
        for c in range(problem.n_cameras):
            sel = problem.obs_cam == c
            img = pc.Image(name=str(c), keypoints=np.ascontiguousarray(uv[sel]), camera_id=1, image_id=c + 1)
            R = np.ascontiguousarray(T[c, :3, :3])
            t = np.ascontiguousarray(T[c, :3, 3])
            rec.add_image_with_trivial_frame(img, pc.Rigid3d(pc.Rotation3d(R), t))
        for j in range(problem.n_points):
            tr = pc.Track()
            for o in order[bounds[j] : bounds[j + 1]]:
                tr.add_element(int(problem.obs_cam[o]) + 1, int(kp_index[o]))
            rec.add_point3D(np.ascontiguousarray(problem.points[j]), tr)
        opts = pc.BundleAdjustmentOptions()
        opts.refine_focal_length = False
        opts.refine_extra_params = False
        opts.refine_principal_point = False
        opts.print_summary = False
        opts.ceres.solver_options.num_threads = 2
        cfg = pc.BundleAdjustmentConfig()
        for c in range(problem.n_cameras):
            cfg.add_image(c + 1)
        # keep rec/opts/cfg alive: the adjuster holds references to them
        return pc.create_default_bundle_adjuster(opts, cfg, rec), (rec, opts, cfg)

    times, cpus, summary = [], [], None
    for _ in range(runs):
        adjuster, keep = build()
        t0, c0 = time.perf_counter(), time.process_time()
        summary = adjuster.solve()
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    cs = summary.ceres_summary
    return [dict(solver=f"Ceres {pc.__ceres_version__} (pycolmap {pc.__version__}, 2 threads)", stop="converged",
                 compile=None, compile_cpu=None, cpu=statistics.median(cpus), median=statistics.median(times), spread=(min(times), max(times)),
                 iterations=int(cs.num_successful_steps + cs.num_unsuccessful_steps), cost=float(cs.final_cost))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="timed runs per row after the compiling call")
    ap.add_argument("--no-ceres", action="store_true", help="skip the pycolmap/Ceres reference")
    args = ap.parse_args()
    shared = shared_dir()
    if shared is None:
        raise SystemExit("../shared is absent (set PRIVSLAM_SHARED)")
    path = shared / "reference/ba/kitti_seq1_perturbed.bal.txt.bz2"
    t0 = time.perf_counter()
    problem = read_bal(path)
    t_read = time.perf_counter() - t0
    print(f"{path.name}: {problem.n_cameras} cameras, {problem.n_points} points, {problem.n_observations} observations; "
          f"start cost {bal_cost(problem):,.0f} px² (read in {t_read:.2f} s); load average {os.getloadavg()[0]:.1f}")
    t0 = time.perf_counter()
    st = analyze(problem.obs_cam, problem.obs_pt, problem.n_cameras, problem.n_observations + 1, BAConfig().chunk, pad=False)
    n_pairs = int(np.sum(np.asarray(st.pair_a) != problem.n_observations))
    print(f"Schur structure: {n_pairs:,} observation pairs in {st.chunk_seg.shape[0]:,} chunks "
          f"(host analysis {time.perf_counter() - t0:.2f} s)")
    rows = [] if args.no_ceres else _ceres_rows(problem, args.runs)
    ceres = rows[0]["median"] if rows else None
    if ceres is None:
        print("pycolmap not installed: Ceres reference from ../shared/README.md: 13,272 px² in 2.2 s (2 threads)")
        ceres = 2.2
    rows += _jax_rows(problem, args.runs)
    print()
    print("| solver | stop | compile wall / CPU (s) | median wall (s) | min–max (s) | median CPU (s) | iterations "
          "| final cost (px²) | time / Ceres |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        comp = "–" if r["solver"].startswith("Ceres") else "cached" if r["compile"] is None else (
            f"{r['compile']:.1f} / {r['compile_cpu']:.1f}")
        print(f"| {r['solver']} | {r['stop']} | {comp} | {r['median']:.2f} | {r['spread'][0]:.2f}–{r['spread'][1]:.2f} "
              f"| {r['cpu']:.2f} | {r['iterations']} | {r['cost']:,.1f} | {r['median'] / ceres:.2f}× |")
    print(f"\n{args.runs} timed runs per row; target cost ≤ {TARGET:,.0f} px²; 'target' rows stop there, 'converged' rows at "
          "Ceres' default tolerances (relative decrease 1e-6).\nCPU = process CPU time (all threads); on a busy "
          "machine it is closer to the idle wall time than the wall time is.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
