"""``privslam run [SEQUENCE]``: the main job (see :mod:`privslam_jax.pipeline`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, positive_int, unit_interval

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from privslam_jax.inpaint.filter import FILTER_METHODS
    from privslam_jax.pipeline import PipelineConfig

    d = PipelineConfig()
    p = subparsers.add_parser(
        "run",
        help="the main job: sequence -> privacy filter -> SLAM -> line-cloud attack, with a report",
        description="Remove the privacy objects of a sequence (the embedded synthetic street sequence, or SEQUENCE), "
        "run SLAM on the original and the filtered frames, lift the map to a random line cloud and attack it; every "
        "stage writes its files under DIR, the summary is printed, and DIR/report.html, report.md and report.json "
        "are written; DIR/manifest.json says complete=true once all of it finished. "
        "See privslam_jax/pipeline.py.",
    )
    p.add_argument("sequence", nargs="?", default=None, metavar="SEQUENCE",
                   help="a KITTI-layout sequence folder (…/sequences/<id> with calib.txt; ground truth from "
                        "…/poses/<id>.txt when present). Default: render the embedded synthetic sequence")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    p.add_argument("--frames", type=positive_int, default=d.frames, help=f"number of synthetic frames (default {d.frames})")
    p.add_argument("--seed", type=nonnegative_int, default=d.seed, help=f"synthetic world seed (default {d.seed})")
    p.add_argument("--filter", default=d.filter_method, dest="filter_method", choices=FILTER_METHODS, metavar="METHOD",
                   help=f"privacy filter method (any of `privslam filter --method`; default {d.filter_method})")
    p.add_argument("--masks", choices=("detect", "gt"), default=d.masks,
                   help=f"filter masks from the detector or the renderer's ground truth (default {d.masks})")
    p.add_argument("--detector", default=None, metavar="PATH",
                   help="detector weights (default: the embedded detector made for the frames' domain)")
    p.add_argument("--conf", type=unit_interval, default=None, help="detection threshold (default 0.4)")
    p.add_argument("--tta", action="store_true", help="detector test-time augmentation (recall-first)")
    p.add_argument("--propagate", type=nonnegative_int, default=None, metavar="K",
                   help="carry detections to the K frames before and after by optical flow (recall-first; "
                        "default 3 on a real SEQUENCE, 0 on the synthetic one; 0 turns it off)")
    p.add_argument("--inpainter", default=None, metavar="PATH",
                   help="EdgeConnect checkpoint for --filter edgeconnect or tradeoff (default: the embedded inpainter)")
    p.add_argument("--mode", choices=("mono", "stereo"), default=d.mode, help=f"SLAM input (default {d.mode})")
    p.add_argument("--ignore-masked", action=argparse.BooleanOptionalAction, default=None,
                   help="SLAM on the filtered frames extracts no features where the filter filled in (default: on for "
                        "stereo, off for mono, the better choice of each in Table 4; docs/slam.md)")
    p.add_argument("--lift-seed", type=int, default=None, help="fixed lift seed (experiments only; default: OS entropy)")
    p.add_argument("--no-slam", action="store_true", help="stop after the privacy filter")
    p.add_argument("--edge", action="store_true",
                   help="run the filtered frames' SLAM through the edge split: a gRPC server on loopback and the "
                        "device client, as `privslam serve` and `privslam client` (docs/edge.md); the same poses")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--overwrite", action="store_true",
                   help="clear --out first if it holds an earlier privslam run (otherwise such a folder is refused)")
    p.set_defaults(func=run, owns_out=True)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.data.files import write_atomic
    from privslam_jax.pipeline import PipelineConfig, run_pipeline
    from privslam_jax.report import write_report

    config = PipelineConfig(
        sequence=None if args.sequence is None else str(args.sequence), frames=args.frames, seed=args.seed,
        filter_method=args.filter_method, masks=args.masks, detector=args.detector, conf=args.conf, tta=args.tta,
        propagate=args.propagate, inpainter=args.inpainter, mode=args.mode, lift_seed=args.lift_seed,
        slam=not args.no_slam, attack=not args.no_slam, edge=args.edge, ignore_masked=args.ignore_masked,
    )
    report = run_pipeline(config, args.out, progress=not args.quiet)
    print(report.summary)
    md, page = write_report(args.out, report)
    print(f"read first: {page} (self-contained) or {md}")
    path = Path(args.out) / "report.json"
    write_atomic(path, json.dumps(report.to_json_dict(), indent=2) + "\n")
    print(f"report: {path}")
    return 0
