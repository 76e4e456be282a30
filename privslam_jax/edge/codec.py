"""What crosses the wire, both ways: PNG frames, calibration and poses (``edge.proto``).

Every check of a message a peer sent is here, before anything is decoded or allocated: a PNG's
header must say the size and depth the session announced (so a small message cannot claim a
huge image), calibration values must be finite and positive.  A failed check raises
:class:`~privslam_jax.errors.InputError` with a message naming the frame and the field.
"""

from __future__ import annotations

import re
import struct

import cv2
import numpy as np

from privslam_jax.edge import edge_pb2 as pb
from privslam_jax.errors import InputError
from privslam_jax.types import Camera

__all__ = ["MODES", "MAX_PIXELS", "SESSION_ID", "encode_png", "decode_png", "camera_of", "calibration_dict",
           "pose_message", "pose_matrix"]

MODES = ("mono", "stereo", "rgbd")
MAX_PIXELS = 4096 * 4096
"""Largest ``width × height`` a session may announce."""
SESSION_ID = re.compile(r"[A-Za-z0-9_-]{1,64}")
"""Session ids: they name a folder of the server's store."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def encode_png(image: np.ndarray) -> bytes:
    """Lossless PNG of an ``(H, W)`` uint8 or uint16 image."""
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"encode_png expects an (H, W) uint8 or uint16 image, got {img.dtype} {img.shape}")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes, what: str, shape: tuple[int, int], bits: int = 8) -> np.ndarray:
    """An ``(H, W)`` grey PNG of ``bits`` bits (8 or 16) whose size must be ``shape``; anything else
    (another format, colour, another size or depth, a truncated or corrupt file) is refused."""
    h, w = shape
    if len(data) < 33 or data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise InputError(f"{what}: not a PNG ({len(data)} bytes)")
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    if (height, width) != (h, w):
        raise InputError(f"{what}: the PNG is {width}x{height}, the session's calibration says {w}x{h}")
    if colour != 0 or depth != bits:
        raise InputError(f"{what}: the PNG has colour type {colour} and {depth} bits, expected a grey PNG "
                         f"(colour type 0) of {bits} bits")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    dtype = np.uint8 if bits == 8 else np.uint16
    if img is None or img.shape != (h, w) or img.dtype != dtype:
        raise InputError(f"{what}: the PNG could not be decoded (truncated or corrupt)")
    return img


def camera_of(cal: pb.Calibration) -> Camera:
    """The session's camera, after checking the calibration (finite, positive, a known mode)."""
    if not SESSION_ID.fullmatch(cal.session_id):
        raise InputError(f"calibration: session_id must be 1-64 characters of [A-Za-z0-9_-], got {cal.session_id!r}")
    if cal.mode not in MODES:
        raise InputError(f"calibration: mode must be one of {MODES}, got {cal.mode!r}")
    values = {"fx": cal.fx, "fy": cal.fy, "cx": cal.cx, "cy": cal.cy, "baseline": cal.baseline}
    bad = [k for k, v in values.items() if not np.isfinite(v)]
    if bad:
        raise InputError(f"calibration: {', '.join(bad)} not finite")
    if cal.fx <= 0 or cal.fy <= 0:
        raise InputError(f"calibration: fx and fy must be positive, got {cal.fx}, {cal.fy}")
    if not (0 < cal.width and 0 < cal.height and cal.width * cal.height <= MAX_PIXELS):
        raise InputError(f"calibration: the image size {cal.width}x{cal.height} is not within 1 .. {MAX_PIXELS} pixels")
    if cal.baseline < 0 or (cal.mode == "stereo" and cal.baseline == 0):
        raise InputError(f"calibration: baseline must be {'positive' if cal.mode == 'stereo' else '>= 0'}, "
                         f"got {cal.baseline}")
    return Camera(fx=float(cal.fx), fy=float(cal.fy), cx=float(cal.cx), cy=float(cal.cy), width=int(cal.width),
                  height=int(cal.height), baseline=float(cal.baseline) or None)


def calibration_dict(cal: pb.Calibration) -> dict:
    """The calibration as a JSON-able dict (what the store keeps and compares on resume)."""
    return {f.name: getattr(cal, f.name) for f in pb.Calibration.DESCRIPTOR.fields}


def pose_message(index: int, timestamp: float, T_w_c: np.ndarray, tracked: bool, inliers: int, map_id: int) -> pb.Pose:
    """A :class:`Pose` message of one frame."""
    return pb.Pose(index=index, timestamp=timestamp, T_w_c=np.asarray(T_w_c, np.float64)[:3].reshape(-1).tolist(),
                   state=pb.TRACKED if tracked else pb.LOST, inliers=max(0, int(inliers)), map_id=int(map_id))


def pose_matrix(msg: pb.Pose) -> np.ndarray:
    """The ``(4, 4)`` ``T_w_c`` of a :class:`Pose` message."""
    if len(msg.T_w_c) != 12:
        raise InputError(f"pose of frame {msg.index}: {len(msg.T_w_c)} values, expected 12")
    T = np.eye(4)
    T[:3] = np.asarray(msg.T_w_c, np.float64).reshape(3, 4)
    return T
