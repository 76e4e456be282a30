"""Every public image entry point takes uint8 (0-255) and float [0, 1] images alike, or refuses.

Reference: the same call on ``uint8 / 255`` as float32 (the documented convention). A uint8 image
used to come back from ``filter_frame`` as 0-255 pixels mixed with 0-1 fills (issue 14 item 6).
"""

import numpy as np
import pytest

from privslam_jax.data.images import as_unit_image, like_input, read_raw, write_rgb
from privslam_jax.detect.predict import letterbox
from privslam_jax.detect.temporal import flow_grey
from privslam_jax.inpaint.baselines import fill
from privslam_jax.inpaint.filter import Inpainter, filter_frame
from privslam_jax.inpaint.masks import to_grey
from privslam_jax.metrics.image import l1, psnr, ssim
from privslam_jax.slam.frontend import to_gray_u8


def _image(h=72, w=160, seed=0):
    rng = np.random.default_rng(seed)
    u = np.linspace(0, 1, w)[None, :, None] * np.linspace(0.3, 1, h)[:, None, None] * np.array([1.0, 0.6, 0.3])
    return np.clip(np.rint(255 * (u + 0.1 * rng.random((h, w, 3)))), 0, 255).astype(np.uint8)


U8 = _image()
F32 = U8.astype(np.float32) / 255
MASK = np.zeros(U8.shape[:2], bool)
MASK[20:45, 40:90] = True


def _filter(method):
    return lambda im: filter_frame(im, MASK[None], method, seed=1)


# name -> (function of one image, tolerance of the uint8 result against the float result on the 0-1 scale)
ENTRY_POINTS = {
    "filter_frame edgeconnect": (_filter("edgeconnect"), 0.5 / 255 + 1e-6),
    "filter_frame telea": (_filter("telea"), 0.5 / 255 + 1e-6),
    "filter_frame gaussian": (_filter("gaussian"), 0.5 / 255 + 1e-6),
    "baselines.fill ns": (lambda im: fill(im, MASK, "ns"), 0.5 / 255 + 1e-6),
    "Inpainter.inpaint_crop": (lambda im: Inpainter.embedded().inpaint_crop(im[:64, :64] * (~MASK[:64, :64, None]), MASK[:64, :64]), 1e-6),
    "to_grey": (to_grey, 1e-6),
    "to_gray_u8 (SLAM)": (to_gray_u8, 0),
    "flow_grey": (lambda im: flow_grey(im, 0.5), 0),
    "letterbox": (lambda im: letterbox(im, 320).image, 1.0 / 255 + 1e-6),
}


def _unit(x, like):
    x = np.asarray(x)
    return x.astype(np.float64) / 255 if x.dtype == np.uint8 and np.asarray(like).dtype != np.uint8 else x.astype(np.float64)


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_uint8_and_float_images_give_the_same_result(name):
    f, tol = ENTRY_POINTS[name]
    a, b = np.asarray(f(U8)), np.asarray(f(F32))
    if name.startswith(("filter_frame", "baselines")):
        assert a.dtype == np.uint8 and b.dtype == np.float32  # the caller's dtype comes back
        np.testing.assert_array_equal(a[~MASK], U8[~MASK])  # untouched outside the hole
        a = a / 255
    elif a.dtype == np.uint8 and b.dtype == np.uint8:  # functions whose output is uint8 either way
        a, b = a.astype(np.float64), b.astype(np.float64)
    assert a.shape == b.shape
    assert np.abs(a.astype(np.float64) - b.astype(np.float64)).max() <= tol * (255 if name in ("to_gray_u8 (SLAM)", "flow_grey") else 1)


@pytest.mark.parametrize("name", ENTRY_POINTS)
@pytest.mark.parametrize("bad", ["0-255 float", "NaN", "int32", "negative"])
def test_images_outside_the_convention_are_refused(name, bad):
    f, _ = ENTRY_POINTS[name]
    image = {"0-255 float": U8.astype(np.float32), "NaN": np.where(MASK[..., None], np.nan, F32),
             "int32": U8.astype(np.int32), "negative": F32 - 0.5}[bad]
    if name == "Inpainter.inpaint_crop" and bad == "NaN":
        image = np.where(np.ones_like(MASK)[..., None], np.nan, F32)  # NaN inside the crop it reads
    with pytest.raises(ValueError, match="dtype|must lie in|NaN|float in"):
        f(image)


def test_detector_takes_uint8_and_float_alike():
    from privslam_jax.detect import Detector

    det = Detector.embedded(domain="real")
    a, b = det.detect([U8])[0], det.detect([F32])[0]
    np.testing.assert_allclose(np.asarray(a.boxes), np.asarray(b.boxes), atol=1e-3)
    with pytest.raises(ValueError):
        det.detect([U8.astype(np.float32)])


def test_image_metrics_map_integer_images_onto_the_data_range():
    other = np.roll(U8, 3, axis=1)
    for fn in (psnr, ssim, l1):
        np.testing.assert_allclose(float(fn(U8, other)), float(fn(F32, other.astype(np.float32) / 255)), rtol=1e-5)
    np.testing.assert_allclose(float(psnr(U8, other, data_range=255.0)),
                               float(psnr(U8.astype(np.float32), other.astype(np.float32), data_range=255.0)), rtol=1e-5)


def test_write_rgb_takes_uint8_and_float_alike(tmp_path):
    write_rgb(tmp_path / "a.png", U8)
    write_rgb(tmp_path / "b.png", F32)
    np.testing.assert_array_equal(read_raw(tmp_path / "a.png"), read_raw(tmp_path / "b.png"))
    with pytest.raises(ValueError, match="divide by 255"):
        write_rgb(tmp_path / "c.png", U8.astype(np.float32))
    assert not (tmp_path / "c.png").exists()


def test_as_unit_image_and_like_input_round_trip():
    np.testing.assert_array_equal(like_input(as_unit_image(U8), U8), U8)
    u16 = (U8.astype(np.uint16) * 257)
    np.testing.assert_allclose(as_unit_image(u16), F32, atol=1e-6)
    assert like_input(as_unit_image(u16), u16).dtype == np.uint16
    with pytest.raises(ValueError, match="dtype bool"):
        as_unit_image(MASK)
