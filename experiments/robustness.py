"""SLAM fault suite (issue 15 item 2): no crash, and tracking back within 3 frames of a fault's end.

Runs ``privslam_jax.slam`` on sequences with one injected fault each (:mod:`privslam_jax.data.faults`):
runs of black, white, blurred and exposure-jumped frames, a stalled camera (duplicated frames), a
gap (dropped frames) and frames delivered out of order (swapped pairs).  RANSAC seed ``s`` = 0–9
also sets the fault: ``length = 1 + s`` frames (capped so that the fault ends before the last
frame), blur σ = ``1 + s`` px, exposure gain 0.25 (even ``s``) or 3.0 (odd ``s``).  Every fault starts
at ``--start`` (default frame 20, where every mode tracks); on KITTI ``00`` (5 shared frames) at frame 2.

Sequences and modes: KITTI ``seq1`` (51 frames, monocular: the shared frames are the left camera
only) and ``00`` (5 frames, monocular) from ``../shared``; the synthetic street world 0
(``--synth-frames`` frames, 640×192, 8 m/s) in monocular, stereo and RGB-D.  Each (sequence, mode,
seed) also runs clean, for the ATE ratio.

Per run: crash (any exception), a finite pose for every frame, the frames marked lost, the
recovery delay (frames from the fault's last frame to the next tracked one; 1 = the next frame),
and the ATE (Sim(3) for monocular, SE(3) else) over the tracked frames outside the fault, against
the ground truth of each frame's source frame, relative to the clean run's.  A run counts for
"resumed ≤ 3" only if tracking was established before the fault (monocular needs its two-view
initialisation first); the others are listed.

Command:
    python experiments/robustness.py --jobs 2                    # everything (≈ 460 runs)
    python experiments/robustness.py --seeds 0,1 --kinds black   # a quick look
Finished runs go to ``--log`` (JSON lines, default ``runs/robustness.jsonl``) and are reused by
a rerun, so a killed suite resumes.  Writes ``results/robustness.md``.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import sys
import time
import traceback
from functools import lru_cache
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

RESUME_WITHIN = 3
"""Tracking must be back within this many frames of a fault's last frame."""


@lru_cache(maxsize=None)
def _sequence(name: str, mode: str, synth_frames: int):
    """``(frames, camera, ground truth T_w_c (N, 4, 4), n_images per frame item)``, cached per worker."""
    if name.startswith("KITTI"):
        from privslam_jax._shared import shared_dir
        from privslam_jax.data.kitti import KittiSequence
        from privslam_jax.slam.frontend import to_gray_u8

        seq = KittiSequence(shared_dir() / "data/kitti_odometry/sequences" / name.split()[1], grey=True)
        frames = [to_gray_u8(seq.image(i)) for i in range(len(seq))]
        return frames, seq.camera, np.asarray(seq.poses, np.float64)[: len(seq)], 1
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    seq = make_sequence(SynthConfig(num_frames=synth_frames, seed=0, stereo=True))
    fs = [seq[i] for i in range(synth_frames)]
    camera = seq.camera
    if mode == "mono":
        items, n_img = [f.image for f in fs], 1
    elif mode == "stereo":
        items, n_img = [(f.image, f.image_right) for f in fs], 2
    else:
        items, n_img, camera = [(f.image, f.depth) for f in fs], 1, camera.replace(baseline=None)
    return items, camera, np.asarray(seq.poses, np.float64), n_img


