"""Atomic writers (data/files.py): whole new file or the old one, never a part."""

from __future__ import annotations

import os

import numpy as np
import pytest

from privslam_jax.data.files import write_atomic, write_npz


def test_write_npz_roundtrip_and_a_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    path = tmp_path / "weights.bin"  # used as given: np.savez would have written weights.bin.npz
    write_npz(path, compressed=True, a=a, b=np.array("meta"))
    with np.load(path) as d:
        np.testing.assert_array_equal(d["a"], a)
        assert str(d["b"]) == "meta"
    before = path.read_bytes()

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="weights.bin"):
        write_npz(path, a=np.zeros(1000))
    with pytest.raises(OSError, match="notes.txt"):
        write_atomic(tmp_path / "notes.txt", "text")
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["weights.bin"]


def test_trim_log_keeps_whole_rows_up_to_the_checkpoint(tmp_path):
    from privslam_jax.data.files import trim_log

    log = tmp_path / "log.csv"
    header = "step,seconds,loss\n"
    rows = [f"{k},0.5,{k / 10:.6f}\n" for k in range(1, 6)]
    log.write_text(header + "".join(rows) + "6,0.")  # killed while writing step 6
    trim_log(log, 10)
    assert log.read_text() == header + "".join(rows)  # the cut row is gone, the whole ones stay
    log.write_text(header + "".join(rows) + "6,0.")
    trim_log(log, 3)
    assert log.read_text() == header + "".join(rows[:3])  # rows after the checkpoint dropped
    # a row cut to a shorter number ("4" of "40,...") is not mistaken for step 4
    log.write_text(header + "".join(rows[:3]) + "4")
    trim_log(log, 5)
    assert log.read_text() == header + "".join(rows[:3])
    log.write_text("step,sec")  # killed inside the header
    trim_log(log, 5)
    assert log.read_text() == ""
    trim_log(tmp_path / "none.csv", 3)
    assert not (tmp_path / "none.csv").exists()
