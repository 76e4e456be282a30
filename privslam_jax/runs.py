"""Run folders: a manifest that says what made a folder and whether it finished.

A command that owns its output folder (``privslam run``, ``slam``, ``detect``; ``filter`` and
``synth`` own the sequence folder they write, ``DIR/sequences/NAME``, and ``DIR/poses/NAME.txt``
beside it) first claims it with :func:`claim_run_folder`: the folder must be new or empty, or hold
an earlier privslam run (``manifest.json``) and come with ``overwrite=True``, which clears it
first. Anything else is refused, so a rerun never mixes its files with another run's, and
``--overwrite`` never deletes a folder privslam did not write. The manifest records the command, its arguments, the versions of
the software and ``"complete": false``; :func:`complete_run_folder` rewrites it with
``"complete": true`` after the command succeeded. A folder whose manifest says ``false`` is a run
that died or failed: its files are not results.
"""

from __future__ import annotations

import json
import math
import platform
import shutil
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any

from privslam_jax.data.files import write_atomic

__all__ = ["MANIFEST", "check_run_folder", "claim_run_folder", "complete_run_folder", "read_manifest", "run_is_complete"]

MANIFEST = "manifest.json"


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in ("privslam_jax", "jax", "flax", "optax", "numpy", "opencv-python-headless"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def read_manifest(folder: str | Path) -> dict[str, Any] | None:
    """The folder's manifest, ``None`` without one; a manifest that is not JSON is an error naming it."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path} is not a privslam manifest ({err})") from None


def run_is_complete(folder: str | Path) -> bool:
    """``folder`` holds a privslam run that finished (its manifest says ``"complete": true``)."""
    manifest = read_manifest(folder)
    return bool(manifest and manifest.get("complete") is True)


def check_run_folder(out: str | Path, overwrite: bool = False, companions: tuple[Path, ...] = ()) -> dict[str, Any] | None:
    """Raise ``ValueError`` if :func:`claim_run_folder` would refuse ``out``; writes nothing.

    Returns the earlier run's manifest (``None`` if there is none).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder")
    previous = read_manifest(out) if out.is_dir() else None
    if out.is_dir() and any(out.iterdir()):
        if previous is None:
            raise ValueError(f"--out {out} is not empty and holds no privslam run ({MANIFEST}); choose a new folder "
                             "(--overwrite only clears folders privslam wrote)")
        if not overwrite:
            state = "finished" if previous.get("complete") else "unfinished"
            raise ValueError(f"--out {out} holds an earlier {state} `privslam {previous.get('command', '?')}` run; "
                             "choose a new folder or pass --overwrite to clear it first")
    for path in companions:
        if path.exists() and previous is None:
            raise ValueError(f"{path} already exists and no privslam run in {out} owns it; choose a new --out")
    return previous


def claim_run_folder(out: str | Path, command: str, arguments: dict[str, Any], overwrite: bool = False,
                     companions: tuple[Path, ...] = ()) -> dict[str, Any]:
    """Make ``out`` this run's folder and write its manifest (``"complete": false``); returns the manifest.

    ``companions``: files outside ``out`` that the run writes too (``filter``/``synth``:
    ``DIR/poses/NAME.txt``); one that exists is cleared with an earlier run of ``out`` and refused
    when no earlier run of ``out`` owns it.

    Raises ``ValueError`` if ``out`` is a file, holds files of something else, or holds another
    run and ``overwrite`` is false, or a companion exists that no earlier run of ``out`` owns
    (:func:`check_run_folder`, which commands call first when they can refuse bad input before
    writing anything).
    """
    out = Path(out)
    if check_run_folder(out, overwrite, companions) is not None:  # an earlier run, and overwrite: clear it
        for child in out.iterdir():
            shutil.rmtree(child) if child.is_dir() and not child.is_symlink() else child.unlink()
        for path in companions:
            path.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    manifest = {"command": command, "argv": sys.argv[1:], "arguments": arguments, "versions": _versions(),
                "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "complete": False}
    write_atomic(out / MANIFEST, _manifest_json(manifest))
    return manifest


def complete_run_folder(out: str | Path, manifest: dict[str, Any]) -> None:
    """Mark the run finished: the manifest, rewritten last with ``"complete": true``."""
    done = dict(manifest, complete=True, finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    write_atomic(Path(out) / MANIFEST, _manifest_json(done))


def _strict(value: Any) -> Any:
    """``value`` with every non-finite float as its string (``"inf"``, ``"nan"``): JSON has no Infinity."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    return value


def _manifest_json(manifest: dict[str, Any]) -> str:
    """The manifest as strict JSON (an argument such as ``--stereo-max-depth-baselines inf`` included)."""
    return json.dumps(_strict(manifest), indent=1, default=str, allow_nan=False) + "\n"
