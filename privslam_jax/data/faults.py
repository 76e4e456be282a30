"""Faults injected into a frame sequence, to test that SLAM survives them (issue 15's fault suite).

A :class:`Fault` damages a run of ``length`` frames starting at frame ``start``:

* photometric — ``black`` (all zero), ``white`` (saturated), ``blur`` (Gaussian, σ = ``strength``
  px), ``exposure`` (every pixel × ``strength``, clipped: an auto-exposure jump);
* temporal — ``duplicate`` (frame ``start`` repeated ``length`` more times: a stalled camera),
  ``drop`` (the frames are missing: a gap of ``length + 1`` frames' motion), ``swap`` (``length``
  consecutive pairs exchanged: frames delivered out of order).

:func:`inject_fault` applies one to a list of frames, which may be images (monocular) or tuples
whose first ``n_images`` entries are images (stereo pairs, or ``(image, depth)`` with
``n_images=1``: depth is left as it is); it returns the new list, the source index of each output
frame, and the output window ``[a, b)`` the fault touched.  :func:`recovery_delay` says how many
frames after the end of that window tracking was back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

__all__ = ["FAULT_KINDS", "Fault", "inject_fault", "recovery_delay"]

FAULT_KINDS = ("black", "white", "blur", "exposure", "duplicate", "drop", "swap")


@dataclasses.dataclass(frozen=True)
class Fault:
    """``length`` frames from ``start`` damaged by ``kind`` (one of :data:`FAULT_KINDS`)."""

    kind: str
    start: int
    length: int = 1
    strength: float = 0.0
    """σ in pixels for ``blur``, the gain for ``exposure``; unused otherwise."""

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"fault kind must be one of {FAULT_KINDS}, got {self.kind!r}")
        if self.start < 1 or self.length < 1:
            raise ValueError(f"a fault needs start >= 1 and length >= 1, got {self.start}, {self.length}")
        if self.kind == "blur" and not self.strength > 0:
            raise ValueError(f"blur needs sigma (strength) > 0, got {self.strength}")
        if self.kind == "exposure" and not (self.strength > 0 and np.isfinite(self.strength)):
            raise ValueError(f"exposure needs a finite gain (strength) > 0, got {self.strength}")


def _photometric(image: np.ndarray, fault: Fault) -> np.ndarray:
    top = 255.0 if image.dtype == np.uint8 else 1.0
    if fault.kind == "black":
        return np.zeros_like(image)
    if fault.kind == "white":
        return np.full_like(image, top)
    if fault.kind == "blur":
        return cv2.GaussianBlur(image, (0, 0), fault.strength)
    return np.clip(image.astype(np.float32) * fault.strength, 0.0, top).astype(image.dtype)


def inject_fault(frames: Sequence[Any], fault: Fault, n_images: int = 1) -> tuple[list[Any], np.ndarray, tuple[int, int]]:
    """``(frames with the fault, (M,) source frame index of each, (a, b) output window of the fault)``.

    The fault must end before the last frame (so that there is a frame to recover on).
    """
    n, s, k = len(frames), fault.start, fault.length
    end = s + (2 * k if fault.kind == "swap" else k)  # source frames touched: [s, end)
    if end > n - 1 and fault.kind != "duplicate" or fault.kind == "duplicate" and s > n - 2:
        raise ValueError(f"{fault} does not end before the last of the {n} frames")
    src = np.arange(n)
    if fault.kind == "duplicate":
        src = np.concatenate([src[: s + 1], np.full(k, s), src[s + 1:]])
        window = (s + 1, s + 1 + k)
    elif fault.kind == "drop":
        src = np.concatenate([src[:s], src[end:]])
        window = (s, s + 1)  # the first frame after the gap
    elif fault.kind == "swap":
        for i in range(s, end, 2):
            src[i], src[i + 1] = src[i + 1], src[i]
        window = (s, end)
    else:
        window = (s, end)
    out = []
    for j, i in enumerate(src):
        item = frames[int(i)]
        if fault.kind in ("black", "white", "blur", "exposure") and window[0] <= j < window[1]:
            if isinstance(item, tuple):
                item = tuple(_photometric(x, fault) if m < n_images else x for m, x in enumerate(item))
            else:
                item = _photometric(item, fault)
        out.append(item)
    return out, src, window


def recovery_delay(tracked: np.ndarray, window: tuple[int, int]) -> int | None:
    """Frames from the fault's last frame to the first tracked frame after it (1 = the next frame was
    tracked); ``None`` if tracking never came back."""
    after = np.flatnonzero(np.asarray(tracked, bool)[window[1]:])
    return int(after[0]) + 1 if len(after) else None
