"""``privslam_jax.pool.process_pool``: a killed experiment leaves no workers running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PARENT = """
import os, sys, time
from privslam_jax.pool import process_pool

pool = process_pool(1)
print(pool.submit(os.getpid).result(), flush=True)  # the worker's pid
pool.submit(time.sleep, 120)                         # a long job, as a SLAM run
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    """Running (a zombie, which nobody may reap in a container, counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_workers_exit_when_their_parent_is_killed():
    """SIGKILL on the parent (no cleanup runs there): the busy worker is gone within a few seconds.
    A plain spawn ProcessPoolExecutor keeps it running its job (checked below as the reference)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for source, should_exit in ((PARENT, True),
                                (PARENT.replace("process_pool(1)", "__import__('concurrent.futures').futures"
                                                ".ProcessPoolExecutor(1, mp_context=__import__('multiprocessing')"
                                                ".get_context('spawn'))"), False)):
        with subprocess.Popen([sys.executable, "-c", source], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              env=env) as parent:
            worker = int(parent.stdout.readline())
            assert _alive(worker)
            parent.send_signal(signal.SIGKILL)
            parent.wait(10)
            deadline = time.monotonic() + 5
            while _alive(worker) and time.monotonic() < deadline:
                time.sleep(0.1)
            survived = _alive(worker)
            if survived:
                os.kill(worker, signal.SIGKILL)
        assert survived != should_exit, (source, should_exit)
