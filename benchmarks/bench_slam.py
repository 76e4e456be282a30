"""Per-stage SLAM timings at 1226×370 after compilation: monocular on KITTI seq1, or stereo.

Command:  python benchmarks/bench_slam.py [--frames 51] [--stereo [--no-stereo-zero-mean-sad]] [--mapper-busy-frames N] [--loop-closing] [--repeats 1]

``--stereo`` runs stereo SLAM on a synthetic stereo street at KITTI's size (1226×370, seed 0;
``seq1`` in ``../shared`` has no right images), so that the stereo matching stage is timed too.

Runs the sequence ``1 + repeats`` times in one process: the first run compiles the jitted JAX solvers
(pose refinement, local BA; reported as its extra time over the timed runs' median), the others are
timed.  Prints the whole-run rate of every timed run and their median (the machine's noise shows in
their spread), checks that they gave bit-identical poses and maps (SLAM is deterministic for a seed;
the script exits 1 if not), and for the median run the median and mean per frame of each stage, the tracking rate (extraction + tracking, the work of
ORB-SLAM's tracking thread; local mapping separately) and, as a reference measured in the same
process, plain OpenCV ORB ``detectAndCompute`` with 2,000 features on the same frames.
Numbers on a shared machine are noisy: say so when quoting them.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import cv2  # noqa: E402
import numpy as np  # noqa: E402


def main() -> None:
    from privslam_jax.argtypes import nonnegative_int, positive_int

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=51)
    p.add_argument("--stereo", action="store_true", help="stereo SLAM on a synthetic 1226x370 stereo street")
    p.add_argument("--stereo-zero-mean-sad", action=argparse.BooleanOptionalAction, default=None,
                   help="with --stereo: SlamConfig.stereo_zero_mean_sad (default: SlamConfig's, on; --no-...: ORB-SLAM's "
                        "centre-pixel SAD)")
    p.add_argument("--mapper-busy-frames", type=nonnegative_int, default=None,
                   help="SlamConfig.mapper_busy_frames (default: SlamConfig's)")
    p.add_argument("--loop-closing", action="store_true",
                   help="SlamConfig.loop_closing=True: place recognition over every keyframe (the whole system)")
    p.add_argument("--repeats", type=positive_int, default=1,
                   help="timed runs after the compiling one (default 1); their median rate is the headline")
    a = p.parse_args()
    if a.stereo_zero_mean_sad is not None and not a.stereo:
        p.error("--[no-]stereo-zero-mean-sad needs --stereo")
    from privslam_jax.slam.frontend import to_gray_u8
    from privslam_jax.slam.system import SlamConfig, run_slam

    if a.stereo:
        from privslam_jax.data.synthetic import SynthConfig, make_sequence

        world = make_sequence(SynthConfig(width=1226, height=370, num_frames=a.frames, stereo=True, seed=0))
        n, camera, name, config = a.frames, world.camera, "synthetic stereo street", SlamConfig(mode="stereo")
        images = [(to_gray_u8(f.image), to_gray_u8(f.image_right)) for f in world]
    else:
        from privslam_jax._shared import shared_dir
        from privslam_jax.data.kitti import KittiSequence

        shared = shared_dir()
        if shared is None:
            raise SystemExit("needs ../shared (KITTI seq1)")
        seq = KittiSequence(shared / "data/kitti_odometry/sequences/seq1", grey=True)
        n, camera, name, config = min(a.frames, len(seq)), seq.camera, "KITTI seq1", SlamConfig()
        images = [to_gray_u8(seq.image(i)) for i in range(n)]
    if a.stereo_zero_mean_sad is not None:
        config = dataclasses.replace(config, stereo_zero_mean_sad=a.stereo_zero_mean_sad)
    if a.mapper_busy_frames is not None:
        config = dataclasses.replace(config, mapper_busy_frames=a.mapper_busy_frames)
    if a.loop_closing:
        config = dataclasses.replace(config, loop_closing=True)
    t0 = time.perf_counter()
    run_slam(images, camera, config)
    first = time.perf_counter() - t0
    runs = []
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        res = run_slam(images, camera, config)
        runs.append((time.perf_counter() - t0, res))
    second, res = sorted(runs, key=lambda r: r[0])[(len(runs) - 1) // 2]  # the median run (lower middle)
    poses = [np.asarray(r.trajectory.poses.wxyz_xyz) for _, r in runs]
    points = [np.asarray(r.map.xyz) for _, r in runs]
    identical = all(np.array_equal(x, poses[0]) for x in poses) and all(np.array_equal(x, points[0]) for x in points)
    orb = cv2.ORB_create(nfeatures=2000, scaleFactor=1.2, nlevels=8)
    ref = []
    for img in images:
        img = img[0] if a.stereo else img
        t = time.perf_counter()
        orb.detectAndCompute(img, None)
        ref.append(time.perf_counter() - t)
    tm = res.timings
    tracking = tm["total"] - np.nan_to_num(tm.get("mapping", np.zeros(n)))
    rows = [(k, v) for k, v in tm.items()] + [("tracking (total − mapping)", tracking),
                                              ("reference: cv2 ORB detectAndCompute 2000", np.array(ref))]
    print(f"{name} ({config.mode}, mapper_busy_frames={config.mapper_busy_frames}, loop_closing={config.loop_closing}), "
          f"{n} frames, {res.tracked.sum()} tracked, {len(res.keyframe_indices)} keyframes, {len(res.loops)} loops closed")
    print(f"{'stage':45s} {'runs':>5s} {'median ms':>10s} {'mean ms':>10s}")
    for k, v in rows:
        v = np.asarray(v)
        ok = np.isfinite(v)
        print(f"{k:45s} {ok.sum():5d} {np.median(v[ok]) * 1e3:10.1f} {np.mean(v[ok]) * 1e3:10.1f}")
    print(f"tracking rate (median): {1.0 / np.median(tracking):.1f} frames/s; "
          f"whole run incl. mapping: {n / second:.2f} frames/s")
    if len(runs) > 1:
        print(f"whole run incl. mapping, each of {len(runs)} timed runs: "
              + " / ".join(f"{n / s:.2f}" for s, _ in runs) + f" frames/s; median {n / second:.2f}; "
              + ("poses and map bit-identical in every run" if identical else "RUNS DIFFER"))
    print(f"first run (with compilation): {first:.1f} s, timed run (median): {second:.1f} s, "
          f"compile overhead ≈ {first - second:.1f} s")
    if not identical:
        raise SystemExit("the timed runs gave different poses or maps: SLAM should be deterministic for a seed")


if __name__ == "__main__":
    main()
