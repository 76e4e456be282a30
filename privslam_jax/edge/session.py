"""One SLAM session of the edge server, persisted under the server's store as it grows.

Store layout, ``STORE/<session_id>/``:

* ``calibration.json``: the session's :class:`~privslam_jax.edge.edge_pb2.Calibration`;
* ``frames/<index>.png`` (and ``right/``, ``depth/``, ``mask/``): every accepted frame exactly as
  it arrived (the filtered frames: nothing else ever reaches the server), then
  ``frames/<index>.json`` (its timestamp), the record that the frame was accepted: each file is
  written atomically, the record last, and all of them before the frame is answered;
* ``trajectory.txt`` (TUM), ``frames.txt`` (``timestamp tracked map``, as ``privslam slam``
  writes them) and ``times.txt``, rewritten atomically every ``persist_every`` frames and whenever the client asks
  for the trajectory;
* ``lines.ply``: the last map sent, as a line cloud (never points);
* ``lift.key``: the session's secret lift key (mode 0600).

**Resuming.**  SLAM is deterministic for a seed (:mod:`privslam_jax.slam.system`), so a session is
resumed by replaying its stored frames through a new :class:`~privslam_jax.slam.system.Slam`: the
state after the replay is the state the killed server had after the same frames.  A frame is
acknowledged (its :class:`Pose` sent) only after it is stored, so a client that resends every
unacknowledged frame loses none.

**The map a client receives** is the random lift of the good map points with one direction per
map point, drawn from the session key and the point's id (:func:`privslam_jax.privacy.lift.random_lift`
with ``ids``): a map that grows keeps the lines it had (a new draw for an old point would give two
lines through it, which meet at the point).  Lines are sorted by direction, not by when their
point was made, and carry the points' ORB descriptors so the client can localise against them.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import cv2
import numpy as np

from privslam_jax.data.files import write_atomic
from privslam_jax.edge import edge_pb2 as pb
from privslam_jax.edge.codec import calibration_dict, camera_of, decode_png, pose_message
from privslam_jax.errors import InputError

__all__ = ["EdgeSession"]


class EdgeSession:
    """SLAM over the frames one client sends (mutable; one thread at a time, see ``lock``)."""

    def __init__(self, folder: Path, cal: pb.Calibration, persist_every: int = 10):
        from privslam_jax.slam.system import Slam, SlamConfig

        self.folder = folder
        self.calibration = cal
        self.camera = camera_of(cal)
        self.mode = cal.mode
        self.persist_every = persist_every
        self.lock = threading.Lock()
        """Held by the call serving the session: a second connection to it is refused."""
        self.config = SlamConfig(mode=cal.mode, seed=int(cal.seed))
        cv2.setRNGSeed(self.config.seed)  # OpenCV's RNG is per thread: the serving thread's
        self.slam = Slam(self.camera, self.config)
        self.timestamps: list[float] = []
        self.replies: list[pb.Pose] = []

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, store: Path, cal: pb.Calibration, persist_every: int = 10) -> "EdgeSession":
        """Start the session ``cal.session_id`` in ``store``, or resume it when stored with the same
        calibration (a different one is refused)."""
        camera_of(cal)  # checks the id before it names a folder
        folder = store / cal.session_id
        stored = folder / "calibration.json"
        if stored.is_file():
            before = json.loads(stored.read_text())
            if before != calibration_dict(cal):
                changed = sorted(k for k in before if before[k] != calibration_dict(cal).get(k))
                raise InputError(f"session {cal.session_id} is stored with another calibration ({', '.join(changed)} "
                                 "differ): use a new session id")
            session = cls(folder, cal, persist_every)
            session._replay()
            return session
        for sub in ("frames", "right", "depth", "mask"):
            (folder / sub).mkdir(parents=True, exist_ok=True)
        key = os.urandom(8)
        fd = os.open(folder / "lift.key", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key)
        write_atomic(stored, json.dumps(calibration_dict(cal), indent=2) + "\n")  # last: marks the session stored
        return cls(folder, cal, persist_every)

    def _replay(self) -> None:
        index = 0
        while (record := self.folder / "frames" / f"{index:06d}.json").is_file():
            parts = {sub: self._stored(sub, index) for sub in ("frames", "right", "depth", "mask")}
            self._track(index, float(json.loads(record.read_text())["timestamp"]), parts)
            index += 1

    def _stored(self, sub: str, index: int) -> bytes | None:
        path = self.folder / sub / f"{index:06d}.png"
        return path.read_bytes() if path.is_file() else None

    @property
    def next_index(self) -> int:
        """The index the next new frame must have."""
        return len(self.timestamps)

    # ------------------------------------------------------------------ frames
    def accept(self, frame: pb.Frame) -> pb.Pose:
        """Check, store and track one frame; returns its pose (the acknowledgement: the tracked pose; a
        new keyframe's local mapping is left for :meth:`after_reply`).  A frame already
        accepted (a resend) is answered with its first reply; a gap or a bad frame raises
        :class:`InputError` and changes nothing."""
        if frame.index < self.next_index:
            return self.replies[frame.index]
        if frame.index != self.next_index:
            raise InputError(f"frame {frame.index}: the next frame of session {self.calibration.session_id} is "
                             f"{self.next_index} (frames come in order without gaps)")
        if not np.isfinite(frame.timestamp):
            raise InputError(f"frame {frame.index}: timestamp is not finite")
        parts = {"frames": frame.image, "right": frame.right or None, "depth": frame.depth or None,
                 "mask": frame.mask or None}
        self._decode(frame.index, parts)  # refuse before storing anything
        for sub, data in parts.items():
            if data is not None:
                write_atomic(self.folder / sub / f"{frame.index:06d}.png", data)
        write_atomic(self.folder / "frames" / f"{frame.index:06d}.json", json.dumps({"timestamp": frame.timestamp}))
        return self._track(frame.index, float(frame.timestamp), parts)

    def after_reply(self) -> None:
        """The work :meth:`accept` left for after its answer: the local mapping of a new keyframe, and
        every ``persist_every`` frames the trajectory files."""
        self.slam.finish_mapping()
        if self.next_index % self.persist_every == 0:
            self.persist()

    def _decode(self, index: int, parts: dict[str, bytes | None]) -> dict[str, np.ndarray | None]:
        shape = self.camera.shape
        what = f"frame {index}"
        if not parts["frames"]:
            raise InputError(f"{what}: no image")
        need = {"stereo": "right", "rgbd": "depth"}.get(self.mode)
        if need is not None and parts[need] is None:
            raise InputError(f"{what}: {self.mode} mode needs the {need} image")
        extra = [k for k in ("right", "depth") if parts[k] is not None and k != need]
        if extra:
            raise InputError(f"{what}: {self.mode} mode takes no {extra[0]} image")
        return {
            "frames": decode_png(parts["frames"], f"{what} image", shape),
            "right": None if parts["right"] is None else decode_png(parts["right"], f"{what} right image", shape),
            "depth": None if parts["depth"] is None else decode_png(parts["depth"], f"{what} depth", shape, bits=16),
            "mask": None if parts["mask"] is None else decode_png(parts["mask"], f"{what} mask", shape),
        }

    def _track(self, index: int, timestamp: float, parts: dict[str, bytes | None]) -> pb.Pose:
        img = self._decode(index, parts)
        ignore = img["mask"] > 0 if (self.calibration.ignore_masked and img["mask"] is not None) else None
        depth = None if img["depth"] is None else img["depth"].astype(np.float32) / 1000.0
        T_w_c, tracked = self.slam.track(img["frames"], right=img["right"], depth=depth, ignore=ignore,
                                         defer_mapping=True)
        self.timestamps.append(timestamp)
        ref = self.slam.frames_rel[index][0]
        map_id = int(self.slam.map.map_ids()[ref]) if ref >= 0 else -1
        reply = pose_message(index, timestamp, T_w_c, tracked, self.slam.inliers[index], map_id)
        self.replies.append(reply)
        return reply

    # ------------------------------------------------------------------ outputs
    def trajectory(self) -> pb.Trajectory:
        """Every frame's current pose estimate (refined by mapping and loop closing since it was sent)."""
        if not self.timestamps:
            return pb.Trajectory()
        r = self.slam.result(np.asarray(self.timestamps))
        T = np.asarray(r.trajectory.as_matrices(), np.float64)
        maps = r.frame_maps if r.frame_maps is not None else np.zeros(len(T), np.int64)
        return pb.Trajectory(poses=[pose_message(i, t, T[i], bool(r.tracked[i]), int(r.inliers[i]), int(maps[i]))
                                    for i, t in enumerate(self.timestamps)])

    def persist(self) -> None:
        """Write ``trajectory.txt``, ``frames.txt`` and ``times.txt`` (atomically)."""
        if not self.timestamps:
            return
        from privslam_jax.data.trajectory_io import write_tum_matrices
        from privslam_jax.slam.outputs import write_frame_status

        r = self.slam.result(np.asarray(self.timestamps))
        write_tum_matrices(self.folder / "trajectory.txt", np.asarray(self.timestamps),
                           np.asarray(r.trajectory.as_matrices(), np.float64))
        write_frame_status(self.folder / "frames.txt", self.timestamps, r.tracked, r.frame_maps)
        write_atomic(self.folder / "times.txt", "".join(f"{t!r}\n" for t in self.timestamps))

    def line_cloud(self) -> pb.LineCloud:
        """The map as a line cloud (module docstring); also written to ``lines.ply``."""
        import jax

        from privslam_jax.data.ply import save_line_cloud
        from privslam_jax.privacy.lift import random_lift

        mp = self.slam.map
        ids = np.flatnonzero(~mp.bad & (mp.n_obs > 0))
        words = np.frombuffer((self.folder / "lift.key").read_bytes(), np.uint32)
        key = jax.random.wrap_key_data(words, impl="threefry2x32")
        if len(ids):
            lines = random_lift(mp.xyz[ids].astype(np.float64), key, ids=ids)
            order = np.lexsort(np.asarray(lines.directions, np.float64).T)
            lines = type(lines)(directions=np.asarray(lines.directions)[order], moments=np.asarray(lines.moments)[order])
            desc = mp.desc[ids][order]
        else:
            from privslam_jax.types import LineCloud

            lines, desc = LineCloud(directions=np.zeros((0, 3)), moments=np.zeros((0, 3))), None
        path = self.folder / "lines.ply"
        save_line_cloud(path, lines, descriptors=desc)
        return pb.LineCloud(ply=path.read_bytes(), lines=len(ids), frames=self.next_index)
