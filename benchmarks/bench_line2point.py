"""Benchmark: Line2Point in JAX vs the numpy reference, and its memory at N = 100,000.

    python benchmarks/bench_line2point.py                 # all parts, prints a Markdown table
    python benchmarks/bench_line2point.py --part 20k      # one part: 2k | 20k | 100k

* ``2k``:  N = 2,000 lines, JAX (float32, after compile; median of ``--repeats-2k`` runs) against
  the plain numpy reference of ``tests/line2point_reference.py`` (float64, one run: it is slow),
  in the same process.  Goal: ≥ 10× speed-up.
* ``20k``: N = 20,000 lines, full Line2Point (coarse + 2 refinement rounds) after compile
  (median of ``--repeats-20k`` runs), plus the coarse pass alone and one refinement round alone
  (medians of the same number of runs).  Goal: ≤ 10 s.
* ``100k``: N = 100,000 lines in a subprocess, one run: wall time, XLA compile time inside it
  (``jax.monitoring`` backend-compile events) and the child's peak RSS
  (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``).  Goal: fits in 16 GiB.

Compile time = XLA backend-compile time reported by ``jax.monitoring`` during the first call.
Departure from the project's "median of ≥ 20 runs": a 20k run takes seconds, so the default
is 5 runs there (20 at 2k).  Lines: the random lift of a street-like map (two façades and a
road).  The load average (``os.getloadavg``) is printed before and after: on a shared CPU the
numbers are noisy, the 2k speed-up (same process) is the robust one.  On a shared Linux machine
``--autogroup-nice -19`` gives this process's session priority over the other sessions' jobs
(the kernel's autogroup scheduling otherwise gives each session one share whatever its thread
count), which approximates an idle machine for the length of the run.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import importlib  # noqa: E402

l2p_module = importlib.import_module("privslam_jax.attacks.line2point")  # the module (the package re-exports the function)
from privslam_jax.attacks.line2point import Line2PointConfig, line2point  # noqa: E402
from privslam_jax.privacy.lift import fixed_key, random_lift  # noqa: E402


def street_lines(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    k = n // 3
    f1 = np.stack([rng.uniform(-40, 40, k), np.full(k, -6.0) + rng.normal(0, 0.1, k), rng.uniform(0, 10, k)], 1)
    f2 = np.stack([rng.uniform(-40, 40, k), np.full(k, 6.0) + rng.normal(0, 0.1, k), rng.uniform(0, 10, k)], 1)
    m = n - 2 * k
    road = np.stack([rng.uniform(-40, 40, m), rng.uniform(-6, 6, m), rng.normal(0, 0.05, m)], 1)
    pts = np.concatenate([f1, f2, road])
    return pts, random_lift(jnp.asarray(pts, jnp.float32), fixed_key(seed))


_COMPILE_S = [0.0]


def _on_duration(event: str, duration: float, **_) -> None:
    if "backend_compile" in event:
        _COMPILE_S[0] += duration


jax.monitoring.register_event_duration_secs_listener(_on_duration)


_CPU_S = [0.0]  # process CPU seconds (all threads) of the last `timed` call: median over the runs


def timed(fn, repeats: int) -> tuple[float, float, np.ndarray]:
    """(XLA compile seconds during the first call, median of `repeats` warm calls, last result)."""
    c0 = _COMPILE_S[0]
    out = jax.block_until_ready(fn())
    compile_s = _COMPILE_S[0] - c0
    ts, cpu = [], []
    for _ in range(repeats):
        t0, p0 = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - p0)
    _CPU_S[0] = float(np.median(cpu))
    return compile_s, float(np.median(ts)), np.asarray(out)


def part_2k(repeats: int) -> dict:
    from line2point_reference import line2point_reference

    pts, lines = street_lines(2000)
    comp, warm, _ = timed(lambda: line2point(lines)[0], repeats)
    d = np.asarray(lines.directions, np.float64)
    a = np.cross(d, np.asarray(lines.moments, np.float64))
    t0 = time.perf_counter()
    line2point_reference(a, d)
    ref = time.perf_counter() - t0
    return {"N": 2000, "jax_s": warm, "compile_s": comp, "numpy_ref_s": ref, "speedup": ref / warm}


def part_20k(repeats: int) -> dict:
    pts, lines = street_lines(20000)
    comp, warm, rec = timed(lambda: line2point(lines)[0], repeats)
    cpu_s = _CPU_S[0]
    within = float(np.mean(np.linalg.norm(rec - pts, axis=1) < 0.5) * 100)
    # stages alone (same jitted functions as inside line2point)
    cfg = Line2PointConfig()
    d = lines.directions / jnp.linalg.norm(lines.directions, axis=-1, keepdims=True)
    a = jnp.cross(d, lines.moments)
    k = l2p_module.num_coarse_neighbours(20000, cfg)
    coarse = lambda: l2p_module._run_rows(lambda r: l2p_module._coarse_rows(r, a, d, k=k, config=cfg), 20000, cfg, None)
    _, coarse_s, t = timed(coarse, repeats)
    t = jnp.asarray(t)
    refine = lambda: l2p_module._run_rows(lambda r: l2p_module._refine_rows(r, a, d, t, config=cfg), 20000, cfg, None)
    _, refine_s, _ = timed(refine, repeats)
    return {"N": 20000, "jax_s": warm, "compile_s": comp, "within_0.5_pct": within, "coarse_s": coarse_s, "refine_s": refine_s, "cpu_s": cpu_s}


def part_100k_child() -> None:
    pts, lines = street_lines(100000)
    t0 = time.perf_counter()
    rec = np.asarray(line2point(lines)[0])
    wall = time.perf_counter() - t0
    within = float(np.mean(np.linalg.norm(rec - pts, axis=1) < 0.5) * 100)
    print(json.dumps({"N": 100000, "wall_s_incl_compile": wall, "compile_s": _COMPILE_S[0], "within_0.5_pct": within}))


def part_100k() -> dict:
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, __file__, "--child-100k"], capture_output=True, text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["peak_rss_GiB"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20  # KiB on Linux
    res["process_s"] = time.perf_counter() - t0
    return res


def _load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=("all", "2k", "20k", "100k"), default="all")
    ap.add_argument("--repeats-2k", type=int, default=20)
    ap.add_argument("--repeats-20k", type=int, default=5)
    ap.add_argument(
        "--autogroup-nice",
        type=int,
        default=None,
        help="Linux: set this process group's scheduler niceness (/proc/self/autogroup; -19 = take the "
        "cores before other sessions' jobs) to approximate an idle machine on a shared one",
    )
    ap.add_argument("--child-100k", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.autogroup_nice is not None:  # the group is the whole login session: restored at exit
        group = Path("/proc/self/autogroup")
        before = int(group.read_text().split()[-1])
        group.write_text(f"{args.autogroup_nice}\n")
        atexit.register(lambda: group.write_text(f"{before}\n"))
    if args.child_100k:
        part_100k_child()
        return
    load_before = _load()
    rows = []
    extra = []
    if args.part in ("all", "2k"):
        r = part_2k(args.repeats_2k)
        rows.append(
            f"| 2,000 | {r['jax_s']:.3f} | {r['compile_s']:.1f} | {r['numpy_ref_s']:.1f} | **{r['speedup']:.0f}×** (goal ≥ 10×) | – | – |"
        )
    if args.part in ("all", "20k"):
        r = part_20k(args.repeats_20k)
        ok = "met" if r["jax_s"] <= 10 else "NOT met"
        rows.append(f"| 20,000 | **{r['jax_s']:.2f}** (goal ≤ 10 s: {ok}) | {r['compile_s']:.1f} | – | – | – | {r['within_0.5_pct']:.1f} |")
        extra.append(
            f"N = 20,000: process CPU time of a full run {r['cpu_s']:.1f} s (all threads; the wall time on an "
            f"idle machine is about this divided by the threads); stages alone (median wall s): coarse pass "
            f"{r['coarse_s']:.2f}, one refinement round {r['refine_s']:.2f}"
        )
    if args.part in ("all", "100k"):
        r = part_100k()
        run = r["wall_s_incl_compile"] - r["compile_s"]
        rows.append(
            f"| 100,000 | {run:.0f} (one run) | {r['compile_s']:.1f} | – | – | {r['peak_rss_GiB']:.2f} (goal ≤ 16) | {r['within_0.5_pct']:.1f} |"
        )
    threads = l2p_module._num_threads(Line2PointConfig())
    nice = "" if args.autogroup_nice is None else f"; autogroup niceness {args.autogroup_nice}"
    print(
        f"\nLine2Point (JAX {jax.__version__}, float32, {threads} host threads, 2 refinement rounds); "
        f"load average (1/5/15 min) before {load_before}, after {_load()}{nice}.\n"
    )
    print("| N lines | JAX run (s) | compile (s) | numpy reference (s) | speed-up | peak RSS (GiB) | % within 0.5 m |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    for line in extra:
        print("\n" + line)


if __name__ == "__main__":
    main()
