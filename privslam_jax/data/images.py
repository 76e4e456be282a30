"""Image files → float32 arrays (the project's image convention: HWC RGB in [0, 1]).

OpenCV decodes (PNG 8/16-bit, JPEG, …); a file that is missing raises ``FileNotFoundError`` and
one that OpenCV cannot decode (corrupt, truncated, not an image) a ``ValueError``, both naming the
file.  Writing goes through OpenCV too; 16-bit single-channel PNGs hold integer maps (instance
ids, depth).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Float, Shaped

__all__ = ["read_image", "read_raw", "write_rgb", "write_uint16", "check_unit_image"]


def read_raw(path: str | os.PathLike) -> np.ndarray:
    """Decode an image file as stored (``cv2.IMREAD_UNCHANGED``: dtype and channels as in the file, BGR order)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ValueError(f"cannot decode image (corrupt, truncated or not an image): {path}")
    return img


def check_unit_image(image: np.ndarray, what: str = "image") -> np.ndarray:
    """``image`` as float32 after checking the convention: floating point, finite, within ``[0, 1]``.

    Raises ``ValueError`` naming ``what`` otherwise: a privacy stage that silently processes
    0–255 floats, NaN or negative pixels finds nothing and hides nothing.
    """
    img = np.asarray(image)
    if not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"{what} must be float in [0, 1], got dtype {img.dtype} (divide uint8 images by 255)")
    if img.size and not np.isfinite(img).all():
        raise ValueError(f"{what} has NaN or infinite pixels")
    if img.size and (img.min() < 0 or img.max() > 1):
        hint = " (it looks like 0-255 values: divide by 255)" if img.max() > 1.5 else ""
        raise ValueError(f"{what} must lie in [0, 1], got values in [{img.min():.3g}, {img.max():.3g}]{hint}")
    return img.astype(np.float32, copy=False)


def read_image(path: str | os.PathLike, grey: bool = False) -> Float[np.ndarray, "H W *C"]:
    """Read an image as float32 in ``[0, 1]``: ``(H, W, 3)`` RGB, or ``(H, W)`` when ``grey``.

    Grey files are repeated to three channels for RGB; colour files are converted to grey with
    OpenCV's BT.601 weights for ``grey``.  Alpha is dropped; 16-bit files are divided by 65535.
    """
    img = read_raw(path)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"unsupported image dtype {img.dtype} in {path}")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if grey:
        out = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim == 2:
        out = np.repeat(img[:, :, None], 3, axis=2)
    else:
        out = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return (out.astype(np.float32) / np.float32(scale)).astype(np.float32)


def write_rgb(path: str | os.PathLike, image: Float[np.ndarray, "H W 3"]) -> None:
    """Write a float RGB image in ``[0, 1]`` as an 8-bit PNG (rounded, clipped)."""
    img = np.clip(np.rint(np.asarray(image, np.float32) * 255.0), 0, 255).astype(np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"write_rgb expects an (H, W, 3) image, got {img.shape}")
    _write(path, cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def write_uint16(path: str | os.PathLike, values: Shaped[np.ndarray, "H W"]) -> None:
    """Write a 2-D integer map (``0 … 65535``) as a 16-bit single-channel PNG."""
    v = np.asarray(values)
    if v.ndim != 2:
        raise ValueError(f"write_uint16 expects an (H, W) map, got {v.shape}")
    if v.size and (v.min() < 0 or v.max() > 65535):
        raise ValueError(f"values out of the uint16 range for {path}")
    _write(path, v.astype(np.uint16))


def _write(path: str | os.PathLike, img: np.ndarray) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise ValueError(f"OpenCV could not write {path}")
