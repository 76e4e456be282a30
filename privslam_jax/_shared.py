"""Locate the optional ``../shared`` folder (real data, weights and reference outputs).

Nothing in ``shared/`` is ever committed; tests and experiments that need it look it up
here and skip or fail with a clear reason when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["shared_dir"]


def shared_dir() -> Path | None:
    """``$PRIVSLAM_SHARED`` if set, else ``<repo>/../shared``; ``None`` when it does not exist."""
    env = os.environ.get("PRIVSLAM_SHARED")
    path = Path(env) if env else Path(__file__).resolve().parents[2] / "shared"
    return path if path.is_dir() else None
