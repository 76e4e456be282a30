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

from privslam_jax.errors import input_error

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


MAX_BZ2_RATIO = 100
"""A ``.bz2`` BAL file may decompress to at most ``MAX_BZ2_RATIO ×`` its size plus ``BZ2_SLACK`` bytes.

Real problems compress about 3× (the shared KITTI problems: 2.7×); a larger ratio means a file that
is mostly one repeated byte, i.e. not a BAL problem, and refusing it bounds the memory a small file
can make the reader take."""
BZ2_SLACK = 1 << 16
_CHUNK = 1 << 16


def _read_bytes(path: Path) -> bytes:
    """The file's bytes (decompressed for ``.bz2``, at most ``MAX_BZ2_RATIO × size + BZ2_SLACK``)."""
    if not path.is_file():
        raise FileNotFoundError(f"BAL file not found: {path}")
    if path.suffix != ".bz2":
        return path.read_bytes()
    limit = MAX_BZ2_RATIO * path.stat().st_size + BZ2_SLACK
    chunks: list[bytes] = []
    total = 0
    with open(path, "rb") as raw, bz2.BZ2File(raw) as fh:
        while True:
            try:
                chunk = fh.read(_CHUNK)
            except (OSError, EOFError) as err:  # bz2: OSError for corrupt data, EOFError for a truncated stream
                raise input_error(path, "corrupt or truncated bz2 stream", err) from err
            if not chunk:
                break
            total += len(chunk)
            if total > limit:
                raise input_error(path, f"decompresses to more than {MAX_BZ2_RATIO} times its size: not a BAL problem")
            chunks.append(chunk)
    return b"".join(chunks)


def _shown(token: bytes) -> str:
    return repr(token[:40].decode("ascii", "replace")) + ("..." if len(token) > 40 else "")


def read_bal(path: str | Path) -> BALProblem:
    """Read a BAL problem (plain text or ``.bz2``).

    ``FileNotFoundError`` for a missing file; :class:`~privslam_jax.errors.InputError` naming the file
    for anything else: a corrupt or truncated bz2 stream (or one that decompresses more than
    ``MAX_BZ2_RATIO``-fold), a header that is not three positive integers, a number of values that
    differs from what the header promises (checked before any array is allocated, so an inflated
    header costs nothing), non-numeric, NaN or infinite values, non-integer or out-of-range
    observation indices.  Peak memory is a small multiple of the (decompressed) file size.
    """
    path = Path(path)
    tokens = _read_bytes(path).split()  # ASCII whitespace; bytes tokens parse with int()/float() like str
    if len(tokens) < 3:
        raise input_error(path, "missing header 'n_cameras n_points n_observations'")
    try:
        n_cam, n_pt, n_obs = (int(t) for t in tokens[:3])
    except ValueError as exc:
        raise input_error(path, f"header must be three integers, got {', '.join(_shown(t) for t in tokens[:3])}") from exc
    if min(n_cam, n_pt, n_obs) <= 0:
        raise input_error(path, f"header counts must be positive, got {n_cam} {n_pt} {n_obs}")
    expected = 3 + 4 * n_obs + 9 * n_cam + 3 * n_pt
    if len(tokens) != expected:
        what = "truncated" if len(tokens) < expected else "has trailing data"
        raise input_error(
            path, f"file {what}: header promises {n_obs} observations, {n_cam} cameras, {n_pt} points "
            f"({expected} numbers), found {len(tokens)}"
        )
    try:
        obs = np.array(tokens[3 : 3 + 4 * n_obs], dtype=np.float64).reshape(n_obs, 4)
        params = np.array(tokens[3 + 4 * n_obs :], dtype=np.float64)
    except ValueError as exc:
        bad = next((i for i, t in enumerate(tokens) if not _is_number(t)), None)
        where = "" if bad is None else f" {_shown(tokens[bad])} (value {bad + 1})"
        raise input_error(path, f"non-numeric value{where}") from exc
    if not np.all(np.isfinite(obs)) or not np.all(np.isfinite(params)):
        raise input_error(path, "contains NaN or inf")
    cam, pt = obs[:, 0], obs[:, 1]
    if np.any(cam != np.round(cam)) or np.any(pt != np.round(pt)):
        raise input_error(path, "observation camera/point indices must be integers")
    if cam.min() < 0 or cam.max() >= n_cam:
        raise input_error(path, f"camera index out of range [0, {n_cam})")
    if pt.min() < 0 or pt.max() >= n_pt:
        raise input_error(path, f"point index out of range [0, {n_pt})")
    return BALProblem(
        cameras=params[: 9 * n_cam].reshape(n_cam, 9),
        points=params[9 * n_cam :].reshape(n_pt, 3),
        obs_cam=cam.astype(np.int32),
        obs_pt=pt.astype(np.int32),
        obs_xy=obs[:, 2:].copy(),
    )


def _is_number(token: bytes) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


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
