"""Self-training on unlabelled real frames: a detector's own confident boxes become labels.

Self-training (Lee, ICML-W 2013; for detection e.g. Sohn et al. 2020, "STAC") closes part of a
domain gap with data that has no labels: the detector labels real frames itself, and is trained
on them next to the synthetic data. Two rules keep the labels from teaching it wrong things:

* **Labels** are boxes the detector is sure of: score ≥ ``label_conf`` after test-time
  augmentation and temporal propagation over consecutive frames
  (:func:`privslam_jax.detect.temporal.detect_sequence`), so an object seen confidently in a
  neighbouring frame is labelled here too.
* **Uncertain regions** (boxes with ``ignore_conf`` ≤ score < ``label_conf``) are neither objects
  nor background: the loss has no ignore mask, so the region is painted with the letterbox grey
  (114) in the written training image, except where it overlaps a label — a real car the
  detector was unsure of must not be taught as background.

Nothing here uses third-party weights or their outputs: the labels come from the detector being
trained (licence-clean, as the issue requires of shipped weights).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from privslam_jax.data.images import read_rgb8, write_image_file
from privslam_jax.data.yolo import write_yolo_labels
from privslam_jax.detect.temporal import PropagationConfig, detect_sequence

__all__ = ["PseudoLabelConfig", "pseudo_label", "export_pseudo_yolo"]


@dataclasses.dataclass(frozen=True)
class PseudoLabelConfig:
    """Thresholds of :func:`pseudo_label`."""

    label_conf: float = 0.5
    """Boxes at or above this score (after TTA and propagation) become labels."""
    ignore_conf: float = 0.1
    """Boxes between this and ``label_conf`` are painted grey (neither object nor background)."""
    window: int = 2
    """Temporal propagation window over consecutive frames (0: per frame)."""
    tta_scales: tuple[float, ...] = (1.0, 1.5)
    """Test-time augmentation scales (each also flipped); empty: none."""
    min_height: float = 12.0
    """Smallest labelled box height in pixels (smaller confident boxes are painted grey instead)."""


def pseudo_label(detector, frames: Sequence[np.ndarray], config: PseudoLabelConfig = PseudoLabelConfig()
                 ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per frame ``(label boxes (K, 4), label classes (K,), ignore boxes (J, 4))`` for consecutive ``frames``."""
    det = detector.with_config(dataclasses.replace(detector.config, conf=config.ignore_conf))
    prop = PropagationConfig(window=config.window, high_conf=config.label_conf, low_conf=config.ignore_conf)
    dets, _ = detect_sequence(det, frames, prop if config.window else None, config.tta_scales or None)
    out = []
    for d in dets:
        b = np.asarray(d.boxes, np.float64).reshape(-1, 4)
        s, c = np.asarray(d.scores).reshape(-1), np.asarray(d.class_ids).reshape(-1)
        label = (s >= config.label_conf) & (b[:, 3] - b[:, 1] >= config.min_height)
        out.append((b[label], c[label].astype(np.int32), b[~label]))
    return out


def export_pseudo_yolo(detector, runs: Sequence[Sequence[Path]], root: str | Path, split: str,
                       config: PseudoLabelConfig = PseudoLabelConfig()) -> tuple[int, int, int]:
    """Pseudo-label runs of consecutive frame files into a YOLO split; returns ``(frames, labels, ignored)``.

    Images are written as PNG with the ignore regions painted grey (``<run>_<stem>.png``).
    """
    img_dir, lab_dir = Path(root) / "images" / split, Path(root) / "labels" / split
    img_dir.mkdir(parents=True, exist_ok=True)
    lab_dir.mkdir(parents=True, exist_ok=True)
    n = n_lab = n_ign = 0
    for r, paths in enumerate(runs):
        frames = [read_rgb8(p) for p in paths]
        for p, img, (boxes, cls, ignore) in zip(paths, frames, pseudo_label(detector, frames, config)):
            h, w = img.shape[:2]
            paint = np.zeros((h, w), bool)
            for x1, y1, x2, y2 in np.round(ignore).astype(int):
                paint[max(y1, 0):min(y2, h), max(x1, 0):min(x2, w)] = True
            for x1, y1, x2, y2 in np.round(boxes).astype(int):  # never paint over a labelled object
                paint[max(y1, 0):min(y2, h), max(x1, 0):min(x2, w)] = False
            img = np.where(paint[..., None], np.uint8(114), img)
            stem = f"r{r:02d}_{Path(p).stem}"
            write_image_file(img_dir / f"{stem}.png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            write_yolo_labels(lab_dir / f"{stem}.txt", cls, np.clip(boxes, 0, [w, h, w, h]), w, h)
            n, n_lab, n_ign = n + 1, n_lab + len(boxes), n_ign + len(ignore)
    return n, n_lab, n_ign
