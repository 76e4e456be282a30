"""Photometric domain randomisation and self-training labels."""

from __future__ import annotations

import dataclasses

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.data.yolo import YoloDataset
from privslam_jax.detect.domain_rand import DomainRandConfig, randomize_photometric
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
