"""Bundle Adjustment in the Large (BAL) problems: reader, BAL-convention residual, conversion.

Format (Agarwal et al., ECCV 2010, https://grail.cs.washington.edu/projects/bal/): a header
``n_cameras n_points n_observations``, then ``n_observations`` lines ``cam point x y``, then
``9·n_cameras`` camera parameters (Rodrigues rotation ``r`` (3), translation ``t`` (3), focal ``f``,
radial ``k1``, ``k2``), then ``3·n_points`` point coordinates; whitespace-separated, optionally bz2.

Projection (the BAL/Ceres ``SnavelyReprojectionError``):

    P = R(r) X + t,   p = −P_xy / P_z,   d = 1 + k1‖p‖² + k2‖p‖⁴,   obs ≈ f·d·p,

with the image origin at the principal point and ``y`` up; the cost is ``½ Σ ‖f d p − obs‖²`` (px²).

Conversion to the project's OpenCV convention (:func:`bal_to_opencv`): with ``F = diag(1, −1, −1)``
(a rotation), ``T_c_w = F·[R | t]`` looks along ``+z`` with ``y`` down and gives ``u = obs_x``,
``v = −obs_y`` for ``fx = fy = f``, ``cx = cy = 0`` — the same residuals up to the sign of ``v``,
hence the same cost (without distortion).
"""

from __future__ import annotations

import bz2
import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["BALProblem", "read_bal", "bal_residuals", "bal_cost", "bal_to_opencv", "opencv_to_bal_cameras"]


