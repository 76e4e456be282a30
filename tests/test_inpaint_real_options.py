"""``experiments/inpaint_real.py`` refuses a ``--model`` it cannot use before any work (exit 2)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def inpaint_real():
    spec = importlib.util.spec_from_file_location("inpaint_real", ROOT / "experiments/inpaint_real.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("kind, message", [("missing", "not found"), ("corrupt", "bad.npz"), ("no-name", "NAME=PATH")])
def test_inpaint_real_refuses_a_bad_model(inpaint_real, kind, message, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PRIVSLAM_SHARED", str(tmp_path / "absent"))  # refused before ../shared is needed
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz")
    spec = {"missing": f"m={tmp_path / 'none.npz'}", "corrupt": f"m={bad}", "no-name": str(bad)}[kind]
    with pytest.raises(SystemExit) as exc:
        inpaint_real.main(["--model", spec, "--out", str(tmp_path / "t.md")])
    assert exc.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "t.md").exists()
