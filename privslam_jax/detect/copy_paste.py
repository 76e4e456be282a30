"""Copy-paste augmentation: cut labelled real objects out of their frames and paste them into others.

A detector fine-tuned on a few labelled real frames sees few people: the real training frames
allowed by ``../shared`` hold 16 hand-drawn person boxes against 162 cars, and the real-frame
detector found 0 of 10 pedestrians on ``kitti_object`` (``docs/model_card_detector.md``).
Copy-paste (Dwibedi et al., "Cut, Paste and Learn", ICCV 2017; Ghiasi et al., "Simple Copy-Paste
is a Strong Data Augmentation Method for Instance Segmentation", CVPR 2021) multiplies those
instances: each is segmented out of its keyframe and pasted, many times, into other real frames at
places and sizes a street camera would see it.

* **Cut** (:func:`cut_instance`): the object's matte is its instance mask where one exists (the
  Mask R-CNN masks of ``kitti_raw_a``), else a soft ellipse inscribed in the drawn box; the edge
  is feathered so that the paste has no hard seam. A group of boxes (a person on a bicycle) is
  cut as one instance and keeps one label per box.
* **Paste** (:func:`paste_instances`): the camera is assumed level at a common height, so an object
  standing on the road at image row ``y_b`` (its bottom) below the horizon row ``y_h`` has an image
  height proportional to ``y_b − y_h`` (flat ground, pinhole). A new bottom row is drawn below the
  horizon and the instance is scaled by the ratio of the two distances to the horizon; it is
  flipped left-right with probability ½ and placed at a random column. A placement that would
  cover more than ``max_cover`` of an existing labelled box is redrawn (that object would no
  longer be visible enough to keep its label). Pasted objects are drawn on top, so their labels
  are exact: the box of each member is its drawn box mapped into the new frame.

Everything is numpy + OpenCV on ``uint8`` RGB frames with ``xyxy`` pixel boxes; randomness comes
from a ``numpy`` generator, so a training set is reproducible.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from jaxtyping import Float, Int, Real, UInt8

__all__ = ["Instance", "PasteConfig", "cut_instance", "object_groups", "paste_instances"]


@dataclasses.dataclass(frozen=True)
class Instance:
    """An object cut out of a frame: a colour patch, its alpha matte and the labels it carries."""

    rgb: UInt8[np.ndarray, "h w 3"]
    """The patch (the drawn boxes' union plus nothing else)."""
    alpha: Float[np.ndarray, "h w"]
    """Matte in ``[0, 1]`` (1 = object)."""
    boxes: Float[np.ndarray, "k 4"]
    """``xyxy`` boxes of the members in patch pixels."""
    class_ids: Int[np.ndarray, " k"]
    """Class of each member."""
    bottom_row: float
    """Row of the patch's bottom edge in the source frame (where it stands on the ground)."""
    source_height: int
    """Height of the source frame in pixels."""


@dataclasses.dataclass(frozen=True)
class PasteConfig:
    """Placement rules of :func:`paste_instances`."""

    horizon: float = 0.48
    """Horizon row as a fraction of the frame height (KITTI: about 180 of 375 rows)."""
    min_height: int = 16
    """Smallest pasted height in pixels (smaller draws are redrawn)."""
    max_scale: float = 2.0
    """Largest and (inverse) smallest scale relative to the source."""
    max_cover: float = 0.4
    """Largest share of an existing box that a pasted matte may cover."""
    tries: int = 20
    """Placement draws per instance before it is skipped."""


def object_groups(boxes: Real[np.ndarray, "n 4"], class_ids: Int[np.ndarray, " n"],
                  skip: tuple[int, ...] = ()) -> list[list[int]]:
    """Indices of the boxes that form one object: a person with the bicycle or motorcycle it rides.

    A person (class 0) and a bicycle (1) or motorcycle (3) are one object when their boxes overlap
    by more than half of the narrower one's width and overlap vertically. Every other box is an
    object of its own; boxes of a class in ``skip`` are left out.
    """
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    c = np.asarray(class_ids).reshape(-1)
    groups: list[list[int]] = []
    used: set[int] = set()
    for i in range(len(b)):
        if i in used or int(c[i]) in skip:
            continue
        g = [i]
        for j in range(len(b)):
            pair = {int(c[i]), int(c[j])}
            if j == i or j in used or pair not in ({0, 1}, {0, 3}) or any(int(c[k]) == int(c[j]) for k in g):
                continue
            overlap_x = min(b[i, 2], b[j, 2]) - max(b[i, 0], b[j, 0])
            if overlap_x > 0.5 * min(b[i, 2] - b[i, 0], b[j, 2] - b[j, 0]) and min(b[i, 3], b[j, 3]) > max(b[i, 1], b[j, 1]):
                g.append(j)
        used.update(g)
        groups.append(g)
    return groups


def _ellipse_matte(h: int, w: int, soft: float = 0.15) -> np.ndarray:
    """A matte that is 1 inside the ellipse inscribed in an ``h × w`` box and falls to 0 at its edge.

    ``soft`` is the width of the fall-off as a share of the normalised radius.
    """
    y = (np.arange(h) + 0.5) / h * 2 - 1
    x = (np.arange(w) + 0.5) / w * 2 - 1
    r = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2)
    return np.clip((1.0 + soft / 2 - r) / soft, 0.0, 1.0).astype(np.float32)


