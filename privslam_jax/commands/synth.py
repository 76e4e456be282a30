"""``privslam synth``: render a synthetic street sequence and write it in the KITTI odometry layout.

The layout is described in :mod:`privslam_jax.data.kitti_write` (and docs/formats.md).  The
sequence folder carries ``manifest.json``, ``"complete": true`` once everything is written; a
folder holding an earlier run is refused unless ``--overwrite``, which clears it first.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from privslam_jax.argtypes import nonnegative_int
from privslam_jax.data.kitti_write import summarize_sequence, write_kitti_sequence

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "synth",
        help="render a synthetic street sequence and write it as a KITTI odometry folder",
        description="Render the synthetic street world (RGB, depth, instance masks, object-free background, "
        "YOLO labels, ground-truth poses) and write DIR/sequences/NAME + DIR/poses/NAME.txt.",
    )
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output root (KITTI layout)")
    p.add_argument("--frames", type=int, default=100, help="number of frames (default 100)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="world seed (default 0)")
    p.add_argument("--width", type=int, default=640, help="image width in px (default 640)")
    p.add_argument("--height", type=int, default=192, help="image height in px (default 192)")
    p.add_argument("--stereo", action="store_true", help="also render and write the right camera (image_3)")
    p.add_argument("--route", choices=("staircase", "loop"), default="staircase",
                   help="camera route: 'staircase' (default; turns, never the same street twice) or 'loop' "
                   "(laps around a 3x2-block rectangle, 463 m a lap: the start is passed again near frame 580-600)")
    p.add_argument("--name", default="synth", help="sequence name (default 'synth')")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier run in DIR/sequences/NAME (cleared first, with DIR/poses/NAME.txt)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    if args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    if args.width < 16 or args.height < 16:
        raise ValueError(f"--width/--height must be at least 16 px, got {args.width}x{args.height}")
    if not args.name or "/" in args.name or args.name in (".", ".."):
        raise ValueError(f"--name must be a plain folder name, got {args.name!r}")
    seq = make_sequence(
        SynthConfig(width=args.width, height=args.height, num_frames=args.frames, seed=args.seed, stereo=args.stereo,
                    route=args.route)
    )
    records: list[Any] = []
    seq_dir = write_kitti_sequence(seq, args.out, args.name, progress=not args.quiet, collect=records,
                                   overwrite=args.overwrite)
    print(summarize_sequence(seq, frames=records, title=f"wrote {seq_dir}"))
    return 0
