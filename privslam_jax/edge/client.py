"""The device side of the edge split: send filtered frames, get poses and a line-cloud map back.

:func:`frame_message` turns a filtered frame in memory into what crosses the wire: the grey 8-bit
image SLAM reads (``grey_as_read`` of the filtered frame, so the server computes what ``privslam
slam`` computes on the filtered sequence), the right image (stereo) or the depth in millimetres
with **0 inside the masks** (RGB-D: a depth map would still carry the removed objects' shapes),
and the mask of the filled-in pixels (a 0/255 PNG: no object ids or classes).  Colour never
leaves the device; nothing else does either.

:func:`run_session` streams them to a server (:mod:`privslam_jax.edge.server`) with at most
``window`` frames unacknowledged, reconnects with exponential backoff when the connection fails
or the server restarts, resends only the frames not yet acknowledged, and finally asks for the
trajectory and the map.  Every message of the call can be watched with ``interceptors``
(``grpc.StreamStreamClientInterceptor``), as the trust-boundary tests do.
"""

from __future__ import annotations

import dataclasses
import queue
import time
from collections.abc import Sequence

import grpc
import numpy as np

from privslam_jax.edge import edge_pb2 as pb
from privslam_jax.edge import edge_pb2_grpc as pb_grpc
from privslam_jax.edge.codec import encode_png, pose_matrix
from privslam_jax.types import Camera

__all__ = ["EdgeResult", "EdgeError", "calibration_message", "frame_message", "device_frames", "run_session"]

_RETRY = (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.ABORTED, grpc.StatusCode.CANCELLED,
          grpc.StatusCode.RESOURCE_EXHAUSTED)
"""Failures worth another connection (server down or restarting, the session still held by a dead
connection, the server full); any other status (a refused token or frame) ends the session."""


class EdgeError(ConnectionError):
    """The server refused the session (the message says why), or it could not be reached in time."""


@dataclasses.dataclass(frozen=True)
class EdgeResult:
    """What came back from the server."""

    timestamps: np.ndarray
    """``(N,)`` seconds."""
    T_w_c: np.ndarray
    """``(N, 4, 4)`` final pose of every frame (the trajectory asked for at the end)."""
    tracked: np.ndarray
    """``(N,)`` bool."""
    maps: np.ndarray
    """``(N,)`` Atlas map of each pose (``-1``: none)."""
    streamed: np.ndarray
    """``(N, 4, 4)`` the pose of each frame as it was acknowledged (before later refinement)."""
    line_cloud_ply: bytes
    """The map as the server sent it: a canonical line-cloud PLY (``privslam lift``'s format)."""
    latency_s: np.ndarray
    """``(N,)`` seconds from sending a frame (its last send) to its acknowledgement."""
    bytes_up: int
    """Serialized bytes of every message sent (resends included)."""
    bytes_down: int
    """Serialized bytes of every message received."""
    reconnects: int
    """Connections after the first."""


def calibration_message(session_id: str, camera: Camera, mode: str, *, seed: int = 0,
                        ignore_masked: bool = False) -> pb.Calibration:
    """The calibration a session starts with."""
    return pb.Calibration(session_id=session_id, mode=mode, fx=float(camera.fx), fy=float(camera.fy),
                          cx=float(camera.cx), cy=float(camera.cy), width=int(camera.width), height=int(camera.height),
                          baseline=float(camera.baseline or 0.0), seed=int(seed), ignore_masked=ignore_masked)


def frame_message(index: int, timestamp: float, image: np.ndarray, *, right: np.ndarray | None = None,
                  depth: np.ndarray | None = None, mask: np.ndarray | None = None) -> pb.Frame:
    """One filtered frame as it crosses the wire (module docstring).

    ``image``/``right``: 8-bit filtered frames, ``(H, W, 3)`` RGB or ``(H, W)`` grey; ``depth``:
    ``(H, W)`` metres (RGB-D); ``mask``: ``(H, W)``, nonzero where the filter filled in.
    """
    from privslam_jax.data.images import grey_as_read

    def grey(img: np.ndarray) -> bytes:
        return encode_png(np.rint(grey_as_read(np.asarray(img)) * 255.0).astype(np.uint8))

    hidden = None if mask is None else np.asarray(mask) > 0
    msg = pb.Frame(index=index, timestamp=float(timestamp), image=grey(image))
    if right is not None:
        msg.right = grey(right)
    if depth is not None:
        d = np.asarray(depth, np.float64)
        mm = np.rint(np.where(np.isfinite(d), d, 0.0) * 1000.0)
        mm[(mm <= 0) | (mm > 65535)] = 0.0  # 16-bit millimetres: beyond 65.535 m is "no depth", not 65.5 m
        if hidden is not None:
            mm[hidden] = 0.0  # the removed objects' shapes stay on the device
        msg.depth = encode_png(mm.astype(np.uint16))
    if hidden is not None and hidden.any():
        msg.mask = encode_png(hidden.astype(np.uint8) * 255)
    return msg


