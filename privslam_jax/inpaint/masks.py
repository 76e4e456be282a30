"""Privacy masks and leak-free edge maps (host side, numpy + OpenCV).

Masks are boolean ``(H, W)`` arrays, ``True`` = hidden (privacy object). Images are float32
``(H, W, 3)`` RGB in [0, 1].

**Departure from the source paper's Algorithm 1.** The paper (like EdgeConnect's data loader)
runs Canny on the *original* grey image and masks the edge map afterwards. Gaussian smoothing
(σ = 2, support ±3σ), the Sobel step and Canny's hysteresis reach across the mask border, so
edges just outside the mask depend on the hidden object's pixels. Here the hidden pixels are
replaced *before* any filtering by a fill computed from the outside pixels only (zero, then
OpenCV Telea inpainting), so every output is a function of the outside pixels and the mask
alone — bit-identical whatever the hidden pixels are (tested with random fills). Edges the fill
may create inside the mask and in a border band of width ``band`` (default 3σ + 2 = 8 px, the
smoothing + Sobel + non-maximum-suppression support) are erased; the edge generator is then
asked to draw the edges over the mask grown by that band.

Canny: grey = skimage ``rgb2gray`` weights (0.2125, 0.7154, 0.0721), OpenCV ``GaussianBlur``
with σ = 2 (kernel 2·⌈3σ⌉+1 = 13, reflect-101 border), 3×3 Sobel, L2 magnitude, hysteresis
thresholds 0.1 / 0.2 of the Sobel magnitude of a [0, 1] image — the defaults of
``skimage.feature.canny`` that EdgeConnect calls (``canny(gray, sigma=2)``).
"""

from __future__ import annotations

import cv2
import numpy as np
from jaxtyping import Bool, Float, Shaped

__all__ = [
    "GREY_WEIGHTS",
    "boxes_to_masks",
    "dilate",
    "edge_band",
    "fill_hole_from_outside",
    "instance_masks",
    "random_box_mask",
    "random_irregular_mask",
    "safe_canny",
    "to_grey",
    "union",
]

GREY_WEIGHTS = (0.2125, 0.7154, 0.0721)
"""skimage ``rgb2gray`` (ITU-R BT.709) weights, as used by EdgeConnect."""

_SOBEL_SCALE = 2048.0  # grey [0,1] → int16 Sobel input scale (|Sobel| ≤ 4·2048 fits int16)


def _check_mask(mask: np.ndarray, shape: tuple[int, ...]) -> None:
    if mask.dtype != np.bool_ or mask.shape != shape:
        raise ValueError(f"mask must be bool with shape {shape}, got {mask.dtype} {mask.shape}")


def _check_image(image: np.ndarray) -> None:
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) RGB, got shape {image.shape}")


