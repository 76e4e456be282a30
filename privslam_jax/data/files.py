"""Atomic file writes: a reader sees the old file or the whole new one, never a part."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["write_atomic", "write_figure", "write_npz"]


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
