"""``privslam slam SEQUENCE [--mode mono|stereo|rgbd] --out DIR``: run SLAM on a KITTI-layout sequence.

SEQUENCE is a ``…/sequences/<id>`` folder (KITTI odometry, or what ``privslam synth`` writes);
ground truth is read from ``…/poses/<id>.txt`` when present. DIR receives ``trajectory.txt``
(TUM, every frame), ``frames.txt`` (tracked flag and Atlas map per frame), ``keyframes.txt``,
``map.ply``, ``metrics.json`` and two plots, described in :mod:`privslam_jax.slam.outputs`.

Tracking loss is reported (metrics.json, stderr), never a crash.

``--ignore-masked`` extracts no ORB feature where the sequence's ``masks/`` map is nonzero: on the
output of ``privslam filter`` these are the regions it filled in, whose texture is made up.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, positive_int, positive_or_inf
from privslam_jax.slam.outputs import (
    load_sequence_frames,
    masked_regions,
    write_outputs,
)

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "slam",
        help="run ORB-SLAM-style SLAM (mono / stereo / RGB-D) on a KITTI-layout sequence",
        description="Run SLAM on a KITTI-layout sequence folder (…/sequences/<id>); writes trajectory.txt (TUM, "
                    "every frame), frames.txt, keyframes.txt, map.ply, metrics.json and two plots into --out.",
    )
    p.add_argument("sequence", help="KITTI-layout sequence folder …/sequences/<id>")
    p.add_argument("--mode", choices=("mono", "stereo", "rgbd"), default="mono", help="input mode (default mono)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="RANSAC shuffling seed (default 0)")
    p.add_argument("--max-frames", type=positive_int, default=None, help="process only the first N frames")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--ignore-masked", action="store_true",
                   help="extract no features where the sequence's masks/ is nonzero (on a `privslam filter` "
                        "output: the filled-in objects)")
    p.add_argument("--loop-closing", action="store_true",
                   help="detect and close loops (ORB vocabulary place recognition, Sim(3)/SE(3) check, essential graph, "
                        "global BA); closed loops are listed in metrics.json")
    p.add_argument("--vocabulary", type=_vocabulary_file, default=None,
                   help="ORB vocabulary .npz (implies --loop-closing; default: the embedded one, train/vocabulary.py)")
    p.add_argument("--new-map-after", type=nonnegative_int, default=50, metavar="N",
                   help="Atlas: start a new map after N consecutive lost frames and merge it into an earlier map "
                        "where place recognition finds they overlap (default 50; 0: stay in one map)")
    p.add_argument("--stereo-max-depth-baselines", type=positive_or_inf, default=None, metavar="B",
                   help="stereo: keypoints B baselines away or farther are used as monocular ones (default inf: "
                        "every stereo depth, as ORB-SLAM; docs/slam.md, 'Far stereo points')")
    p.add_argument("--stereo-zero-mean-sad", action=argparse.BooleanOptionalAction, default=True,
                   help="stereo: refine stereo matches by SAD of zero-mean patches (default), or with --no-... by "
                        "ORB-SLAM's patches minus their centre pixel (docs/slam.md, 'Stereo disparities of coarse "
                        "keypoints')")
    p.add_argument("--overwrite", action="store_true",
                   help="clear --out first if it holds an earlier privslam run (otherwise such a folder is refused)")
    p.set_defaults(func=run, owns_out=True)


def _vocabulary_file(text: str) -> Path:
    """argparse type: a readable vocabulary ``.npz`` (checked before the output folder is claimed)."""
    from privslam_jax.errors import InputError
    from privslam_jax.slam.vocabulary import load_vocabulary

    try:
        load_vocabulary(text)
    except (FileNotFoundError, InputError) as err:
        raise argparse.ArgumentTypeError(" ".join(str(err).split())) from err
    return Path(text)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.slam.system import SlamConfig, run_slam

    seq, frames, n = load_sequence_frames(args.sequence, args.mode, args.max_frames)
    ignore = masked_regions(seq, n) if args.ignore_masked else None
    cfg = SlamConfig(mode=args.mode, seed=args.seed, loop_closing=args.loop_closing or args.vocabulary is not None,
                     vocabulary=None if args.vocabulary is None else str(args.vocabulary),
                     new_map_after=args.new_map_after, stereo_zero_mean_sad=args.stereo_zero_mean_sad,
                     **({} if args.stereo_max_depth_baselines is None
                        else {"stereo_max_depth_baselines": args.stereo_max_depth_baselines}))
    t0 = time.perf_counter()
    result = run_slam(frames, seq.camera, cfg, timestamps=seq.timestamps[:n], progress=True, total=n, ignore=ignore)
    wall = time.perf_counter() - t0
    out = Path(args.out)
    metrics = write_outputs(out, result, seq.timestamps[:n], seq.poses, args.mode, wall, plots=not args.no_plots)
    if "alignment_error" in metrics:
        print(f"privslam slam: no ATE/RPE: {metrics['alignment_error']}", file=sys.stderr)
    lost = metrics["lost_frames"]
    if lost:
        print(f"privslam slam: tracking lost on {len(lost)} of {n} frames: {lost} "
              "(motion-model poses written for them)", file=sys.stderr)
    if metrics["maps"] > 1:
        print(f"privslam slam: the run ends with {metrics['maps']} Atlas maps that were never merged; their poses "
              f"are in different world frames (frames.txt); ATE/RPE use map {metrics.get('metrics_map', 0)} only",
              file=sys.stderr)
    summary = {k: metrics[k] for k in ("frames", "tracked", "keyframes", "map_points", "maps", "fps", "tracking_fps")}
    for k in ("ate_rmse_se3", "ate_rmse_sim3", "rpe_trans", "rpe_rot"):
        if k in metrics:
            summary[k] = round(metrics[k], 4)
    print(json.dumps(summary))
    print(f"wrote {out}/trajectory.txt, frames.txt, keyframes.txt, map.ply, metrics.json"
          + ("" if args.no_plots else ", trajectory_xz.png, ate_over_time.png"))
    return 0
