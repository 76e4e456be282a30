"""Host-side input of the numpy attacks (:mod:`~privslam_jax.attacks.centred`, :mod:`~privslam_jax.attacks.two_peaks`)."""

from __future__ import annotations

import numpy as np

from privslam_jax.types import LineCloud


def host_lines(lines: LineCloud, min_lines: int) -> tuple[np.ndarray, np.ndarray]:
    """``(a, d)`` in float64 numpy: closest points to the origin ``a = d × m`` and unit directions,
    after checking shapes, the line count and the values (``ValueError``)."""
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    if d.ndim != 2 or d.shape[1] != 3 or m.shape != d.shape or len(d) < min_lines:
        raise ValueError(f"need at least {min_lines} lines of shape (N, 3), got directions {d.shape}, moments {m.shape}")
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(m)) and np.all(norm > 0)):
        raise ValueError("line cloud contains NaN/inf or zero directions")
    d = d / norm
    return np.cross(d, m), d
