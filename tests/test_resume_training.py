"""A training process killed by SIGKILL between two checkpoints, then resumed with the same command,
ends with exactly the weights of an uninterrupted run (issue 22 item 4).

Both trainers run as real subprocesses through their command lines (``train/detector.py``,
``train/inpaint.py``) on tiny synthetic data. The run to be killed is killed with SIGKILL once its
first checkpoint is on disk and before the next one; then the same command resumes it to the end
while the uninterrupted run (same command, another folder) runs beside it. Every leaf of the final orbax checkpoint
(weights, BatchNorm statistics, EMA, optimiser moments, step) and the exported ``.npz`` must be
bit-identical: data order and augmentation are pure functions of (seed, step) and XLA on CPU is
deterministic, so no tolerance is needed.

The three processes share a persistent XLA compilation cache (in ``tmp_path``) so only the first
one compiles the train steps; a cached executable is the one XLA compiled for the same
program, so this changes the run time only.

The detector's SIGKILL run is ``slow`` (docs/testing.md); the default command resumes the detector
from a checkpoint in one process instead, and kills the inpainter.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 600.0
"""Seconds any one wait may take before the test fails (the machine may be busy)."""


@dataclasses.dataclass
class _Proc:
    name: str
    popen: subprocess.Popen


class _Runner:
    """Starts training subprocesses (output to files) and kills whatever is left at the end."""

    def __init__(self, tmp_path: Path):
        self.tmp = tmp_path
        self.procs: list[_Proc] = []
        self.env = dict(os.environ)
        self.env.update(JAX_COMPILATION_CACHE_DIR=str(tmp_path / "xla_cache"),
                        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PLATFORMS="cpu")

    def start(self, name: str, argv: list[str]) -> _Proc:
        with (self.tmp / f"{name}.out").open("w") as out, (self.tmp / f"{name}.err").open("w") as err:
            p = _Proc(name, subprocess.Popen([sys.executable, *argv], cwd=REPO, env=self.env, stdout=out,
                                             stderr=err, stdin=subprocess.DEVNULL))
        self.procs.append(p)
        return p

    def log(self, p: _Proc) -> str:
        return (self.tmp / f"{p.name}.out").read_text() + (self.tmp / f"{p.name}.err").read_text()[-3000:]

    def wait_ok(self, p: _Proc) -> None:
        try:
            rc = p.popen.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{p.name} still running after {TIMEOUT} s:\n{self.log(p)}") from None
        assert rc == 0, f"{p.name} exited {rc}:\n{self.log(p)}"

    def kill_when(self, p: _Proc, ready: Callable[[], bool]) -> None:
        """Poll ``ready()`` every few ms; SIGKILL ``p`` as soon as it holds."""
        deadline = time.monotonic() + TIMEOUT
        while not ready():
            assert p.popen.poll() is None, f"{p.name} ended (rc {p.popen.returncode}) before the kill:\n{self.log(p)}"
            assert time.monotonic() < deadline, f"{p.name}: not ready after {TIMEOUT} s:\n{self.log(p)}"
            time.sleep(0.002)
        p.popen.send_signal(signal.SIGKILL)
        assert p.popen.wait(timeout=60) == -signal.SIGKILL

    def cleanup(self) -> None:
        for p in self.procs:
            if p.popen.poll() is None:
                p.popen.kill()
                p.popen.wait(timeout=60)


@contextlib.contextmanager
def _runner(tmp_path: Path) -> Iterator[_Runner]:
    r = _Runner(tmp_path)
    try:
        yield r
    finally:
        r.cleanup()


def _programs(cache: Path, name: str) -> set[str]:
    """Distinct cached programs called ``name`` (an entry is ``<name>-<key>-cache``, with an
    ``-atime`` file beside it when the cache has a size limit, ``JAX_COMPILATION_CACHE_MAX_SIZE``)."""
    return {p.name[len(name) + 1:].split("-")[0] for p in cache.glob(f"{name}-*")}


def _finalized(ckpt_dir: Path) -> list[int]:
    """Steps of the finished orbax checkpoints (a save in progress is a ``<step>.orbax-checkpoint-tmp*`` folder)."""
    if not ckpt_dir.is_dir():
        return []
    return sorted(int(p.name) for p in ckpt_dir.iterdir() if p.is_dir() and p.name.isdigit())


def _restore(step_dir: Path) -> list[tuple[str, np.ndarray]]:
    import orbax.checkpoint as ocp

    with ocp.StandardCheckpointer() as c:
        tree = c.restore(step_dir.resolve() / "default")
    return [(jax.tree_util.keystr(k), np.asarray(v)) for k, v in jax.tree_util.tree_leaves_with_path(tree)]


def _assert_same_leaves(a: list[tuple[str, np.ndarray]], b: list[tuple[str, np.ndarray]], min_leaves: int) -> None:
    assert [k for k, _ in a] == [k for k, _ in b] and len(a) >= min_leaves
    for (k, x), (_, y) in zip(a, b, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape, k
        np.testing.assert_array_equal(x, y, err_msg=k)


def _assert_same_npz(a: Path, b: Path) -> None:
    with np.load(a) as x, np.load(b) as y:
        assert sorted(x.files) == sorted(y.files) and len(x.files) > 10
        for k in x.files:
            np.testing.assert_array_equal(x[k], y[k], err_msg=k)


def _yolo_dataset(root: Path, n: int = 8, size: int = 64) -> None:
    """``n`` flat images with two coloured boxes each (class 0 red, 1 green), YOLO layout."""
    rng = np.random.default_rng(0)
    (root / "images" / "train").mkdir(parents=True)
    (root / "labels" / "train").mkdir(parents=True)
    for i in range(n):
        img = np.full((size, size, 3), 60, np.uint8)
        lines = []
        for _ in range(2):
            c = int(rng.integers(0, 2))
            w, h = (int(v) for v in rng.integers(12, 30, 2))
            x, y = int(rng.integers(0, size - w)), int(rng.integers(0, size - h))
            img[y : y + h, x : x + w] = (220, 40, 40) if c == 0 else (40, 220, 40)
            lines.append(f"{c} {(x + w / 2) / size:.6f} {(y + h / 2) / size:.6f} {w / size:.6f} {h / size:.6f}")
        cv2.imwrite(str(root / "images" / "train" / f"{i:03d}.png"), img[..., ::-1])
        (root / "labels" / "train" / f"{i:03d}.txt").write_text("\n".join(lines) + "\n")


def test_detector_resumed_in_process_ends_with_the_weights_of_an_uninterrupted_run(tmp_path):
    """``train`` to step 2 with a checkpoint, then the same config to step 4 (it resumes from
    checkpoint 2), against an uninterrupted 4-step run: every leaf of the final checkpoint
    (weights, BatchNorm statistics, EMA, optimiser moments, step) bit-identical.  The in-process
    counterpart of the SIGKILL test below (slow), as ``tests/test_inpaint_train.py`` is the inpainter's."""
    from privslam_jax.detect.train import TrainConfig, train

    _yolo_dataset(tmp_path / "ds")

    def config(run: str, steps: int) -> TrainConfig:
        return TrainConfig(data=str(tmp_path / "ds"), num_classes=2, scale="tiny", imgsz=64, batch_size=2, epochs=1,
                           warmup_epochs=0.0, max_steps=steps, ckpt_every=2, ckpt_dir=str(tmp_path / run))

    train(config("resumed", 2), progress=False)
    assert _finalized(tmp_path / "resumed") == [2]
    at_2 = _restore(tmp_path / "resumed" / "2")
    train(config("resumed", 4), progress=False)
    train(config("full", 4), progress=False)
    assert _finalized(tmp_path / "resumed")[-1] == _finalized(tmp_path / "full")[-1] == 4
    at_4 = _restore(tmp_path / "resumed" / "4")
    _assert_same_leaves(_restore(tmp_path / "full" / "4"), at_4, min_leaves=500)
    # steps 3-4 trained: the weights moved
    assert sum(not np.array_equal(x, y) for (k, x), (_, y) in zip(at_2, at_4, strict=True) if "kernel" in k) > 50


