"""Bring your own frames: a folder of images or a video file, written as a KITTI odometry sequence.

Every command that runs SLAM (``privslam run``, ``slam``, ``client``) reads the KITTI layout, which
carries the camera in ``calib.txt``. :func:`import_frames` writes it for frames from any camera::

    DIR/sequences/NAME/image_0/%06d.png   grey frames (8-bit), or
                       image_2/%06d.png   colour frames (8-bit RGB)
                       calib.txt          P0 and P2 = K[I|0] (monocular: no right camera)
                       times.txt          frame i at i · every / fps seconds
                       manifest.json      "complete": true once every frame is written

Image folders are read in natural order (``frame2.png`` before ``frame10.png``); PNG, JPEG, BMP,
TIFF, WebP and PNM files are frames, other files are ignored. Videos are read by OpenCV's FFmpeg
backend (mp4, avi, mov, mkv, webm, …). The intrinsics are the user's calibration
(``fx, fy, cx, cy`` in pixels, origin at the centre of the top-left pixel) or, approximately, a
horizontal field of view: ``fx = fy = (W/2) / tan(hfov/2)``, ``cx = (W−1)/2``, ``cy = (H−1)/2``
(no distortion model: undistort the frames first if the lens needs it). The output has no
``background/`` folder, so the filter treats it as real frames (the real-frame detector and
inpainter, ``privslam_jax.inpaint.sequence.check_detector_domain``).

Refused with a message naming the file, before the run folder can look complete: an empty
folder or video, a frame that does not decode, a frame whose size differs from the first one's,
a video OpenCV cannot open.
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from privslam_jax.data.files import write_atomic
from privslam_jax.data.images import read_rgb8, write_image_file, write_rgb
from privslam_jax.errors import input_error
from privslam_jax.runs import claim_run_folder, complete_run_folder

__all__ = ["IMAGE_SUFFIXES", "hfov_intrinsics", "import_frames", "source_frames"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm", ".pnm")
"""File suffixes (any case) read as frames from an image folder."""


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def hfov_intrinsics(hfov_deg: float, width: int, height: int) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of a pinhole camera with square pixels, centred principal point and
    horizontal field of view ``hfov_deg`` (in ``(0, 180)``): ``fx = fy = (W/2) / tan(hfov/2)``."""
    if not 0 < hfov_deg < 180:
        raise ValueError(f"the horizontal field of view must lie in (0, 180) degrees, got {hfov_deg}")
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    return f, f, (width - 1) / 2, (height - 1) / 2


def source_frames(source: str | Path, every: int = 1, max_frames: int | None = None
                  ) -> Iterator[tuple[str, np.ndarray]]:
    """``(name, (H, W, 3) uint8 RGB)`` for every ``every``-th frame of an image folder or a video,
    at most ``max_frames``; ``name`` is the file (folder) or ``"<video>#<index>"`` (video)."""
    source = Path(source)
    if every < 1:
        raise ValueError(f"every must be at least 1, got {every}")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be at least 1, got {max_frames}")
    limit = math.inf if max_frames is None else max_frames
    if source.is_dir():
        paths = sorted((p for p in source.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                       key=_natural_key)
        if not paths:
            raise input_error(source, f"no image files ({', '.join(IMAGE_SUFFIXES)}) in the folder")
        for n, p in enumerate(paths[::every]):
            if n >= limit:
                return
            yield str(p), read_rgb8(p)
        return
    if not source.exists():
        raise FileNotFoundError(f"no such image folder or video: {source}")
    cap = cv2.VideoCapture(str(source))
    try:
        if not cap.isOpened():
            raise input_error(source, "OpenCV cannot open it as a video (and it is not a folder of images)")
        index = written = 0
        while written < limit:
            ok, bgr = cap.read()
            if not ok:
                break
            if index % every == 0:
                if bgr.dtype != np.uint8 or bgr.ndim != 3 or bgr.shape[2] != 3:
                    raise input_error(source, f"frame {index} decoded to {bgr.dtype} {bgr.shape}, not 8-bit colour")
                yield f"{source}#{index}", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
                written += 1
            index += 1
        if index == 0:
            raise input_error(source, "the video has no frames that OpenCV can decode")
    finally:
        cap.release()


def _is_grey(rgb: np.ndarray) -> bool:
    return bool(np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]))


