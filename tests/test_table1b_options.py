"""``experiments/table1b_real_recall.py`` refuses a ``--weights`` spec it cannot use before any work (exit 2)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def table1b():
    spec = importlib.util.spec_from_file_location("table1b_real_recall", ROOT / "experiments/table1b_real_recall.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("suffix, message", [("", "no such file"), ("@abc", "multiple of 32"), ("@900", "multiple of 32"),
                                             ("@0", "multiple of 32")])
def test_table1b_refuses_a_bad_weights_spec(table1b, suffix, message, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PRIVSLAM_SHARED", str(tmp_path / "absent"))  # the refusal comes before ../shared is needed
    weights = tmp_path / "w.npz"
    if suffix:
        weights.write_bytes(b"")
    with pytest.raises(SystemExit) as exc:
        table1b.main(["--weights", f"{weights}{suffix}", "--out", str(tmp_path / "t.md")])
    assert exc.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "t.md").exists()
