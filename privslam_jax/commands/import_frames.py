"""``privslam import SOURCE --out DIR (--camera FX,FY,CX,CY | --hfov DEG)``: your own frames as a KITTI sequence.

SOURCE is a folder of images (natural order) or a video file; the frames are written to
``DIR/sequences/NAME`` with ``calib.txt`` and ``times.txt`` (``privslam_jax.data.import_frames``),
ready for ``privslam run DIR/sequences/NAME --out RUN``, ``filter`` and ``slam``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from privslam_jax.argtypes import intrinsics, positive_float, positive_int

__all__ = ["add_parser", "run"]


def _hfov(text: str) -> float:
    value = positive_float(text)
    if not value < 180:
        raise argparse.ArgumentTypeError(f"must be a field of view in (0, 180) degrees, got {text!r}")
    return value


def _name(text: str) -> str:
    if not text or "/" in text or "\\" in text or text in (".", ".."):
        raise argparse.ArgumentTypeError(f"must be a plain folder name, got {text!r}")
    return text


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("import", help="write a folder of images or a video as a KITTI-layout sequence",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", type=Path, help="a folder of images (png, jpg, …) or a video file (mp4, avi, …)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output root (DIR/sequences/NAME is written)")
    p.add_argument("--name", type=_name, default="imported", help="sequence name (default 'imported')")
    cam = p.add_mutually_exclusive_group(required=True)
    cam.add_argument("--camera", type=intrinsics, metavar="FX,FY,CX,CY", help="pinhole intrinsics in pixels (calibration)")
    cam.add_argument("--hfov", type=_hfov, metavar="DEG",
                     help="horizontal field of view in degrees, when no calibration is at hand (approximate intrinsics)")
    p.add_argument("--fps", type=positive_float, default=None, help="capture rate (default: the video's, else 10)")
    p.add_argument("--every", type=positive_int, default=1, help="keep every K-th frame (default 1)")
    p.add_argument("--max-frames", type=positive_int, default=None, help="stop after N frames")
    colour = p.add_mutually_exclusive_group()
    colour.add_argument("--grey", dest="grey", action="store_true", default=None, help="write grey frames (image_0)")
    colour.add_argument("--colour", dest="grey", action="store_false", help="write colour frames (image_2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier import in DIR/sequences/NAME")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.data.import_frames import import_frames

    r = import_frames(args.source, args.out, args.name, camera=args.camera, hfov=args.hfov, fps=args.fps,
                      every=args.every, max_frames=args.max_frames, grey=args.grey, overwrite=args.overwrite,
                      progress=not args.quiet)
    print(f"wrote {r['frames']} {'grey' if r['grey'] else 'colour'} frames of {r['width']}x{r['height']} at "
          f"{r['fps']:g} fps to {r['sequence']}")
    print(f"camera fx={r['fx']:.2f} fy={r['fy']:.2f} cx={r['cx']:.2f} cy={r['cy']:.2f}")
    print(f"next: privslam run {r['sequence']} --out RUN")
    return 0
