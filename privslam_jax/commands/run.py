"""``privslam run``: the main job on the embedded default (see :mod:`privslam_jax.pipeline`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from privslam_jax.pipeline import PipelineConfig

    d = PipelineConfig()
    p = subparsers.add_parser(
        "run",
        help="the main job: synthetic sequence -> privacy filter -> SLAM -> line-cloud attack, with a report",
        description="Render the embedded synthetic street sequence, remove its privacy objects, run SLAM on the "
        "original and the filtered frames, lift the map to a random line cloud and attack it; every stage "
        "writes its files under DIR and the summary is printed (also DIR/report.json). See privslam_jax/pipeline.py.",
    )
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    p.add_argument("--frames", type=int, default=d.frames, help=f"number of frames (default {d.frames})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"world seed (default {d.seed})")
    p.add_argument("--filter", default=d.filter_method, dest="filter_method",
                   help=f"privacy filter method (any of `privslam filter --method`; default {d.filter_method})")
    p.add_argument("--masks", choices=("detect", "gt"), default=d.masks,
                   help=f"filter masks from the detector or the renderer's ground truth (default {d.masks})")
    p.add_argument("--detector", default=None, metavar="PATH", help="detector weights (default: the embedded detector)")
    p.add_argument("--inpainter", default=None, metavar="PATH",
                   help="EdgeConnect checkpoint for --filter edgeconnect (default: the embedded inpainter)")
    p.add_argument("--lift-seed", type=int, default=None, help="fixed lift seed (experiments only; default: OS entropy)")
    p.add_argument("--no-slam", action="store_true", help="stop after the privacy filter")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.pipeline import PipelineConfig, run_pipeline

    config = PipelineConfig(
        frames=args.frames, seed=args.seed, filter_method=args.filter_method, masks=args.masks,
        detector=args.detector, inpainter=args.inpainter, lift_seed=args.lift_seed,
        slam=not args.no_slam, attack=not args.no_slam,
    )
    report = run_pipeline(config, args.out, progress=not args.quiet)
    print(report["summary"])
    print(f"report: {Path(args.out) / 'report.json'}")
    (Path(args.out) / "report.json").write_text(json.dumps({k: v for k, v in report.items() if k != "summary"}, indent=2) + "\n")
    return 0
