"""Photometric domain randomisation: make rendered frames look like many real cameras.

A detector trained on the flat-shaded synthetic world fails on real frames (recall 0.07 on real
KITTI, ``results/table1b_real_recall.md``). Domain randomisation (Tobin et al., IROS 2017;
Tremblay et al., CVPRW 2018) trains on renders whose nuisance factors vary more than the real
world's, so that the real camera is one more sample. The factors here are the ones in which real
street cameras differ from the renderer and from each other (each applied with its own
probability, drawn from the given ``numpy`` generator so that a batch is reproducible):

* colour: grey sensors (KITTI odometry's left camera), white balance (per-channel gains),
  exposure and gamma, contrast;
* optics: vignetting ``1 − k·r²``, defocus (Gaussian blur), horizontal motion blur, loss of
  resolution (down- and up-sampling);
* texture: smooth multiplicative shading noise (real surfaces are not uniform), per-pixel sensor
  noise, JPEG compression artefacts.

Boxes are unchanged by all of them (no geometric effect).

:func:`fourier_style` is a different kind of shift: Fourier domain adaptation (Yang & Soatto,
CVPR 2020) gives a render the low-frequency amplitude spectrum of a real frame (its global
illumination, colour cast and contrast at coarse scales) and keeps the render's phase (its edges and
shapes, hence its boxes). It needs real frames, so it is not part of :func:`randomize_photometric`.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

__all__ = ["DomainRandConfig", "fourier_style", "randomize_photometric"]


@dataclasses.dataclass(frozen=True)
class DomainRandConfig:
    """Probabilities and ranges of :func:`randomize_photometric`."""

    grey: float = 0.3
    """Probability of converting to grey (repeated to three channels)."""
    white_balance: float = 0.5
    """Probability of per-channel gains ``U(0.8, 1.2)``."""
    gamma: float = 0.5
    """Probability of a gamma ``U(0.6, 1.6)`` with a contrast change ``U(0.7, 1.3)`` about the mean."""
    vignette: float = 0.3
    """Probability of vignetting ``1 − k·r²``, ``k ~ U(0.1, 0.5)``, ``r`` = distance from the centre / half-diagonal."""
    blur: float = 0.3
    """Probability of a Gaussian blur, ``σ ~ U(0.3, 1.5)`` px."""
    motion_blur: float = 0.15
    """Probability of a horizontal box blur of 3–9 px (camera motion)."""
    resample: float = 0.25
    """Probability of down-sampling by ``U(1.5, 3)`` and back (soft, low-resolution cameras)."""
    shading: float = 0.5
    """Probability of smooth multiplicative noise ``1 + a·N``, ``a ~ U(0.05, 0.2)``, from a coarse random grid."""
    sensor_noise: float = 0.6
    """Probability of per-pixel Gaussian noise, ``σ ~ U(0.005, 0.04)``."""
    jpeg: float = 0.3
    """Probability of JPEG compression at quality ``U(30, 90)``."""


def randomize_photometric(image: np.ndarray, rng: np.random.Generator,
                          cfg: DomainRandConfig = DomainRandConfig()) -> np.ndarray:
    """One random draw of the nuisance factors above on a ``(H, W, 3)`` float RGB image in ``[0, 1]``."""
    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"randomize_photometric expects an (H, W, 3) image, got {img.shape}")
    h, w = img.shape[:2]
    if rng.random() < cfg.white_balance:
        img = img * rng.uniform(0.8, 1.2, 3).astype(np.float32)
    if rng.random() < cfg.grey:
        img = np.repeat(img @ np.array([0.299, 0.587, 0.114], np.float32), 3).reshape(h, w, 3)
    if rng.random() < cfg.gamma:
        img = np.clip(img, 0, 1) ** np.float32(rng.uniform(0.6, 1.6))
        m = img.mean()
        img = (img - m) * np.float32(rng.uniform(0.7, 1.3)) + m
    if rng.random() < cfg.shading:
        gh, gw = rng.integers(2, 8), rng.integers(4, 16)
        field = cv2.resize(rng.standard_normal((gh, gw)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
        img = img * (1 + np.float32(rng.uniform(0.05, 0.2)) * field)[..., None]
    if rng.random() < cfg.vignette:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        img = img * (1 - np.float32(rng.uniform(0.1, 0.5)) * r2)[..., None]
    img = np.clip(img, 0, 1).astype(np.float32)
    if rng.random() < cfg.blur:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, 1.5)))
    if rng.random() < cfg.motion_blur:
        k = int(rng.integers(3, 10))
        img = cv2.blur(img, (k, 1))
    if rng.random() < cfg.resample:
        f = rng.uniform(1.5, 3.0)
        small = cv2.resize(img, (max(1, round(w / f)), max(1, round(h / f))), interpolation=cv2.INTER_AREA)
        img = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < cfg.sensor_noise:
        img = img + rng.normal(0, rng.uniform(0.005, 0.04), img.shape).astype(np.float32)
    img = np.clip(img, 0, 1)
    if rng.random() < cfg.jpeg:
        q = int(rng.integers(30, 91))
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor((img * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, q])
        if not ok:
            raise RuntimeError("cv2.imencode failed to write a JPEG in memory")
        img = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB).astype(np.float32) / 255
    return np.ascontiguousarray(img, np.float32)


def fourier_style(image: np.ndarray, style: np.ndarray, beta: float) -> np.ndarray:
    """``image`` with the low-frequency amplitude spectrum of ``style`` (FDA, Yang & Soatto, CVPR 2020, eq. 3).

    Per channel, with ``F = FFT2(image)``, ``S = FFT2(style)`` centred by ``fftshift``,
    ``M_b`` = the ``(2b+1) × (2b+1)`` window around zero frequency, ``b = ⌊beta · min(H, W)⌋``::

        out = IFFT2( ((1 − M_b)·|F| + M_b·|S|) · exp(i·arg F) ),  clipped to [0, 1]

    ``beta = 0`` swaps only the mean (the DC term); the paper uses 0.01–0.09. ``style`` is resized to
    ``image``'s size when they differ. Both are ``(H, W, 3)`` float RGB in ``[0, 1]``.
    """
    img = np.asarray(image, np.float32)
    sty = np.asarray(style, np.float32)
    if img.ndim != 3 or img.shape[-1] != 3 or sty.ndim != 3 or sty.shape[-1] != 3:
        raise ValueError(f"fourier_style expects (H, W, 3) images, got {img.shape} and {sty.shape}")
    if not 0.0 <= beta < 0.5:
        raise ValueError(f"beta must be in [0, 0.5), got {beta}")
    h, w = img.shape[:2]
    if sty.shape[:2] != (h, w):
        sty = cv2.resize(sty, (w, h), interpolation=cv2.INTER_AREA)
    f = np.fft.fftshift(np.fft.fft2(img, axes=(0, 1)), axes=(0, 1))
    s = np.fft.fftshift(np.fft.fft2(sty, axes=(0, 1)), axes=(0, 1))
    b = int(np.floor(beta * min(h, w)))
    ch, cw = h // 2, w // 2  # the zero frequency after fftshift
    win = (slice(max(ch - b, 0), ch + b + 1), slice(max(cw - b, 0), cw + b + 1))
    amp = np.abs(f)
    amp[win] = np.abs(s[win])
    out = np.fft.ifft2(np.fft.ifftshift(amp * np.exp(1j * np.angle(f)), axes=(0, 1)), axes=(0, 1)).real
    return np.ascontiguousarray(np.clip(out, 0, 1), np.float32)
