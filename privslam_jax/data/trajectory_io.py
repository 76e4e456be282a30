"""Trajectory files: TUM (``timestamp tx ty tz qx qy qz qw``) and KITTI (3×4 row-major per line).

Both formats store camera-to-world poses ``T_w_c`` (DESIGN §3).

* **TUM** (Sturm et al., IROS 2012, https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
  one pose per line, ``timestamp tx ty tz qx qy qz qw``, space separated, ``#`` starts a comment.
  The quaternion is Hamilton, scalar last.  We write ``qw ≥ 0`` (``q`` and ``-q`` are the same
  rotation) and every number with Python's shortest round-trip ``repr``, so a float64 trajectory
  survives a write/read cycle bit for bit and ``evo`` (``evo.tools.file_interface.
  read_tum_trajectory_file``) reads exactly the poses we meant.
* **KITTI odometry** (Geiger et al., CVPR 2012, devkit ``readme.txt``): one pose per line, the first
  three rows of ``T_w_c`` flattened row-major (12 numbers), no timestamps (frames are 10 Hz; the
  sequence's ``times.txt`` carries them).

The ``*_matrices`` functions work on float64 numpy arrays (host side, full precision: TUM
timestamps such as ``1305031102.175304`` do not fit a float32).  :func:`load_tum` /
:func:`load_kitti` / :func:`save_tum` / :func:`save_kitti` convert to and from
:class:`~privslam_jax.types.Trajectory`, whose arrays follow JAX's default precision (float32
unless ``jax_enable_x64`` is on).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import jax
import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation

from privslam_jax.data.files import write_atomic
from privslam_jax.errors import InputError, input_error
from privslam_jax.types import Trajectory

__all__ = [
    "read_tum_matrices",
    "write_tum_matrices",
    "read_kitti_matrices",
    "read_pose_matrices",
    "write_kitti_matrices",
    "load_tum",
    "save_tum",
    "load_kitti",
    "save_kitti",
    "matrices_to_tum_rows",
    "tum_rows_to_matrices",
]

PathLike = str | os.PathLike

ROTATION_TOLERANCE = 1e-2
"""Largest ``|RᵀR − I|`` entry accepted in a KITTI pose's rotation block (files carry 6–7 digits: ~1e-7)."""


def _fmt(x: float) -> str:
    """Shortest decimal string that reads back to the same float64 (``repr``)."""
    return repr(float(x))