def import_frames(
    source: str | Path, out: str | Path, name: str = "imported", *,
    camera: tuple[float, float, float, float] | None = None, hfov: float | None = None, fps: float | None = None,
    every: int = 1, max_frames: int | None = None, grey: bool | None = None, overwrite: bool = False,
    progress: bool = True,
) -> dict:
    """Write the frames of ``source`` (an image folder or a video) as ``out/sequences/name``.

    ``camera``: ``(fx, fy, cx, cy)`` in pixels, or ``hfov``: the horizontal field of view in degrees
    (:func:`hfov_intrinsics`); exactly one. ``fps``: the capture rate (default: the video's, else 10).
    ``grey``: write ``image_0`` (grey) or ``image_2`` (colour); default from the first frame (grey when
    its three channels are equal). Returns ``{"sequence", "frames", "width", "height", "grey", "fx",
    "fy", "cx", "cy", "fps"}``. ``out/sequences/name`` is a run folder (:mod:`privslam_jax.runs`):
    an earlier run there is refused unless ``overwrite``, and the manifest says complete only at
    the end.
    """
    if (camera is None) == (hfov is None):
        raise ValueError("SLAM needs the camera's intrinsics: give camera=(fx, fy, cx, cy) from its calibration, "
                         "or hfov (the horizontal field of view in degrees) for an approximation; not both")
    if camera is not None:
        if len(camera) != 4 or not all(math.isfinite(v) for v in camera) or not (camera[0] > 0 and camera[1] > 0):
            raise ValueError(f"camera must be four finite numbers fx, fy, cx, cy with fx, fy > 0, got {camera}")
    if not name or "/" in name or name in (".", ".."):
        raise ValueError(f"the sequence name must be a plain folder name, got {name!r}")
    source = Path(source)
    if fps is None and not source.is_dir() and source.exists():
        cap = cv2.VideoCapture(str(source))
        fps = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else None
        cap.release()
    fps = float(fps) if fps and math.isfinite(fps) and fps > 0 else 10.0
    frames = source_frames(source, every, max_frames)
    first_name, first = next(frames)  # reads and checks the source before anything is written
    h, w = first.shape[:2]
    grey = _is_grey(first) if grey is None else grey
    fx, fy, cx, cy = (float(v) for v in (camera if camera is not None else hfov_intrinsics(hfov, w, h)))
    seq_dir = Path(out) / "sequences" / name
    manifest = claim_run_folder(seq_dir, "import", {"source": str(source), "name": name, "camera": [fx, fy, cx, cy],
                                                    "fps": fps, "every": every, "grey": grey}, overwrite)
    K = f"{fx:.12e} 0.000000000000e+00 {cx:.12e} 0.000000000000e+00 0.000000000000e+00 {fy:.12e} {cy:.12e} " \
        "0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00"
    write_atomic(seq_dir / "calib.txt", f"P0: {K}\nP2: {K}\n")
    folder = seq_dir / ("image_0" if grey else "image_2")
    count = 0
    bar = tqdm(desc=f"import {name}", unit="frame", disable=not progress)
    for frame_name, rgb in itertools.chain([(first_name, first)], frames):
        if rgb.shape[:2] != (h, w):
            raise input_error(frame_name, f"{rgb.shape[1]}x{rgb.shape[0]} frame in a {w}x{h} sequence "
                                          f"(the first frame, {first_name}, sets the size)")
        path = folder / f"{count:06d}.png"
        if grey:
            write_image_file(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
        else:
            write_rgb(path, rgb)
        count += 1
        bar.update()
    bar.close()
    write_atomic(seq_dir / "times.txt", "".join(f"{i * every / fps:.6e}\n" for i in range(count)))
    complete_run_folder(seq_dir, manifest)
    return {"sequence": seq_dir, "frames": count, "width": w, "height": h, "grey": grey, "fx": fx, "fy": fy,
            "cx": cx, "cy": cy, "fps": fps}
