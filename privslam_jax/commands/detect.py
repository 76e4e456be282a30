"""``privslam detect``: run the YOLOv8 detector on an image, a folder of images or a sequence.

Writes ``OUT/detections.json``::

    {"images": [{"file": str, "detections": [{"xyxy": [x1, y1, x2, y2], "conf": float,
                                               "class_id": int, "class_name": str}]}]}

with boxes in original pixels (``file`` relative to SOURCE when SOURCE is a folder), plus one
annotated PNG per image in ``OUT/`` (same relative path, ``/`` → ``__``, suffix ``.png``).

SOURCE may be an image file, a folder of images, or a sequence folder (KITTI layout: the images
in ``image_2/``, else ``image_0/``). ``--weights`` takes our ``.npz`` checkpoint or an
ultralytics ``.pt`` (zip or unzipped folder); without it the embedded real-frame detector runs
(``--embedded synthetic``: the synthetic-world one, for ``privslam synth`` frames). ``--classes privacy`` keeps person, bicycle, car,
motorcycle, bus and truck and defaults ``--conf`` to the paper's 0.4; ``all`` (default) keeps
every class with ultralytics' default 0.25.
"""

from __future__ import annotations

import argparse
import sys
import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from privslam_jax.argtypes import multiple_of_32, unit_interval

__all__ = ["add_parser", "run", "list_images", "EMBEDDED_WEIGHTS", "EMBEDDED_REAL_WEIGHTS"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
EMBEDDED_WEIGHTS = Path(__file__).resolve().parents[1] / "assets" / "detector_yolov8n_privacy.npz"
"""The embedded synthetic-world detector (same path as ``privslam_jax.detect.EMBEDDED_WEIGHTS``; not
imported from there to keep ``privslam --help`` free of JAX)."""
EMBEDDED_REAL_WEIGHTS = EMBEDDED_WEIGHTS.with_name("detector_yolov8n_real.npz")
"""The embedded real-frame detector (``privslam_jax.detect.EMBEDDED_REAL_WEIGHTS``)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("detect", help="detect objects (YOLOv8) in images", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", type=Path, help="image file, folder of images, or sequence folder")
    p.add_argument("--weights", type=Path, default=None,
                   help="detector weights: our .npz checkpoint or an ultralytics .pt (default: an embedded detector)")
    p.add_argument("--embedded", choices=("real", "synthetic"), default="real",
                   help="which embedded detector without --weights: for real photographs (default) or for "
                        "privslam synth frames")
    p.add_argument("--conf", type=unit_interval, default=None,
                   help="confidence threshold (default 0.25; 0.4 with --classes privacy)")
    p.add_argument("--iou", type=unit_interval, default=0.7, help="NMS IoU threshold (default 0.7)")
    p.add_argument("--imgsz", type=multiple_of_32, default=640, help="letterbox size, multiple of 32 (default 640)")
    p.add_argument("--classes", choices=("privacy", "all"), default="all", help="class filter (default all)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true",
                   help="clear --out first if it holds an earlier privslam run (otherwise such a folder is refused)")
    p.set_defaults(func=run, owns_out=True)


def list_images(source: Path) -> tuple[Path, list[Path]]:
    """``(root, image paths)`` for an image file, a folder of images or a sequence folder."""
    source = Path(source)
    if source.is_file():
        if source.suffix.lower() not in IMAGE_SUFFIXES:
            raise ValueError(f"{source} is not an image ({', '.join(IMAGE_SUFFIXES)})")
        return source.parent, [source]
    if not source.is_dir():
        raise FileNotFoundError(f"source not found: {source}")
    for folder in (source, source / "image_2", source / "image_0"):
        files = sorted(p for p in folder.glob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES) \
            if folder.is_dir() else []
        if files:
            return source, files
    raise ValueError(f"no images in {source} (nor in its image_2/ or image_0/)")


def _annotate(rgb: np.ndarray, boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray,
              names: dict[int, str]) -> np.ndarray:
    import cv2

    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    for (x1, y1, x2, y2), s, c in zip(boxes, scores, classes):
        hue = (int(c) * 47) % 180
        color = tuple(int(v) for v in cv2.cvtColor(np.uint8([[[hue, 220, 255]]]), cv2.COLOR_HSV2BGR)[0, 0])
        p1, p2 = (int(round(x1)), int(round(y1))), (int(round(x2)), int(round(y2)))
        cv2.rectangle(img, p1, p2, color, 2)
        label = f"{names.get(int(c), str(int(c)))} {s:.2f}"
        (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        y = max(p1[1], th + 4)
        cv2.rectangle(img, (p1[0], y - th - 4), (p1[0] + tw + 2, y), color, -1)
        cv2.putText(img, label, (p1[0] + 1, y - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def run(args: argparse.Namespace) -> int:
    from privslam_jax.data.files import write_atomic
    from privslam_jax.data.images import read_rgb8, write_image_file
    from privslam_jax.detect.predict import PRIVACY_CLASSES, Detector, DetectorConfig

    weights = args.weights
    if weights is None:
        weights = EMBEDDED_REAL_WEIGHTS if args.embedded == "real" else EMBEDDED_WEIGHTS
        if not weights.is_file():
            raise ValueError(f"no embedded detector at {weights}: pass --weights PATH "
                             "(an ultralytics .pt such as yolov8n.pt, or a privslam .npz checkpoint)")
    classes = PRIVACY_CLASSES if args.classes == "privacy" else None
    conf = args.conf if args.conf is not None else (0.4 if args.classes == "privacy" else 0.25)
    config = DetectorConfig(imgsz=args.imgsz, conf=conf, iou=args.iou, classes=classes)
    root, files = list_images(args.source)
    detector = Detector.from_weights(weights, config)
    if detector.domain == "synthetic":
        rr = detector.meta["card"].get("real_recall")
        measured = f" (recall on real KITTI frames {rr['recall']:.2f}, {rr['command']})" if isinstance(rr, dict) else ""
        print(f"note: {weights} was trained on the synthetic world only{measured}; on real images it misses most "
              "people and vehicles: use --weights with a detector trained on real images (docs/detector.md)",
              file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    chunk = 8
    with tqdm(total=len(files), desc="detect", unit="img") as bar:
        for start in range(0, len(files), chunk):
            paths = files[start : start + chunk]
            images = [read_rgb8(p) for p in paths]
            for p, img, det in zip(paths, images, detector.detect(images)):
                boxes, scores = np.asarray(det.boxes, np.float64), np.asarray(det.scores, np.float64)
                cls = np.asarray(det.class_ids).astype(int)
                rel = p.relative_to(root).as_posix()
                records.append({"file": rel, "detections": [
                    {"xyxy": [float(v) for v in b], "conf": float(s), "class_id": int(c),
                     "class_name": detector.names.get(int(c), str(int(c)))}
                    for b, s, c in zip(boxes, scores, cls)
                ]})
                png = out / (Path(rel.replace("/", "__")).with_suffix(".png").name)
                write_image_file(png, _annotate(img, boxes, scores, cls, detector.names))
                bar.update(1)
    write_atomic(out / "detections.json", json.dumps({"images": records}, indent=1))
    n = sum(len(r["detections"]) for r in records)
    print(f"{n} detections in {len(records)} images -> {out / 'detections.json'}")
    return 0
