r"""Trajectory metrics: ATE (absolute trajectory error) and RPE (relative pose error), as evo.

Definitions follow Sturm et al., "A benchmark for the evaluation of RGB-D SLAM systems" (IROS 2012)
and their implementation in evo (Grupp, https://github.com/MichaelGrupp/evo, v1.38), so that the
numbers equal ``evo_ape``/``evo_rpe`` on the same TUM files (tested to 1e-6):

* **ATE** (``evo_ape tum ref est -a`` / ``-as``, pose relation ``translation_part``): align the
  estimated camera centres :math:`p_i` to the reference centres :math:`q_i` with Umeyama
  (SE(3), or Sim(3) for monocular estimates; :mod:`privslam_jax.geometry.align`), then
  :math:`\mathrm{ATE} = \sqrt{\frac1n\sum_i \lVert q_i - (c R p_i + t)\rVert^2}`.
* **RPE** (``evo_rpe tum ref est``: ``delta = 1`` frame, consecutive pairs only, no alignment by
  default): for reference poses :math:`Q_i` and estimated poses :math:`P_i` (camera-to-world),
  :math:`E_i = (Q_i^{-1} Q_{i+\Delta})^{-1} (P_i^{-1} P_{i+\Delta})`; the translation error is
  :math:`\lVert \mathrm{trans}(E_i)\rVert` (metres per ``delta`` frames) and the rotation error
  :math:`\angle(\mathrm{rot}(E_i))` in **degrees**; both reported as RMSE over the pairs
  (mean/median/max in the result too).  RPE is invariant to an SE(3) alignment of the estimate;
  a monocular estimate needs ``align="sim3"`` (as ``evo_rpe -as``) for a meaningful translation part.

Association: poses are matched by timestamp, each estimated stamp to the nearest reference stamp
within ``max_diff`` seconds (default 1e-6 s, i.e. exact: this project writes the estimate with the
reference's timestamps).  evo's default ``--t_max_diff`` is 0.01 s; with identical stamps the two
agree.

All computations are float64 numpy on the host: metrics are evaluation, not part of a jitted
program, and agreement with evo to 1e-6 needs float64.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float

from privslam_jax.geometry.align import apply_similarity, umeyama_np
from privslam_jax.types import Trajectory

__all__ = [
    "ErrorStats",
    "associate",
    "ate",
    "rpe",
    "trajectory_metrics",
    "rotation_angle_deg",
]

Alignment = str  # "none" | "se3" | "sim3" (a plain str so a bad value gets our ValueError)
TrajectoryLike = Trajectory | tuple[np.ndarray, np.ndarray]


@dataclasses.dataclass(frozen=True)
class ErrorStats:
    """Per-pair (RPE) or per-pose (ATE) errors and their statistics (evo's ``get_all_statistics``)."""

    errors: np.ndarray
    """``(K,)`` float64 errors (metres or degrees)."""
    rmse: float
    """:math:`\\sqrt{\\mathrm{mean}(e^2)}`."""
    mean: float
    """Mean error."""
    median: float
    """Median error."""
    std: float
    """Population standard deviation (numpy default, as evo)."""
    min: float
    """Smallest error."""
    max: float
    """Largest error."""

    @staticmethod
    def of(errors: Float[np.ndarray, " K"]) -> "ErrorStats":
        e = np.asarray(errors, dtype=np.float64)
        if e.size == 0:
            raise ValueError("no errors to summarise (empty trajectory or no pose pairs)")
        return ErrorStats(
            errors=e,
            rmse=float(np.sqrt(np.mean(e * e))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
        )


def _as_arrays(traj: TrajectoryLike, name: str) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(traj, Trajectory):
        t, T = np.asarray(traj.timestamps, np.float64), np.asarray(traj.as_matrices(), np.float64)
    else:
        t, T = (np.asarray(a, np.float64) for a in traj)
    if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)) or t.shape != (T.shape[0],):
        raise ValueError(f"{name}: expected timestamps (N,) and poses (N, 4, 4), got {t.shape} and {T.shape}")
    if T.shape[1] == 3:
        T = np.concatenate([T, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (T.shape[0], 1, 1))], axis=1)
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(t))):
        raise ValueError(f"{name}: NaN or inf in the trajectory")
    return t, T


