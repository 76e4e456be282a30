"""Experiment scripts refuse an input they cannot use before any work and before ``../shared`` is needed
(exit 2): ``table1b_real_recall.py --weights``, ``inpaint_real.py --model``, ``inpaint_blend_scan.py --model``."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "experiments" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def table1b():
    return _load("table1b_real_recall")


@pytest.fixture(scope="module")
def inpaint_real():
    return _load("inpaint_real")


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


def test_table1b_refuses_a_shared_folder_without_its_sets(table1b, tmp_path, capsys, monkeypatch):
    """A ``../shared`` that lacks one of the evaluation sets is refused before any work, naming it."""
    shared = tmp_path / "shared"
    (shared / "weights").mkdir(parents=True)
    (shared / "weights" / "yolov8n.pt").write_bytes(b"")
    for rel in ("data/real/kitti_object/image_2", "data/real/kitti_raw_a/frames"):
        (shared / rel).mkdir(parents=True)
        (shared / rel / "000000.png").write_bytes(b"")
    monkeypatch.setenv("PRIVSLAM_SHARED", str(shared))
    assert table1b.main(["--out", str(tmp_path / "t.md")]) == 2
    err = capsys.readouterr().err
    assert "data/real/nuscenes_front/images" in err and "kitti_object" not in err
    assert not (tmp_path / "t.md").exists()


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


@pytest.mark.parametrize("kind, message", [("missing", "not found"), ("corrupt", "bad.npz"), ("white", "prefill is white")])
def test_inpaint_blend_scan_refuses_a_bad_model(kind, message, tmp_path, capsys, monkeypatch):
    from privslam_jax.inpaint.filter import EMBEDDED_INPAINTER

    monkeypatch.setenv("PRIVSLAM_SHARED", str(tmp_path / "absent"))  # refused before ../shared is needed
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz")
    model = {"missing": tmp_path / "none.npz", "corrupt": bad, "white": EMBEDDED_INPAINTER}[kind]  # the synthetic one: white
    with pytest.raises(SystemExit) as exc:
        _load("inpaint_blend_scan").main(["--model", str(model)])
    assert exc.value.code == 2 and message in capsys.readouterr().err
