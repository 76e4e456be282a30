"""Worker processes for experiments that run whole SLAM jobs in parallel.

:func:`process_pool` is a :class:`concurrent.futures.ProcessPoolExecutor` with the two settings
every such experiment needs:

- **spawn**, not fork: JAX's runtime threads do not survive ``fork``;
- **workers die with their parent**: a run killed with ``kill`` or ``SIGKILL`` (or a closed
  terminal) would otherwise leave its workers running their SLAM jobs, sharing the CPU with the
  next run for tens of minutes. Each worker watches its parent process id and exits as soon as it
  changes (the parent died and the worker was re-parented).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor

__all__ = ["process_pool"]


def _exit_with_parent(parent: int, period: float) -> None:
    """Worker initializer: a daemon thread that ends the worker once ``parent`` is gone."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period)
        os._exit(1)  # no cleanup: the parent that would collect the result is gone

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def process_pool(jobs: int, *, max_tasks_per_child: int | None = None, period: float = 0.5) -> ProcessPoolExecutor:
    """A spawn-context process pool of ``max(jobs, 1)`` workers that exit within ``period`` seconds
    of their parent's death. ``max_tasks_per_child=1`` gives every task a fresh process."""
    return ProcessPoolExecutor(max(jobs, 1), mp_context=mp.get_context("spawn"),
                               max_tasks_per_child=max_tasks_per_child,
                               initializer=_exit_with_parent, initargs=(os.getpid(), period))