def associate(
    t_est: Float[np.ndarray, " N"], t_ref: Float[np.ndarray, " M"], max_diff: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i_est, i_ref)`` of estimated/reference stamps that match within ``max_diff`` seconds.

    Each estimated stamp takes its nearest reference stamp; matches are one-to-one (a reference
    stamp claimed twice keeps the closer estimate).  Order follows the estimate.
    """
    t_est = np.asarray(t_est, np.float64)
    t_ref = np.asarray(t_ref, np.float64)
    if t_est.size == 0 or t_ref.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.argsort(t_ref)
    ts = t_ref[order]
    j = np.clip(np.searchsorted(ts, t_est), 1, max(len(ts) - 1, 1))
    left = np.clip(j - 1, 0, len(ts) - 1)
    right = np.clip(j, 0, len(ts) - 1)
    pick = np.where(np.abs(ts[left] - t_est) <= np.abs(ts[right] - t_est), left, right)
    diff = np.abs(ts[pick] - t_est)
    ok = diff <= max_diff
    i_est = np.nonzero(ok)[0]
    i_ref = order[pick[ok]]
    # one-to-one: keep the closest estimate per reference index
    best: dict[int, int] = {}
    for a, b in zip(i_est, i_ref):
        if b not in best or diff[a] < diff[best[b]]:
            best[int(b)] = int(a)
    keep = sorted(best.values())
    i_est = np.asarray(keep, dtype=np.int64)
    i_ref = order[pick[i_est]].astype(np.int64)
    return i_est, i_ref


def _matched(est: TrajectoryLike, ref: TrajectoryLike, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    t_e, T_e = _as_arrays(est, "estimate")
    t_r, T_r = _as_arrays(ref, "reference")
    i_e, i_r = associate(t_e, t_r, max_diff)
    if i_e.size == 0:
        raise ValueError(
            f"no matching timestamps between estimate ({t_e.size} poses) and reference ({t_r.size} poses) "
            f"within {max_diff} s"
        )
    return T_e[i_e], T_r[i_r]


def _align(T_est: np.ndarray, T_ref: np.ndarray, align: Alignment) -> np.ndarray:
    if align == "none":
        return T_est
    if align not in ("se3", "sim3"):
        raise ValueError(f"align must be 'none', 'se3' or 'sim3', got {align!r}")
    R, t, c = umeyama_np(T_est[:, :3, 3], T_ref[:, :3, 3], with_scale=align == "sim3")
    return apply_similarity(R, t, c, T_est)


def rotation_angle_deg(R: Float[np.ndarray, "*batch 3 3"]) -> Float[np.ndarray, "*batch"]:
    """Rotation angle ``‖log(R)‖`` in degrees, ``atan2(‖vee(R − Rᵀ)‖/2, (tr R − 1)/2)`` (accurate near 0 and π)."""
    R = np.asarray(R, np.float64)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin = 0.5 * np.linalg.norm(w, axis=-1)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.degrees(np.arctan2(sin, cos))


def ate(est: TrajectoryLike, ref: TrajectoryLike, align: Alignment = "se3", max_diff: float = 1e-6) -> ErrorStats:
    """Absolute trajectory error of the camera centres after ``align`` (``"se3"``, ``"sim3"`` or ``"none"``).

    Equals ``evo_ape tum ref est -a`` (se3) / ``-as`` (sim3) / no flag (none), metres.
    ``est``/``ref`` are :class:`Trajectory` or ``(timestamps (N,), T_w_c (N, 4, 4))`` numpy tuples
    (float64 keeps full precision).
    """
    T_e, T_r = _matched(est, ref, max_diff)
    T_a = _align(T_e, T_r, align)
    return ErrorStats.of(np.linalg.norm(T_r[:, :3, 3] - T_a[:, :3, 3], axis=1))


def rpe(
    est: TrajectoryLike,
    ref: TrajectoryLike,
    delta: int = 1,
    align: Alignment = "none",
    all_pairs: bool = False,
    max_diff: float = 1e-6,
) -> tuple[ErrorStats, ErrorStats]:
    """Relative pose error of matched poses: ``(translation m, rotation deg)``.

    Pairs as evo's ``filter_pairs_by_index``: ``(0, Δ), (Δ, 2Δ), …`` (non-overlapping), or every
    ``(i, i + Δ)`` with ``all_pairs``; for ``Δ = 1`` both are all consecutive pairs.  Equals
    ``evo_rpe tum ref est --delta Δ --pose_relation trans_part`` and ``... angle_deg``
    (``-a``/``-as`` for ``align="se3"``/``"sim3"``, ``--all_pairs``).
    """
    if delta < 1:
        raise ValueError(f"delta must be a positive number of frames, got {delta}")
    T_e, T_r = _matched(est, ref, max_diff)
    if T_e.shape[0] <= delta:
        raise ValueError(f"RPE with delta={delta} needs more than {delta} matched poses, got {T_e.shape[0]}")
    T_e = _align(T_e, T_r, align)
    n = T_e.shape[0]
    i = np.arange(n - delta) if all_pairs else np.arange(0, n, delta)[:-1]
    j = i + delta
    rel_r = np.linalg.inv(T_r[i]) @ T_r[j]
    rel_e = np.linalg.inv(T_e[i]) @ T_e[j]
    E = np.linalg.inv(rel_r) @ rel_e
    return ErrorStats.of(np.linalg.norm(E[:, :3, 3], axis=1)), ErrorStats.of(rotation_angle_deg(E[:, :3, :3]))


def trajectory_metrics(est: TrajectoryLike, ref: TrajectoryLike, max_diff: float = 1e-6) -> dict[str, float]:
    """The headline numbers for ``metrics.json``: ``ate_rmse_se3``, ``ate_rmse_sim3`` (m), ``sim3_scale``,
    ``rpe_trans`` (m/frame RMSE) and ``rpe_rot`` (deg/frame RMSE), both RPE without alignment (evo defaults),
    and ``matched`` (number of associated poses)."""
    T_e, T_r = _matched(est, ref, max_diff)
    stamps = np.arange(T_e.shape[0], dtype=np.float64)  # already associated: index stamps
    e, r = (stamps, T_e), (stamps, T_r)
    _, _, scale = umeyama_np(T_e[:, :3, 3], T_r[:, :3, 3], with_scale=True)
    rt, rr = rpe(e, r)
    return {
        "matched": float(T_e.shape[0]),
        "ate_rmse_se3": ate(e, r, "se3").rmse,
        "ate_rmse_sim3": ate(e, r, "sim3").rmse,
        "sim3_scale": scale,
        "rpe_trans": rt.rmse,
        "rpe_rot": rr.rmse,
    }
