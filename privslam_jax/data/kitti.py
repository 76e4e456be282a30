"""KITTI odometry sequences (and what ``privslam synth`` writes in the same layout).

Layout (KITTI odometry devkit ``readme.txt``)::

    <root>/sequences/<id>/image_0/000000.png …   left grey      (P0)
                         image_1/                 right grey     (P1)
                         image_2/                 left colour    (P2)
                         image_3/                 right colour   (P3)
                         calib.txt                ``P0: 12 numbers`` … ``P3:`` (3×4 row-major), optional ``Tr:``
                         times.txt                optional, one timestamp (s) per frame; 10 Hz when absent
    <root>/poses/<id>.txt                         optional ground truth, 12 numbers per line (T_w_c of cam 0)

Extras written by ``privslam synth`` (read when present, ``None`` otherwise; see docs/formats.md):
``depth/%06d.png`` (uint16, metres × 256, 0 = no depth: the KITTI depth-benchmark convention),
``masks/%06d.png`` (uint16 instance ids, 0 = none) with ``instance_classes.json``
(``{"<instance id>": <COCO class id>}``), ``background/%06d.png`` (the frame without the privacy
objects) and ``labels/%06d.txt`` (YOLO, normalised ``class cx cy w h``); with stereo also
``depth_3/`` and ``background_3/`` for the right camera.

Frames are the PNG files of the left image folder in order of their frame *numbers*, the file
stems (digits only; two files for one number are an error).  Timestamps and poses are indexed by
frame number, so a folder holding only some frames of a sequence (the shared ``00`` holds frames
0–4 and the full 4,541-pose ground truth) reads correctly; a pose or time file with fewer entries
than the highest frame number needs is an error.  Every file whose content is wrong raises
:class:`~privslam_jax.errors.InputError` naming it (a missing file: ``FileNotFoundError``).

Camera: intrinsics from the left camera's ``P`` row; the stereo baseline from the left/right pair,
``b = (P_left[0, 3] − P_right[0, 3]) / fx``.  KITTI's ground truth is the pose of camera 0; when
the left camera's ``P`` carries a translation (real KITTI ``P2``), poses are moved to that camera:
``T_w_cL = T_w_c0 · T_c0_cL`` with ``T_c0_cL = [I | −K⁻¹ P_left[:, 3]]`` (rectified cameras share
the rotation).

Images load lazily (one PNG decode per access) as float32 ``(H, W, 3)`` RGB in ``[0, 1]``
(grey repeated to three channels), or ``(H, W)`` grey with ``grey=True``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np

from privslam_jax.data.images import read_image, read_raw
from privslam_jax.data.trajectory_io import _check_fits_trajectory, _read_rows, read_kitti_matrices
from privslam_jax.data.yolo import cxcywhn_to_xyxy, read_yolo_labels
from privslam_jax.errors import InputError, input_error
from privslam_jax.types import Camera, Trajectory

__all__ = ["KittiFrame", "KittiSequence", "read_calib", "DEPTH_SCALE"]

DEPTH_SCALE = 256.0
"""Depth PNGs store ``round(depth_m · 256)`` as uint16 (KITTI depth benchmark; 0 = no depth, max 255.99 m)."""

_LEFT_RIGHT = {False: ("image_2", "image_3", "P2", "P3"), True: ("image_0", "image_1", "P0", "P1")}


def read_calib(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a KITTI ``calib.txt``: ``{"P0": (3, 4), …}`` for every ``KEY: 12 numbers`` row.

    ``FileNotFoundError`` for a missing file; :class:`~privslam_jax.errors.InputError` naming
    ``file:line`` for a row that is not ``KEY:`` followed by 12 finite numbers, or a key given twice.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file not found: {path}")
    out: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"{path}:{lineno}: expected 'KEY: 12 numbers', got {line.strip()[:60]!r}")
        try:
            vals = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in row {key[:30]!r}") from None
        if vals.size != 12 or not np.all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: row {key[:30]!r} must have 12 finite numbers, got {vals.size}")
        if key in out:
            raise InputError(f"{path}:{lineno}: row {key[:30]!r} appears twice")
        out[key] = vals.reshape(3, 4)
    return out


def _read_times(path: Path) -> np.ndarray:
    """``times.txt``: one finite timestamp per line (``#`` comments and blank lines allowed), strictly
    increasing; :class:`~privslam_jax.errors.InputError` naming the file and line otherwise."""
    linenos: list[int] = []
    times = _read_rows(path, 1, "timestamps", linenos)[:, 0]
    bad = np.flatnonzero(np.diff(times) <= 0)  # evo and our readers reject it, and ATE would silently skip frames
    if bad.size:
        raise InputError(f"{path}: timestamps must increase, line {linenos[bad[0] + 1]} is not after line "
                         f"{linenos[bad[0]]}")
    return times


@dataclasses.dataclass(frozen=True)
class KittiFrame:
    """One frame of a KITTI-layout sequence (numpy arrays; optional parts are ``None`` when absent)."""

    index: int
    """Position in the sequence (0-based)."""
    frame_id: int
    """Frame number (the PNG file stem)."""
    timestamp: float
    """Seconds (``times.txt``, else ``frame_id / fps``)."""
    image: np.ndarray
    """Left image, ``(H, W, 3)`` float32 RGB in [0, 1] (``(H, W)`` when the sequence reads grey)."""
    image_right: np.ndarray | None
    """Right image when the sequence is opened stereo."""
    T_w_c: np.ndarray | None
    """``(4, 4)`` float64 ground-truth camera-to-world pose of the left camera, if poses exist."""
    depth: np.ndarray | None = None
    """``(H, W)`` float32 z-depth in metres, 0 where unknown (synth extra ``depth/``)."""
    instance_ids: np.ndarray | None = None
    """``(H, W)`` int32 instance ids, 0 = no privacy object (synth extra ``masks/``)."""
    background: np.ndarray | None = None
    """``(H, W, 3)`` float32 RGB object-free render (synth extra ``background/``)."""
    depth_right: np.ndarray | None = None
    """Right-camera depth (synth extra ``depth_3/``, stereo only)."""
    background_right: np.ndarray | None = None
    """Right-camera object-free render (synth extra ``background_3/``, stereo only)."""
    boxes: np.ndarray | None = None
    """``(K, 4)`` float64 xyxy pixel boxes (synth extra ``labels/``)."""
    class_ids: np.ndarray | None = None
    """``(K,)`` int32 COCO class ids of ``boxes``."""


class KittiSequence:
    """A KITTI odometry sequence folder ``<root>/sequences/<id>``, read lazily.

    Args:
        path: the sequence folder (``…/sequences/<id>``).
        stereo: also load the right image (``image_1``/``image_3``); needs its ``P`` row.
        colour: ``True`` → ``image_2``/``image_3``; ``False`` → ``image_0``/``image_1``;
            ``None`` (default) → colour when ``image_2`` exists, else grey.
        grey: return ``(H, W)`` grey images instead of RGB.
        fps: frame rate for the timestamps when ``times.txt`` is absent (KITTI: 10 Hz).
        poses_path: ground-truth file; default ``<root>/poses/<id>.txt`` when it exists.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        stereo: bool = False,
        colour: bool | None = None,
        grey: bool = False,
        fps: float = 10.0,
        poses_path: str | os.PathLike | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"KITTI sequence folder not found: {self.path}")
        self.name = self.path.name
        self.stereo = stereo
        self.grey = grey
        self.fps = fps
        if colour is None:
            colour = (self.path / "image_2").is_dir()
            if not colour and not (self.path / "image_0").is_dir():
                raise input_error(self.path, "not a KITTI sequence folder (no image_0/ or image_2/ folder)")
        left_dir, right_dir, p_left, p_right = _LEFT_RIGHT[not colour]
        self.left_dir = self.path / left_dir
        self.right_dir = self.path / right_dir if stereo else None
        if not self.left_dir.is_dir():
            raise FileNotFoundError(f"image folder not found: {self.left_dir}")
        self.image_paths = sorted(p for p in self.left_dir.glob("*.png") if p.is_file())
        if not self.image_paths:
            raise input_error(self.left_dir, "no PNG frames in the image folder")
        for p in self.image_paths:
            if not (p.stem.isascii() and p.stem.isdigit()):
                raise input_error(p, f"frame files must be named by number (e.g. 000000.png) in {self.left_dir}")
        self.image_paths.sort(key=lambda p: int(p.stem))  # by number: 9.png before 10.png (zero-padded: unchanged)
        try:
            self.frame_ids = np.array([int(p.stem) for p in self.image_paths], dtype=np.int64)
        except OverflowError as err:
            raise input_error(self.left_dir, "frame number too large", err) from err
        if np.unique(self.frame_ids).size != self.frame_ids.size:
            dup = np.unique(self.frame_ids, return_counts=True)
            raise input_error(self.left_dir, f"two files for frame {int(dup[0][np.argmax(dup[1] > 1)])}")
        if self.right_dir is not None:
            if not self.right_dir.is_dir():
                raise FileNotFoundError(f"stereo needs the right image folder: {self.right_dir}")
            for p in self.image_paths:
                if not (self.right_dir / p.name).is_file():
                    raise FileNotFoundError(f"right image missing: {self.right_dir / p.name}")

        calib_path = self.path / "calib.txt"
        self.calib = read_calib(calib_path)
        if p_left not in self.calib:
            raise InputError(f"{calib_path}: no {p_left} row for {left_dir}")
        P = self.calib[p_left]
        fx, fy, cx, cy = P[0, 0], P[1, 1], P[0, 2], P[1, 2]
        if not (fx > 0 and fy > 0):
            raise InputError(f"{calib_path}: {p_left} has non-positive focal length")
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        baseline = None
        with np.errstate(all="ignore"):  # extreme rows overflow here; refused just below
            if p_right in self.calib:
                baseline = float((P[0, 3] - self.calib[p_right][0, 3]) / fx)
            shift = -np.linalg.solve(K, P[:, 3])
        if (baseline is not None and not math.isfinite(baseline)) or not np.all(np.isfinite(shift)):
            raise InputError(f"{calib_path}: {p_left}/{p_right} give an infinite baseline or camera offset")
        if stereo and (baseline is None or not baseline > 0):
            raise InputError(f"{calib_path}: stereo needs a {p_right} row with a positive baseline")
        first = read_raw(self.image_paths[0])
        self.camera = Camera(
            fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=int(first.shape[1]), height=int(first.shape[0]),
            baseline=baseline,
        )
        self._T_c0_cl = np.eye(4)
        self._T_c0_cl[:3, 3] = shift

        need = int(self.frame_ids.max()) + 1
        times_path = self.path / "times.txt"
        if times_path.is_file():
            times = _read_times(times_path)
            if times.shape[0] < need:
                raise InputError(f"{times_path}: {times.shape[0]} timestamps but frame {need - 1} needs {need}")
            self.timestamps = times[self.frame_ids]
        else:
            self.timestamps = self.frame_ids.astype(np.float64) / fps

        if poses_path is None:
            cand = self.path.parent.parent / "poses" / f"{self.name}.txt"
            poses_path = cand if cand.is_file() else None
        self.poses_path = Path(poses_path) if poses_path is not None else None
        self.poses: np.ndarray | None = None
        if self.poses_path is not None:
            T = read_kitti_matrices(self.poses_path)
            if T.shape[0] < need:
                raise InputError(
                    f"{self.poses_path}: {T.shape[0]} poses but {len(self.image_paths)} frames in {self.left_dir} "
                    f"(frame {need - 1} needs {need})"
                )
            with np.errstate(all="ignore"):
                self.poses = T[self.frame_ids] @ self._T_c0_cl[None]
            if not np.all(np.isfinite(self.poses)):
                raise InputError(f"{self.poses_path}: poses overflow when moved to the {left_dir} camera")

        cls_path = self.path / "instance_classes.json"
        self.instance_classes: dict[int, int] = {}
        if cls_path.is_file():
            try:  # ValueError covers bad UTF-8 and bad JSON; RecursionError deep nesting; OverflowError inf
                self.instance_classes = {int(k): int(v) for k, v in json.loads(cls_path.read_bytes()).items()}
            except (ValueError, AttributeError, TypeError, RecursionError, OverflowError) as err:
                raise input_error(cls_path, 'expected {"instance id": class id}', err) from err

    @staticmethod
    def from_root(root: str | os.PathLike, sequence: str, **kwargs) -> "KittiSequence":
        """Open ``<root>/sequences/<sequence>`` (poses from ``<root>/poses/<sequence>.txt``)."""
        return KittiSequence(Path(root) / "sequences" / sequence, **kwargs)

    def __len__(self) -> int:
        return len(self.image_paths)

    @property
    def trajectory(self) -> Trajectory | None:
        """Ground truth as a :class:`Trajectory` (JAX precision), or ``None`` without poses.

        :class:`~privslam_jax.errors.InputError` when the poses or ``times.txt`` hold values beyond
        that precision's range."""
        if self.poses is None:
            return None
        _check_fits_trajectory(self.poses_path, self.poses)
        _check_fits_trajectory(self.path / "times.txt", self.timestamps)  # frame / fps always fits
        return Trajectory.from_matrices(self.timestamps, self.poses)

    def has_extra(self, name: str) -> bool:
        """Whether the synth extra folder ``name`` (``depth``, ``masks``, ``background``, ``labels``) exists."""
        return (self.path / name).is_dir()

    def image(self, i: int, right: bool = False) -> np.ndarray:
        """Decode the left (or right) image of frame ``i`` only."""
        i = self._check(i)
        if right:
            if self.right_dir is None:
                raise ValueError("sequence opened without stereo=True")
            return read_image(self.right_dir / self.image_paths[i].name, grey=self.grey)
        return read_image(self.image_paths[i], grey=self.grey)

    def instance_ids(self, i: int, right: bool = False) -> np.ndarray:
        """``(H, W)`` int32 ``masks/`` map of frame ``i`` only (0 = none; object ids from ``privslam synth``
        or the removed objects of ``privslam filter``); ``right``: the right camera's ``masks_3/``
        (``privslam synth --stereo``)."""
        folder = "masks_3" if right else "masks"
        p = self._extra(folder, self._check(i))
        if p is None:
            raise FileNotFoundError(f"{self.path / folder} does not exist")
        return self._read_map(p).astype(np.int32)

    def _check(self, i: int) -> int:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range for {len(self)} frames")
        return i % len(self)

    def _extra(self, folder: str, i: int, suffix: str = ".png") -> Path | None:
        d = self.path / folder
        if not d.is_dir():
            return None
        p = d / (self.image_paths[i].stem + suffix)
        if not p.is_file():
            raise FileNotFoundError(f"{folder} file missing for frame {self.image_paths[i].stem}: {p}")
        return p

    def _read_map(self, p: Path) -> np.ndarray:
        m = read_raw(p)
        if m.ndim != 2 or m.dtype != np.uint16:
            raise ValueError(f"{p}: expected a single-channel 16-bit PNG, got {m.dtype} {m.shape}")
        if m.shape != self.camera.shape:
            raise ValueError(f"{p}: size {m.shape} differs from the images {self.camera.shape}")
        return m

    def _read_depth(self, p: Path) -> np.ndarray:
        return (self._read_map(p).astype(np.float32) / np.float32(DEPTH_SCALE)).astype(np.float32)

    def __getitem__(self, i: int) -> KittiFrame:
        i = self._check(i)
        image = self.image(i)
        right = self.image(i, right=True) if self.stereo else None
        depth = ids = background = boxes = class_ids = depth_r = background_r = None
        if (p := self._extra("depth", i)) is not None:
            depth = self._read_depth(p)
        if self.stereo and (p := self._extra("depth_3", i)) is not None:
            depth_r = self._read_depth(p)
        if self.stereo and (p := self._extra("background_3", i)) is not None:
            background_r = read_image(p, grey=self.grey)
        if (p := self._extra("masks", i)) is not None:
            ids = self._read_map(p).astype(np.int32)
        if (p := self._extra("background", i)) is not None:
            background = read_image(p, grey=self.grey)
        if (p := self._extra("labels", i, ".txt")) is not None:
            class_ids, n = read_yolo_labels(p)
            with np.errstate(over="ignore", invalid="ignore"):
                boxes = cxcywhn_to_xyxy(n, self.camera.width, self.camera.height)
            if not np.all(np.isfinite(boxes)):
                raise InputError(f"{p}: box coordinates overflow in pixels")
        return KittiFrame(
            index=i,
            frame_id=int(self.frame_ids[i]),
            timestamp=float(self.timestamps[i]),
            image=image,
            image_right=right,
            T_w_c=None if self.poses is None else self.poses[i],
            depth=depth,
            instance_ids=ids,
            background=background,
            depth_right=depth_r,
            background_right=background_r,
            boxes=boxes,
            class_ids=class_ids,
        )

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __repr__(self) -> str:
        return (
            f"KittiSequence({str(self.path)!r}, frames={len(self)}, size={self.camera.width}x{self.camera.height}, "
            f"stereo={self.stereo}, poses={'yes' if self.poses is not None else 'no'})"
        )
