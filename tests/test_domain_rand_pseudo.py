"""Photometric domain randomisation and self-training labels."""

from __future__ import annotations

import dataclasses

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.data.yolo import YoloDataset
from privslam_jax.detect.domain_rand import DomainRandConfig, fourier_style, randomize_photometric
from privslam_jax.detect.train import TrainConfig, augment
from privslam_jax.detect.pseudo import PseudoLabelConfig, export_pseudo_yolo
from privslam_jax.types import Detections

OFF = DomainRandConfig(**{f.name: 0.0 for f in dataclasses.fields(DomainRandConfig)})


def _image(seed=0, h=48, w=80):
    return np.random.default_rng(seed).uniform(0.05, 0.95, (h, w, 3)).astype(np.float32)


def test_domain_rand_all_off_is_identity_and_draws_are_reproducible():
    img = _image()
    np.testing.assert_array_equal(randomize_photometric(img, np.random.default_rng(0), OFF), img)
    for seed in range(20):
        a = randomize_photometric(img, np.random.default_rng(seed))
        b = randomize_photometric(img, np.random.default_rng(seed))
        np.testing.assert_array_equal(a, b)
        assert a.shape == img.shape and a.dtype == np.float32 and 0 <= a.min() and a.max() <= 1
    with pytest.raises(ValueError):
        randomize_photometric(img[..., 0], np.random.default_rng(0))


def test_domain_rand_grey_and_vignette_follow_their_formulas():
    img = _image(1)
    grey = randomize_photometric(img, np.random.default_rng(0), dataclasses.replace(OFF, grey=1.0))
    lum = img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114
    for c in range(3):
        np.testing.assert_allclose(grey[..., c], lum, atol=1e-6)
    flat = np.full((49, 81, 3), 0.8, np.float32)
    for seed in range(10):
        v = randomize_photometric(flat, np.random.default_rng(seed), dataclasses.replace(OFF, vignette=1.0))
        k = 1 - v[0, 0, 0] / 0.8  # r = 1 at the corner: factor 1 - k, k in [0.1, 0.5]
        assert v[24, 40, 0] == pytest.approx(0.8) and 0.1 <= k <= 0.5
        yy, xx = np.mgrid[0:49, 0:81]
        r2 = ((xx - 40) ** 2 + (yy - 24) ** 2) / (40**2 + 24**2)
        np.testing.assert_allclose(v[..., 1], 0.8 * (1 - k * r2), atol=1e-5)


def test_domain_rand_noise_and_blur_change_statistics_as_expected():
    img = np.full((64, 64, 3), 0.5, np.float32)
    noisy = randomize_photometric(img, np.random.default_rng(3), dataclasses.replace(OFF, sensor_noise=1.0))
    assert 0.004 < noisy.std() < 0.045
    edge = np.zeros((32, 32, 3), np.float32)
    edge[:, 16:] = 1
    blurred = randomize_photometric(edge, np.random.default_rng(0), dataclasses.replace(OFF, blur=1.0))
    assert 0 < blurred[0, 15, 0] < 0.5 < blurred[0, 16, 0] < 1


class _TwoBlobs:
    """Stand-in detector: a box with score 0.9 around pixels == 250 and 0.2 around pixels == 180."""

    @dataclasses.dataclass(frozen=True)
    class Cfg:
        imgsz: int = 640
        conf: float = 0.25

    def __init__(self, config=Cfg()):
        self.config = config

    def with_config(self, config):
        return _TwoBlobs(config)

    def detect(self, images):
        out = []
        for im in images:
            boxes, scores = [], []
            for value, score in ((250, 0.9), (180, 0.2)):
                ys, xs = np.nonzero(np.asarray(im)[..., 0] == value)
                if len(xs) and score >= self.config.conf:
                    boxes.append([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1])
                    scores.append(score)
            out.append(Detections(boxes=jnp.asarray(np.asarray(boxes, np.float32).reshape(-1, 4)),
                                  scores=jnp.asarray(np.asarray(scores, np.float32)),
                                  class_ids=jnp.asarray(np.full(len(boxes), 2, np.int32))))
        return out