@dataclasses.dataclass(frozen=True)
class BALProblem:
    """A BAL problem held in numpy arrays (host side)."""

    cameras: np.ndarray
    """``(C, 9)`` float64: Rodrigues ``r`` (3), ``t`` (3), ``f``, ``k1``, ``k2``."""
    points: np.ndarray
    """``(P, 3)`` float64 world points."""
    obs_cam: np.ndarray
    """``(O,)`` int32 camera index of each observation."""
    obs_pt: np.ndarray
    """``(O,)`` int32 point index of each observation."""
    obs_xy: np.ndarray
    """``(O, 2)`` float64 observed image coordinates (BAL convention: centred, ``y`` up)."""

    @property
    def n_cameras(self) -> int:
        return int(self.cameras.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_observations(self) -> int:
        return int(self.obs_cam.shape[0])


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise FileNotFoundError(f"BAL file not found: {path}")
    try:
        if path.suffix == ".bz2":
            with bz2.open(path, "rt") as fh:
                return fh.read()
        return path.read_text()
    except (OSError, EOFError, UnicodeDecodeError) as exc:  # bz2 raises OSError on corrupt data
        raise ValueError(f"cannot read BAL file {path}: {exc}") from exc


def read_bal(path: str | Path) -> BALProblem:
    """Read a BAL problem (plain text or ``.bz2``); ``ValueError`` naming the file on any inconsistency."""
    path = Path(path)
    tokens = _read_text(path).split()
    if len(tokens) < 3:
        raise ValueError(f"{path}: missing header 'n_cameras n_points n_observations'")
    try:
        n_cam, n_pt, n_obs = (int(t) for t in tokens[:3])
    except ValueError as exc:
        raise ValueError(f"{path}: header must be three integers, got {tokens[:3]}") from exc
    if min(n_cam, n_pt, n_obs) <= 0:
        raise ValueError(f"{path}: header counts must be positive, got {n_cam} {n_pt} {n_obs}")
    expected = 3 + 4 * n_obs + 9 * n_cam + 3 * n_pt
    if len(tokens) != expected:
        what = "truncated" if len(tokens) < expected else "has trailing data"
        raise ValueError(
            f"{path}: file {what}: header promises {n_obs} observations, {n_cam} cameras, {n_pt} points "
            f"({expected} numbers), found {len(tokens)}"
        )
    try:
        obs = np.array(tokens[3 : 3 + 4 * n_obs], dtype=np.float64).reshape(n_obs, 4)
        params = np.array(tokens[3 + 4 * n_obs :], dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: non-numeric value: {exc}") from exc
    idx = obs[:, :2]
    if np.any(idx != np.round(idx)):
        raise ValueError(f"{path}: observation camera/point indices must be integers")
    cam, pt = idx[:, 0].astype(np.int64), idx[:, 1].astype(np.int64)
    if cam.min() < 0 or cam.max() >= n_cam:
        raise ValueError(f"{path}: camera index out of range [0, {n_cam})")
    if pt.min() < 0 or pt.max() >= n_pt:
        raise ValueError(f"{path}: point index out of range [0, {n_pt})")
    if not np.all(np.isfinite(obs)) or not np.all(np.isfinite(params)):
        raise ValueError(f"{path}: contains NaN or inf")
    return BALProblem(
        cameras=params[: 9 * n_cam].reshape(n_cam, 9),
        points=params[9 * n_cam :].reshape(n_pt, 3),
        obs_cam=cam.astype(np.int32),
        obs_pt=pt.astype(np.int32),
        obs_xy=obs[:, 2:].copy(),
    )


def bal_residuals(problem: BALProblem, cameras: np.ndarray | None = None, points: np.ndarray | None = None) -> np.ndarray:
    """``(O, 2)`` BAL-convention residuals ``f·d·p − obs`` (numpy, float64), optionally at other parameters."""
    cams = problem.cameras if cameras is None else np.asarray(cameras, np.float64)
    pts = problem.points if points is None else np.asarray(points, np.float64)
    c = cams[problem.obs_cam]
    P = Rotation.from_rotvec(c[:, :3]).apply(pts[problem.obs_pt]) + c[:, 3:6]
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    d = 1.0 + c[:, 7] * r2 + c[:, 8] * r2 * r2
    return (c[:, 6] * d)[:, None] * p - problem.obs_xy


def bal_cost(problem: BALProblem, cameras: np.ndarray | None = None, points: np.ndarray | None = None) -> float:
    """``½ Σ ‖r‖²`` in px² (Ceres' cost with the squared loss)."""
    r = bal_residuals(problem, cameras, points)
    return 0.5 * float(np.sum(r * r))


_FLIP = np.diag([1.0, -1.0, -1.0])


def bal_to_opencv(problem: BALProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert to the project convention.

    Returns ``(T_c_w, intrinsics, uv)``: ``(C, 4, 4)`` world-to-camera matrices (camera looks along
    ``+z``, ``y`` down), ``(C, 5)`` intrinsics ``(fx, fy, cx, cy, baseline=0)`` and ``(O, 2)``
    pixels ``(obs_x, −obs_y)``.  Points and observation indices are unchanged.  Raises ``ValueError``
    when a camera has radial distortion (the project's cameras are pinhole).
    """
    k = problem.cameras[:, 7:9]
    if np.any(k != 0):
        raise ValueError(f"{int(np.sum(np.any(k != 0, axis=1)))} cameras have radial distortion; pinhole needed")
    R = Rotation.from_rotvec(problem.cameras[:, :3]).as_matrix()
    T = np.tile(np.eye(4), (problem.n_cameras, 1, 1))
    T[:, :3, :3] = _FLIP @ R
    T[:, :3, 3] = problem.cameras[:, 3:6] @ _FLIP.T
    f = problem.cameras[:, 6]
    z = np.zeros_like(f)
    intr = np.stack([f, f, z, z, z], axis=1)
    uv = problem.obs_xy * np.array([1.0, -1.0])
    return T, intr, uv


def opencv_to_bal_cameras(T_c_w: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Inverse of :func:`bal_to_opencv` for the cameras: ``(C, 9)`` BAL parameters (no distortion)."""
    T = np.asarray(T_c_w, np.float64)
    R = _FLIP @ T[:, :3, :3]
    t = T[:, :3, 3] @ _FLIP.T
    f = np.asarray(intrinsics)[:, 0]
    z = np.zeros_like(f)
    return np.concatenate([Rotation.from_matrix(R).as_rotvec(), t, f[:, None], z[:, None], z[:, None]], axis=1)
