"""Net2Net widening of the image generator: the wider network computes the narrow one's function;
a training run can start from it; checkpoints with a wider image generator load and are checked."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.inpaint.filter import Inpainter, InpainterConfig
from privslam_jax.inpaint.widen import widen_inpaint_generator

NARROW = InpainterConfig(width=4, num_residual_blocks=2, size=32)


def _input(seed: int, size: int = 32) -> jnp.ndarray:
    return jnp.asarray(np.random.default_rng(seed).uniform(size=(2, size, size, 4)), jnp.float32)


@pytest.mark.parametrize("width", [5, 6, 8])
def test_widening_preserves_the_function_and_breaks_the_symmetry_of_the_copies(width):
    _, gen = Inpainter.init(NARROW, seed=3).modules
    x = _input(0)
    exact = widen_inpaint_generator(gen, width, noise=0.0)
    assert exact.width == width and exact.enc1.kernel.shape == (7, 7, 4, width)
    assert exact.middle[1].conv2.kernel.shape == (3, 3, 4 * width, 4 * width)
    assert exact.dec3.kernel.shape == (7, 7, width, 3)
    # reference: the narrow network itself (the widening is exact up to float rounding)
    np.testing.assert_allclose(np.asarray(exact.logits(x)), np.asarray(gen.logits(x)), atol=2e-5, rtol=1e-4)
    noisy = widen_inpaint_generator(gen, width, noise=0.01, seed=1)
    np.testing.assert_allclose(np.asarray(noisy.logits(x)), np.asarray(gen.logits(x)), atol=0.05)
    # the copies are not duplicates: incoming weights differ (noise) and so do outgoing ones (unequal splits)
    k_in = np.asarray(noisy.enc1.kernel[...])
    k_out = np.asarray(exact.enc2.kernel[...])
    for j in range(4, width):
        assert not any(np.allclose(k_in[..., j], k_in[..., i]) for i in range(width) if i != j)
        assert not any(np.allclose(k_out[:, :, j], k_out[:, :, i]) for i in range(width) if i != j)


def test_widening_refuses_narrower_or_more_than_twice_the_width():
    _, gen = Inpainter.init(NARROW).modules
    for width in (3, 9):
        with pytest.raises(ValueError, match="widen"):
            widen_inpaint_generator(gen, width)


def test_a_wider_image_generator_saves_loads_and_is_checked(tmp_path):
    from privslam_jax.errors import InputError

    model = Inpainter.init(dataclasses.replace(NARROW, inpaint_width=6), seed=2)
    edge_gen, gen = model.modules
    assert (edge_gen.width, gen.width) == (4, 6)
    with pytest.raises(ValueError, match="do not match"):
        Inpainter(edge_gen, gen, NARROW)
    model.save(tmp_path / "w.npz")
    back = Inpainter.load(tmp_path / "w.npz")
    assert back.config == model.config and back.config.g2_width == 6
    rng = np.random.default_rng(0)
    img = rng.uniform(size=(32, 32, 3)).astype(np.float32)
    hole = np.zeros((32, 32), bool)
    hole[10:20, 8:22] = True
    img[hole] = 0
    np.testing.assert_array_equal(back.inpaint_crop(img, hole), model.inpaint_crop(img, hole))
    with np.load(tmp_path / "w.npz") as z:
        arrays = {k: z[k] for k in z.files}
    for name, value in (("narrower", 4), ("huge", 10**9), ("negative", -1)):
        np.savez(tmp_path / f"{name}.npz", **{**arrays, "config/inpaint_width": np.asarray(value)})
        with pytest.raises(InputError, match=rf"{name}\.npz"):
            Inpainter.load(tmp_path / f"{name}.npz")


def test_training_starts_from_the_widened_generator(tmp_path):
    from test_inpaint_train import CFG, _data

    from privslam_jax.inpaint.train import train

    init = Inpainter.init(dataclasses.replace(NARROW, num_residual_blocks=1), seed=11)
    cfg = dataclasses.replace(CFG, inpaint_width=6)
    tr = train(cfg, _data, tmp_path / "wide", max_steps=0, init=init, progress=False)
    inp = tr.inpainter()
    assert inp.config.g2_width == 6 and tr.inpaint_d.convs[0].kernel.shape[-1] == 6
    img, hole = (v[0] for v in _data(3, 1))
    img = np.where(hole[..., None], np.float32(0), img)
    # the widened copy (noise 0.01 on the copies' incoming weights) fills as the narrow one did
    np.testing.assert_allclose(inp.inpaint_crop(img, hole), init.inpaint_crop(img, hole), atol=0.02)
    for width in (3, 13):
        with pytest.raises(ValueError, match="at most twice"):
            train(dataclasses.replace(CFG, inpaint_width=width), _data, tmp_path / f"bad{width}", max_steps=0,
                  init=init, progress=False)


def test_train_script_widens_its_init_and_exports_the_inference_settings(tmp_path):
    """``train/inpaint.py --init narrow.npz --inpaint-width 6 --export-flip-average --export-prefill-blend 0.8
    --export-prefill-blend-distance 5 --export-prefill-blend-unit model``:
    the exported checkpoint has the wider image generator and carries those settings in its config."""
    import importlib.util
    from pathlib import Path

    import cv2

    rng = np.random.default_rng(0)
    (tmp_path / "img").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "img" / f"{i}.png"), rng.integers(0, 255, (48, 48, 3)).astype(np.uint8))
    init = Inpainter.init(dataclasses.replace(NARROW, num_residual_blocks=1, prefill="telea", residual=True), seed=5)
    init.save(tmp_path / "narrow.npz")
    script = Path(__file__).resolve().parents[1] / "train" / "inpaint.py"
    spec = importlib.util.spec_from_file_location("train_inpaint_widen", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    argv = ["--folder", str(tmp_path / "img"), "--width", "4", "--blocks", "1", "--size", "32", "--batch", "2",
            "--stages", "edge_inpaint:1", "--prefill", "telea", "--residual", "--init", str(tmp_path / "narrow.npz"),
            "--inpaint-width", "6", "--workdir", str(tmp_path / "run"), "--export", str(tmp_path / "wide.npz"),
            "--export-flip-average", "--export-prefill-blend", "0.8", "--export-prefill-blend-distance", "5",
            "--export-prefill-blend-unit", "model", "--sample-every", "0"]
    assert module.main(argv) == 0
    out = Inpainter.load(tmp_path / "wide.npz")
    assert out.config == dataclasses.replace(init.config, inpaint_width=6, flip_average=True, prefill_blend=0.8,
                                             prefill_blend_distance=5.0, prefill_blend_unit="model")
    assert out.modules[1].enc1.kernel.shape == (7, 7, 4, 6)