def _read_rows(path: PathLike, ncols: int, what: str, linenos: list[int] | None = None) -> np.ndarray:
    """Parse a whitespace table with ``ncols`` finite numbers per non-comment line.

    ``FileNotFoundError`` for a missing file; :class:`InputError` naming ``file:line`` for anything
    else (not UTF-8, wrong column count, not a number, NaN/inf, no rows).  ``linenos`` (if given)
    receives the line number of each row.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    rows: list[list[float]] = []
    try:
        with open(path, encoding="utf-8") as f:
            for lineno, line in enumerate(f, 1):
                text = line.split("#", 1)[0].strip()
                if not text:
                    continue
                parts = text.replace(",", " ").split()
                if len(parts) != ncols:
                    raise InputError(f"{path}:{lineno}: expected {ncols} numbers per line ({what}), got {len(parts)}")
                try:
                    vals = [float(p) for p in parts]
                except ValueError:
                    raise InputError(f"{path}:{lineno}: not a number in {text[:80]!r}") from None
                if not all(map(math.isfinite, vals)):
                    raise InputError(f"{path}:{lineno}: NaN or inf in {what}")
                rows.append(vals)
                if linenos is not None:
                    linenos.append(lineno)
    except UnicodeDecodeError as err:
        raise input_error(path, f"not a {what} file (not UTF-8 text)", err) from err
    if not rows:
        raise InputError(f"{path}: no poses in {what} file")
    return np.asarray(rows, dtype=np.float64)


def _check_fits_trajectory(path: PathLike, *arrays: np.ndarray) -> None:
    """Refuse values a :class:`Trajectory` (JAX default precision) would turn into ``inf``."""
    dtype = jax.dtypes.canonicalize_dtype(np.float64)
    limit = float(np.finfo(dtype).max)
    for a in arrays:
        if a.size and float(np.max(np.abs(a))) > limit:
            raise InputError(f"{path}: values beyond the {np.dtype(dtype).name} range of a Trajectory (|x| > {limit:.4g})")


def _check_matrices(T_w_c: np.ndarray) -> np.ndarray:
    T = np.asarray(T_w_c, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)):
        raise ValueError(f"T_w_c must have shape (N, 4, 4) or (N, 3, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError("T_w_c contains NaN or inf")
    return T


def matrices_to_tum_rows(T_w_c: Float[np.ndarray, "N _ _"]) -> Float[np.ndarray, "N 7"]:
    """``(N, 4, 4)``/``(N, 3, 4)`` matrices → ``(N, 7)`` rows ``tx ty tz qx qy qz qw`` with ``qw ≥ 0``.

    The rotation block goes through scipy's ``Rotation.from_matrix`` (nearest rotation for
    matrices that are orthonormal only to the precision they were written with, as KITTI's).
    """
    T = _check_matrices(T_w_c)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    q = np.where(q[:, 3:4] < 0, -q, q)
    return np.concatenate([T[:, :3, 3], q], axis=1)


def tum_rows_to_matrices(rows: Float[np.ndarray, "N 7"]) -> Float[np.ndarray, "N 4 4"]:
    """``(N, 7)`` rows ``tx ty tz qx qy qz qw`` → ``(N, 4, 4)`` homogeneous matrices (quaternions normalised)."""
    rows = np.asarray(rows, dtype=np.float64)
    q = rows[:, 3:7]
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(q, axis=1)
    huge = np.isinf(norm) & np.all(np.isfinite(q), axis=1)
    if huge.any():  # components near the float64 limit: scale before normalising (other rows unchanged)
        q = q.copy()
        q[huge] /= np.max(np.abs(q[huge]), axis=1, keepdims=True)
        norm[huge] = np.linalg.norm(q[huge], axis=1)
    if np.any(norm < 1e-12):
        raise ValueError(f"zero quaternion in row {int(np.argmin(norm))}")
    T = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    T[:, :3, :3] = Rotation.from_quat(q / norm[:, None]).as_matrix()
    T[:, :3, 3] = rows[:, :3]
    return T


def read_tum_matrices(path: PathLike) -> tuple[Float[np.ndarray, " N"], Float[np.ndarray, "N 4 4"]]:
    """Read a TUM trajectory: ``(timestamps (N,), T_w_c (N, 4, 4))`` in float64.

    Raises ``FileNotFoundError`` for a missing file and :class:`~privslam_jax.errors.InputError`
    (naming ``file:line``) for text that is not UTF-8, a malformed line, NaN/inf, a zero quaternion
    or timestamps that do not increase strictly.
    """
    rows = _read_rows(path, 8, "TUM trajectory")
    t = rows[:, 0]
    with np.errstate(over="ignore"):  # ±1e308 neighbours: the difference is ±inf, still the right sign
        bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        raise InputError(f"{path}: timestamps must increase strictly (pose {bad[0] + 1} at t={t[bad[0] + 1]!r})")
    try:
        T = tum_rows_to_matrices(rows[:, 1:])
    except ValueError as err:
        raise InputError(f"{path}: {err}") from err
    return t, T


def write_tum_matrices(path: PathLike, timestamps: Float[np.ndarray, " M"], T_w_c: Float[np.ndarray, "N _ _"]) -> None:
    """Write float64 timestamps and ``T_w_c`` matrices as a TUM file (round-trip exact).

    Parent folders are created.
    """
    T = _check_matrices(T_w_c)
    t = np.asarray(timestamps, dtype=np.float64)
    if t.shape != (T.shape[0],):
        raise ValueError(f"timestamps must have shape ({T.shape[0]},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("timestamps contain NaN or inf")
    rows = matrices_to_tum_rows(T)
    write_atomic(path, "".join(" ".join([_fmt(ti)] + [_fmt(v) for v in r]) + "\n" for ti, r in zip(t, rows)))


def read_kitti_matrices(path: PathLike) -> Float[np.ndarray, "N 4 4"]:
    """Read a KITTI odometry pose file (12 numbers per line) into ``(N, 4, 4)`` float64 ``T_w_c``.

    Raises ``FileNotFoundError`` for a missing file and :class:`~privslam_jax.errors.InputError`
    (naming ``file:line``) for text that is not UTF-8, a malformed line, NaN/inf or a rotation
    block that is not a rotation (``|RᵀR − I| > ROTATION_TOLERANCE`` or ``det R ≤ 0``).
    """
    linenos: list[int] = []
    rows = _read_rows(path, 12, "KITTI poses", linenos)
    T = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    R = T[:, :3, :3]
    with np.errstate(all="ignore"):  # garbage near the float64 limit overflows here; it is refused below
        dev = np.max(np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)), axis=(1, 2))
        det = np.linalg.det(R)
    bad = np.nonzero(~(dev <= ROTATION_TOLERANCE) | ~(det > 0))[0]
    if bad.size:
        i = int(bad[0])
        raise InputError(f"{path}:{linenos[i]}: the rotation block of pose {i} is not a rotation "
                         f"(max |R^T R - I| = {dev[i]:.3g}, det = {det[i]:.3g})")
    return T


def read_pose_matrices(path: PathLike) -> Float[np.ndarray, "N 4 4"]:
    """``T_w_c (N, 4, 4)`` float64 of a TUM trajectory (8 numbers per line, as ``privslam slam`` writes
    ``trajectory.txt`` and ``keyframes.txt``) or a KITTI pose file (12), told apart by the first
    non-comment line; the errors of :func:`read_tum_matrices` / :func:`read_kitti_matrices`, and
    :class:`~privslam_jax.errors.InputError` for any other column count."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pose file not found: {path}")
    try:
        with path.open(encoding="utf-8") as f:  # the fields as _read_rows reads them: '#' comments, commas
            fields = (line.split("#", 1)[0].replace(",", " ").split() for line in f)
            first = next((x for x in fields if x), [])
    except UnicodeDecodeError as err:
        raise input_error(path, "not a pose file (not UTF-8 text)", err) from err
    if len(first) == 8:
        return read_tum_matrices(path)[1]
    if len(first) == 12:
        return read_kitti_matrices(path)
    raise InputError(f"{path}: neither a TUM trajectory (8 numbers per line) nor KITTI poses (12): "
                     f"{len(first)} fields on the first line")


