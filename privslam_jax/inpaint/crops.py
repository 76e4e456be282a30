"""Crop-and-paste geometry for inpainting each privacy region at the model's resolution.

Each object is inpainted in its own square crop (the mask's bounding box grown by ``pad``
of its larger side on every side, at least ``min_side`` px, shifted to lie inside the frame;
when the frame is too small the side shrinks to the frame, never below the mask's extent), resized to ``size × size``. Before resizing, the pixels of
the **union** of all privacy masks are set to zero, so no crop ever sees a hidden pixel; the
crop's hole is every model pixel the resampling lets a hidden pixel reach. The model's output is
resized back and pasted under the object's **own** mask only. Hence an object's result depends
on the other objects only where their masks fall inside its crop.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from jaxtyping import Float

__all__ = ["CropBox", "crop_box", "extract", "paste_back"]


@dataclasses.dataclass(frozen=True)
class CropBox:
    """Pixel rectangle ``[v0, v1) × [u0, u1)`` of a frame."""

    v0: int
    v1: int
    u0: int
    u1: int

    @property
    def height(self) -> int:
        return self.v1 - self.v0

    @property
    def width(self) -> int:
        return self.u1 - self.u0


def crop_box(mask: np.ndarray, pad: float = 0.5, min_side: int = 32) -> CropBox:
    """Square crop around the ``True`` pixels of ``mask (H, W)`` (see module docstring)."""
    if mask.ndim != 2 or not mask.any():
        raise ValueError("crop_box needs a non-empty (H, W) mask")
    h, w = mask.shape
    vs, us = np.nonzero(mask)
    v0, v1, u0, u1 = int(vs.min()), int(vs.max()) + 1, int(us.min()), int(us.max()) + 1
    side = max(v1 - v0, u1 - u0)
    side = max(int(np.ceil(side * (1 + 2 * pad))), min_side)

    common = min(side, h, w)  # stay square unless the frame is too small or the mask too long

    def place(lo: int, hi: int, n: int) -> tuple[int, int]:
        s = max(common, hi - lo)
        start = (lo + hi) // 2 - s // 2
        start = min(max(start, 0), n - s)
        return start, start + s

    cv0, cv1 = place(v0, v1, h)
    cu0, cu1 = place(u0, u1, w)
    return CropBox(cv0, cv1, cu0, cu1)


def _resize(x: np.ndarray, width: int, height: int) -> np.ndarray:
    shrink = width < x.shape[1] or height < x.shape[0]
    return cv2.resize(x, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def extract(
    image: Float[np.ndarray, "H W 3"], hidden: np.ndarray, box: CropBox, size: int
) -> tuple[Float[np.ndarray, "S S 3"], np.ndarray]:
    """``(rgb, hole)`` at ``size × size``: hidden pixels zeroed before resampling; ``hole``
    (bool) marks every model pixel any hidden pixel contributes to."""
    sl = (slice(box.v0, box.v1), slice(box.u0, box.u1))
    hid = hidden[sl].astype(np.float32)
    rgb = np.where(hidden[sl][..., None], np.float32(0), image[sl]).astype(np.float32)
    rgb_s = np.clip(_resize(rgb, size, size), 0.0, 1.0)  # float32 resampling can round to 1 + 1e-7
    hole_s = _resize(hid, size, size) > 0
    return np.where(hole_s[..., None], np.float32(0), rgb_s).astype(np.float32), hole_s


def paste_back(
    out_s: Float[np.ndarray, "S S 3"], box: CropBox
) -> Float[np.ndarray, "h w 3"]:
    """Resize the model output back to the crop's size (to be pasted under the object's mask)."""
    return _resize(out_s, box.width, box.height).astype(np.float32)