def _fault(kind: str | None, seed: int, start: int, n: int):
    from privslam_jax.data.faults import Fault

    if kind is None:
        return None
    room = n - 1 - start  # source frames the fault may take, so that one is left to recover on
    room = {"swap": room // 2, "drop": room - 1}.get(kind, room)  # drop: the frame after the gap is the fault's
    length = max(1, min(1 + seed, room))
    strength = {"blur": 1.0 + seed, "exposure": 0.25 if seed % 2 == 0 else 3.0}.get(kind, 0.0)
    return Fault(kind, start, length, strength)


def run_case(name: str, mode: str, kind: str | None, seed: int, start: int, synth_frames: int) -> dict:
    """One SLAM run with one fault (``kind=None``: clean); never raises: a crash is a result."""
    from privslam_jax.data.faults import inject_fault, recovery_delay
    from privslam_jax.metrics.trajectory import ate
    from privslam_jax.slam.system import SlamConfig, run_slam

    frames, camera, gt, n_img = _sequence(name, mode, synth_frames)
    fault = _fault(kind, seed, start, len(frames))
    row = {"sequence": name, "mode": mode, "kind": kind or "clean", "seed": seed,
           "length": fault.length if fault else 0, "strength": fault.strength if fault else 0.0}
    if fault is None:
        items, src, window = list(frames), np.arange(len(frames)), (len(frames), len(frames))
    else:
        items, src, window = inject_fault(frames, fault, n_img)
    t0 = time.perf_counter()
    try:
        res = run_slam(items, camera, SlamConfig(mode=mode, seed=seed))
    except Exception as err:  # the suite's point: record it, go on
        row.update(crash=f"{type(err).__name__}: {err}", traceback=traceback.format_exc(limit=4))
        return row
    T = np.asarray(res.trajectory.as_matrices(), np.float64)
    tracked = np.asarray(res.tracked, bool)
    outside = np.ones(len(items), bool)
    outside[window[0]: window[1]] = False
    use = tracked & outside
    ate_m = float("nan")
    if use.sum() >= 3:
        t = np.arange(len(items), dtype=np.float64)[use]
        ate_m = ate((t, T[use]), (t, gt[src[use]]), align="sim3" if mode == "mono" else "se3").rmse
    row.update(
        crash=None, frames=len(items), poses=len(T), finite=bool(np.isfinite(T).all()),
        lost=int((~tracked).sum()), established=bool(fault is None or tracked[window[0] - 1]),
        delay=None if fault is None else recovery_delay(tracked, window), ate=ate_m,
        events=res.events[:6], seconds=round(time.perf_counter() - t0, 2),
    )
    return row


def _cases(a) -> list[tuple]:
    from privslam_jax._shared import shared_dir
    from privslam_jax.data.faults import FAULT_KINDS

    seqs = [("synthetic world 0", m, a.start) for m in ("mono", "stereo", "rgbd")]
    if shared_dir() is not None and not a.skip_kitti:
        seqs = [("KITTI seq1", "mono", a.start), ("KITTI 00", "mono", 2)] + seqs
    elif not a.skip_kitti:
        print("no ../shared: KITTI seq1 and 00 skipped", file=sys.stderr)
    kinds = [None] + [k for k in FAULT_KINDS if a.kinds is None or k in a.kinds]
    return [(name, mode, kind, seed, start, a.synth_frames) for name, mode, start in seqs
            for seed in a.seeds for kind in kinds]


def _key(case: tuple) -> str:
    return f"{case[0]}|{case[1]}|{case[2] or 'clean'}|{case[3]}|{case[4]}|{case[5]}"


def _report(rows: list[dict], a, minutes: float) -> str:
    clean = {(r["sequence"], r["mode"], r["seed"]): r.get("ate", np.nan) for r in rows if r["kind"] == "clean"}
    faulty = [r for r in rows if r["kind"] != "clean"]

    def stats(rs: list[dict]) -> list[str]:
        crashes = sum(r["crash"] is not None for r in rs)
        ok = [r for r in rs if r["crash"] is None]
        bad_pose = sum(not (r["finite"] and r["poses"] == r["frames"]) for r in ok)
        est = [r for r in ok if r["established"]]
        resumed = [r for r in est if r["delay"] is not None and r["delay"] <= RESUME_WITHIN]
        delays = [r["delay"] for r in est if r["delay"] is not None]
        ratios = [r["ate"] / clean[(r["sequence"], r["mode"], r["seed"])] for r in ok
                  if np.isfinite(r["ate"]) and clean.get((r["sequence"], r["mode"], r["seed"]), 0) > 0]
        pct = f"{100 * len(resumed) / len(est):.0f} % ({len(resumed)}/{len(est)})" if est else "–"
        return [str(len(rs)), str(crashes), str(bad_pose), str(len(est)), pct,
                f"{np.median(delays):.0f}" if delays else "–", f"{max(delays)}" if delays else "–",
                f"{np.median(ratios):.2f}" if ratios else "–"]

    head = ("| {} | runs | crashes | runs without a finite pose per frame | tracking established before the fault "
            f"| resumed ≤ {RESUME_WITHIN} frames after | median delay | max delay | median ATE / clean ATE |")
    sep = "|---" * 9 + "|"
    lines = [
        "# SLAM fault suite",
        "",
        f"Command: `python experiments/robustness.py {' '.join(sys.argv[1:])}`".rstrip() + f" ({minutes:.0f} min, "
        f"{len(rows)} runs, seeds {a.seeds[0]}–{a.seeds[-1]}). One fault per run; seed s sets the RANSAC order, "
        "a fault length of 1 + s frames (capped to end before the last frame), blur σ = 1 + s px and exposure "
        "gain 0.25 (even s) / 3.0 (odd s). Delay: frames from the fault's last frame to the next tracked one "
        "(1 = the next frame). ATE (Sim(3) mono, SE(3) else) over tracked frames outside the fault, "
        "over the clean run's with the same seed. Method and definitions: the script's docstring.",
        "",
        "## By sequence and mode", "", head.format("sequence, mode"), sep,
    ]
    groups = sorted({(r["sequence"], r["mode"]) for r in faulty})
    lines += [f"| {s}, {m} | " + " | ".join(stats([r for r in faulty if (r["sequence"], r["mode"]) == (s, m)])) + " |"
              for s, m in groups]
    lines += [f"| **all** | " + " | ".join(stats(faulty)) + " |", "", "## By fault", "", head.format("fault"), sep]
    for kind in dict.fromkeys(r["kind"] for r in faulty):
        lines.append(f"| {kind} | " + " | ".join(stats([r for r in faulty if r["kind"] == kind])) + " |")
    crashed = [r for r in rows if r["crash"] is not None]
    late = [r for r in faulty if r["crash"] is None and r["established"]
            and (r["delay"] is None or r["delay"] > RESUME_WITHIN)]
    unestablished = [r for r in faulty if r["crash"] is None and not r["established"]]
    clean_lost = [r for r in rows if r["kind"] == "clean" and r["crash"] is None and r["lost"]]
    lines += ["", f"## Crashes ({len(crashed)})", ""]
    lines += [f"- {r['sequence']}, {r['mode']}, {r['kind']} seed {r['seed']}: `{r['crash']}`" for r in crashed] or ["none"]
    lines += ["", f"## Runs where tracking did not resume within {RESUME_WITHIN} frames ({len(late)})", ""]
    lines += [f"- {r['sequence']}, {r['mode']}, {r['kind']} × {r['length']}"
              + (f" (strength {r['strength']:g})" if r["strength"] else "") + f", seed {r['seed']}: "
              + ("never resumed" if r["delay"] is None else f"delay {r['delay']}") + f", {r['lost']} of "
              f"{r['frames']} frames lost; events: {'; '.join(r['events'][:3])}" for r in late] or ["none"]
    lines += ["", f"## Runs not yet tracking when the fault started ({len(unestablished)})", ""]
    lines += [f"- {r['sequence']}, {r['mode']}, {r['kind']} seed {r['seed']}: {r['lost']} of {r['frames']} "
              "frames lost" for r in unestablished] or ["none"]
    lines += ["", "Clean runs with lost frames (e.g. before the monocular initialisation): "
              + (", ".join(f"{r['sequence']} {r['mode']} seed {r['seed']}: {r['lost']}" for r in clean_lost) or "none"), ""]
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=lambda s: [int(x) for x in s.split(",")], default=list(range(10)))
    p.add_argument("--kinds", type=lambda s: s.split(","), default=None, help="fault kinds (default: all)")
    p.add_argument("--start", type=int, default=20, help="first faulty frame (KITTI 00: frame 2)")
    p.add_argument("--synth-frames", type=int, default=50)
    p.add_argument("--skip-kitti", action="store_true")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--log", type=Path, default=ROOT / "runs" / "robustness.jsonl")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "robustness.md")
    a = p.parse_args()
    from privslam_jax.data.faults import FAULT_KINDS
    from privslam_jax.data.files import write_atomic
    from privslam_jax.pool import process_pool

    if a.jobs < 1 or a.synth_frames < a.start + 3 or a.start < 1:
        raise SystemExit("need --jobs >= 1, --start >= 1 and --synth-frames >= --start + 3")
    if a.kinds and set(a.kinds) - set(FAULT_KINDS):
        raise SystemExit(f"--kinds: unknown {sorted(set(a.kinds) - set(FAULT_KINDS))}; choose from {FAULT_KINDS}")
    cases = _cases(a)
    done: dict[str, dict] = {}
    if a.log.is_file():
        for line in a.log.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:  # a line cut by a killed run
                continue
            done[row["key"]] = row
    todo = [c for c in cases if _key(c) not in done]
    print(f"{len(cases)} runs, {len(cases) - len(todo)} already in {a.log}", flush=True)
    a.log.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    with open(a.log, "a") as log, process_pool(a.jobs) as pool:
        futures = {pool.submit(run_case, *c): c for c in todo}
        for k, fut in enumerate(cf.as_completed(futures), 1):
            row = dict(fut.result(), key=_key(futures[fut]))
            done[row["key"]] = row
            log.write(json.dumps(row) + "\n")
            log.flush()
            status = row["crash"] or f"delay {row['delay']}, lost {row['lost']}"
            print(f"[{k}/{len(todo)} {time.time() - t0:.0f} s] {row['sequence']} {row['mode']} {row['kind']} "
                  f"seed {row['seed']}: {status}", flush=True)
    rows = [done[_key(c)] for c in cases]
    text = _report(rows, a, (time.time() - t0) / 60)
    write_atomic(a.out, text)
    print(text)


if __name__ == "__main__":
    main()
