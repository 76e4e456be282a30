"""The YOLOv8 stem, ``SiLU(conv3x3/2(x) + b)`` on a 3-channel image, with a native CPU kernel.

XLA:CPU runs a convolution with 3 input channels through Eigen's generic spatial convolution,
3-4× slower than ultralytics' oneDNN (the stem took 6.1 of 75 ms of the YOLOv8n forward at
384×1248 against 1.7 ms in torch; ``python benchmarks/bench_detector.py --layers``). No XLA option
or rewrite of the convolution closed that gap (docs/detector.md), so the inference forward runs
``rgb_stem.cc``: a direct convolution that keeps each pixel's output channels in vector registers,
fused with bias and SiLU, spread over XLA's own thread pool, called through the XLA FFI
(`jax.ffi <https://docs.jax.dev/en/latest/ffi.html>`_).

The kernel is compiled on first use with the machine's C++ compiler (``$CXX``, else ``c++``;
``-O3 -march=native``) against the FFI headers that jaxlib ships, into
``$PRIVSLAM_CACHE`` (default ``~/.cache/privslam_jax``), keyed by source, jaxlib version, compiler
and CPU; later processes load the cached library. Without a compiler, on a non-CPU backend, for
other dtypes or channel counts, or with ``PRIVSLAM_NATIVE=0``, :func:`rgb_stem` is the plain XLA
convolution (same function; when the build or load fails, a warning says why).

Gradients: :func:`rgb_stem` has a custom VJP that differentiates the XLA formulation
(:func:`rgb_stem_reference`), so training and end-to-end optimisation through a fused detector
work unchanged.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlib
from jaxtyping import Array, Float

__all__ = ["rgb_stem", "rgb_stem_reference", "native_stem_available", "NATIVE_CHANNELS"]

SOURCE = Path(__file__).with_name("rgb_stem.cc")
TARGET = "privslam_rgb_stem"
NATIVE_CHANNELS = (8, 16, 32, 48, 64, 80)
"""Output channel counts the kernel is instantiated for (YOLOv8 stems of scales tiny, n, s, m, l, x)."""
_FLAGS = ("-O3", "-march=native", "-ffast-math", "-fopenmp-simd", "-std=c++17",
          "-shared", "-fPIC", "-w")  # fast-math: vectorised expf (glibc libmvec)


def rgb_stem_reference(x: Float[Array, "B H W 3"], kernel: Float[Array, "3 3 3 C"],
                       bias: Float[Array, " C"]) -> Float[Array, "B h w C"]:
    """``SiLU(conv(x, kernel, stride 2, padding 1) + bias)`` in XLA (the function the kernel computes)."""
    y = jax.lax.conv_general_dilated(x, kernel, (2, 2), ((1, 1), (1, 1)), dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return jax.nn.silu(y + bias[None, None, None, :])


def _cpu_id() -> str:
    try:
        info = Path("/proc/cpuinfo").read_text()
        return "".join(line for line in info.splitlines()[:40] if line.startswith(("model name", "flags")))
    except OSError:
        return platform.processor()


def _build() -> Path:
    """Compile ``rgb_stem.cc`` into the cache (once per source, jaxlib, compiler and CPU); return the library."""
    cxx = os.environ.get("CXX", "c++")
    if shutil.which(cxx) is None:
        raise RuntimeError(f"no C++ compiler {cxx!r} on PATH (set $CXX)")
    include = jax.ffi.include_dir()
    key = hashlib.sha256("\0".join([SOURCE.read_text(), jax.__version__, jaxlib.__version__, cxx, " ".join(_FLAGS), _cpu_id(),
                                    platform.machine()]).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("PRIVSLAM_CACHE", Path.home() / ".cache" / "privslam_jax"))
    library = cache / f"rgb_stem-{key}.so"
    if library.is_file():
        return library
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:  # build aside, then rename: safe with parallel processes
        out = Path(tmp) / library.name
        done = subprocess.run([cxx, *_FLAGS, "-I", include, str(SOURCE), "-o", str(out)], capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"{cxx} failed on {SOURCE.name}:\n{done.stderr[-2000:]}")
        os.replace(out, library)
    return library


@functools.cache
def native_stem_available() -> bool:
    """Whether the native kernel is built, loaded and registered (built on the first call)."""
    if os.environ.get("PRIVSLAM_NATIVE", "1") == "0":
        return False
    try:
        library = ctypes.cdll.LoadLibrary(str(_build()))
        jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(library.PrivslamRgbStem), platform="cpu")
    except (OSError, RuntimeError, AttributeError) as err:
        warnings.warn(f"native YOLOv8 stem kernel unavailable, using XLA's convolution (slower): {err}", stacklevel=2)
        return False
    return True


def _native(x, kernel, bias):
    b, h, w, _ = x.shape
    out = jax.ShapeDtypeStruct((b, (h + 1) // 2, (w + 1) // 2, kernel.shape[-1]), jnp.float32)
    call = jax.ffi.ffi_call(TARGET, out, vmap_method="sequential")
    # On another backend (GPU/TPU) the XLA formulation is lowered instead.
    return jax.lax.platform_dependent(x, kernel, bias, cpu=call, default=rgb_stem_reference)


@jax.custom_vjp
def _rgb_stem_native(x, kernel, bias):
    return _native(x, kernel, bias)


def _fwd(x, kernel, bias):
    return _native(x, kernel, bias), (x, kernel, bias)


def _bwd(residuals, g):
    return jax.vjp(rgb_stem_reference, *residuals)[1](g)


_rgb_stem_native.defvjp(_fwd, _bwd)


def rgb_stem(x: Float[Array, "B H W 3"], kernel: Float[Array, "3 3 3 C"],
             bias: Float[Array, " C"]) -> Float[Array, "B h w C"]:
    """``SiLU(conv3x3/2(x) + bias)`` with padding 1: the native kernel where it applies, else XLA.

    ``h = ceil(H / 2)``, ``w = ceil(W / 2)``. Same values as :func:`rgb_stem_reference` up to float
    rounding (summation order); differentiable (the VJP is the reference's).
    """
    if x.ndim != 4 or x.shape[-1] != 3 or kernel.shape[:3] != (3, 3, 3) or bias.shape != kernel.shape[-1:]:
        raise ValueError(f"rgb_stem expects x (B,H,W,3), kernel (3,3,3,C), bias (C,); got {x.shape}, "
                         f"{kernel.shape}, {bias.shape}")
    usable = (x.dtype == kernel.dtype == bias.dtype == jnp.float32 and kernel.shape[-1] in NATIVE_CHANNELS
              and native_stem_available())
    return (_rgb_stem_native if usable else rgb_stem_reference)(x, kernel, bias)