@pytest.mark.slow
def test_detector_killed_between_checkpoints_resumes_to_identical_weights(tmp_path):
    """Left to ``-m slow`` (43 s of the README's test command, the inpainter's test below 17 s), which
    checks instead: a SIGKILL between orbax checkpoints with the inpainter (below), and the
    detector's resume from a checkpoint in one process (above)."""
    _yolo_dataset(tmp_path / "ds")
    # 8 images, batch 2, 3 epochs: 12 steps, orbax checkpoints (asynchronous) after steps 4, 8 and 12
    def command(run: str) -> list[str]:
        return ["train/detector.py", "--data", str(tmp_path / "ds"), "--num-classes", "2", "--scale", "tiny",
                "--imgsz", "64", "--batch", "2", "--epochs", "3", "--warmup-epochs", "0", "--ckpt-every", "4",
                "--ckpt-dir", str(tmp_path / run / "ckpt"), "--out", str(tmp_path / run / "detector.npz")]

    with _runner(tmp_path) as r:
        killed = r.start("killed", command("killed"))
        ckpt = tmp_path / "killed" / "ckpt"
        # kill as soon as checkpoint 4 is complete: checkpoint 8 cannot be complete yet (its save
        # starts only once the save of 4 has finished), at most being written
        r.kill_when(killed, lambda: 4 in _finalized(ckpt))
        assert _finalized(ckpt) == [4]
        assert not (tmp_path / "killed" / "detector.npz").exists()
        at_4 = _restore(ckpt / "4")
        resumed = r.start("resumed", command("killed"))  # the same command again
        full = r.start("full", command("full"))  # uninterrupted, from the compilation cache the killed run filled
        r.wait_ok(resumed)
        r.wait_ok(full)
    first = re.search(r"(\d+)/12 \[", (tmp_path / "resumed.err").read_text())
    assert first is not None and first.group(1) == "4", "the resumed run did not start from checkpoint 4"
    assert "after 12 steps" in (tmp_path / "resumed.out").read_text()
    assert _finalized(tmp_path / "full" / "ckpt")[-1] == _finalized(ckpt)[-1] == 12
    at_12 = _restore(ckpt / "12")
    _assert_same_leaves(_restore(tmp_path / "full" / "ckpt" / "12"), at_12, min_leaves=500)
    _assert_same_npz(tmp_path / "full" / "detector.npz", tmp_path / "killed" / "detector.npz")
    # steps 5-12 trained: the weights moved
    assert sum(not np.array_equal(x, y) for (k, x), (_, y) in zip(at_4, at_12, strict=True) if "kernel" in k) > 50
    assert len(_programs(tmp_path / "xla_cache", "jit_step_fn")) == 1  # one compiled train step for all runs


