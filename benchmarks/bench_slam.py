"""Per-stage SLAM timings on KITTI seq1 (1226×370, monocular), after compilation.

Command:  python benchmarks/bench_slam.py [--frames 51]

Runs the sequence twice in one process: the first run compiles the jitted JAX solvers (pose
refinement, local BA; reported as the first run's extra time), the second is timed.  Prints the
median and mean per frame of each stage, the tracking rate (extraction + tracking, the work of
ORB-SLAM's tracking thread; local mapping separately) and, as a reference measured in the same
process, plain OpenCV ORB ``detectAndCompute`` with 2,000 features on the same frames.
Numbers on a shared machine are noisy: say so when quoting them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import cv2  # noqa: E402
import numpy as np  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=51)
    a = p.parse_args()
    from privslam_jax._shared import shared_dir
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.slam.frontend import to_gray_u8
    from privslam_jax.slam.system import SlamConfig, run_slam

    shared = shared_dir()
    if shared is None:
        raise SystemExit("needs ../shared (KITTI seq1)")
    seq = KittiSequence(shared / "data/kitti_odometry/sequences/seq1", grey=True)
    n = min(a.frames, len(seq))
    images = [to_gray_u8(seq.image(i)) for i in range(n)]
    t0 = time.perf_counter()
    run_slam(images, seq.camera, SlamConfig())
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = run_slam(images, seq.camera, SlamConfig())
    second = time.perf_counter() - t0
    orb = cv2.ORB_create(nfeatures=2000, scaleFactor=1.2, nlevels=8)
    ref = []
    for img in images:
        t = time.perf_counter()
        orb.detectAndCompute(img, None)
        ref.append(time.perf_counter() - t)
    tm = res.timings
    tracking = tm["total"] - np.nan_to_num(tm.get("mapping", np.zeros(n)))
    rows = [(k, v) for k, v in tm.items()] + [("tracking (total − mapping)", tracking),
                                              ("reference: cv2 ORB detectAndCompute 2000", np.array(ref))]
    print(f"KITTI seq1, {n} frames, {res.tracked.sum()} tracked, {len(res.keyframe_indices)} keyframes")
    print(f"{'stage':45s} {'runs':>5s} {'median ms':>10s} {'mean ms':>10s}")
    for k, v in rows:
        v = np.asarray(v)
        ok = np.isfinite(v)
        print(f"{k:45s} {ok.sum():5d} {np.median(v[ok]) * 1e3:10.1f} {np.mean(v[ok]) * 1e3:10.1f}")
    print(f"tracking rate (median): {1.0 / np.median(tracking):.1f} frames/s; "
          f"whole run incl. mapping: {n / second:.2f} frames/s")
    print(f"first run (with compilation): {first:.1f} s, second run: {second:.1f} s, "
          f"compile overhead ≈ {first - second:.1f} s")


if __name__ == "__main__":
    main()
