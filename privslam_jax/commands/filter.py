"""``privslam filter``: remove the privacy objects of a KITTI-layout sequence and fill the holes.

``privslam filter SEQUENCE [--method M] --out DIR [--masks gt|detect] [--detector PATH] [--model PATH]``

``--method`` defaults to ``edgeconnect`` with the embedded checkpoint.

Reads ``SEQUENCE`` (``…/sequences/<name>``, :class:`~privslam_jax.data.kitti.KittiSequence`) and
writes ``DIR/sequences/<name>/`` with the filtered left images in the same image folder
(``image_2`` or ``image_0``; grey sequences stay grey), ``calib.txt`` and ``times.txt`` copied,
``DIR/poses/<name>.txt`` copied when present, and ``masks/%06d.png``: uint16, pixel = the id of the
(dilated) object that hid it (0 = untouched), with ``instance_classes.json`` (id → COCO class).
The right camera is written only with ``--masks detect`` (each image filtered with its own
detections); with ground-truth masks, which exist for the left camera only, it is left out.

``--masks gt`` uses the synthetic ground-truth instance masks (``masks/`` written by
``privslam synth``); ``detect`` runs the YOLOv8 detector (``--detector``: an ultralytics ``.pt``
or our ``.npz``; default ``../shared/weights/yolov8n.pt`` when present) with the paper's privacy
preset (person, bicycle, car, motorcycle, bus, truck at confidence 0.4) and masks its boxes.
``--method edgeconnect`` uses ``--model`` (an ``Inpainter`` ``.npz`` from ``train/inpaint.py``) or,
without it, the embedded CPU-preset checkpoint (``privslam_jax/assets/inpainter_cpu16.npz``, see
``docs/model_card_inpainter.md``).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

__all__ = ["add_parser", "run", "filter_sequence"]


def add_parser(subparsers) -> None:
    from privslam_jax.inpaint.filter import FILTER_METHODS

    p = subparsers.add_parser("filter", help="remove privacy objects from a KITTI-layout sequence",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, help="sequence folder (…/sequences/<name>)")
    p.add_argument("--method", default="edgeconnect", choices=FILTER_METHODS, metavar="METHOD",
                   help="edgeconnect (default: the embedded checkpoint, +2 dB PSNR over Telea on held-out "
                        "synthetic frames) | " + " | ".join(FILTER_METHODS[1:]))
    p.add_argument("--out", type=Path, required=True, help="output root (sequences/<name> is created)")
    p.add_argument("--masks", choices=("gt", "detect"), default=None,
                   help="ground-truth synthetic masks or detections (default: gt when masks/ exists)")
    p.add_argument("--detector", type=Path, default=None, help="detector weights (.pt or .npz; default: the embedded detector)")
    p.add_argument("--model", type=Path, default=None,
                   help="EdgeConnect Inpainter .npz (for edgeconnect; default: the embedded checkpoint)")
    p.add_argument("--dilation", type=int, default=4, help="mask dilation in pixels (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise baselines")
    p.set_defaults(func=run)


def _write_image(path: Path, image: np.ndarray, grey: bool) -> None:
    u8 = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    cv2.imwrite(str(path), u8[..., 0] if grey else cv2.cvtColor(u8, cv2.COLOR_RGB2BGR))


def _label_map(masks: np.ndarray, ids: list[int], shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, np.uint16)
    for m, i in zip(masks, ids, strict=True):
        out[m & (out == 0)] = i
    return out


def filter_sequence(
    sequence: Path,
    out: Path,
    method: str,
    masks_source: str | None = None,
    detector_path: Path | None = None,
    model_path: Path | None = None,
    dilation: int = 4,
    seed: int = 0,
    progress: bool = True,
) -> Path:
    """Filter every frame of ``sequence`` into ``out``; returns the written sequence folder."""
    from privslam_jax.data.images import read_image
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.inpaint.filter import FILTER_METHODS, Inpainter, filter_frame
    from privslam_jax.inpaint.masks import boxes_to_masks, instance_masks

    if method not in FILTER_METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(FILTER_METHODS)}")
    seq = KittiSequence(sequence)
    if masks_source is None:
        masks_source = "gt" if seq.has_extra("masks") else "detect"
    if masks_source == "gt" and not seq.has_extra("masks"):
        raise FileNotFoundError(f"--masks gt needs {seq.path / 'masks'} (written by `privslam synth`)")
    inpainter = None
    if method == "edgeconnect":
        inpainter = Inpainter.embedded() if model_path is None else Inpainter.load(model_path)
    detector = None
    if masks_source == "detect":
        from privslam_jax.detect import PRIVACY_PRESET, Detector

        detector = Detector.embedded() if detector_path is None else Detector.from_weights(detector_path, PRIVACY_PRESET)

    out = Path(out)
    out_dir = out / "sequences" / seq.name
    if out_dir.resolve() == seq.path.resolve():
        raise ValueError("--out must differ from the input sequence's root (it would overwrite the originals)")
    grey_input = seq.left_dir.name in ("image_0", "image_1")
    right_dir = seq.path / {"image_2": "image_3", "image_0": "image_1"}[seq.left_dir.name]
    do_right = masks_source == "detect" and right_dir.is_dir()
    folders = [(seq.left_dir, out_dir / seq.left_dir.name)]
    if do_right:
        folders.append((right_dir, out_dir / right_dir.name))
    for _, d in folders:
        d.mkdir(parents=True, exist_ok=True)
    (out_dir / "masks").mkdir(exist_ok=True)
    for name in ("calib.txt", "times.txt"):
        if (seq.path / name).is_file():
            shutil.copy2(seq.path / name, out_dir / name)
    if seq.poses_path is not None:
        (out / "poses").mkdir(parents=True, exist_ok=True)
        shutil.copy2(seq.poses_path, out / "poses" / f"{seq.name}.txt")

    classes: dict[int, int] = {}
    next_id = 1  # detections get sequence-unique ids
    h, w = seq.camera.height, seq.camera.width
    for i in tqdm(range(len(seq)), desc=f"filter {method}", disable=not progress):
        stem = seq.image_paths[i].stem
        for k, (src, dst) in enumerate(folders):
            image = read_image(src / f"{stem}.png")
            if masks_source == "gt":
                frame = seq[i]
                ids = sorted(int(x) for x in np.unique(frame.instance_ids[frame.instance_ids > 0]))
                masks = instance_masks(frame.instance_ids, np.asarray(ids, np.int64), dilation)
                for j in ids:
                    classes[j] = int(seq.instance_classes.get(j, -1))
            else:
                det = detector.detect([image])[0]
                boxes = np.asarray(det.boxes, np.float64).reshape(-1, 4)
                masks = boxes_to_masks(boxes, h, w, dilation)
                ids = list(range(next_id, next_id + len(boxes)))
                next_id += len(boxes)
                for j, c in zip(ids, np.asarray(det.class_ids).tolist(), strict=True):
                    classes[j] = int(c)
            filtered = filter_frame(image, masks, method, inpainter=inpainter, seed=seed + i)
            _write_image(dst / f"{stem}.png", filtered, grey_input)
            if k == 0:
                cv2.imwrite(str(out_dir / "masks" / f"{stem}.png"), _label_map(masks, ids, (h, w)))
    (out_dir / "instance_classes.json").write_text(json.dumps({str(k): v for k, v in sorted(classes.items())}))
    return out_dir


def run(args: argparse.Namespace) -> int:
    out_dir = filter_sequence(args.sequence, args.out, args.method, args.masks, args.detector, args.model,
                              args.dilation, args.seed)
    print(f"filtered sequence written to {out_dir}")
    return 0
