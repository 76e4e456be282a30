"""``privslam localize LINES.ply SEQUENCE --out DIR``: localise a sequence's frames against a line cloud.

LINES.ply is a line cloud that carries its lines' descriptors: ``privslam lift`` of a map that has
them (``privslam slam``'s ``map.ply`` carries the ORB descriptor of every map point).  SEQUENCE is a
KITTI-layout folder (its ``calib.txt`` gives the camera).  Each query frame's ORB features are matched to
the lines' descriptors and the pose is found by generalized relative pose + LO-RANSAC and refined on
the least-squares core (:mod:`privslam_jax.privacy.localize`).  Poses are in the map's world frame.

DIR receives ``poses.txt`` (TUM, camera → world, the localised frames only) and ``queries.txt``
(``timestamp frame matches inliers localised`` per query frame), both written atomically.  A frame
that does not localise is listed as such, never given a made-up pose.  ``--depth`` takes each keypoint's
depth from the sequence's ``depth/`` maps (as ``privslam slam --mode rgbd`` reads them; e.g. a
time-of-flight sensor) and solves with it: sphere clouds, whose lines all meet at one point so that the
camera's distance is not observable from keypoints alone, need it and are refused without it.
``--heading-prior POSES`` (camera → world, one pose per frame of the sequence, KITTI or TUM: e.g. a GNSS
or odometry trajectory, good to ±90° in heading) discards candidate poses more than 90° from frame i's
pose: axial clouds (``privslam lift --method axial``) need it and are refused without it, since the
half-turn about their axis maps them onto themselves and every pose has a twin turned 180° that explains
the keypoints as well.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, positive_float, positive_int

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("localize", help="localise a sequence's frames against a line cloud (PLY with descriptors)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("lines", type=Path, help="line cloud PLY with a descriptor element (privslam lift of a SLAM map.ply)")
    p.add_argument("sequence", help="KITTI-layout sequence folder …/sequences/<id> (query frames and calib.txt)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--every", type=positive_int, default=1, help="localise every N-th frame (default 1)")
    p.add_argument("--max-frames", type=positive_int, default=None, help="consider only the first N frames")
    p.add_argument("--threshold", type=positive_float, default=2.0, help="inlier distance in pixels (default 2)")
    p.add_argument("--min-inliers", type=positive_int, default=12, help="inliers needed to accept a pose (default 12)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="RANSAC seed (default 0)")
    p.add_argument("--depth", action="store_true",
                   help="use the sequence's depth/ maps as the keypoints' depth (needed for sphere clouds)")
    p.add_argument("--heading-prior", type=Path, default=None, metavar="POSES",
                   help="rough camera-to-world poses, one per frame (KITTI or TUM): candidates more than 90 degrees "
                        "from frame i's are discarded (what axial clouds need)")
    p.add_argument("--overwrite", action="store_true",
                   help="clear --out first if it holds an earlier privslam run (otherwise such a folder is refused)")
    p.set_defaults(func=run, owns_out=True)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from privslam_jax.data.files import write_atomic
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.ply import load_line_cloud_and_descriptors
    from privslam_jax.data.trajectory_io import read_pose_matrices, write_tum_matrices
    from privslam_jax.privacy.localize import localize_image

    lines, desc = load_line_cloud_and_descriptors(args.lines)
    if desc is None:
        raise ValueError(f"{args.lines} carries no descriptors, so no image can be matched to its lines: lift a map "
                         "that has them (privslam slam writes map.ply with ORB descriptors; privslam lift keeps them)")
    seq = KittiSequence(args.sequence, grey=True)
    if args.depth and not seq.has_extra("depth"):
        raise FileNotFoundError(f"--depth needs a depth/ folder in {seq.path} (z-depth PNGs as privslam synth writes them)")
    n = len(seq) if args.max_frames is None else min(len(seq), args.max_frames)
    frames = list(range(0, n, args.every))
    if not frames:
        raise ValueError(f"{args.sequence}: no frames to localise")
    priors = None
    if args.heading_prior is not None:
        priors = read_pose_matrices(args.heading_prior)
        if len(priors) < n:
            raise ValueError(f"{args.heading_prior}: {len(priors)} poses for {n} frames; --heading-prior needs one pose per "
                             "frame of the sequence")
    K = np.asarray(seq.camera.K, np.float64)
    rows, poses, stamps, times = [], [], [], []
    for i in frames:
        t0 = time.perf_counter()
        loc, uv, _ = localize_image(seq.image(i), lines, desc, K, depth=seq[i].depth if args.depth else None,
                                    threshold=args.threshold, min_inliers=args.min_inliers, seed=args.seed,
                                    rotation_prior=None if priors is None else priors[i, :3, :3].T)
        times.append(time.perf_counter() - t0)
        ts = float(seq.timestamps[i])
        rows.append(f"{ts!r} {i} {len(uv)} {int(loc.inliers.sum())} {int(loc.success)}\n")
        if loc.success:
            poses.append(np.linalg.inv(loc.T_c_w))
            stamps.append(ts)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_tum_matrices(out / "poses.txt", np.asarray(stamps, np.float64), np.asarray(poses, np.float64).reshape(-1, 4, 4))
    write_atomic(out / "queries.txt", "# timestamp frame matches inliers localised\n" + "".join(rows))
    print(json.dumps({"queries": len(frames), "localised": len(poses), "lines": len(lines),
                      "median_s_per_query": round(float(np.median(times)), 3)}))
    return 0
