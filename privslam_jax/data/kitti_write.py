"""Write a rendered sequence in the KITTI odometry layout, and describe a sequence (``privslam synth``).

Written layout (read back by :class:`privslam_jax.data.kitti.KittiSequence`; docs/formats.md)::

    DIR/sequences/NAME/image_2/%06d.png      left RGB (8-bit)
                       image_3/%06d.png      right RGB (only with --stereo)
                       calib.txt             P0..P3: K[I|0] for P0/P2, K[I|(-b,0,0)] (P[0,3] = -fx·b) for P1/P3
                       times.txt             one timestamp per frame (i / fps)
                       depth/%06d.png        uint16 z-depth · 256 (KITTI depth convention; 0 = none or ≥ 256 m)
                       masks/%06d.png        uint16 instance ids (0 = no privacy object)
                       instance_classes.json {"<instance id>": <COCO class id>}
                       background/%06d.png   the same frame rendered without the privacy objects (RGB)
                       depth_3/, background_3/  the same for the right camera (only with --stereo)
                       labels/%06d.txt       YOLO boxes: class cx cy w h (normalised)
                       manifest.json         what wrote the folder; "complete": true once all of it is written
    DIR/poses/NAME.txt                       ground truth T_w_c of the left camera, KITTI 3×4 per line

:func:`write_kitti_sequence` works on any object with the :class:`SyntheticSequence` interface
(``len``, indexing → frames with ``image``, ``image_right``, ``depth``, ``instance_ids``,
``background``, ``boxes``, ``class_ids``, ``T_w_c``, ``timestamp``; ``camera``;
``instance_classes``), :func:`summarize_sequence` on those and on a :class:`KittiSequence`.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from tqdm import tqdm

from privslam_jax.data.files import write_atomic
from privslam_jax.data.images import write_rgb, write_uint16
from privslam_jax.data.kitti import DEPTH_SCALE
from privslam_jax.data.trajectory_io import write_kitti_matrices
from privslam_jax.data.yolo import write_yolo_labels
from privslam_jax.runs import claim_run_folder, complete_run_folder

__all__ = ["COCO_NAMES", "sequence_stats", "summarize_sequence", "write_kitti_sequence"]

COCO_NAMES = {0: "person", 1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
"""Names of the COCO privacy classes (ids as in COCO/ultralytics)."""


def _calib_text(fx: float, fy: float, cx: float, cy: float, baseline: float) -> str:
    rows = []
    for k in range(4):
        P = np.array([[fx, 0.0, cx, 0.0], [0.0, fy, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
        if k in (1, 3):
            P[0, 3] = -fx * baseline
        rows.append(f"P{k}: " + " ".join(f"{v:.12e}" for v in P.ravel()))
    return "\n".join(rows) + "\n"


def _depth_png(depth: np.ndarray) -> np.ndarray:
    d = np.asarray(depth, np.float64)
    q = np.rint(np.where(np.isfinite(d) & (d > 0), d, 0.0) * DEPTH_SCALE)
    return np.where(q <= 65535, q, 0).astype(np.uint16)


def write_kitti_sequence(
    seq: Any, out: str | Path, name: str = "synth", progress: bool = True, collect: list[Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Render every frame of ``seq`` and write it to ``out`` in the KITTI layout; returns the sequence folder.

    ``collect``: a list that receives, per frame, a light record with ``class_ids`` and
    ``instance_of_box`` (for :func:`summarize_sequence` without re-rendering).
    ``DIR/sequences/NAME`` is a run folder (:mod:`privslam_jax.runs`): one that holds an earlier
    run is refused unless ``overwrite``, which clears it and ``DIR/poses/NAME.txt`` first, and its
    manifest says ``"complete": true`` only once every file is written.  The baseline in ``calib.txt`` is the camera's
    (``seq.camera.baseline``) or, for a monocular sequence, ``seq.config.baseline`` when present.
    """
    out = Path(out)
    seq_dir = out / "sequences" / name
    cam = seq.camera
    baseline = cam.baseline
    if baseline is None:
        baseline = getattr(getattr(seq, "config", None), "baseline", 0.54)
    config = getattr(seq, "config", None)
    manifest = claim_run_folder(seq_dir, "synth", {"name": name, "frames": len(seq), "config": repr(config)},
                                overwrite, (out / "poses" / f"{name}.txt",))
    write_atomic(seq_dir / "calib.txt", _calib_text(float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy),
                                                   float(baseline)))
    write_atomic(seq_dir / "instance_classes.json",
        json.dumps({str(int(k)): int(v) for k, v in sorted(seq.instance_classes.items())}, indent=0) + "\n"
    )
    times, poses = [], []
    for i in tqdm(range(len(seq)), desc=f"synth {name}", unit="frame", disable=not progress):
        f = seq[i]
        stem = f"{i:06d}"
        write_rgb(seq_dir / "image_2" / f"{stem}.png", np.asarray(f.image))
        if getattr(f, "image_right", None) is not None:
            write_rgb(seq_dir / "image_3" / f"{stem}.png", np.asarray(f.image_right))
        write_uint16(seq_dir / "depth" / f"{stem}.png", _depth_png(f.depth))
        ids = np.asarray(f.instance_ids)
        if ids.size and int(ids.max()) > 65535:
            raise ValueError(f"instance id {int(ids.max())} does not fit the 16-bit mask PNG")
        write_uint16(seq_dir / "masks" / f"{stem}.png", ids)
        write_rgb(seq_dir / "background" / f"{stem}.png", np.asarray(f.background))
        if getattr(f, "image_right", None) is not None:
            if getattr(f, "depth_right", None) is not None:
                write_uint16(seq_dir / "depth_3" / f"{stem}.png", _depth_png(f.depth_right))
            if getattr(f, "background_right", None) is not None:
                write_rgb(seq_dir / "background_3" / f"{stem}.png", np.asarray(f.background_right))
            if getattr(f, "instance_ids_right", None) is not None:
                write_uint16(seq_dir / "masks_3" / f"{stem}.png", np.asarray(f.instance_ids_right))
        h, w = ids.shape
        write_yolo_labels(
            seq_dir / "labels" / f"{stem}.txt", np.asarray(f.class_ids, np.int32), np.asarray(f.boxes, np.float64), w, h
        )
        if collect is not None:
            inst = getattr(f, "instance_of_box", None)
            collect.append(SimpleNamespace(class_ids=np.asarray(f.class_ids), instance_of_box=None if inst is None else np.asarray(inst)))
        times.append(float(f.timestamp))
        poses.append(np.asarray(f.T_w_c, np.float64))
    write_atomic(seq_dir / "times.txt", "".join(f"{t:.6e}\n" for t in times))
    write_kitti_matrices(out / "poses" / f"{name}.txt", np.stack(poses))
    complete_run_folder(seq_dir, manifest)
    return seq_dir


