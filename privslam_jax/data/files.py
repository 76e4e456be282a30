"""Atomic file writes: a reader sees the old file or the whole new one, never a part."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["trim_log", "write_atomic", "write_figure", "write_npz"]


def write_atomic(path: str | os.PathLike, data: bytes | str) -> None:
    """Write ``data`` (``str`` as UTF-8) to a temporary name beside ``path``, then rename it over ``path``.

    Any failure (full disk, a folder in the way, no permission) raises ``OSError`` naming ``path``
    and leaves no temporary file behind.
    """
    path = Path(path)
    raw = data.encode() if isinstance(data, str) else bytes(data)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            f.write(raw)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise OSError(f"could not write {path}: {err.strerror or err}") from err


def write_figure(fig, path: str | os.PathLike, dpi: int = 100) -> None:
    """Render a matplotlib figure to PNG in memory and :func:`write_atomic` it to ``path``."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    write_atomic(path, buf.getvalue())


def write_npz(path: str | os.PathLike, *, compressed: bool = False, **arrays) -> None:
    """``np.savez[_compressed]`` into memory, then :func:`write_atomic` to ``path`` (used as given: no
    ``.npz`` is appended)."""
    import io

    import numpy as np

    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    write_atomic(path, buf.getvalue())


def trim_log(path: str | os.PathLike, last_step: int) -> None:
    """Cut a training run's CSV log back to the checkpoint it resumes from.

    Keeps the header and the whole rows (ending in a newline, as many fields as the header) whose
    first field, the step, is at most ``last_step``; a row cut short when the run was killed, and the
    rows logged after its last checkpoint, are dropped.  The log is replaced atomically
    (:func:`write_atomic`), so a crash here loses nothing.  A missing log is left missing.
    """
    path = Path(path)
    if not path.is_file():
        return
    rows = path.read_text().splitlines(keepends=True)
    if not rows or not rows[0].endswith("\n"):
        write_atomic(path, "")
        return
    fields = rows[0].count(",")
    keep = [rows[0]]
    for r in rows[1:]:
        head = r.split(",", 1)[0]
        if r.endswith("\n") and r.count(",") == fields and head.isdigit() and int(head) <= last_step:
            keep.append(r)
    write_atomic(path, "".join(keep))