def device_frames(filtered, timestamps: np.ndarray | Sequence[float], mode: str,
                  depths: Sequence[np.ndarray] | None = None) -> list[pb.Frame]:
    """The messages of a filtered sequence in memory (:class:`~privslam_jax.inpaint.sequence.FilteredFrames`):
    frame ``i`` with ``timestamps[i]``, its filtered right image (stereo; a sequence whose right
    frames were not filtered is refused: they would leave the device unfiltered) or ``depths[i]``
    in metres (RGB-D), and its mask."""
    if mode not in ("mono", "stereo", "rgbd"):
        raise ValueError(f"mode must be mono, stereo or rgbd, got {mode!r}")
    if mode == "stereo" and filtered.right is None:
        raise ValueError("stereo needs the filtered right frames, and the right frames were not filtered (they need "
                         "detected masks, --masks detect, or the right camera's ground-truth masks, masks_3/)")
    if mode == "rgbd" and (depths is None or len(depths) < len(filtered)):
        raise ValueError("rgbd needs a depth map per frame")
    if len(timestamps) < len(filtered):
        raise ValueError(f"{len(timestamps)} timestamps for {len(filtered)} frames")
    return [frame_message(i, float(timestamps[i]), filtered.left[i],
                          right=filtered.right[i] if mode == "stereo" else None,
                          depth=depths[i] if mode == "rgbd" else None, mask=filtered.label_maps[i] > 0)
            for i in range(len(filtered))]


def _channel(server: str, root_certificates: bytes | None, max_message_bytes: int, interceptors: Sequence) -> grpc.Channel:
    options = [("grpc.max_receive_message_length", max_message_bytes),
               ("grpc.max_send_message_length", max_message_bytes)]
    if root_certificates is not None:
        channel = grpc.secure_channel(server, grpc.ssl_channel_credentials(root_certificates=root_certificates),
                                      options=options)
    else:
        channel = grpc.insecure_channel(server, options=options)
    return grpc.intercept_channel(channel, *interceptors) if interceptors else channel


