"""Strict test settings (in the manner of optimistix/equinox).

* XLA flags as the CLI sets them, before jax is imported.
* ``jax_numpy_rank_promotion = "raise"``: implicit rank broadcasting is a bug here.
* warnings are errors (pyproject ``filterwarnings``); jaxtyping + beartype check every
  annotated function of the package (pyproject ``--jaxtyping-packages``).
* ``shared`` fixture: the ``../shared`` folder, or a skip with the reason.
* ``count_compiles`` fixture: a context manager that counts the XLA programs compiled inside it.
* one persistent XLA compilation cache per test run (a temporary folder, removed at the end), shared
  by the xdist workers and every subprocess they start: a program compiled once (the renderer, a
  train step, a CLI stage) is loaded, not compiled again, by the next process that needs it.  A
  cached executable is what XLA compiled for the same program and flags, so this changes run time
  only.  A ``JAX_COMPILATION_CACHE_DIR`` set by the caller is used as it is and kept.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile

from privslam_jax._xla import configure_xla

configure_xla()

import jax  # noqa: E402
import pytest  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402

jax.config.update("jax_numpy_rank_promotion", "raise")

_CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"


def pytest_configure(config):
    """The run's compilation cache (module docstring): made by the controller (or the only process)
    before the xdist workers start, so that they and their subprocesses inherit it."""
    if not hasattr(config, "workerinput") and _CACHE_ENV not in os.environ:
        config._privslam_cache = tempfile.mkdtemp(prefix="privslam_jax-xla-cache-")
        os.environ[_CACHE_ENV] = config._privslam_cache
    if os.environ.get(_CACHE_ENV):
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")  # measured: small programs pay too
        jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_ENV])
        jax.config.update("jax_persistent_cache_min_compile_time_secs",
                          float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))


def pytest_unconfigure(config):
    cache = getattr(config, "_privslam_cache", None)
    if cache is not None:
        shutil.rmtree(cache, ignore_errors=True)


@pytest.fixture(scope="session")
def shared():
    """Path to ``../shared``; skips the test when it is absent."""
    path = shared_dir()
    if path is None:
        pytest.skip("../shared is absent (set PRIVSLAM_SHARED to its location)")
    return path


@pytest.fixture
def count_compiles():
    """``with count_compiles() as names: ...`` lists the programs JAX compiled inside the block
    (``jax.log_compiles``' "Compiling <name>" records; a persistent-cache hit still counts, as it is
    a program this process had not built yet)."""

    @contextlib.contextmanager
    def counting():
        names: list[str] = []

        class Handler(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                msg = record.getMessage()
                if msg.startswith("Compiling "):
                    names.append(msg.split()[1])

        handler = Handler(logging.DEBUG)
        logger = logging.getLogger("jax")
        logger.addHandler(handler)
        try:
            with jax.log_compiles(True):
                yield names
        finally:
            logger.removeHandler(handler)

    return counting
