"""Point-recovery metrics for line-cloud attacks (DESIGN §5.5), host-side numpy + scipy.

Given the original points ``P`` and the points ``R`` an attack recovered (``R_i`` from line ``i``,
which was lifted from ``P_i``):

* ``nn_mean`` — the source paper's metric: mean over originals of the distance to the nearest
  recovered point, ``(1/N) Σ_i min_j ‖P_i − R_j‖`` (kd-tree).  On sparse outdoor maps it barely
  separates attack from no attack, because any recovered point near *some* original counts.
* per-point error with known correspondences ``e_i = ‖R_i − P_i‖``: ``per_point_median``,
  ``per_point_mean`` and the percentages ``within_0.1``, ``within_0.5``, ``within_1.0``
  (``100·mean(e_i < τ)``, metres).
* ``chamfer`` — symmetric Chamfer distance ``½(mean_i min_j ‖P_i − R_j‖ + mean_j min_i ‖R_j − P_i‖)``,
  with both directions also reported (``chamfer_orig_to_rec``, ``chamfer_rec_to_orig``).
* the **no-attack baseline** (:func:`baseline_points`): one point per line by a rule that uses the
  line only — ``"closest"``: the line's closest point to the origin (the start of the canonical
  export); ``"uniform"``: a uniform point of the line's chord inside the bounding box of all
  lines' closest points (what an attacker knows of the scene's extent), seeded.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike
from scipy.spatial import cKDTree

from privslam_jax.types import LineCloud

__all__ = ["nn_distances", "point_recovery_metrics", "baseline_points", "METRIC_KEYS"]

METRIC_KEYS = ("nn_mean", "per_point_median", "per_point_mean", "within_0.1", "within_0.5", "within_1.0", "chamfer")


def _points(x: ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, 3) with N > 0, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    return a


def nn_distances(query: ArrayLike, reference: ArrayLike) -> np.ndarray:
    """Distance from each query point to its nearest reference point (kd-tree)."""
    return cKDTree(_points(reference, "reference")).query(_points(query, "query"), k=1)[0]


def point_recovery_metrics(original: ArrayLike, recovered: ArrayLike) -> dict[str, float]:
    """All metrics of the module docstring; ``original[i]`` corresponds to ``recovered[i]``."""
    p = _points(original, "original points")
    r = _points(recovered, "recovered points")
    if p.shape != r.shape:
        raise ValueError(f"original {p.shape} and recovered {r.shape} must correspond one to one")
    o2r = nn_distances(p, r)
    r2o = nn_distances(r, p)
    e = np.linalg.norm(r - p, axis=1)
    return {
        "nn_mean": float(o2r.mean()),
        "per_point_median": float(np.median(e)),
        "per_point_mean": float(e.mean()),
        "within_0.1": float(100.0 * np.mean(e < 0.1)),
        "within_0.5": float(100.0 * np.mean(e < 0.5)),
        "within_1.0": float(100.0 * np.mean(e < 1.0)),
        "chamfer": float(0.5 * (o2r.mean() + r2o.mean())),
        "chamfer_orig_to_rec": float(o2r.mean()),
        "chamfer_rec_to_orig": float(r2o.mean()),
    }


def baseline_points(lines: LineCloud, rule: str = "closest", seed: int = 0) -> np.ndarray:
    """No-attack guess of one point per line (see module docstring for the rules)."""
    d = np.asarray(lines.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    c = np.cross(d, np.asarray(lines.moments, np.float64))
    if rule == "closest":
        return c
    if rule != "uniform":
        raise ValueError(f"unknown baseline rule {rule!r} (use 'closest' or 'uniform')")
    lo, hi = c.min(0), c.max(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - c) / d
        t2 = (hi - c) / d
    tmin = np.where(d != 0, np.minimum(t1, t2), -np.inf).max(1)
    tmax = np.where(d != 0, np.maximum(t1, t2), np.inf).min(1)
    ok = np.isfinite(tmin) & np.isfinite(tmax) & (tmax >= tmin)
    u = np.random.default_rng(seed).uniform(size=len(c))
    t = np.where(ok, tmin + u * (tmax - tmin), 0.0)
    return c + t[:, None] * d
