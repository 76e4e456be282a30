"""Strict test settings (in the manner of optimistix/equinox).

* XLA flags as the CLI sets them, before jax is imported.
* ``jax_numpy_rank_promotion = "raise"``: implicit rank broadcasting is a bug here.
* warnings are errors (pyproject ``filterwarnings``); jaxtyping + beartype check every
  annotated function of the package (pyproject ``--jaxtyping-packages``).
* ``shared`` fixture: the ``../shared`` folder, or a skip with the reason.
* ``count_compiles`` fixture: a context manager that counts the XLA programs compiled inside it.
* one persistent XLA compilation cache per test run (a temporary folder, removed at the end, instead
  of the user cache ``configure_xla`` would pick), shared by the xdist workers and every subprocess
  they start: a program compiled once (the renderer, a train step, a CLI stage) is loaded, not
  compiled again, by the next process that needs it.  A cached executable is what XLA compiled for
  the same program and flags, so this changes run time only.  A ``JAX_COMPILATION_CACHE_DIR`` set by the caller is used as it is and kept.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

from privslam_jax._xla import configure_xla

# The run's compilation cache (module docstring), made when the controller (or the only process)
# imports this file, before the xdist workers start: they and their subprocesses inherit it.
_OWN_CACHE = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _OWN_CACHE = os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="privslam_jax-xla-cache-")
configure_xla()

import jax  # noqa: E402
import pytest  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402

jax.config.update("jax_numpy_rank_promotion", "raise")


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


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


SLOWEST_MODULES = ("test_data_parallel.py", "test_notebooks.py", "test_tradeoff_train.py", "test_pipeline.py",
                   "test_solvers.py", "test_tradeoff_objectives.py", "test_resume_training.py", "test_slam_atlas.py",
                   "test_pareto_tradeoff.py", "test_slam_loop.py", "test_filter_image.py", "test_localize.py",
                   "test_edge.py", "test_attack_gradients.py", "test_yolo11_model.py", "test_inpaint_train.py",
                   "test_optimised_lift.py")
"""The modules with the most worker time, slowest first, as ``python benchmarks/suite_time.py`` lists
them (a run at 9d5ec08); the rest of the 86 modules took less than the last of these."""


def pytest_collection_modifyitems(config, items):
    """Slowest modules first, the rest in collection order: ``--dist loadfile`` (with
    ``--no-loadscope-reorder``, pyproject addopts) hands files out in this order, so the two workers
    end together instead of one waiting on a long file handed out last.  xdist's own reordering puts
    files with many tests first, which leaves the few-test, long files (data-parallel training, the
    loop world) to the end."""
    if missing := [name for name in SLOWEST_MODULES if not (Path(__file__).parent / name).is_file()]:
        raise pytest.UsageError(f"tests/conftest.py SLOWEST_MODULES names modules that do not exist: {missing}")
    rank = {name: i for i, name in enumerate(SLOWEST_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_configure(config):
    if os.environ.get("PRIVSLAM_TEST_TIMES"):  # benchmarks/suite_time.py: per-test wall and compile seconds
        config.pluginmanager.register(_TestTimes(os.environ["PRIVSLAM_TEST_TIMES"]))


class _TestTimes:
    """Appends ``{"id", "wall", "start", "worker", "<event>": seconds}`` per test to ``$PRIVSLAM_TEST_TIMES`` (one JSON line
    each; every xdist worker appends), the events being JAX's ``/jax/core/compile/*_duration``:
    tracing, lowering and XLA compilation in this process (not in subprocesses it starts)."""

    def __init__(self, path: str):
        import collections
        import jax.monitoring

        self.path, self.seconds = path, collections.Counter()
        jax.monitoring.register_event_duration_secs_listener(
            lambda event, secs, **kw: self.seconds.update({event.rsplit("/", 1)[-1]: secs})
            if event.startswith("/jax/core/compile/") else None)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        import json
        import time

        self.seconds.clear()
        start, begun = time.perf_counter(), time.time()
        yield
        row = {"id": item.nodeid, "wall": time.perf_counter() - start, "start": begun,
               "worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), **self.seconds}
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")
