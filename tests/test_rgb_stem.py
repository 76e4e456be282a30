"""The native YOLOv8 stem kernel (rgb_stem.cc) against numpy and XLA's convolution."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from privslam_jax.detect.rgb_stem import NATIVE_CHANNELS, native_stem_available, rgb_stem, rgb_stem_reference
from privslam_jax.detect.yolov8 import YOLOv8Config, fuse_batchnorm, init_yolov8

HAS_COMPILER = shutil.which(os.environ.get("CXX", "c++")) is not None
needs_native = pytest.mark.skipif(not HAS_COMPILER or os.environ.get("PRIVSLAM_NATIVE") == "0",
                                  reason="no C++ compiler (or PRIVSLAM_NATIVE=0): the XLA stem is used")


def numpy_stem(x, k, b) -> np.ndarray:
    """Direct definition: zero-pad 1, 3×3 taps at stride 2, float64, then SiLU."""
    x, k, b = (np.asarray(a, np.float64) for a in (x, k, b))
    bsz, h, w, _ = x.shape
    xp = np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
    ho, wo = (h + 1) // 2, (w + 1) // 2
    y = np.zeros((bsz, ho, wo, k.shape[-1])) + b
    for dy in range(3):
        for dx in range(3):
            y += xp[:, dy:dy + 2 * ho:2, dx:dx + 2 * wo:2, :] @ k[dy, dx]
    return y / (1.0 + np.exp(-y))


def _inputs(shape, channels, seed=0):
    rng = np.random.default_rng(seed)
    return (jnp.asarray(rng.random(shape, np.float32)), jnp.asarray(rng.standard_normal((3, 3, 3, channels)) * 0.5, jnp.float32),
            jnp.asarray(rng.standard_normal(channels), jnp.float32))


@needs_native
def test_native_kernel_builds():
    assert native_stem_available(), "a C++ compiler is on PATH but the native stem did not build (see the warning)"


@needs_native
@pytest.mark.parametrize("channels", NATIVE_CHANNELS)
@pytest.mark.parametrize("shape", [(2, 32, 64, 3), (1, 7, 9, 3), (1, 2, 1, 3)])
def test_matches_numpy(shape, channels):
    x, k, b = _inputs(shape, channels)
    fn = jax.jit(rgb_stem)
    assert "privslam_rgb_stem" in fn.lower(x, k, b).as_text()  # the native kernel runs, not the fallback
    np.testing.assert_allclose(np.asarray(fn(x, k, b)), numpy_stem(x, k, b), rtol=1e-5, atol=1e-5)


@needs_native
def test_gradients_match_xla():
    x, k, b = _inputs((1, 16, 24, 3), 16, seed=1)

    def loss(fn):
        return lambda x, k, b: jnp.sum(jnp.sin(fn(x, k, b)))

    ours = jax.grad(loss(rgb_stem), argnums=(0, 1, 2))(x, k, b)
    ref = jax.grad(loss(rgb_stem_reference), argnums=(0, 1, 2))(x, k, b)
    for g, r in zip(ours, ref):
        np.testing.assert_allclose(np.asarray(g), np.asarray(r), rtol=1e-4, atol=1e-5)


@needs_native
def test_nan_propagates_like_xla():
    x, k, b = _inputs((1, 8, 8, 3), 16)
    x = x.at[0, 3, 4, 1].set(jnp.nan)
    np.testing.assert_array_equal(np.isnan(np.asarray(rgb_stem(x, k, b))),
                                  np.isnan(np.asarray(rgb_stem_reference(x, k, b))))


@needs_native
@pytest.mark.parametrize("pre_activation", [-1e30, -1e4, -100.0, -89.0, -88.0, 0.0, 30.0, 1e30])
def test_extreme_pre_activations(pre_activation):
    x = jnp.ones((1, 6, 6, 3), jnp.float32)
    k = jnp.zeros((3, 3, 3, 16), jnp.float32)
    b = jnp.full(16, pre_activation, jnp.float32)
    np.testing.assert_allclose(np.asarray(rgb_stem(x, k, b)), np.asarray(rgb_stem_reference(x, k, b)), rtol=1e-6, atol=1e-30)


@needs_native
def test_fused_yolov8_uses_kernel_and_matches_unfused():
    model = init_yolov8(YOLOv8Config(num_classes=3, scale="n"), seed=2)
    model.eval()
    fused = fuse_batchnorm(model)
    graphdef, state = nnx.split(fused)
    forward = jax.jit(lambda st, v: nnx.merge(graphdef, st)(v))
    x = jnp.asarray(np.random.default_rng(3).random((1, 64, 96, 3), np.float32))
    assert "privslam_rgb_stem" in forward.lower(state, x).as_text()
    ref = jax.lax.conv_general_dilated(x, model.stem.conv.kernel[...], (2, 2), ((1, 1), (1, 1)),
                                       dimension_numbers=("NHWC", "HWIO", "NHWC"))
    ref = jax.nn.silu(model.stem.bn(ref))
    np.testing.assert_allclose(np.asarray(fused.stem(x)), np.asarray(ref), rtol=1e-4, atol=1e-5)
    for a, r in zip(forward(state, x), model(x)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(r), rtol=1e-3, atol=1e-3)


def test_other_channel_counts_use_xla():
    x, k, b = _inputs((1, 10, 12, 3), 24)  # 24 is not instantiated in the kernel
    assert "privslam_rgb_stem" not in jax.jit(rgb_stem).lower(x, k, b).as_text()
    np.testing.assert_allclose(np.asarray(rgb_stem(x, k, b)), numpy_stem(x, k, b), rtol=1e-5, atol=1e-5)


def test_bad_shapes_raise():
    """The function's own check raises ``ValueError`` naming the expected and the given shapes; under
    the test suite's jaxtyping hook (pyproject ``--jaxtyping-packages``) the annotation check runs
    first and names the offending parameter."""
    import inspect

    x, k, b = _inputs((1, 8, 8, 3), 16)
    plain = inspect.unwrap(rgb_stem)  # without the jaxtyping/beartype wrapper
    with pytest.raises(ValueError, match=re.escape("rgb_stem expects x (B,H,W,3), kernel (3,3,3,C), bias (C,); "
                                                   "got (1, 8, 8, 2), (3, 3, 2, 16), (16,)")):
        plain(x[..., :2], k[:, :, :2], b)
    with pytest.raises(ValueError, match=re.escape("got (1, 8, 8, 3), (3, 3, 3, 16), (8,)")):
        plain(x, k, b[:8])
    with pytest.raises(ValueError, match=re.escape("got (8, 8, 3), (3, 3, 3, 16), (16,)")):
        plain(x[0], k, b)
    if plain is not rgb_stem:
        from jaxtyping import TypeCheckError

        with pytest.raises(TypeCheckError, match="parameter 'x'"):
            rgb_stem(x[..., :2], k[:, :, :2], b)
        with pytest.raises(TypeCheckError, match="parameter 'bias'"):
            rgb_stem(x, k, b[:8])


def test_without_compiler_falls_back_with_a_warning(tmp_path):
    code = ("import warnings, numpy as np\n"
            "from privslam_jax.detect.rgb_stem import native_stem_available, rgb_stem\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            "    print(native_stem_available(), any('XLA' in str(m.message) for m in w))\n"
            "x = np.ones((1, 4, 4, 3), np.float32); k = np.ones((3, 3, 3, 16), np.float32)\n"
            "print(rgb_stem(x, k, np.zeros(16, np.float32)).shape)\n")
    env = dict(os.environ, CXX=str(tmp_path / "no-such-compiler"), PRIVSLAM_CACHE=str(tmp_path / "cache"),
               JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True", "(1,", "2,", "2,", "16)"]
