"""Image files → float32 arrays (the project's image convention: HWC RGB in [0, 1]).

OpenCV decodes PNG (8/16-bit), JPEG, BMP, TIFF, WebP and PNM files; a file that is missing raises
``FileNotFoundError`` and one that cannot be used (corrupt, truncated, not an image, another
format, a decompression bomb) an :class:`~privslam_jax.errors.InputError` (a ``ValueError``), both
naming the file.  Writing goes through OpenCV too; 16-bit single-channel PNGs hold integer maps
(instance ids, depth).

Decompression bombs are refused before decoding, from the width and height in the file's header
(:func:`image_header`):

* every image: at most :data:`MAX_PIXELS` (2^28) pixels;
* PNG: its uncompressed scanlines (``height × (1 + ⌈width × channels × bit depth / 8⌉)`` bytes) at
  most :data:`MAX_EXPANSION` (1100) × the file size — deflate cannot expand more than 1032:1, so
  no valid PNG is refused;
* JPEG, BMP, TIFF, WebP, PNM: ``3 × width × height`` at most ``1100 × file size + 1 MiB``
  (baseline JPEG, uncompressed and RLE files never expand that much; extreme progressive-JPEG,
  WebP or LZW-TIFF compression, e.g. a large uniform frame, is refused).

So a decoded image never has more than 2^28 pixels, nor more than ``8 × 1100`` pixels per byte of
file (a 1-bit PNG) — at most 12 bytes per pixel once :func:`read_image` made it float RGB.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Float, Shaped

from privslam_jax.data.files import write_atomic
from privslam_jax.errors import input_error

__all__ = ["grey_as_read", "read_image", "read_raw", "read_rgb8", "write_rgb", "write_uint16", "write_image_file", "check_unit_image",
           "as_unit_image", "like_input", "image_header", "MAX_PIXELS", "MAX_EXPANSION"]

MAX_PIXELS = 1 << 28
"""Largest image decoded (width × height)."""
MAX_EXPANSION = 1100
"""Largest accepted ratio of decoded bytes to file bytes (deflate's own limit is 1032:1)."""
_SLACK = 1 << 20
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_FORMATS = "PNG, JPEG, BMP, TIFF, WebP or PNM"


class _Unreadable(Exception):
    """The header cannot be understood (turned into an InputError naming the file)."""


def _png_header(head: bytes) -> tuple[int, int, int]:
    if len(head) < 29 or head[12:16] != b"IHDR" or struct.unpack(">I", head[8:12])[0] != 13:
        raise _Unreadable("PNG without an IHDR chunk")
    w, h, depth, colour = struct.unpack(">IIBB", head[16:26])
    if colour not in _PNG_CHANNELS or depth not in (1, 2, 4, 8, 16):
        raise _Unreadable(f"PNG with bit depth {depth} and colour type {colour}")
    raw = h * (1 + (w * _PNG_CHANNELS[colour] * depth + 7) // 8)
    return w, h, raw


def _jpeg_header(f) -> tuple[int, int]:
    pos = 2
    for _ in range(1 << 16):
        f.seek(pos)
        b = f.read(9)
        if len(b) < 2 or b[0] != 0xFF:
            break
        marker = b[1]
        if marker == 0xFF:  # fill byte
            pos += 1
        elif marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:  # markers without a segment
            pos += 2
        elif marker in (0xD9, 0xDA) or len(b) < 4:  # end of image or a scan before any frame header
            break
        elif marker in _JPEG_SOF:
            if len(b) < 9:
                break
            h, w = struct.unpack(">HH", b[5:9])
            return w, h
        else:
            length = struct.unpack(">H", b[2:4])[0]
            if length < 2:
                break
            pos += 2 + length
    raise _Unreadable("JPEG without a frame header")


def _tiff_header(f, head: bytes) -> tuple[int, int]:
    end = "<" if head[:2] == b"II" else ">"
    f.seek(struct.unpack(end + "I", head[4:8])[0])
    count = f.read(2)
    if len(count) < 2:
        raise _Unreadable("TIFF whose first directory lies outside the file")
    n = struct.unpack(end + "H", count)[0]
    entries = f.read(12 * n)
    dims: dict[int, int] = {}
    for k in range(len(entries) // 12):
        tag, typ = struct.unpack(end + "HH", entries[12 * k:12 * k + 4])
        if tag in (256, 257) and typ in (3, 4):
            value = entries[12 * k + 8:12 * k + 12]
            dims[tag] = struct.unpack(end + "H", value[:2])[0] if typ == 3 else struct.unpack(end + "I", value)[0]
    if 256 not in dims or 257 not in dims:
        raise _Unreadable("TIFF without ImageWidth/ImageLength")
    return dims[256], dims[257]


def _webp_header(head: bytes) -> tuple[int, int]:
    kind, data = head[12:16], head[20:30]
    if kind == b"VP8 " and len(data) >= 10 and data[3:6] == b"\x9d\x01\x2a":
        w, h = struct.unpack("<HH", data[6:10])
        return w & 0x3FFF, h & 0x3FFF
    if kind == b"VP8L" and len(data) >= 5 and data[0] == 0x2F:
        bits = int.from_bytes(data[1:5], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8X" and len(data) >= 10:
        return int.from_bytes(data[4:7], "little") + 1, int.from_bytes(data[7:10], "little") + 1
    raise _Unreadable("WebP without a VP8/VP8L/VP8X header")


def _pnm_header(f, head: bytes) -> tuple[int, int]:
    f.seek(0)
    text = f.read(1 << 16)
    if head[1:2] == b"7":  # PAM: "WIDTH w" / "HEIGHT h" lines up to ENDHDR
        fields = dict(line.split()[:2] for line in text.split(b"\n")[1:64] if len(line.split()) >= 2)
        tokens = [fields.get(b"WIDTH", b""), fields.get(b"HEIGHT", b"")]
    else:  # P1-P6: magic, width, height separated by whitespace and #-comments
        tokens = []
        for line in text[2:].split(b"\n")[:256]:
            tokens += line.split(b"#", 1)[0].split()
            if len(tokens) >= 2:
                break
    if len(tokens) < 2 or not all(t.isdigit() and len(t) < 12 for t in tokens[:2]):
        raise _Unreadable("PNM without a width and height")
    return int(tokens[0]), int(tokens[1])


def image_header(path: str | os.PathLike) -> tuple[str, int, int]:
    """``(format, width, height)`` read from an image file's header, without decoding it.

    Refuses (:class:`~privslam_jax.errors.InputError` naming the file) a file that is not a PNG,
    JPEG, BMP, TIFF, WebP or PNM image, a header that cannot be read, and a decompression bomb
    (see the module docstring for the bounds).
    """
    path = Path(path)
    size = path.stat().st_size
    try:
        with open(path, "rb") as f:
            head = f.read(32)
            if head.startswith(b"\x89PNG\r\n\x1a\n"):
                fmt, (w, h, raw) = "PNG", _png_header(head)
            else:
                if head.startswith(b"\xff\xd8"):
                    fmt, (w, h) = "JPEG", _jpeg_header(f)
                elif head.startswith(b"BM") and len(head) >= 26:
                    dib = struct.unpack("<I", head[14:18])[0]
                    w, h = struct.unpack("<HH", head[18:22]) if dib == 12 else struct.unpack("<ii", head[18:26])
                    fmt, w, h = "BMP", abs(w), abs(h)
                elif head[:4] in (b"II*\0", b"MM\0*") and len(head) >= 8:
                    fmt, (w, h) = "TIFF", _tiff_header(f, head)
                elif head[:4] == b"RIFF" and head[8:12] == b"WEBP":
                    fmt, (w, h) = "WebP", _webp_header(head)
                elif len(head) >= 3 and head[:1] == b"P" and head[1:2] in b"1234567" and head[2:3].isspace():
                    fmt, (w, h) = "PNM", _pnm_header(f, head)
                else:
                    raise input_error(path, f"not a {_FORMATS} image (unknown or unsupported format)")
                raw = 3 * w * h
    except _Unreadable as err:
        raise input_error(path, f"cannot decode image: {err} (corrupt, truncated or not an image)") from None
    except struct.error as err:
        raise input_error(path, "cannot decode image: truncated header", err) from err
    if w * h > MAX_PIXELS:
        raise input_error(path, f"{fmt} image of {w}x{h} pixels is larger than the {MAX_PIXELS} pixels this "
                                "reader decodes (corrupt or a decompression bomb)")
    limit = MAX_EXPANSION * size + (0 if fmt == "PNG" else _SLACK)
    if raw > limit:
        raise input_error(path, f"{fmt} image claims {w}x{h} pixels ({raw} bytes decoded) in a file of {size} bytes, "
                                f"more than {MAX_EXPANSION} times its size (corrupt or a decompression bomb)")
    return fmt, w, h


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


def _decode(path: str | os.PathLike, flag: int) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    image_header(path)
    try:
        img = cv2.imread(str(path), flag)
    except cv2.error as err:
        raise input_error(path, f"cannot decode image (corrupt, truncated or not an image): {_one_line(err)}") from err
    if img is None or img.size == 0:
        raise input_error(path, "cannot decode image (corrupt, truncated or not an image)")
    return img


def read_raw(path: str | os.PathLike) -> np.ndarray:
    """Decode an image file as stored (``cv2.IMREAD_UNCHANGED``: dtype and channels as in the file, BGR order)."""
    return _decode(path, cv2.IMREAD_UNCHANGED)


def read_rgb8(path: str | os.PathLike) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB as ultralytics reads images (``cv2.imread`` colour, grey repeated)."""
    img = _decode(path, cv2.IMREAD_COLOR)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise input_error(path, f"decoded to an unexpected {img.dtype} array of shape {img.shape}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


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
        raise input_error(path, f"unsupported image dtype {img.dtype} (8- or 16-bit images only)")
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise input_error(path, f"unsupported image layout {img.shape} (grey, RGB or RGBA)")
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


def grey_as_read(image: Shaped[np.ndarray, "H W *C"]) -> Float[np.ndarray, "H W"]:
    """An 8-bit frame (``(H, W, 3)`` RGB or ``(H, W)`` grey) as :func:`read_image` with ``grey=True``
    reads it back from the PNG it is written to: OpenCV's BGR → grey, float32 / 255."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"grey_as_read expects an (H, W, 3) or (H, W) uint8 image, got {img.dtype} {img.shape}")
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[..., ::-1]), cv2.COLOR_BGR2GRAY)
    return img.astype(np.float32) / np.float32(255.0)


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
