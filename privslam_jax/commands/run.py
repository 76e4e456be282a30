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
        help="the main job: render the embedded synthetic street sequence and summarise it",
        description="Render the embedded synthetic street sequence (stereo, KITTI layout) under DIR and print "
        "its summary (also in DIR/report.json). Later pipeline stages join as they are wired in "
        "(see privslam_jax/pipeline.py).",
    )
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    p.add_argument("--frames", type=int, default=d.frames, help=f"number of frames (default {d.frames})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"world seed (default {d.seed})")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.pipeline import PipelineConfig, run_pipeline

    report = run_pipeline(PipelineConfig(frames=args.frames, seed=args.seed), args.out, progress=not args.quiet)
    print(report["summary"])
    print(f"report: {Path(args.out) / 'report.json'}")
    (Path(args.out) / "report.json").write_text(json.dumps({k: v for k, v in report.items() if k != "summary"}, indent=2) + "\n")
    return 0
