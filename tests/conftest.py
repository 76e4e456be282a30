"""Strict test settings (in the manner of optimistix/equinox).

* XLA flags as the CLI sets them, before jax is imported.
* ``jax_numpy_rank_promotion = "raise"``: implicit rank broadcasting is a bug here.
* warnings are errors (pyproject ``filterwarnings``); jaxtyping + beartype check every
  annotated function of the package (pyproject ``--jaxtyping-packages``).
* ``shared`` fixture: the ``../shared`` folder, or a skip with the reason.
* ``count_compiles`` fixture: a context manager that counts the XLA programs compiled inside it.
* files run longest first (``tests/file_seconds.json``), so the xdist workers end together.
* one persistent XLA compilation cache per test run (a temporary folder, removed at the end, instead
  of the user cache ``configure_xla`` would pick), shared by the xdist workers and every subprocess
  they start: a program compiled once (the renderer, a train step, a CLI stage) is loaded, not
  compiled again, by the next process that needs it.  A cached executable is what XLA compiled for
  the same program and flags, so this changes run time only.  A ``JAX_COMPILATION_CACHE_DIR`` set by the caller is used as it is and kept.
* XLA's optimisations are off (``jax_disable_most_optimizations``, as the Flax examples' tests set
  it; for subprocesses ``JAX_DISABLE_MOST_OPTIMIZATIONS``) except in tests marked ``xla_optimized``:
  most tests run each program a few times, and compiling it takes longer than running it.  The
  marked ones run programs long (SLAM on whole sequences, training loops, the pipeline) or compare
  two compilations of one solve to float64 rounding; they run the code as users compile it.  The
  synthetic renderer and EdgeConnect's forward keep the optimisations everywhere
  (``privslam_jax._xla.OPTIMISED``), so every test renders the frames users get.
  Measured on 2 cores (``benchmarks/suite_time.py``, docs/testing.md): the README's test command
  took 992 s instead of 1180 s with every test optimised (in-process compilation 664 s, not 925 s).
"""

from __future__ import annotations

import contextlib
import json
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
_OPTIMISATION_MODE = jax.make_user_context(default_value=False)  # jit cache key: the mode the program was compiled in


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


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """XLA optimisations off unless the test is marked ``xla_optimized`` (module docstring); set
    before the test's fixtures are made, so that programs a module fixture compiles follow the test."""
    fast = item.get_closest_marker("xla_optimized") is None
    if fast != jax.config.read("jax_disable_most_optimizations"):
        # the setting is not part of jit's in-memory cache key (the persistent cache keys on it):
        # _OPTIMISATION_MODE is, so a program traced and compiled in one mode is not reused in the
        # other, and each mode keeps its programs when tests switch back and forth
        _OPTIMISATION_MODE.set_global(fast)
        jax.config.update("jax_disable_most_optimizations", fast)
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1" if fast else "0"


_FILE_SECONDS = Path(__file__).with_name("file_seconds.json")
"""Each test file's measured wall seconds (``benchmarks/suite_time.py --write-order``)."""


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """Files in the order of their measured cost, longest first (``tests/file_seconds.json``; a file
    not listed counts as 0 s); the tests of a file keep their order (a stable sort).  With
    ``--dist loadfile``, xdist hands out the files in this order (``pytest_configure`` turns off its
    own reordering by test count): the longest-processing-time-first rule, so the workers end
    together instead of one finishing a long file of few tests while the other idles.  Simulated on
    the per-test times of a run (``suite_time.py``): 986 s instead of 1025 s for two workers."""
    if _FILE_SECONDS.is_file():
        seconds = json.loads(_FILE_SECONDS.read_text())
        items.sort(key=lambda item: -seconds.get(item.nodeid.split("::")[0], 0.0))


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist: keep the order above
        config.option.loadscopereorder = False
    if os.environ.get("PRIVSLAM_TEST_TIMES"):  # benchmarks/suite_time.py: per-test wall and compile seconds
        config.pluginmanager.register(_TestTimes(os.environ["PRIVSLAM_TEST_TIMES"]))


class _TestTimes:
    """Appends ``{"id", "wall", "start", "worker", "<event>": seconds, "misses": [...]}`` per test to
    ``$PRIVSLAM_TEST_TIMES`` (one JSON line each; every xdist worker appends), the events being JAX's
    ``/jax/core/compile/*_duration``: tracing, lowering and XLA compilation in this process (not in
    subprocesses it starts).  ``misses`` lists ``[program, persistent-cache key, seconds]`` for each
    program compiled because the compilation cache did not hold it (JAX's "PERSISTENT COMPILATION
    CACHE MISS" debug record, then the compile event that follows it), so a program two tests compile
    under one key shows up."""

    def __init__(self, path: str):
        import collections
        import jax.monitoring

        self.path, self.seconds, self.misses, self.pending = path, collections.Counter(), [], None
        outer = self

        class Misses(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                if record.getMessage().startswith("PERSISTENT COMPILATION CACHE MISS"):
                    outer.pending = [str(a) for a in record.args[:2]]

        compiler_log = logging.getLogger("jax._src.compiler")
        compiler_log.addHandler(Misses(logging.DEBUG))
        compiler_log.setLevel(logging.DEBUG)
        jax.monitoring.register_event_duration_secs_listener(self._event)

    def _event(self, event: str, secs: float, **kwargs) -> None:
        if not event.startswith("/jax/core/compile/"):
            return
        self.seconds.update({event.rsplit("/", 1)[-1]: secs})
        if event.endswith("backend_compile_duration") and self.pending is not None:
            self.misses.append([*self.pending, secs])
            self.pending = None

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        import json
        import time

        self.seconds.clear()
        self.misses = []
        start, begun = time.perf_counter(), time.time()
        yield
        row = {"id": item.nodeid, "wall": time.perf_counter() - start, "start": begun,
               "worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), **self.seconds, "misses": self.misses}
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")