def _log_rows(workdir: Path) -> list[str]:
    path = workdir / "log.csv"
    return path.read_text().splitlines()[1:] if path.is_file() else []


def test_inpainter_killed_between_checkpoints_resumes_to_identical_weights(tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:40, 0:48]
    for i in range(3):
        img = np.stack([(xx * rng.uniform(2, 5) + yy * rng.uniform(0, 3) + (yy > rng.integers(5, 35)) * 90) % 256
                        for _ in range(3)], -1).astype(np.uint8)
        cv2.imwrite(str(images / f"{i}.png"), img)
    # 32 steps (edge 2, inpaint 2, joint 28), synchronous orbax checkpoints after steps 16 and 32
    def command(run: str) -> list[str]:
        return ["train/inpaint.py", "--folder", str(images), "--width", "4", "--blocks", "1", "--size", "32",
                "--batch", "2", "--steps", "2,2,28", "--checkpoint-every", "16", "--sample-every", "0",
                "--workdir", str(tmp_path / run), "--export", str(tmp_path / run / "inpainter.npz")]

    work = tmp_path / "killed"
    with _runner(tmp_path) as r:
        killed = r.start("killed", command("killed"))
        # kill two steps after checkpoint 16, well before checkpoint 32: steps 17 and 18 (at least) are lost
        r.kill_when(killed, lambda: len(_log_rows(work)) >= 18)
        before = _log_rows(work)
        assert _finalized(work / "checkpoints") == [16] and 18 <= len(before) < 32, (before, _finalized(work / "checkpoints"))
        assert not (work / "inpainter.npz").exists()
        resumed = r.start("resumed", command("killed"))
        full = r.start("full", command("full"))
        r.wait_ok(resumed)
        r.wait_ok(full)
    after, reference = _log_rows(work), _log_rows(tmp_path / "full")
    # the resumed run kept the killed run's rows up to its checkpoint (timings included) and redid the rest
    assert after[:16] == before[:16], "the resumed run did not start from checkpoint 16"
    assert len(after) == len(reference) == 32
    columns = lambda rows: [(s, stage, losses) for s, stage, _, losses in (row.split(",") for row in rows)]  # noqa: E731
    assert columns(after[16 : len(before)]) == columns(before[16:])  # the redone steps had the same losses
    assert columns(after) == columns(reference)
    assert _finalized(tmp_path / "full" / "checkpoints")[-1] == _finalized(work / "checkpoints")[-1] == 32
    _assert_same_leaves(_restore(tmp_path / "full" / "checkpoints" / "32"), _restore(work / "checkpoints" / "32"),
                        min_leaves=100)
    _assert_same_npz(tmp_path / "full" / "inpainter.npz", work / "inpainter.npz")
    # the resumed run reused the killed run's compiled steps (restored arrays were once committed to
    # the device, a different jit signature: every step compiled twice)
    for fn in ("_edge_g_step", "_edge_d_step", "_inpaint_g_step", "_inpaint_d_step"):
        assert len(_programs(tmp_path / "xla_cache", f"jit_{fn}")) == 1, fn
