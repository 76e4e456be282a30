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

* **Synthetic objects** (:func:`synthetic_instances`): the allowed real frames hold about five
  different people, so the bank also takes people, bicycles and motorcycles rendered by the
  synthetic world (:mod:`privslam_jax.data.synthetic`) at the real camera's size, cut by their
  exact instance masks and photometrically randomised
  (:func:`~privslam_jax.detect.domain_rand.randomize_photometric`). Pasted into real frames they
  teach the shape of a person against real clutter, which neither source gives alone (synthetic
  frames have no real clutter, real frames almost no people). ``PasteConfig.match_light`` scales
  each pasted patch towards the brightness of the frame region it covers, since renders are lit
  evenly and real streets are not.

Everything is numpy + OpenCV on ``uint8`` RGB frames with ``xyxy`` pixel boxes; randomness comes
from a ``numpy`` generator, so a training set is reproducible.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import cv2
import numpy as np
from jaxtyping import Float, Int, Real, UInt8

if TYPE_CHECKING:
    from privslam_jax.detect.domain_rand import DomainRandConfig

__all__ = ["Instance", "PasteConfig", "cut_instance", "object_groups", "paste_instances", "synthetic_instances"]


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
    horizon: float | None = None
    """The source frame's horizon row as a fraction of its height (``None``: ``PasteConfig.horizon``)."""


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
    match_light: float = 0.0
    """Strength in ``[0, 1]`` of the brightness match: the patch is multiplied by
    ``clip(m_bg / m_obj, 1/3, 3) ** (match_light · U(0.5, 1))``, with ``m_bg`` the mean of the frame
    region it covers and ``m_obj`` the alpha-weighted mean of the object (0 = paste as cut)."""


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
        src = inst.bottom_row - (cfg.horizon if inst.horizon is None else inst.horizon) * inst.source_height
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
            if cfg.match_light > 0:
                m_obj = float((a * rgb).sum() / max(3 * a.sum(), 1e-6))
                gain = np.clip(region.mean() / max(m_obj, 1.0), 1 / 3, 3) ** (cfg.match_light * rng.uniform(0.5, 1.0))
                rgb = np.clip(rgb * gain, 0, 255)
            out[y0:y0 + th, x0:x0 + tw] = np.clip(np.rint(a * rgb + (1 - a) * region), 0, 255).astype(np.uint8)
            kb = inst.boxes * [tw / pw, th / ph, tw / pw, th / ph]
            if flip:
                kb = np.stack([tw - kb[:, 2], kb[:, 1], tw - kb[:, 0], kb[:, 3]], 1)
            all_boxes.append(kb + [x0, y0, x0, y0])
            all_cls.append(inst.class_ids)
            break
    return out, np.concatenate(all_boxes), np.concatenate(all_cls)