def _positions(seq: Any) -> np.ndarray | None:
    poses = getattr(seq, "poses", None)  # KittiSequence: float64 matrices
    if poses is not None:
        return np.asarray(poses)[:, :3, 3]
    traj = getattr(seq, "trajectory", None)
    return None if traj is None else np.asarray(traj.positions, np.float64)


def sequence_stats(seq: Any, frames: list[Any] | None = None, progress: bool = False) -> dict[str, Any]:
    """Numbers describing a sequence: frames, resolution, fps, path length, objects and boxes per class.

    ``frames``: already rendered/loaded frames (avoids rendering twice); otherwise every frame is
    read (synthetic frames are rendered).  Objects per class come from the instance table
    (``instance_classes``) when the sequence has one; boxes per class from the frames' labels.
    """
    cam = seq.camera
    pos = _positions(seq)
    path_length = float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum()) if pos is not None else float("nan")
    boxes: Counter[int] = Counter()
    visible: dict[int, set[int]] = {}
    n = 0
    it = frames if frames is not None else (seq[i] for i in tqdm(range(len(seq)), desc="summary", disable=not progress))
    for f in it:
        n += 1
        cls = getattr(f, "class_ids", None)
        if cls is None:
            continue
        cls = np.asarray(cls).reshape(-1)
        boxes.update(int(c) for c in cls)
        inst = getattr(f, "instance_of_box", None)
        if inst is not None:
            for c, k in zip(cls, np.asarray(inst).reshape(-1)):
                visible.setdefault(int(c), set()).add(int(k))
    objects = Counter(int(c) for c in getattr(seq, "instance_classes", {}).values())
    return {
        "frames": len(seq),
        "width": int(cam.width),
        "height": int(cam.height),
        "stereo_baseline": cam.baseline,
        "path_length_m": path_length,
        "objects_per_class": dict(sorted(objects.items())),
        "visible_objects_per_class": {c: len(s) for c, s in sorted(visible.items())},
        "boxes_per_class": dict(sorted(boxes.items())),
        "mean_boxes_per_frame": sum(boxes.values()) / n if n else 0.0,
    }


def summarize_sequence(seq: Any, frames: list[Any] | None = None, title: str = "sequence", progress: bool = False) -> str:
    """A printable summary of :func:`sequence_stats`."""
    s = sequence_stats(seq, frames, progress)

    def per_class(d: dict[int, int]) -> str:
        return ", ".join(f"{COCO_NAMES.get(c, c)} {v}" for c, v in d.items()) or "none"

    lines = [
        f"{title}: {s['frames']} frames, {s['width']}x{s['height']} px"
        + (f", stereo baseline {s['stereo_baseline']:.3f} m" if s["stereo_baseline"] else ""),
    ]
    if np.isfinite(s["path_length_m"]):  # unknown without ground-truth poses (the next lines of the run say so)
        lines.append(f"  camera path length: {s['path_length_m']:.1f} m")
    if s["objects_per_class"]:
        lines.append(f"  privacy objects in the world: {per_class(s['objects_per_class'])}")
    if s["visible_objects_per_class"]:
        lines.append(f"  objects seen (>= 1 box): {per_class(s['visible_objects_per_class'])}")
    if s["boxes_per_class"] or s["objects_per_class"]:  # sequences without labels have no box count to show
        lines.append(f"  boxes: {per_class(s['boxes_per_class'])}; mean {s['mean_boxes_per_frame']:.2f} per frame")
    return "\n".join(lines)