def run_session(server: str, calibration: pb.Calibration, frames: Sequence[pb.Frame], *, token: str | None = None,
                root_certificates: bytes | None = None, window: int = 4, deadline_s: float = 3600.0,
                reconnect_for_s: float = 60.0, want_map: bool = True, interceptors: Sequence = (),
                max_message_bytes: int = 16 * 1024 * 1024, on_pose=None, rate_hz: float | None = None) -> EdgeResult:
    """Stream ``frames`` (indices 0 … N−1, :func:`frame_message`) to ``server`` as the session of
    ``calibration``; returns the poses and the map (module docstring).

    ``token``: the bearer token; ``root_certificates``: PEM of the CA that signed the server's
    certificate (TLS; ``None``: a plain channel).  ``deadline_s`` bounds each connection;
    ``reconnect_for_s`` how long to keep reconnecting after a failure (backoff 0.1 s doubling to
    5 s).  ``on_pose(pose)`` is called with every acknowledgement as it arrives.  ``rate_hz``: send
    frame ``i`` no earlier than ``i / rate_hz`` seconds after the first (a camera's rate; ``None``: as
    fast as the window allows).  Raises
    :class:`EdgeError` when the server refuses the session or cannot be reached.
    """
    if [f.index for f in frames] != list(range(len(frames))):
        raise ValueError("frames must have indices 0, 1, ..., N-1 in order")
    metadata = (("authorization", f"Bearer {token}"),) if token else ()
    acked: dict[int, pb.Pose] = {}
    sent_at: dict[int, float] = {}
    latency = np.full(len(frames), np.nan)
    counts = {"up": 0, "down": 0}
    final: dict[str, pb.Trajectory | pb.LineCloud] = {}
    reconnects, failed_since, backoff = -1, None, 0.1
    start = time.perf_counter()
    due = None if rate_hz is None else (lambda i: start + i / rate_hz)
    while True:
        reconnects += 1
        before = len(acked)
        channel = _channel(server, root_certificates, max_message_bytes, interceptors)
        try:
            _attempt(pb_grpc.EdgeSlamStub(channel), calibration, frames, metadata, deadline_s, window, want_map,
                     acked, sent_at, latency, counts, final, on_pose, due)
            break
        except grpc.RpcError as err:
            code = err.code() if hasattr(err, "code") else grpc.StatusCode.UNKNOWN
            details = err.details() if hasattr(err, "details") else str(err)
            if code not in _RETRY:
                raise EdgeError(f"the server refused session {calibration.session_id}: {code.name}: {details}") from err
            now = time.monotonic()
            if failed_since is None or len(acked) > before:  # a connection that made progress restarts the clock
                failed_since, backoff = now, 0.1
            if now - failed_since > reconnect_for_s:
                raise EdgeError(f"session {calibration.session_id}: no connection to {server} for "
                                f"{reconnect_for_s:.0f} s ({code.name}: {details}); "
                                f"{len(acked)} of {len(frames)} frames acknowledged") from err
            time.sleep(backoff)
            backoff = min(5.0, backoff * 2)
        finally:
            channel.close()
    traj = final["trajectory"]
    assert isinstance(traj, pb.Trajectory)
    poses = list(traj.poses)
    if [p.index for p in poses] != list(range(len(frames))):
        raise EdgeError(f"the server's trajectory has {len(poses)} poses for {len(frames)} frames")
    cloud = final.get("line_cloud")
    return EdgeResult(
        timestamps=np.array([p.timestamp for p in poses]),
        T_w_c=np.stack([pose_matrix(p) for p in poses]) if poses else np.zeros((0, 4, 4)),
        tracked=np.array([p.state == pb.TRACKED for p in poses], bool),
        maps=np.array([p.map_id for p in poses], np.int64),
        streamed=np.stack([pose_matrix(acked[i]) for i in range(len(frames))]) if frames else np.zeros((0, 4, 4)),
        line_cloud_ply=cloud.ply if isinstance(cloud, pb.LineCloud) else b"",
        latency_s=latency, bytes_up=counts["up"], bytes_down=counts["down"], reconnects=reconnects)


def _attempt(stub, calibration, frames, metadata, deadline_s, window, want_map, acked, sent_at, latency, counts,
             final, on_pose, due) -> None:
    """One connection: send the calibration, every unacknowledged frame (``window`` in flight), then the
    requests; fills ``acked``, ``latency``, ``counts`` and ``final`` as answers arrive."""
    outbox: queue.Queue = queue.Queue()

    def requests():
        while True:
            msg = outbox.get()
            if msg is None:
                return
            if msg.WhichOneof("kind") == "frame":
                if due is not None:
                    time.sleep(max(0.0, due(msg.frame.index) - time.perf_counter()))
                sent_at[msg.frame.index] = time.perf_counter()
            counts["up"] += msg.ByteSize()
            yield msg

    def send(msg: pb.Up) -> None:
        outbox.put(msg)

    send(pb.Up(calibration=calibration))
    responses = stub.Session(requests(), metadata=metadata, timeout=deadline_s)
    try:
        todo = [i for i in range(len(frames)) if i not in acked]
        queued = 0

        def top_up() -> None:
            nonlocal queued
            while queued < len(todo) and queued - sum(1 for i in todo[:queued] if i in acked) < window:
                send(pb.Up(frame=frames[todo[queued]]))
                queued += 1

        asked = False
        for down in responses:
            counts["down"] += down.ByteSize()
            kind = down.WhichOneof("kind")
            if kind == "pose":
                i = down.pose.index
                if i not in acked:
                    acked[i] = down.pose
                    latency[i] = time.perf_counter() - sent_at.get(i, np.nan)
                    if on_pose is not None:
                        on_pose(down.pose)
            elif kind == "trajectory":
                final["trajectory"] = down.trajectory
            elif kind == "line_cloud":
                final["line_cloud"] = down.line_cloud
            if kind in ("started", "pose"):
                top_up()
            if len(acked) == len(frames) and not asked:
                asked = True
                send(pb.Up(trajectory_request=pb.TrajectoryRequest()))
                if want_map:
                    send(pb.Up(map_request=pb.MapRequest()))
            if asked and "trajectory" in final and ("line_cloud" in final or not want_map):
                outbox.put(None)  # end of the requests: the server ends the call
        if "trajectory" not in final:
            raise EdgeError(f"session {calibration.session_id}: the server ended the call before answering")
    finally:
        outbox.put(None)
        responses.cancel()  # no effect on a finished call