def cut_instance(image: UInt8[np.ndarray, "H W 3"], boxes: Float[np.ndarray, "k 4"],
                 class_ids: Int[np.ndarray, " k"], matte: np.ndarray | None = None,
                 feather: float = 1.0) -> Instance | None:
    """Cut the object(s) inside ``boxes`` out of ``image`` as an :class:`Instance`.

    ``boxes`` (``xyxy`` pixels) are the members of one object (a rider and the bicycle); the patch
    is their union. Its alpha is ``matte`` (a frame-sized object mask, e.g. the Mask R-CNN masks of
    ``kitti_raw_a``; nonzero = object) inside the union, feathered by a Gaussian of ``feather`` px,
    when it covers at least 15 % of the union; otherwise a soft ellipse inscribed in the union (the
    object with a thin ring of its own background, which the feathered edge blends away). GrabCut
    inside the box was tried first and keeps under 5 % of the people in these frames: their dark
    clothes share the colours of the shadows around them.

    Returns ``None`` when the union touches the frame border (a truncated object would be pasted
    cut off) or is smaller than 4 × 8 px.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3 or img.dtype != np.uint8:
        raise ValueError(f"image must be uint8 (H, W, 3), got {img.dtype} {img.shape}")
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    h, w = img.shape[:2]
    x1, y1 = (int(v) for v in np.floor(b[:, :2].min(0)))
    x2, y2 = (int(v) for v in np.ceil(b[:, 2:].max(0)))
    if x1 <= 1 or y1 <= 1 or x2 >= w - 1 or y2 >= h - 1 or x2 - x1 < 4 or y2 - y1 < 8:
        return None
    alpha = _ellipse_matte(y2 - y1, x2 - x1)
    if matte is not None:
        if np.shape(matte)[:2] != (h, w):
            raise ValueError(f"matte must be {(h, w)}, got {np.shape(matte)}")
        m = (np.asarray(matte)[y1:y2, x1:x2].reshape(y2 - y1, x2 - x1, -1).max(-1) > 0).astype(np.float32)
        if m.mean() >= 0.15:
            alpha = np.minimum(m, cv2.GaussianBlur(m, (0, 0), feather)) if feather > 0 else m
    local = b - [x1, y1, x1, y1]
    return Instance(rgb=img[y1:y2, x1:x2].copy(), alpha=alpha, boxes=local,
                    class_ids=np.asarray(class_ids, np.int32).reshape(-1), bottom_row=float(y2),
                    source_height=h)


def _cover(a: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Share of each of ``boxes`` covered by box ``a``."""
    iw = np.clip(np.minimum(a[2], boxes[:, 2]) - np.maximum(a[0], boxes[:, 0]), 0, None)
    ih = np.clip(np.minimum(a[3], boxes[:, 3]) - np.maximum(a[1], boxes[:, 1]), 0, None)
    return iw * ih / np.maximum((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), 1e-9)


def paste_instances(image: UInt8[np.ndarray, "H W 3"], boxes: Float[np.ndarray, "n 4"],
                    class_ids: Int[np.ndarray, " n"], instances: list[Instance], rng: np.random.Generator,
                    cfg: PasteConfig = PasteConfig()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paste ``instances`` into ``image`` on the ground plane (module docstring).

    Returns the new frame and the labels: the existing ``boxes``/``class_ids`` followed by one box
    per pasted member. A grey frame (all channels equal) gets grey pastes. Instances that find no
    placement in ``cfg.tries`` draws are skipped.
    """
    out = np.array(image, np.uint8, copy=True)
    if out.ndim != 3 or out.shape[-1] != 3:
        raise ValueError(f"image must be (H, W, 3), got {out.shape}")
    h, w = out.shape[:2]
    grey = bool(np.all(out[..., 0] == out[..., 1]) and np.all(out[..., 1] == out[..., 2]))
    all_boxes = [np.asarray(boxes, np.float64).reshape(-1, 4)]
    all_cls = [np.asarray(class_ids, np.int32).reshape(-1)]
    y_h = cfg.horizon * h
    for inst in instances:
        r = h / inst.source_height  # focal length ratio of the two frames (same field of view)
        src = inst.bottom_row - cfg.horizon * inst.source_height
        if src <= 1:
            continue
        ph, pw = inst.alpha.shape
        for _ in range(cfg.tries):
            s = r * rng.uniform(1 / cfg.max_scale, cfg.max_scale)
            yb = y_h + s * src
            th, tw = round(ph * s), round(pw * s)
            if th < cfg.min_height or tw < 2 or tw >= w or yb > h or yb - th < 0:
                continue
            x0, y0 = int(rng.integers(0, w - tw + 1)), int(round(yb)) - th
            cand = np.array([x0, y0, x0 + tw, y0 + th], np.float64)
            existing = np.concatenate(all_boxes)
            if len(existing) and _cover(cand, existing).max() > cfg.max_cover:
                continue
            flip = bool(rng.random() < 0.5)
            rgb = cv2.resize(inst.rgb, (tw, th), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
            alpha = cv2.resize(inst.alpha, (tw, th), interpolation=cv2.INTER_LINEAR)
            if flip:
                rgb, alpha = rgb[:, ::-1], alpha[:, ::-1]
            if grey:
                rgb = np.repeat(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)[..., None], 3, -1)
            region = out[y0:y0 + th, x0:x0 + tw].astype(np.float32)
            a = alpha[..., None]
            out[y0:y0 + th, x0:x0 + tw] = np.clip(np.rint(a * rgb + (1 - a) * region), 0, 255).astype(np.uint8)
            kb = inst.boxes * [tw / pw, th / ph, tw / pw, th / ph]
            if flip:
                kb = np.stack([tw - kb[:, 2], kb[:, 1], tw - kb[:, 0], kb[:, 3]], 1)
            all_boxes.append(kb + [x0, y0, x0, y0])
            all_cls.append(inst.class_ids)
            break
    return out, np.concatenate(all_boxes), np.concatenate(all_cls)