@pytest.mark.parametrize("shape", [(48, 80), (47, 81)])
@pytest.mark.parametrize("beta", [0.0, 0.03, 0.1])
def test_fourier_style_swaps_the_low_frequency_amplitude_as_a_plain_numpy_reference(shape, beta):
    rng = np.random.default_rng(0)
    img = (0.5 + 0.1 * rng.standard_normal((*shape, 3))).clip(0.2, 0.8).astype(np.float32)
    sty = (0.45 + 0.05 * rng.standard_normal((*shape, 3))).astype(np.float32)
    # Reference without fftshift: integer frequencies |ky|, |kx| <= b form the window around 0.
    b = int(np.floor(beta * min(shape)))
    ky = np.abs(np.round(np.fft.fftfreq(shape[0]) * shape[0]))[:, None]
    kx = np.abs(np.round(np.fft.fftfreq(shape[1]) * shape[1]))[None, :]
    window = ((ky <= b) & (kx <= b))[..., None]
    f, s = np.fft.fft2(img, axes=(0, 1)), np.fft.fft2(sty, axes=(0, 1))
    ref = np.fft.ifft2(np.where(window, np.abs(s), np.abs(f)) * np.exp(1j * np.angle(f)), axes=(0, 1)).real
    assert 0 < ref.min() and ref.max() < 1  # no clipping in this case
    out = fourier_style(img, sty, beta)
    np.testing.assert_allclose(out, ref, atol=1e-5)
    np.testing.assert_allclose(out.mean((0, 1)), sty.mean((0, 1)), atol=1e-5)  # the DC term is the style's
    np.testing.assert_allclose(fourier_style(img, img, beta), img, atol=1e-5)


def test_fourier_style_resizes_the_style_and_refuses_what_it_cannot_use():
    img = 0.4 + 0.2 * _image(2, 40, 64)  # in [0.41, 0.59]: nothing clips after the mean moves to 0.3
    out = fourier_style(img, np.full((80, 128, 3), 0.3, np.float32), 0.0)
    np.testing.assert_allclose(out.mean((0, 1)), 0.3, atol=1e-4)
    for bad in (img[..., 0], img[..., :2]):
        with pytest.raises(ValueError, match="fourier_style expects"):
            fourier_style(bad, img, 0.05)
    with pytest.raises(ValueError, match="beta"):
        fourier_style(img, img, 0.5)


def test_augment_gives_the_style_frames_low_frequencies_and_config_refuses_a_missing_bank(tmp_path):
    cfg = TrainConfig(data=str(tmp_path), num_classes=2, imgsz=64, imgh=32, fliplr=0.0, scale_aug=0.0, translate=0.0,
                      hsv=(0.0, 0.0, 0.0), style=1.0, style_frames=("unused",), style_beta=0.0)
    img = 0.4 + 0.2 * _image(3, 32, 64)  # nothing clips after the mean moves by < 0.2
    bank = np.zeros((2, 32, 64, 3), np.uint8)
    bank[0] = (100, 120, 140)
    bank[1] = (140, 110, 90)
    for seed in range(6):  # beta 0: the canvas takes one bank frame's mean colour
        out, boxes, keep = augment(img, np.array([[8.0, 4, 40, 28]]), cfg, np.random.default_rng(seed), bank)
        means = out.mean((0, 1)) * 255
        assert min(np.abs(means - bank[i, 0, 0]).max() for i in range(2)) < 0.05
        np.testing.assert_allclose(boxes, [[8, 4, 40, 28]], atol=1e-4)  # boxes untouched
    plain = dataclasses.replace(cfg, style=0.0, style_frames=())
    np.testing.assert_allclose(augment(img, np.zeros((0, 4)), plain, np.random.default_rng(0))[0], img, atol=1e-5)
    with pytest.raises(ValueError, match="style_bank"):
        augment(img, np.zeros((0, 4)), cfg, np.random.default_rng(0))
    with pytest.raises(ValueError, match="style_frames"):
        dataclasses.replace(cfg, style_frames=())
    with pytest.raises(ValueError, match="style_beta"):
        dataclasses.replace(cfg, style_beta=0.6)


def test_export_pseudo_yolo_labels_confident_boxes_and_greys_uncertain_ones(tmp_path):
    paths = []
    for i in range(3):
        img = np.full((60, 100, 3), 40, np.uint8)
        img[10:40, 5 + i:35 + i] = 250  # confident object
        img[20:50, 60:90] = 180  # uncertain object
        p = tmp_path / f"{i:04d}.png"
        cv2.imwrite(str(p), img)
        paths.append(p)
    cfg = PseudoLabelConfig(label_conf=0.5, ignore_conf=0.1, window=0, tta_scales=())
    n, labels, ignored = export_pseudo_yolo(_TwoBlobs(), [paths], tmp_path / "ds", "real", cfg)
    assert (n, labels, ignored) == (3, 3, 3)
    ds = YoloDataset(tmp_path / "ds", "real")
    for i, sample in enumerate(ds):
        np.testing.assert_allclose(sample.boxes, [[5 + i, 10, 35 + i, 40]], atol=1e-3)
        assert sample.class_ids.tolist() == [2]
        img = np.rint(sample.image * 255)
        assert (img[20:50, 60:90] == 114).all()  # uncertain region painted grey
        assert (img[10:40, 5 + i:35 + i] == 250).all() and (img[55, 0] == 40).all()  # the rest untouched
