"""Classical privacy-filter baselines behind one interface: ``fill(image, mask, method, seed)``.

``image`` float32 ``(H, W, 3)`` RGB in [0, 1]; ``mask`` bool ``(H, W)``, ``True`` = hidden.
Pixels outside the mask are returned bit-for-bit unchanged. Randomness comes only from the
explicit integer ``seed`` (noise is drawn for the whole frame and then selected, so it depends on
the seed, the frame size and the mask — never on the hidden pixels).

Privacy-safe methods (output bit-identical whatever the hidden pixels are; property-tested):

* ``black`` / ``gray`` / ``white``: constant 0, 0.5, 1.
* ``gaussian``: each hidden channel value drawn from N(0, 25) on the 0–255 scale (σ = 5/255),
  clipped to [0, 1] — the paper's "Gaussian noise N(0, 25)" read literally as a fill (nearly
  black noise). The paper does not say whether the noise replaces or is added to the object;
  *added* noise of σ = 5 would leave the object fully visible (``gaussian_add`` below).
* ``noise25`` / ``noise50``: a random 25 % / 50 % of the hidden pixels get uniform random RGB
  noise; **the rest of the region is set to grey 0.5** (rule chosen here: the paper leaves the
  rest unspecified, and keeping the original pixels there would leak 75 % / 50 % of the object).
* ``telea`` / ``ns``: OpenCV ``cv2.inpaint`` (radius 3) on the 8-bit frame with the hidden
  pixels zeroed first (the output is quantised to 1/255 inside the mask).

Leaky by construction (the paper's baselines as described; **they reveal the hidden pixels** and
are offered only for comparison — the test documents that their output changes with them):

* ``blur``: Gaussian blur (σ = 8 px, 49×49 kernel) of the frame, pasted under the mask.
* ``pixelate``: mean of 16×16 px blocks of the frame (grid anchored at the image origin),
  pasted under the mask.
* ``gaussian_add``: the hidden pixels plus N(0, 25) noise.
"""

from __future__ import annotations

import cv2
import numpy as np
from jaxtyping import Shaped

from privslam_jax.data.images import as_unit_image, like_input

__all__ = ["LEAKY_METHODS", "METHODS", "SAFE_METHODS", "fill"]

SAFE_METHODS: tuple[str, ...] = ("black", "gray", "white", "gaussian", "noise25", "noise50", "telea", "ns")
LEAKY_METHODS: tuple[str, ...] = ("blur", "pixelate", "gaussian_add")
METHODS: tuple[str, ...] = SAFE_METHODS + LEAKY_METHODS

BLUR_SIGMA = 8.0
PIXEL_BLOCK = 16
NOISE_STD = 5.0 / 255.0  # variance 25 on the 0–255 scale


def _inpaint_cv(image: np.ndarray, mask: np.ndarray, flag: int) -> np.ndarray:
    zeroed = np.where(mask[..., None], np.float32(0), image)
    u8 = np.clip(np.round(zeroed * 255.0), 0, 255).astype(np.uint8)
    out = cv2.inpaint(u8, mask.astype(np.uint8), 3, flag)
    return out.astype(np.float32) / np.float32(255.0)


def _pixelate(image: np.ndarray, block: int) -> np.ndarray:
    h, w, _ = image.shape
    hb, wb = -(-h // block), -(-w // block)
    pad = np.pad(image, ((0, hb * block - h), (0, wb * block - w), (0, 0)), mode="edge")
    means = pad.reshape(hb, block, wb, block, 3).mean(axis=(1, 3))
    return np.repeat(np.repeat(means, block, 0), block, 1)[:h, :w].astype(np.float32)


def fill(
    image: np.ndarray,
    mask: np.ndarray,
    method: str,
    seed: int = 0,
) -> Shaped[np.ndarray, "H W 3"]:
    """Fill the masked region of ``image`` with baseline ``method`` (see module docstring).

    ``image``: uint8, uint16 or float in ``[0, 1]`` (:func:`privslam_jax.data.images.as_unit_image`);
    the result has its dtype."""
    original = image
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) RGB, got shape {image.shape}")
    if mask.dtype != np.bool_ or mask.shape != image.shape[:2]:
        raise ValueError(f"mask must be bool {image.shape[:2]}, got {mask.dtype} {mask.shape}")
    if method not in METHODS:
        raise ValueError(f"unknown fill method {method!r}; choose from {', '.join(METHODS)}")
    image = as_unit_image(image, "fill image")
    if not mask.any():
        return like_input(image.copy(), original)
    rng = np.random.default_rng(seed)
    shape = image.shape
    if method in ("black", "gray", "white"):
        src = np.full(shape, {"black": 0.0, "gray": 0.5, "white": 1.0}[method], dtype=np.float32)
    elif method == "gaussian":
        src = np.clip(rng.normal(0.0, NOISE_STD, shape), 0.0, 1.0).astype(np.float32)
    elif method in ("noise25", "noise50"):
        share = 0.25 if method == "noise25" else 0.5
        noisy = rng.random(shape[:2]) < share
        src = np.where(noisy[..., None], rng.random(shape), 0.5).astype(np.float32)
    elif method == "telea":
        src = _inpaint_cv(image, mask, cv2.INPAINT_TELEA)
    elif method == "ns":
        src = _inpaint_cv(image, mask, cv2.INPAINT_NS)
    elif method == "blur":
        k = 2 * int(np.ceil(3 * BLUR_SIGMA)) + 1
        src = cv2.GaussianBlur(image, (k, k), BLUR_SIGMA, borderType=cv2.BORDER_REFLECT_101)
    elif method == "pixelate":
        src = _pixelate(image, PIXEL_BLOCK)
    else:  # gaussian_add
        src = np.clip(image + rng.normal(0.0, NOISE_STD, shape), 0.0, 1.0).astype(np.float32)
    return like_input(np.where(mask[..., None], src, image).astype(np.float32), original)