def write_kitti_matrices(path: PathLike, T_w_c: Float[np.ndarray, "N _ _"]) -> None:
    """Write ``T_w_c`` as a KITTI pose file (first three rows, row-major; round-trip exact)."""
    T = _check_matrices(T_w_c)
    write_atomic(path, "".join(" ".join(_fmt(v) for v in m) + "\n" for m in T[:, :3, :].reshape(-1, 12)))


def load_tum(path: PathLike) -> Trajectory:
    """Read a TUM file as a :class:`Trajectory` (JAX default precision; values beyond its range are an
    :class:`~privslam_jax.errors.InputError`)."""
    t, T = read_tum_matrices(path)
    _check_fits_trajectory(path, t, T)
    return Trajectory.from_matrices(t, T)


def save_tum(path: PathLike, trajectory: Trajectory) -> None:
    """Write a :class:`Trajectory` as a TUM file."""
    write_tum_matrices(path, np.asarray(trajectory.timestamps, np.float64), np.asarray(trajectory.as_matrices(), np.float64))


def load_kitti(path: PathLike, timestamps: Float[np.ndarray, " M"] | None = None, fps: float = 10.0) -> Trajectory:
    """Read a KITTI pose file as a :class:`Trajectory`; timestamps default to ``i / fps`` (KITTI: 10 Hz)."""
    T = read_kitti_matrices(path)
    t = np.arange(T.shape[0], dtype=np.float64) / fps if timestamps is None else np.asarray(timestamps, np.float64)
    if t.shape != (T.shape[0],):
        raise ValueError(f"{path}: {T.shape[0]} poses but {t.shape[0]} timestamps")
    _check_fits_trajectory(path, T)
    return Trajectory.from_matrices(t, T)


def save_kitti(path: PathLike, trajectory: Trajectory) -> None:
    """Write a :class:`Trajectory` as a KITTI pose file (timestamps are not stored)."""
    write_kitti_matrices(path, np.asarray(trajectory.as_matrices(), np.float64))
