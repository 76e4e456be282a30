"""Filter a whole sequence: detect (or read) the privacy objects of every frame, hide and fill them.

:func:`filter_sequence` is the library side of ``privslam filter`` (its command-line help, in
:mod:`privslam_jax.commands.filter`, describes the folders it reads and writes).
:func:`check_detector_domain` refuses a synthetic-only detector on real frames and warns about one
whose measured real-frame recall is low.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
from tqdm import tqdm

from privslam_jax.data.files import write_atomic
from privslam_jax.data.images import write_image_file
from privslam_jax.runs import check_run_folder, claim_run_folder, complete_run_folder

__all__ = ["RECALL_WARNING_BELOW", "check_detector_domain", "filter_sequence"]


def _write_image(path: Path, image: np.ndarray, grey: bool) -> None:
    u8 = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    write_image_file(path, u8[..., 0] if grey else cv2.cvtColor(u8, cv2.COLOR_RGB2BGR))


def _label_map(masks: np.ndarray, ids: list[int], shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, np.uint16)
    for m, i in zip(masks, ids, strict=True):
        out[m & (out == 0)] = i
    return out


class _FrameFolder:
    """A plain folder of frames (any image format, name order = time order) seen as a sequence."""

    def __init__(self, path: Path):
        from privslam_jax.data.images import read_raw
        from privslam_jax.data.yolo import IMAGE_SUFFIXES

        if not path.is_dir():
            raise FileNotFoundError(f"sequence folder not found: {path}")
        self.path, self.name, self.poses_path, self.instance_classes = path, path.name, None, {}
        self.image_paths = sorted(q for q in path.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
        if not self.image_paths:
            raise ValueError(f"{path} holds no image_2/ or image_0/ folder (KITTI layout) and no image files")
        first = read_raw(self.image_paths[0])
        self.grey = first.ndim == 2 or first.shape[-1] == 1
        self.camera = SimpleNamespace(height=first.shape[0], width=first.shape[1])

    def __len__(self) -> int:
        return len(self.image_paths)

    def has_extra(self, name: str) -> bool:
        return False


def _consecutive_runs(stems: list[str]) -> list[tuple[int, int]]:
    """``[start, stop)`` index ranges of consecutively numbered frames (one run if names are not numbers)."""
    if not all(t.isdigit() for t in stems):
        return [(0, len(stems))]
    ids = [int(t) for t in stems]
    cuts = [0] + [i for i in range(1, len(ids)) if ids[i] != ids[i - 1] + 1] + [len(ids)]
    return list(zip(cuts[:-1], cuts[1:]))


RECALL_WARNING_BELOW = 0.9
"""A detector whose measured real-frame recall is below this gets a PRIVACY WARNING on real frames."""


def check_detector_domain(detector, sequence_is_synthetic: bool, allow_mismatch: bool) -> str | None:
    """Refuse, or warn about, a detector that will miss objects in these frames.

    On frames that are not a ``privslam synth`` output: a detector trained on the synthetic world
    only is refused (``ValueError``) unless ``allow_mismatch``, then warned about; any detector
    whose checkpoint states a real-frame recall below :data:`RECALL_WARNING_BELOW` is warned about
    with that number. Returns the warning text (``None`` without one). A privacy filter that
    quietly finds nothing on frames it does not understand leaks every object in them.
    """
    import warnings

    if sequence_is_synthetic:
        return None
    recall = detector.meta.get("card", {}).get("real_recall")
    measured = (f"measured recall on real KITTI frames: {recall['recall']:.2f} at conf {recall.get('conf', 0.4)} with "
                f"{recall['fp_per_image']:.2f} false positives per image ({recall.get('command', '')})"
                if isinstance(recall, dict) else "its recall on real frames has not been measured")
    name = detector.meta.get("path", "embedded")
    if detector.domain == "synthetic":
        text = (f"the detector {name} was trained on the synthetic world only ({measured}); on these frames, which "
                "are not a `privslam synth` output, it leaves most people and vehicles visible")
        if not allow_mismatch:
            raise ValueError(text + ". Give --detector a detector trained on real images (e.g. an ultralytics .pt you "
                             "own, see docs/detector.md), or pass --allow-domain-mismatch to run anyway.")
    elif isinstance(recall, dict) and recall["recall"] < RECALL_WARNING_BELOW:
        text = (f"the detector {name} misses people and vehicles in real frames ({measured}); raise recall with "
                "--tta, --conf 0.1 and --propagate 3, or use a stronger detector (docs/detector.md)")
    else:
        return None
    warnings.warn("PRIVACY WARNING: " + text, UserWarning, stacklevel=2)
    return text


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
    conf: float | None = None,
    propagate: int = 0,
    tta: bool = False,
    allow_domain_mismatch: bool = False,
    overwrite: bool = False,
) -> Path:
    """Filter every frame of ``sequence`` into ``out``; returns the written sequence folder.

    The sequence folder is a run folder (:mod:`privslam_jax.runs`): its ``manifest.json`` says
    ``"complete": true`` only after every frame and report is written; a folder holding an earlier
    run is refused unless ``overwrite``, which clears it (and its ``poses/NAME.txt``) first.

    With ``masks_source="detect"`` the detector runs over the whole sequence first (threshold
    ``conf``, default the paper's 0.4; ``tta`` and ``propagate`` as in
    :func:`privslam_jax.detect.temporal.detect_sequence`), then each frame is filled.
    ``method="edgeconnect"`` without ``model_path`` uses the embedded inpainter made for the frames:
    the synthetic-world one on ``privslam synth`` output, the real-frame one on anything else.
    ``filter_report.json`` records the detector (and its training domain), the inpainter, the settings and the
    number of masks per frame by origin (detected, promoted low-score, propagated).
    """
    from privslam_jax.data.images import read_image
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.inpaint.filter import FILTER_METHODS, Inpainter, filter_frame
    from privslam_jax.inpaint.masks import boxes_to_masks, instance_masks

    if method not in FILTER_METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(FILTER_METHODS)}")
    sequence = Path(sequence)
    kitti = any((sequence / d).is_dir() for d in ("image_2", "image_0"))
    seq = KittiSequence(sequence) if kitti else _FrameFolder(sequence)
    if masks_source is None:
        masks_source = "gt" if seq.has_extra("masks") else "detect"
    if masks_source == "gt" and not seq.has_extra("masks"):
        raise FileNotFoundError(f"--masks gt needs {seq.path / 'masks'} (written by `privslam synth`)")
    if len(seq) == 0:
        raise ValueError(f"{sequence} has no frames")
    report: dict = {"method": method, "masks": masks_source, "frames": len(seq)}
    synthetic = seq.has_extra("background")  # privslam synth writes background/ (the object-free render)
    detector = None
    if masks_source == "detect":
        from privslam_jax.detect import PRIVACY_PRESET, Detector
        from privslam_jax.detect.temporal import PropagationConfig

        preset = PRIVACY_PRESET if conf is None else dataclasses.replace(PRIVACY_PRESET, conf=conf)
        if detector_path is not None:
            detector = Detector.from_weights(detector_path, preset)
        else:  # the embedded detector made for these frames
            detector = Detector.embedded(preset, domain="synthetic" if synthetic else "real")
        mismatch = check_detector_domain(detector, synthetic, allow_domain_mismatch)
        propagation = (PropagationConfig(window=propagate, high_conf=preset.conf, low_conf=min(0.1, preset.conf))
                       if propagate else None)
        report["detector"] = {"weights": detector.meta.get("path", "embedded"), "domain": detector.domain,
                              "card": detector.meta.get("card", {}), "conf": preset.conf, "propagate": propagate,
                              "tta": tta, "privacy_warning": mismatch}
    inpainter = None
    if method == "edgeconnect":
        domain = "synthetic" if synthetic else "real"  # the embedded inpainter made for these frames
        inpainter = Inpainter.embedded(domain) if model_path is None else Inpainter.load(model_path)
        report["inpainter"] = {"weights": str(model_path) if model_path is not None else f"embedded ({domain})",
                               "config": dataclasses.asdict(inpainter.config)}

    out = Path(out)
    out_dir = out / "sequences" / seq.name if kitti else out / seq.name
    if out_dir.resolve() == seq.path.resolve():
        raise ValueError("--out must differ from the input sequence's root (it would overwrite the originals)")
    poses_out = out / "poses" / f"{seq.name}.txt"
    companions = (poses_out,) if kitti else ()
    check_run_folder(out_dir, overwrite, companions)  # refuse now; claim once the frames passed their checks
    stems = [p.stem for p in seq.image_paths]
    if kitti:
        grey_input = seq.left_dir.name in ("image_0", "image_1")
        right_dir = seq.path / {"image_2": "image_3", "image_0": "image_1"}[seq.left_dir.name]
        folders = [([seq.left_dir / f"{t}.png" for t in stems], out_dir / seq.left_dir.name)]
        if masks_source == "detect" and right_dir.is_dir():
            folders.append(([right_dir / f"{t}.png" for t in stems], out_dir / right_dir.name))
    else:
        grey_input = seq.grey
        folders = [(seq.image_paths, out_dir)]

    detections = {}
    if detector is not None:
        from privslam_jax.detect.temporal import detect_sequence

        runs = _consecutive_runs(stems)
        report["runs"] = [[stems[a], stems[b - 1]] for a, b in runs]
        for k, (src, _) in enumerate(folders):
            dets_k, origins_k = [], []
            for a, b in runs:  # propagation never crosses a gap in the frame numbers
                images = [read_image(path) for path in src[a:b]]
                for path, im in zip(src[a:b], images):  # refuse before anything is written
                    if im.shape[:2] != (seq.camera.height, seq.camera.width):
                        raise ValueError(f"{path} is {im.shape[1]}x{im.shape[0]}, the sequence's frames are "
                                         f"{seq.camera.width}x{seq.camera.height}")
                d, o = detect_sequence(detector, images, propagation, (1.0, 1.5) if tta else None)
                dets_k, origins_k = dets_k + d, origins_k + o
            detections[k] = (dets_k, origins_k)
        dets, origins = detections[0]
        counts = np.array([np.bincount(o, minlength=3) for o in origins]).reshape(-1, 3)
        report["masks_per_frame"] = {"detected": counts[:, 0].tolist(), "promoted": counts[:, 1].tolist(),
                                     "propagated": counts[:, 2].tolist()}
        report["frames_without_masks"] = int((counts.sum(1) == 0).sum())

    manifest = claim_run_folder(out_dir, "filter", {
        "sequence": str(sequence), "method": method, "masks": masks_source, "detector": detector_path,
        "model": model_path, "dilation": dilation, "seed": seed, "conf": conf, "propagate": propagate, "tta": tta,
        "allow_domain_mismatch": allow_domain_mismatch}, overwrite, companions)
    for _, d in folders:
        d.mkdir(parents=True, exist_ok=True)
    (out_dir / "masks").mkdir(exist_ok=True)
    for name in ("calib.txt", "times.txt"):
        if (seq.path / name).is_file():
            write_atomic(out_dir / name, (seq.path / name).read_bytes())
    if seq.poses_path is not None:
        write_atomic(poses_out, seq.poses_path.read_bytes())

    classes: dict[int, int] = {}
    next_id = 1  # detections get sequence-unique ids
    h, w = seq.camera.height, seq.camera.width
    for i in tqdm(range(len(seq)), desc=f"filter {method}", disable=not progress):
        stem = stems[i]
        for k, (src, dst) in enumerate(folders):
            image = read_image(src[i])
            if image.shape[:2] != (h, w):
                raise ValueError(f"{src[i]} is {image.shape[1]}x{image.shape[0]}, the sequence's frames are {w}x{h}")
            if masks_source == "gt":
                frame = seq[i]
                ids = sorted(int(x) for x in np.unique(frame.instance_ids[frame.instance_ids > 0]))
                masks = instance_masks(frame.instance_ids, np.asarray(ids, np.int64), dilation)
                for j in ids:
                    classes[j] = int(seq.instance_classes.get(j, -1))
            else:
                det = detections[k][0][i]
                boxes = np.asarray(det.boxes, np.float64).reshape(-1, 4)
                masks = boxes_to_masks(boxes, h, w, dilation)
                ids = list(range(next_id, next_id + len(boxes)))
                next_id += len(boxes)
                for j, c in zip(ids, np.asarray(det.class_ids).tolist(), strict=True):
                    classes[j] = int(c)
            filtered = filter_frame(image, masks, method, inpainter=inpainter, seed=seed + i)
            _write_image(dst / f"{stem}.png", filtered, grey_input)
            if k == 0:
                write_image_file(out_dir / "masks" / f"{stem}.png", _label_map(masks, ids, (h, w)))
    write_atomic(out_dir / "instance_classes.json", json.dumps({str(k): v for k, v in sorted(classes.items())}))
    write_atomic(out_dir / "filter_report.json", json.dumps(report, indent=1))
    complete_run_folder(out_dir, manifest)  # last: the run finished
    return out_dir
