"""XLA and JAX settings the command-line entry points apply before JAX runs anything.

Measured on a 2-core CPU (DESIGN §6): this jaxlib hands most convolutions to YNNPACK, which
splits work poorly over two threads; disabling YNN fusion makes the YOLOv8n forward 20-25 %
faster.  XLA's CPU Cholesky calls into the OpenBLAS that scipy ships, whose extra threads made a
306×306 factorisation take 20-500 ms instead of ~1 ms on a busy 2-core machine
(docs/slam_solvers.md), so OpenBLAS runs single-threaded.

Compiled programs are kept in a persistent XLA compilation cache,
``$XDG_CACHE_HOME/privslam_jax/xla`` (``~/.cache/privslam_jax/xla``): the next command that needs
the same program loads it instead of compiling it.  It grows by a few MB per new configuration (the
quick start adds 4.5 MB) and can be deleted at any time.  No size limit: with one, JAX rescans the
folder and reads every entry's access time on each write (``jax/_src/lru_cache.py``), quadratic in
the number of programs, and the test suite writes thousands.  Measured: ``privslam run --out DIR --quiet`` took 94.1 s with an empty cache and 56.1 s the
second time, with the same trajectories (this machine, 2 cores).  A cached executable is what XLA
compiled for the same program, flags and versions, so results do not change.  Set
``JAX_COMPILATION_CACHE_DIR`` to use another folder, or to an empty string to turn the cache off; it
is also off when the folder cannot be written.

User-set values are left untouched.
"""

from __future__ import annotations

import os
from pathlib import Path

_DEFAULT_XLA_FLAGS = "--xla_cpu_experimental_ynn_fusion_type="

OPTIMISED = {"xla_backend_optimization_level": 3, "xla_llvm_disable_expensive_passes": False}
"""``jax.jit(..., compiler_options=OPTIMISED)``: XLA's CPU defaults, kept when ``jax_disable_most_optimizations``
(``JAX_DISABLE_MOST_OPTIMIZATIONS``) turns them off elsewhere.  For programs whose run time dominates
their compile time wherever they are called: the synthetic renderer (at level 0 a 640×192 frame takes
216 ms of device time instead of 22 ms while compiling in 3.1 s instead of 5.3 s, and its pixels
change in the last bits; ``python benchmarks/bench_synth.py --level0``, 2 cores) and EdgeConnect's
forward pass (slower a frame at level 0, compiling no faster).  The test suite turns the
optimisations off for most tests (``tests/conftest.py``)."""


def configure_xla() -> None:
    """Set ``XLA_FLAGS``, ``OPENBLAS_NUM_THREADS`` and the compilation cache to the project defaults
    unless set (call before JAX runs anything: the flags are read when its CPU backend starts)."""
    os.environ.setdefault("XLA_FLAGS", _DEFAULT_XLA_FLAGS)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "privslam_jax" / "xla"
        try:
            cache.mkdir(parents=True, exist_ok=True)
            writable = os.access(cache, os.W_OK | os.X_OK)
        except OSError:
            writable = False
        if writable:  # an unwritable cache would only add a warning per compilation
            os.environ["JAX_COMPILATION_CACHE_DIR"] = str(cache)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")  # small programs add up (module docstring)
    # JAX reads its JAX_* variables when it is imported, and importing this package has imported it:
    # the environment is for subprocesses, the config update for this process
    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
        jax.config.update("jax_persistent_cache_min_compile_time_secs",
                          float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))
