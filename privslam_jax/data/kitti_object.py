"""KITTI object-detection labels (``label_2/*.txt``) as privacy-recall ground truth.

Label format (KITTI object devkit ``readme.txt``): one object per line,
``type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry`` with ``type`` one of Car, Van, Truck,
Pedestrian, Person_sitting, Cyclist, Tram, Misc, DontCare; ``truncated`` in [0, 1]; ``occluded``
0 (fully visible), 1 (partly), 2 (largely occluded), 3 (unknown); the 2-D box in pixels.

Which objects a privacy detector must find (the protocol of issue 13, close to KITTI's "moderate"
difficulty): box height ≥ 25 px, truncation ≤ 0.5, occlusion ≤ 1, and a type that maps to COCO
privacy classes — Car and Van → car; Truck → truck or car; Pedestrian → person; Cyclist → person or
bicycle (a detection of any of the accepted classes counts). Every other labelled object (too small,
too hidden, Person_sitting, Tram, Misc, DontCare regions) is *ignored*: a detection on it is neither
a hit nor a false positive (:func:`privslam_jax.metrics.detection.privacy_recall`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from privslam_jax.errors import InputError, input_error

__all__ = ["KittiObjectLabels", "read_kitti_object_labels", "KITTI_TO_COCO"]

KITTI_TO_COCO: dict[str, tuple[int, ...]] = {
    "Car": (2,), "Van": (2,), "Truck": (7, 2), "Pedestrian": (0,), "Cyclist": (0, 1),
}
"""KITTI type → the COCO ids a privacy detector may call it (person 0, bicycle 1, car 2, truck 7)."""

KITTI_TYPES = ("Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc", "DontCare")


@dataclasses.dataclass(frozen=True)
class KittiObjectLabels:
    """The evaluated and the ignored objects of one image."""

    boxes: np.ndarray
    """``(M, 4)`` float64 ``xyxy`` of the objects a detector must find."""
    accepted: tuple[tuple[int, ...], ...]
    """Per evaluated object, the COCO ids that count as a correct class."""
    types: tuple[str, ...]
    """Per evaluated object, its KITTI type."""
    ignored: np.ndarray
    """``(K, 4)`` float64 ``xyxy`` of the labelled objects that are neither required nor false positives."""


def read_kitti_object_labels(path: str | Path, min_height: float = 25.0, max_truncation: float = 0.5,
                             max_occlusion: int = 1) -> KittiObjectLabels:
    """Parse one ``label_2`` file and split it into evaluated and ignored objects (module docstring).

    ``FileNotFoundError`` for a missing file; :class:`~privslam_jax.errors.InputError` naming
    ``file:line`` for text that is not UTF-8, an unknown type, fewer than 8 fields, a value that is
    not a number, a NaN/inf truncation or box, a non-integer occlusion or a box with ``x2 < x1`` or
    ``y2 < y1``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"KITTI label file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise input_error(path, "not a KITTI label file (not UTF-8 text)", err) from err
    boxes, accepted, types, ignored = [], [], [], []
    for n, line in enumerate(text.splitlines(), 1):
        f = line.split()
        if not f:
            continue
        if len(f) < 8 or f[0] not in KITTI_TYPES:
            raise InputError(f"{path}:{n}: not a KITTI object label line: {line.strip()[:80]!r}")
        try:
            trunc, occ_f = float(f[1]), float(f[2])
            box = [float(v) for v in f[4:8]]
        except ValueError:
            raise InputError(f"{path}:{n}: bad number in {line.strip()[:80]!r}") from None
        if not (math.isfinite(trunc) and math.isfinite(occ_f) and occ_f == int(occ_f)):
            raise InputError(f"{path}:{n}: truncation must be a finite number and occlusion an integer, "
                             f"got {f[1][:20]!r} {f[2][:20]!r}")
        occ = int(occ_f)
        if not np.all(np.isfinite(box)) or box[2] < box[0] or box[3] < box[1]:
            raise InputError(f"{path}:{n}: bad box {box}")
        required = (f[0] in KITTI_TO_COCO and box[3] - box[1] >= min_height and trunc <= max_truncation
                    and occ <= max_occlusion)
        if required:
            boxes.append(box)
            accepted.append(KITTI_TO_COCO[f[0]])
            types.append(f[0])
        else:
            ignored.append(box)
    return KittiObjectLabels(boxes=np.asarray(boxes, np.float64).reshape(-1, 4), accepted=tuple(accepted),
                             types=tuple(types), ignored=np.asarray(ignored, np.float64).reshape(-1, 4))
