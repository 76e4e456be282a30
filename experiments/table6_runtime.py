"""Table 6: what the privacy filter costs per frame, stage by stage, next to plain SLAM.

Goal (issue 14 item 5, the source paper's Table 6): per-stage milliseconds per frame — detect
(the embedded detector made for the frames, privacy preset), fill (each filter method on those
detections), SLAM tracking and SLAM mapping — and the total of the privacy-preserving pipeline
(detect + fill + SLAM on the filtered frames) against plain SLAM on the original frames, on KITTI
``seq1`` (51 grey frames, 1226×370, from ``../shared``; skipped without it) and on a synthetic
sequence (640×192, ``--synth-frames`` frames, world 0).

Method: every stage is timed per frame with ``time.perf_counter`` after a warm-up that compiles
it (the detector and EdgeConnect on the first frame, SLAM on a 12-frame run), so the numbers are
steady-state CPU costs; they are means over the frames (SLAM mapping runs at keyframes only, so
its mean spreads it over all frames) and medians where noted. Monocular SLAM with RANSAC seed 0.

Command::

    python experiments/table6_runtime.py              # both sequences, ~6 min on 2 cores
    python experiments/table6_runtime.py --skip-kitti  # synthetic only

Writes ``results/table6_runtime.md``. The machine's load changes the numbers; the ratios between
rows of one run are what to compare.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FILTERS = ("edgeconnect", "telea", "gray")


def _slam(frames: list[np.ndarray], camera, timestamps: np.ndarray) -> dict[str, float]:
    from privslam_jax.slam.system import SlamConfig, run_slam

    run_slam(frames[:12], camera, SlamConfig(mode="mono"), timestamps=timestamps[:12])  # compile
    t0 = time.perf_counter()
    r = run_slam(frames, camera, SlamConfig(mode="mono"), timestamps=timestamps)
    wall = time.perf_counter() - t0
    n = len(frames)
    mapping = np.nan_to_num(r.timings["mapping"]) if "mapping" in r.timings else np.zeros(n)
    return {"track": 1e3 * float(np.mean(r.timings["total"] - mapping)), "mapping": 1e3 * float(mapping.sum() / n),
            "wall": 1e3 * wall / n, "tracked": int(r.tracked.sum()), "frames": n}


def measure(name: str, frames: list[np.ndarray], camera, timestamps: np.ndarray, domain: str) -> list[list[str]]:
    from privslam_jax.detect import Detector
    from privslam_jax.inpaint.filter import Inpainter, filter_frame
    from privslam_jax.inpaint.masks import boxes_to_masks

    h, w = frames[0].shape[:2]
    detector = Detector.embedded(domain=domain)
    detector.detect([frames[0]])  # compile
    detections, det_ms = [], []
    for f in frames:
        t = time.perf_counter()
        detections.append(detector.detect([f])[0])
        det_ms.append(1e3 * (time.perf_counter() - t))
    masks = [boxes_to_masks(np.asarray(d.boxes, np.float64).reshape(-1, 4), h, w, 4) for d in detections]
    n_obj = sum(len(m) for m in masks)
    inpainter = Inpainter.embedded()
    plain = _slam(frames, camera, timestamps)
    rows = [[name, "plain SLAM (original frames)", "–", "–", f"{plain['track']:.0f}", f"{plain['mapping']:.0f}",
             f"{plain['wall']:.0f}", "1.00×", f"{plain['tracked']}/{plain['frames']}"]]
    warm = np.zeros((1, h, w), bool)
    warm[0, h // 3: h // 2, w // 3: w // 2] = True
    for method in FILTERS:
        filter_frame(frames[0], warm, method, inpainter=inpainter)  # compile (crops have one size)
        filtered, fill_ms = [], []
        for f, m in zip(frames, masks, strict=True):
            t = time.perf_counter()
            filtered.append(filter_frame(f, m, method, inpainter=inpainter))
            fill_ms.append(1e3 * (time.perf_counter() - t))
        s = _slam(filtered, camera, timestamps)
        total = float(np.mean(det_ms)) + float(np.mean(fill_ms)) + s["wall"]
        rows.append([name, f"detect + {method} + SLAM", f"{np.mean(det_ms):.0f} ({np.median(det_ms):.0f})",
                     f"{np.mean(fill_ms):.0f} ({np.median(fill_ms):.0f})", f"{s['track']:.0f}", f"{s['mapping']:.0f}",
                     f"{total:.0f}", f"{total / plain['wall']:.2f}×", f"{s['tracked']}/{s['frames']}"])
        print(" | ".join(rows[-1]), flush=True)
    rows[0][0] = f"{name} ({len(frames)} frames, {w}×{h}, {n_obj} masks)"
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--skip-kitti", action="store_true")
    p.add_argument("--synth-frames", type=int, default=80)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "table6_runtime.md")
    a = p.parse_args(argv)

    from privslam_jax._shared import shared_dir
    from privslam_jax.data.files import write_atomic
    from privslam_jax.report import markdown_table
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    rows: list[list[str]] = []
    shared = shared_dir()
    if not a.skip_kitti and shared is not None:
        seq = KittiSequence(shared / "data" / "kitti_odometry" / "sequences" / "seq1")
        frames = [seq.image(i) for i in range(len(seq))]
        rows += measure("KITTI seq1", frames, seq.camera, seq.timestamps, "real")
    elif not a.skip_kitti:
        print("no ../shared: KITTI seq1 skipped", file=sys.stderr)
    syn = make_sequence(SynthConfig(width=640, height=192, num_frames=a.synth_frames, seed=0))
    rendered = [syn[i] for i in range(len(syn))]
    rows += measure("synthetic world 0", [np.asarray(f.image) for f in rendered], syn.camera,
                    np.asarray([f.timestamp for f in rendered], np.float64), "synthetic")

    header = ["sequence", "pipeline", "detect ms/frame (median)", "fill ms/frame (median)", "SLAM tracking ms/frame",
              "SLAM mapping ms/frame", "total ms/frame", "total / plain SLAM", "tracked"]
    text = ["# Table 6 — runtime per frame, stage by stage", "",
            f"Written by `python experiments/table6_runtime.py` on {time.strftime('%Y-%m-%d')} (2-core CPU; see its header). "
            "Means over the frames after a warm-up that compiles each stage, medians in brackets; SLAM is monocular, "
            "its mapping runs at keyframes and is spread over all frames here. Total = detect + fill + the SLAM run's "
            "wall time per frame on the filtered frames; plain SLAM = the wall time per frame on the original frames.", "",
            *markdown_table(header, rows)]
    write_atomic(a.out, "\n".join(text) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
