"""Recall-first privacy detection over a sequence: temporal propagation and test-time augmentation.

A per-frame detector at one threshold misses objects that it finds one frame earlier or later
(motion blur, partial occlusion, a pose the network finds hard). For privacy a miss is a leak, so
the filter should use every frame's evidence. :func:`propagate_detections` does that in the
manner of ByteTrack (Zhang et al., ECCV 2022: associate high-score boxes first, then recover
low-score boxes that continue a track):

1. **Motion.** Dense optical flow between consecutive frames (Farnebäck 2003, OpenCV
   ``calcOpticalFlowFarneback`` on grey images at half resolution). A box moves by the median
   flow of its central region, and scales by the least-squares divergence
   ``s = Σ (d·f) / Σ ‖d‖²`` of that flow about the box centre (``d`` = pixel offset from the
   centre, ``f`` = flow minus its median): ``box ← centre + median flow ± (1 + s)·half size``.
2. **Propagation.** Every *high* detection (score ≥ ``high_conf``) of frame ``t`` is carried
   frame by frame to ``t ± 1 … t ± window``.
3. **Association** in each target frame, nearest source frames first: a propagated box that
   overlaps (IoU ≥ ``match_iou``) a high detection is already covered; one that overlaps a *low*
   detection (``low_conf ≤`` score ``< high_conf``) promotes that detection (ByteTrack's second
   stage: the detector's box, localised in this frame); otherwise the propagated box itself is
   added — the detector missed the object here.

:func:`detect_tta` is test-time augmentation: the frame at several letterbox sizes and
left-right flipped, boxes mapped back and merged by class-aware NMS (as ultralytics
``augment=True``, which uses scales 1, 0.83, 0.67 and a flip; here larger scales are offered too,
since small, distant people are what a privacy filter misses).

Every output box carries its origin (:data:`DETECTED`, :data:`PROMOTED`, :data:`PROPAGATED`) so
that the report can say how many masks came from each source.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import jax.numpy as jnp
import numpy as np

from privslam_jax.detect.decode import box_iou, nms
from privslam_jax.types import Detections

__all__ = ["PropagationConfig", "propagate_detections", "box_flow", "dense_flow", "flow_grey", "detect_tta", "detect_sequence",
           "consecutive_runs", "DETECTED", "PROMOTED", "PROPAGATED"]

DETECTED, PROMOTED, PROPAGATED = 0, 1, 2
"""Origin of a box: a high-score detection, a low-score detection confirmed by a track, a propagated box."""


@dataclasses.dataclass(frozen=True)
class PropagationConfig:
    """Settings of :func:`propagate_detections`."""

    window: int = 3
    """Frames ``k``: a high detection of frame ``t`` may mask its object in ``t−k … t+k``."""
    high_conf: float = 0.4
    """Score of a detection trusted on its own (the filter's threshold)."""
    low_conf: float = 0.1
    """Lowest score of a detection that a propagated box can promote (ByteTrack's low-score stage)."""
    match_iou: float = 0.3
    """IoU at which a propagated box and a detection are the same object."""
    flow_scale: float = 0.5
    """Resolution of the optical flow relative to the frames."""
    min_box: float = 4.0
    """Propagated boxes smaller than this (pixels, either side) or fully outside the frame are dropped."""

    def __post_init__(self) -> None:
        if self.window < 0:
            raise ValueError(f"window must be >= 0, got {self.window}")
        if not 0 <= self.low_conf <= self.high_conf <= 1:
            raise ValueError(f"need 0 <= low_conf <= high_conf <= 1, got {self.low_conf}, {self.high_conf}")
        if not 0 < self.flow_scale <= 1:
            raise ValueError(f"flow_scale must lie in (0, 1], got {self.flow_scale}")


def flow_grey(image: np.ndarray, scale: float) -> np.ndarray:
    """The uint8 grey image, resized by ``scale``, that :func:`dense_flow` takes (uint8 / uint16 / float ``[0, 1]`` input)."""
    from privslam_jax.data.images import as_unit_image, like_input

    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = like_input(as_unit_image(img, "flow image"), np.zeros(0, np.uint8))
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.shape[-1] == 3 else img[..., 0]
    if scale != 1:
        img = cv2.resize(img, (round(img.shape[1] * scale), round(img.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    return img


def dense_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dense flow ``(h, w, 2)`` from grey ``a`` to grey ``b`` (pixels of ``a``'s resolution)."""
    return cv2.calcOpticalFlowFarneback(a, b, None, pyr_scale=0.5, levels=4, winsize=21, iterations=3,
                                        poly_n=7, poly_sigma=1.5, flags=0)


def box_flow(box: np.ndarray, flow: np.ndarray, scale: float) -> np.ndarray:
    """Move one ``xyxy`` box (frame pixels) by a dense ``flow`` computed at ``scale`` × the frame size.

    Translation = median flow over the central 60 % of the box; scale change = least-squares
    divergence of the flow about the box centre (module docstring), clipped to ±30 % per frame.
    """
    h, w = flow.shape[:2]
    x1, y1, x2, y2 = np.asarray(box, np.float64) * scale
    cx, cy, hw, hh = (x1 + x2) / 2, (y1 + y2) / 2, (x2 - x1) / 2, (y2 - y1) / 2
    u0, u1 = int(np.clip(np.floor(cx - 0.6 * hw), 0, w - 1)), int(np.clip(np.ceil(cx + 0.6 * hw), 1, w))
    v0, v1 = int(np.clip(np.floor(cy - 0.6 * hh), 0, h - 1)), int(np.clip(np.ceil(cy + 0.6 * hh), 1, h))
    if u1 <= u0 or v1 <= v0:
        return np.asarray(box, np.float64)
    f = flow[v0:v1, u0:u1].reshape(-1, 2).astype(np.float64)
    vv, uu = np.mgrid[v0:v1, u0:u1]
    d = np.stack([uu.ravel() - cx, vv.ravel() - cy], axis=1)
    med = np.median(f, axis=0)
    den = float((d * d).sum())
    s = float(np.clip(((f - med) * d).sum() / den, -0.3, 0.3)) if den > 0 else 0.0
    ncx, ncy = cx + med[0], cy + med[1]
    out = np.array([ncx - (1 + s) * hw, ncy - (1 + s) * hh, ncx + (1 + s) * hw, ncy + (1 + s) * hh])
    return out / scale


def _as_numpy(d: Detections) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    boxes = np.asarray(d.boxes, np.float64).reshape(-1, 4)
    keep = np.ones(len(boxes), bool) if d.valid is None else np.asarray(d.valid, bool)
    return (boxes[keep], np.asarray(d.scores, np.float64).reshape(-1)[keep],
            np.asarray(d.class_ids, np.int64).reshape(-1)[keep])


def propagate_detections(images: Sequence[np.ndarray], detections: Sequence[Detections],
                         config: PropagationConfig = PropagationConfig()) -> tuple[list[Detections], list[np.ndarray]]:
    """Recall-first detections of a sequence of consecutive frames (module docstring).

    ``detections[t]`` are the detector's boxes of ``images[t]`` down to at least ``config.low_conf``
    (run the detector with ``conf = low_conf``). Returns per frame the kept detections and an
    ``(N,)`` int array of their origins (:data:`DETECTED`, :data:`PROMOTED`, :data:`PROPAGATED`);
    a propagated box keeps its source's class and score.
    """
    n = len(images)
    if len(detections) != n:
        raise ValueError(f"{n} images but {len(detections)} detection sets")
    dets = [_as_numpy(d) for d in detections]
    cfg = config
    shapes = {np.asarray(im).shape[:2] for im in images}
    if len(shapes) > 1:
        raise ValueError(f"all frames of a sequence must have one size, got {sorted(shapes)}")
    greys = [flow_grey(im, cfg.flow_scale) for im in images]
    fwd = [dense_flow(greys[t], greys[t + 1]) for t in range(n - 1)] if cfg.window else []
    bwd = [dense_flow(greys[t + 1], greys[t]) for t in range(n - 1)] if cfg.window else []
    h0, w0 = next(iter(shapes)) if shapes else (0, 0)

    # propagated[j]: (distance, box, score, class) carried from high detections of other frames
    propagated: list[list[tuple[int, np.ndarray, float, int]]] = [[] for _ in range(n)]
    for t, (boxes, scores, cls) in enumerate(dets):
        for b, s, c in zip(boxes, scores, cls):
            if s < cfg.high_conf:
                continue
            for step, flows in ((1, fwd), (-1, bwd)):
                cur = b
                for dist in range(1, cfg.window + 1):
                    j = t + step * dist
                    if not 0 <= j < n:
                        break
                    cur = box_flow(cur, flows[j - 1 if step == 1 else j], cfg.flow_scale)
                    clipped = np.array([max(cur[0], 0), max(cur[1], 0), min(cur[2], w0), min(cur[3], h0)])
                    if clipped[2] - clipped[0] < cfg.min_box or clipped[3] - clipped[1] < cfg.min_box:
                        break
                    propagated[j].append((dist, clipped, float(s), int(c)))

    out, origins = [], []
    for j, (boxes, scores, cls) in enumerate(dets):
        high = scores >= cfg.high_conf
        low = (scores >= cfg.low_conf) & ~high
        keep_b, keep_s, keep_c = list(boxes[high]), list(scores[high]), list(cls[high])
        origin = [DETECTED] * int(high.sum())
        promoted = np.zeros(len(boxes), bool)
        for dist, pb, ps, pc in sorted(propagated[j], key=lambda x: (x[0], -x[2])):
            covered = np.asarray(keep_b).reshape(-1, 4)
            if len(covered) and box_iou(pb[None], covered)[0].max() >= cfg.match_iou:
                continue
            cand = np.where(low & ~promoted)[0]
            if len(cand):
                ious = box_iou(pb[None], boxes[cand])[0]
                if ious.max() >= cfg.match_iou:
                    k = cand[int(ious.argmax())]
                    promoted[k] = True
                    keep_b.append(boxes[k]), keep_s.append(scores[k]), keep_c.append(cls[k])
                    origin.append(PROMOTED)
                    continue
            keep_b.append(pb), keep_s.append(ps), keep_c.append(pc)
            origin.append(PROPAGATED)
        out.append(Detections(boxes=jnp.asarray(np.asarray(keep_b, np.float32).reshape(-1, 4)),
                              scores=jnp.asarray(np.asarray(keep_s, np.float32).reshape(-1)),
                              class_ids=jnp.asarray(np.asarray(keep_c, np.int32).reshape(-1)), valid=None))
        origins.append(np.asarray(origin, np.int64))
    return out, origins


def detect_tta(detector, images: Sequence[np.ndarray], scales: Sequence[float] = (1.0, 1.5),
               flip: bool = True, iou: float = 0.6) -> list[Detections]:
    """Detections merged over letterbox sizes ``round(imgsz·s / 32)·32`` and a left-right flip.

    ``detector`` is a :class:`~privslam_jax.detect.predict.Detector`; its threshold, classes and
    NMS settings apply to each pass; the union is reduced by class-aware NMS at ``iou``.
    """
    if not scales or any(s <= 0 for s in scales):
        raise ValueError(f"scales must be positive, got {scales}")
    images = list(images)
    passes: list[list[Detections]] = []
    for s in scales:
        size = max(32, int(round(detector.config.imgsz * s / 32)) * 32)
        det = detector.with_config(dataclasses.replace(detector.config, imgsz=size))
        passes.append(det.detect(images))
        if flip:
            flipped = det.detect([np.ascontiguousarray(np.asarray(im)[:, ::-1]) for im in images])
            unflipped = []
            for im, d in zip(images, flipped):
                b = np.asarray(d.boxes, np.float32).reshape(-1, 4).copy()
                w = np.asarray(im).shape[1]
                b[:, [0, 2]] = w - b[:, [2, 0]]
                unflipped.append(Detections(boxes=jnp.asarray(b), scores=d.scores, class_ids=d.class_ids))
            passes.append(unflipped)
    out = []
    for i in range(len(images)):
        b = np.concatenate([np.asarray(p[i].boxes, np.float32).reshape(-1, 4) for p in passes])
        s = np.concatenate([np.asarray(p[i].scores, np.float32).reshape(-1) for p in passes])
        c = np.concatenate([np.asarray(p[i].class_ids, np.int32).reshape(-1) for p in passes])
        offset = float(np.abs(b).max()) + 1 if len(b) else 0.0  # class-aware: classes never overlap
        keep = nms(b + c[:, None].astype(np.float32) * offset, s, iou) if len(b) else np.zeros(0, np.int64)
        keep = np.asarray(keep, np.int64)
        out.append(Detections(boxes=jnp.asarray(b[keep]), scores=jnp.asarray(s[keep]), class_ids=jnp.asarray(c[keep])))
    return out


def consecutive_runs(frame_numbers: Sequence[int]) -> list[tuple[int, int]]:
    """``[start, stop)`` index ranges of frames sampled at the sequence's step, within which
    propagation may carry boxes.

    The step is the smallest increase between neighbouring frame numbers; a run ends wherever the
    numbers jump by more (a dropped frame, another drive in the same folder) or do not increase.
    So every frame of ``0, 1, 2, …`` is one run, and so is a sequence kept at every third frame
    (``0, 3, 6, …``: flow still follows the objects over that step), while ``0 … 39, 220 … 259``
    is two.
    """
    ids = [int(x) for x in frame_numbers]
    if not ids:
        return []
    steps = [b - a for a, b in zip(ids, ids[1:])]
    step = min((d for d in steps if d > 0), default=1)
    cuts = [0] + [i + 1 for i, d in enumerate(steps) if d != step] + [len(ids)]
    return list(zip(cuts[:-1], cuts[1:]))


def detect_sequence(detector, images: Sequence[np.ndarray], propagation: PropagationConfig | None = None,
                    tta_scales: Sequence[float] | None = None) -> tuple[list[Detections], list[np.ndarray]]:
    """Privacy detections of consecutive frames: per-frame detection, optional TTA, optional propagation.

    Without ``propagation`` the detector's own threshold applies and every box is
    :data:`DETECTED`. With it, the detector runs at ``propagation.low_conf`` and
    :func:`propagate_detections` keeps what its rules keep. ``tta_scales`` switches on
    :func:`detect_tta` (with the flip) at those scales.
    """
    images = list(images)
    if propagation is not None:
        detector = detector.with_config(dataclasses.replace(detector.config, conf=propagation.low_conf))
    dets = detect_tta(detector, images, tta_scales) if tta_scales else detector.detect(images)
    if propagation is None:
        return dets, [np.full(len(d), DETECTED, np.int64) for d in dets]
    return propagate_detections(images, dets, propagation)
