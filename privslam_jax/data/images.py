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

from privslam_jax.data.files import write_atomic

__all__ = ["read_image", "read_raw", "read_rgb8", "write_rgb", "write_uint16", "write_image_file", "check_unit_image",
           "as_unit_image", "like_input"]


def _decode(path: str | os.PathLike, flag: int) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    img = cv2.imread(str(path), flag)
    if img is None or img.size == 0:
        raise ValueError(f"cannot decode image (corrupt, truncated or not an image): {path}")
    return img


def read_raw(path: str | os.PathLike) -> np.ndarray:
    """Decode an image file as stored (``cv2.IMREAD_UNCHANGED``: dtype and channels as in the file, BGR order)."""
    return _decode(path, cv2.IMREAD_UNCHANGED)


def read_rgb8(path: str | os.PathLike) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB as ultralytics reads images (``cv2.imread`` colour, grey repeated)."""
    return cv2.cvtColor(_decode(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


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


def as_unit_image(image: np.ndarray, what: str = "image") -> np.ndarray:
    """Any image the library accepts, as float32 in ``[0, 1]``.

    ``uint8`` is read as 0–255 and ``uint16`` as 0–65535 (divided by 255 or 65535, as
    :func:`read_image` does for files); floating point must already lie in ``[0, 1]`` and be
    finite (:func:`check_unit_image`). Anything else (signed integers, bool, objects) is refused
    with a ``ValueError`` naming ``what``: 0–255 floats, NaN or negative pixels would otherwise be
    processed silently wrong.
    """
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / np.float32(255.0)
    if img.dtype == np.uint16:
        return img.astype(np.float32) / np.float32(65535.0)
    if not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"{what} must be uint8 (0-255), uint16 (0-65535) or float in [0, 1], got dtype {img.dtype}")
    return check_unit_image(img, what)


def like_input(result: np.ndarray, original: np.ndarray) -> np.ndarray:
    """``result`` (float in ``[0, 1]``) in the dtype of the caller's ``original`` image.

    Integer inputs get integer outputs on the same scale (rounded, clipped); float inputs get
    float32.
    """
    dtype = np.asarray(original).dtype
    if dtype in (np.uint8, np.uint16):
        top = 255.0 if dtype == np.uint8 else 65535.0
        # float32 arithmetic, as every 8-bit writer here always did (float64 rounds some x.5 the other way)
        return np.clip(np.rint(np.asarray(result, np.float32) * np.float32(top)), 0, top).astype(dtype)
    return np.asarray(result, np.float32)


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


def write_rgb(path: str | os.PathLike, image: Shaped[np.ndarray, "H W 3"]) -> None:
    """Write an RGB image (float in ``[0, 1]`` or uint8, :func:`as_unit_image`) as an 8-bit PNG (rounded)."""
    img = like_input(as_unit_image(image, f"image for {path}"), np.zeros(0, np.uint8))
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


def write_image_file(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an OpenCV-layout array (BGR or single channel; the suffix picks the format) atomically.

    The file is encoded in memory, written to a temporary name beside ``path`` and renamed over
    it, so a reader sees the old file or the whole new one, never a part. Any failure (encoder
    refusal, full disk, a folder in the way) raises ``OSError`` naming ``path``: a lost frame
    must never look like a shorter sequence.
    """
    path = Path(path)
    ok, buf = cv2.imencode(path.suffix or ".png", img)
    if not ok:
        raise OSError(f"OpenCV could not encode {path}")
    write_atomic(path, buf.tobytes())


_write = write_image_file
