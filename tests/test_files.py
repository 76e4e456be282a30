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
