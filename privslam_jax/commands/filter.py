"""``privslam filter``: remove the privacy objects of a folder of frames or a KITTI-layout sequence and fill the holes.

``privslam filter SEQUENCE [--method M] --out DIR [--masks gt|detect] [--detector PATH] [--model PATH]``

``--method`` defaults to ``edgeconnect`` with the embedded checkpoint.

``SEQUENCE`` is a plain folder of frames (any image format, name order = time order; written as
PNG to ``DIR/<name>/`` with ``masks/`` and the report beside them) or a KITTI-layout sequence.
Reads a KITTI-layout ``SEQUENCE`` (``…/sequences/<name>``, :class:`~privslam_jax.data.kitti.KittiSequence`) and
writes ``DIR/sequences/<name>/`` with the filtered left images in the same image folder
(``image_2`` or ``image_0``; grey sequences stay grey), ``calib.txt`` and ``times.txt`` copied,
``DIR/poses/<name>.txt`` copied when present, and ``masks/%06d.png``: uint16, pixel = the id of the
(dilated) object that hid it (0 = untouched), with ``instance_classes.json`` (id → COCO class).
The right camera is written with ``--masks detect`` (each image filtered with its own
detections) and, with ``--masks gt``, when the right camera's ground-truth ids exist (``masks_3/``,
``privslam synth --stereo``); otherwise it is left out.

``--masks gt`` uses the synthetic ground-truth instance masks (``masks/`` written by
``privslam synth``); ``detect`` runs the YOLOv8 detector (``--detector``: an ultralytics ``.pt``
or our ``.npz``; default the embedded detector made for the frames: the synthetic-world one on a
``privslam synth`` output, the real-frame one elsewhere) with the paper's privacy preset (person, bicycle,
car, motorcycle, bus, truck at confidence 0.4, ``--conf`` to change it) and masks its boxes;
``--tta`` and ``--propagate K`` raise recall (:mod:`privslam_jax.detect.temporal`; ``--propagate``
defaults to 3 frames on real frames, recall first, and to 0 on ``privslam synth`` output). A detector
whose checkpoint says it was trained on the synthetic world only is refused on a sequence that
is not a ``privslam synth`` output (one without ``background/``) unless
``--allow-domain-mismatch`` is given, and then the run warns. ``filter_report.json`` records the
detector, its domain and the masks per frame.
``--method edgeconnect`` uses ``--model`` (an ``Inpainter`` ``.npz`` from ``train/inpaint.py``) or,
without it, the embedded CPU-preset checkpoint made for the frames (``privslam_jax/assets/inpainter_cpu16.npz``
on ``privslam synth`` output, ``inpainter_cpu16_real.npz`` elsewhere; ``docs/model_card_inpainter.md``).
``--method tradeoff`` is the same network with the embedded checkpoint trained for privacy and SLAM
accuracy at once (``inpainter_tradeoff.npz``, ``docs/model_card_inpainter_tradeoff.md``).

The written sequence folder carries ``manifest.json`` (command, arguments, versions) with
``"complete": true`` only once everything is written; a folder holding an earlier run is refused
unless ``--overwrite``, which clears it and ``DIR/poses/<name>.txt`` first.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, unit_interval
from privslam_jax.inpaint.sequence import filter_sequence

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    from privslam_jax.inpaint.filter import FILTER_METHODS

    p = subparsers.add_parser("filter", help="remove privacy objects from a folder of frames or a KITTI-layout sequence",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path,
                   help="a plain folder of frames (name order = time order) or a KITTI-layout sequence (…/sequences/<name>)")
    p.add_argument("--method", default="edgeconnect", choices=FILTER_METHODS, metavar="METHOD",
                   help="edgeconnect (default: the embedded checkpoint made for the frames, synthetic-world on "
                        "privslam synth outputs, real-frame elsewhere; docs/model_card_inpainter*.md) | tradeoff (the embedded inpainter trained for privacy and SLAM accuracy, "
                        "docs/tradeoff.md) | " + " | ".join(FILTER_METHODS[2:]))
    p.add_argument("--out", type=Path, required=True, help="output root (sequences/<name> is created)")
    p.add_argument("--masks", choices=("gt", "detect"), default=None,
                   help="ground-truth synthetic masks or detections (default: gt when masks/ exists)")
    p.add_argument("--detector", type=Path, default=None, help="detector weights (.pt or .npz; default: the embedded detector for the frames' domain)")
    p.add_argument("--model", type=Path, default=None,
                   help="EdgeConnect Inpainter .npz (for edgeconnect or tradeoff; default: the embedded checkpoint)")
    p.add_argument("--conf", type=unit_interval, default=None,
                   help="detection threshold (default 0.4, the paper's; lower it for recall, see docs/detector.md)")
    p.add_argument("--propagate", type=nonnegative_int, default=None, metavar="K",
                   help="carry each detection to the K frames before and after it by optical flow, where the "
                        "detector missed the object (recall-first; default 3 on real frames, 0 on privslam synth "
                        "output; 0 turns it off; docs/detector.md)")
    p.add_argument("--tta", action="store_true", help="test-time augmentation: letterbox 640 and 960, each also flipped")
    p.add_argument("--allow-domain-mismatch", action="store_true",
                   help="run a detector trained on the synthetic world only on real frames anyway (it misses most objects)")
    p.add_argument("--dilation", type=nonnegative_int, default=4, help="mask dilation in pixels (default 4)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the noise baselines")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier filter or synth run in the output sequence folder (cleared first)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out_dir = filter_sequence(args.sequence, args.out, args.method, args.masks, args.detector, args.model,
                              args.dilation, args.seed, conf=args.conf, propagate=args.propagate, tta=args.tta,
                              allow_domain_mismatch=args.allow_domain_mismatch, overwrite=args.overwrite)
    report = json.loads((out_dir / "filter_report.json").read_text())
    det = report.get("detector")
    if det is not None:
        per = report["masks_per_frame"]
        print(f"detector {det['weights']} (trained on {det['domain']} frames), conf {det['conf']}, "
              f"propagate {det['propagate']}, tta {det['tta']}: {sum(per['detected'])} detected, "
              f"{sum(per['promoted'])} promoted, {sum(per['propagated'])} propagated masks; "
              f"{report['frames_without_masks']} of {report['frames']} frames without any mask")
        if det["privacy_warning"]:
            print("PRIVACY WARNING: " + det["privacy_warning"])
    print(f"filtered sequence written to {out_dir}")
    return 0
