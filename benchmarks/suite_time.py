"""Where the test suite's time goes: wall, XLA compile, and trace+lower seconds per file.

Command::

    python benchmarks/suite_time.py            # runs the README's test command, then prints the table
    python benchmarks/suite_time.py --from F   # only summarise an earlier run's JSON lines
    python benchmarks/suite_time.py --from F --write-order tests/file_seconds.json

With the per-test rows it prints the programs compiled because the shared compilation cache did not
hold them: their seconds, how many of those a key compiled before accounts for (the same program
compiled twice, e.g. by both workers at once), the seconds per size band and the largest programs.

``--write-order`` writes each file's wall seconds, the costs by which ``tests/conftest.py`` hands the
files to the xdist workers longest first (rerun it when files are added or their cost changes much).

The suite runs with ``PRIVSLAM_TEST_TIMES`` set (``tests/conftest.py`` then appends one JSON line per
test with its wall time, start time, xdist worker and JAX's compile-event seconds).  Compile seconds are those of the test
processes; subprocesses (CLI runs, notebooks, multi-process training) are counted in wall time only.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", help="JSON lines of an earlier run (skip running the suite)")
    ap.add_argument("--top", type=int, default=25, help="files to list")
    ap.add_argument("--write-order", type=Path, help="write {file: wall seconds} here (tests/file_seconds.json)")
    args = ap.parse_args()
    path = Path(args.source) if args.source else Path(tempfile.mkdtemp()) / "times.jsonl"
    if not args.source:
        root = Path(__file__).resolve().parents[1]
        env = dict(os.environ, PRIVSLAM_TEST_TIMES=str(path))
        subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadfile", "-q"], cwd=root, env=env,
                       check=False)
    try:
        rows = [json.loads(line) for line in path.read_text().splitlines()]
        if not rows or not all(isinstance(r, dict) and "id" in r and "wall" in r for r in rows):
            raise ValueError("no per-test rows with 'id' and 'wall'")
    except (OSError, ValueError) as err:  # a missing, empty or foreign file: say so, exit 2
        ap.error(f"cannot read per-test rows from {path}: {err}")
    files: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for r in rows:
        f = files[r["id"].split("::")[0]]
        f["tests"] += 1
        f["wall"] += r["wall"]
        f["compile"] += r.get("backend_compile_duration", 0.0)
        f["trace"] += r.get("jaxpr_trace_duration", 0.0) + r.get("jaxpr_to_mlir_module_duration", 0.0)
    total = sum(files.values(), collections.Counter())
    print(f"{'file':<40} {'tests':>5} {'wall s':>8} {'compile s':>10} {'trace s':>8}")
    for name, f in sorted(files.items(), key=lambda kv: -kv[1]["wall"])[:args.top]:
        print(f"{name:<40} {f['tests']:5d} {f['wall']:8.1f} {f['compile']:10.1f} {f['trace']:8.1f}")
    print(f"{'all (worker seconds)':<40} {total['tests']:5d} {total['wall']:8.1f} {total['compile']:10.1f} "
          f"{total['trace']:8.1f}")
    workers: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0])
    t0 = min((r["start"] for r in rows if "start" in r), default=0.0)
    for r in rows:
        if "start" in r:  # busy seconds and when the worker's last test ended (load balance of xdist)
            w = workers[r["worker"]]
            w[0] += r["wall"]
            w[1] = max(w[1], r["start"] + r["wall"] - t0)
    for name, (busy, end) in sorted(workers.items()):
        print(f"worker {name}: busy {busy:.0f} s, last test ended at {end:.0f} s")
    misses = [(m[0], m[1], m[2], r["id"]) for r in rows for m in r.get("misses", [])]
    if misses:  # what the compile seconds are: programs the shared cache did not hold, by key
        seen: set[str] = set()
        again = 0.0
        for _, key, secs, _ in misses:
            again += secs if key in seen else 0.0
            seen.add(key)
        print(f"compiled (persistent-cache misses): {len(misses)} programs, {sum(m[2] for m in misses):.0f} s; "
              f"under a key compiled before: {again:.0f} s")
        for lo, hi in ((5.0, float("inf")), (0.5, 5.0), (0.0, 0.5)):
            band = [m[2] for m in misses if lo <= m[2] < hi]
            print(f"  programs of {lo:g}-{hi:g} s: {len(band)}, {sum(band):.0f} s")
        for name, _, secs, test in sorted(misses, key=lambda m: -m[2])[:args.top]:
            print(f"  {secs:6.1f} s  {name:<28} {test}")
    print(f"per-test rows: {path}")
    if args.write_order:
        seconds = {name: round(f["wall"], 1) for name, f in sorted(files.items(), key=lambda kv: -kv[1]["wall"])}
        tmp = args.write_order.with_suffix(".tmp")
        tmp.write_text(json.dumps(seconds, indent=0) + "\n")
        tmp.replace(args.write_order)
        print(f"file costs: {args.write_order}")


if __name__ == "__main__":
    main()