def synthetic_instances(frame, rng: np.random.Generator, classes: tuple[int, ...] = (0, 1, 3),
                        min_height: int = 24, max_other: float = 0.05, feather: float = 0.7,
                        min_person_aspect: float = 2.0, photometric: "DomainRandConfig | None" = None,
                        textures: "list[np.ndarray] | None" = None, retexture: float = 0.0) -> list[Instance]:
    """Cut the people (and bicycles, motorcycles: ``classes``) of a rendered synthetic frame.

    ``frame`` is a :class:`~privslam_jax.data.synthetic.SynthFrame`. An object is cut when its box
    (tight around its visible pixels) is at least ``min_height`` px tall, does not touch the frame
    border and holds at most ``max_other`` of its pixels from other objects (a pasted object
    carries no piece of a neighbour without a label); a person's box must also be at least
    ``min_person_aspect`` times as tall as wide: a shorter one is a person hidden in part (behind a
    parked car), whose bottom edge is not where it stands, so the ground-plane placement of
    :func:`paste_instances` would float it. The matte is the object's instance mask
    feathered by a Gaussian of ``feather`` px; the patch is the rendered frame, randomised by
    :func:`~privslam_jax.detect.domain_rand.randomize_photometric` with ``photometric`` (a
    :class:`~privslam_jax.detect.domain_rand.DomainRandConfig`; ``None`` keeps the render). The
    world's camera is level at a fixed height, so the instance's ``bottom_row`` and
    ``source_height`` feed :func:`paste_instances`' ground-plane model as a real cut does.

    With probability ``retexture`` (and ``textures``, a list of real ``uint8`` RGB frames) the
    object keeps only its render's *shading* and takes a real frame's texture: with ``L`` the
    render's luminance and ``T`` a random patch of a random real frame of the object's size,
    ``rgb = (1 − m)·T·clip(L / L̄, 0.3, 2.5)^g + m·render``, ``L̄`` the mean over the object,
    ``g ~ U(0.5, 1)``, ``m ~ U(0, 0.4)``. The silhouette and the contrast between its parts (head,
    clothes, legs) stay; the flat render texture, which a detector learns to tell apart from real
    surfaces, goes (texture randomisation, Tobin et al., IROS 2017).
    """
    from privslam_jax.detect.domain_rand import randomize_photometric

    img = np.asarray(frame.image, np.float32)
    inst_ids = np.asarray(frame.instance_ids)
    if inst_ids.ndim != 2 or img.shape != (*inst_ids.shape, 3):
        raise ValueError(f"frame.image must be (H, W, 3) and frame.instance_ids (H, W), got {img.shape} and {inst_ids.shape}")
    n_boxes = len(np.asarray(frame.boxes).reshape(-1, 4))
    if not n_boxes == len(np.asarray(frame.class_ids)) == len(np.asarray(frame.instance_of_box)):
        raise ValueError("frame.boxes, frame.class_ids and frame.instance_of_box differ in length")
    if not 0.0 <= retexture <= 1.0:
        raise ValueError(f"retexture must be a probability in [0, 1], got {retexture}")
    for t in textures or ():
        if np.asarray(t).dtype != np.uint8 or np.ndim(t) != 3 or np.shape(t)[-1] != 3:
            raise ValueError(f"textures must be uint8 (H, W, 3) frames, got {np.asarray(t).dtype} {np.shape(t)}")
    h, w = inst_ids.shape
    horizon = (h - 1) / 2 / h  # the world's camera is level with its principal point at the centre
    out = []
    for box, c, iid in zip(np.asarray(frame.boxes).reshape(-1, 4), np.asarray(frame.class_ids),
                           np.asarray(frame.instance_of_box)):
        if int(c) not in classes:
            continue
        x1, y1, x2, y2 = (int(v) for v in np.round(box))
        if x1 <= 1 or y1 <= 1 or x2 >= w - 1 or y2 >= h - 1 or y2 - y1 < min_height or x2 - x1 < 4:
            continue
        if int(c) == 0 and y2 - y1 < min_person_aspect * (x2 - x1):
            continue
        ids = inst_ids[y1:y2, x1:x2]
        mine = ids == iid
        if ((ids > 0) & ~mine).mean() > max_other:
            continue
        m = mine.astype(np.float32)
        alpha = np.minimum(m, cv2.GaussianBlur(m, (0, 0), feather)) if feather > 0 else m
        patch = img[y1:y2, x1:x2]
        if textures and rng.random() < retexture:
            patch = _retexture(patch, m, textures[int(rng.integers(len(textures)))], rng)
        if photometric is not None:
            patch = randomize_photometric(patch, rng, photometric)
        rgb = np.clip(np.rint(patch * 255), 0, 255).astype(np.uint8)
        out.append(Instance(rgb=rgb, alpha=alpha, boxes=np.array([[0.0, 0.0, x2 - x1, y2 - y1]]),
                            class_ids=np.array([int(c)], np.int32), bottom_row=float(y2), source_height=h,
                            horizon=horizon))
    return out


def _retexture(patch: np.ndarray, mask: np.ndarray, texture: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``patch`` (float RGB in [0, 1]) with a real texture under its shading (:func:`synthetic_instances`)."""
    h, w = mask.shape
    th, tw = texture.shape[:2]
    if th < h or tw < w:
        texture = cv2.resize(texture, (max(tw, w), max(th, h)), interpolation=cv2.INTER_LINEAR)
        th, tw = texture.shape[:2]
    y0, x0 = int(rng.integers(0, th - h + 1)), int(rng.integers(0, tw - w + 1))
    t = texture[y0:y0 + h, x0:x0 + w].astype(np.float32) / 255
    lum = patch @ np.array([0.299, 0.587, 0.114], np.float32)
    mean = float((lum * mask).sum() / max(mask.sum(), 1.0))
    shade = np.clip(lum / max(mean, 1e-3), 0.3, 2.5) ** np.float32(rng.uniform(0.5, 1.0))
    m = np.float32(rng.uniform(0.0, 0.4))
    return np.clip((1 - m) * t * shade[..., None] + m * patch, 0, 1).astype(np.float32)