def dilate(mask: Bool[np.ndarray, "H W"], radius: int) -> Bool[np.ndarray, "H W"]:
    """Grow ``mask`` by ``radius`` px: every pixel within Euclidean distance ``radius``."""
    if radius < 0:
        raise ValueError(f"dilation radius must be >= 0, got {radius}")
    if radius == 0:
        return mask.copy()
    r = np.arange(-radius, radius + 1)
    kernel = (r[:, None] ** 2 + r[None, :] ** 2 <= radius**2).astype(np.uint8)
    return cv2.dilate(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


def boxes_to_masks(
    boxes: Float[np.ndarray, "K 4"], height: int, width: int, dilation: int = 4
) -> Bool[np.ndarray, "K H W"]:
    """One mask per ``xyxy`` box: every pixel whose unit square overlaps the box, then dilated.

    Pixel ``(u, v)`` covers ``[u − ½, u + ½) × [v − ½, v + ½)`` (centres at integers).
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if not np.all(np.isfinite(boxes)):
        raise ValueError("boxes contain NaN or inf")
    out = np.zeros((len(boxes), height, width), dtype=bool)
    for k, (x1, y1, x2, y2) in enumerate(boxes):
        u0, v0 = max(int(np.floor(x1 + 0.5)), 0), max(int(np.floor(y1 + 0.5)), 0)
        u1, v1 = min(int(np.ceil(x2 + 0.5)), width), min(int(np.ceil(y2 + 0.5)), height)
        if u1 > u0 and v1 > v0:
            out[k, v0:v1, u0:u1] = True
        out[k] = dilate(out[k], dilation)
    return out


def instance_masks(
    instance_ids: np.ndarray, ids: np.ndarray | None = None, dilation: int = 4
) -> Bool[np.ndarray, "K H W"]:
    """One dilated mask per instance id (``ids`` default: every id > 0 present, sorted)."""
    if instance_ids.ndim != 2:
        raise ValueError(f"instance_ids must be (H, W), got {instance_ids.shape}")
    if ids is None:
        ids = np.unique(instance_ids[instance_ids > 0])
    h, w = instance_ids.shape
    out = np.zeros((len(ids), h, w), dtype=bool)
    for k, i in enumerate(np.asarray(ids).reshape(-1)):
        out[k] = dilate(instance_ids == i, dilation)
    return out


def union(masks: Bool[np.ndarray, "K H W"], height: int, width: int) -> Bool[np.ndarray, "H W"]:
    """Union of per-object masks (an all-False mask when ``K = 0``)."""
    masks = np.asarray(masks, dtype=bool).reshape(-1, height, width)
    return masks.any(axis=0) if len(masks) else np.zeros((height, width), dtype=bool)


def to_grey(image: Shaped[np.ndarray, "H W 3"]) -> Float[np.ndarray, "H W"]:
    """Luminance in ``[0, 1]`` with the skimage ``rgb2gray`` weights (uint8 / uint16 / float ``[0, 1]`` input)."""
    from privslam_jax.data.images import as_unit_image

    _check_image(np.asarray(image))
    w = np.asarray(GREY_WEIGHTS, dtype=np.float32)
    return (as_unit_image(image, "to_grey image") @ w).astype(np.float32)


def fill_hole_from_outside(grey: np.ndarray, mask: np.ndarray, radius: int = 3) -> Float[np.ndarray, "H W"]:
    """Replace the masked pixels by a Telea fill of the outside ones (inside values never read).

    The hidden pixels are first set to zero, so the result is a function of the outside pixels
    and the mask only.
    """
    _check_mask(mask, grey.shape)
    zeroed = np.where(mask, np.float32(0.0), grey.astype(np.float32))
    if not mask.any():
        return zeroed
    filled = cv2.inpaint(zeroed, mask.astype(np.uint8), radius, cv2.INPAINT_TELEA)
    return np.where(mask, filled, zeroed).astype(np.float32)


def edge_band(sigma: float = 2.0) -> int:
    """Border band (px) covering Gaussian (⌈3σ⌉), Sobel (1) and non-max suppression (1)."""
    return int(np.ceil(3 * sigma)) + 2


def safe_canny(
    grey: np.ndarray,
    mask: np.ndarray,
    *,
    sigma: float = 2.0,
    low: float = 0.1,
    high: float = 0.2,
    band: int | None = None,
) -> tuple[Float[np.ndarray, "H W"], Bool[np.ndarray, "H W"]]:
    """Canny edges of float ``grey (H, W)`` that never depend on the pixels under ``mask``.

    Returns ``(edges, edge_hole)``: ``edges`` in {0, 1} float32, zero on ``edge_hole`` =
    ``mask`` grown by ``band`` px (default :func:`edge_band`). ``low``/``high`` are thresholds
    on the L2 Sobel magnitude of the smoothed [0, 1] image (skimage convention).
    """
    if grey.ndim != 2:
        raise ValueError(f"grey must be (H, W), got {grey.shape}")
    _check_mask(mask, grey.shape)
    if not 0 <= low <= high:
        raise ValueError(f"need 0 <= low <= high, got {low}, {high}")
    band = edge_band(sigma) if band is None else band
    filled = fill_hole_from_outside(grey, mask)
    k = 2 * int(np.ceil(3 * sigma)) + 1
    smooth = cv2.GaussianBlur(filled, (k, k), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT_101)
    scaled = smooth * np.float32(_SOBEL_SCALE)
    dx = np.round(cv2.Sobel(scaled, cv2.CV_32F, 1, 0, ksize=3)).astype(np.int16)
    dy = np.round(cv2.Sobel(scaled, cv2.CV_32F, 0, 1, ksize=3)).astype(np.int16)
    edges = cv2.Canny(dx, dy, low * _SOBEL_SCALE, high * _SOBEL_SCALE, L2gradient=True) > 0
    hole = dilate(mask, band)
    return np.where(hole, False, edges).astype(np.float32), hole


def random_box_mask(
    rng: np.random.Generator, height: int, width: int, min_frac: float = 0.15, max_frac: float = 0.5
) -> Bool[np.ndarray, "H W"]:
    """One axis-aligned box whose sides are ``min_frac..max_frac`` of the image sides."""
    bh = int(rng.uniform(min_frac, max_frac) * height)
    bw = int(rng.uniform(min_frac, max_frac) * width)
    v0 = int(rng.integers(0, height - bh + 1))
    u0 = int(rng.integers(0, width - bw + 1))
    m = np.zeros((height, width), dtype=bool)
    m[v0:v0 + max(bh, 1), u0:u0 + max(bw, 1)] = True
    return m


def random_irregular_mask(
    rng: np.random.Generator, height: int, width: int, strokes: int = 4
) -> Bool[np.ndarray, "H W"]:
    """Free-form brush strokes (random walks of thick line segments), as in irregular-mask sets."""
    m = np.zeros((height, width), dtype=np.uint8)
    size = min(height, width)
    for _ in range(strokes):
        u, v = int(rng.integers(0, width)), int(rng.integers(0, height))
        thick = int(rng.integers(max(size // 16, 1), max(size // 6, 2) + 1))
        for _ in range(int(rng.integers(2, 6))):
            angle = rng.uniform(0, 2 * np.pi)
            length = rng.uniform(0.1, 0.35) * size
            u2 = int(np.clip(u + length * np.cos(angle), 0, width - 1))
            v2 = int(np.clip(v + length * np.sin(angle), 0, height - 1))
            cv2.line(m, (u, v), (u2, v2), 1, thick)
            u, v = u2, v2
    return m.astype(bool)
