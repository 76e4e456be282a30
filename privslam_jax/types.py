"""Core data types: immutable pytrees shared by every stage.

Conventions (DESIGN §3):

* ``T_w_c`` maps camera coordinates to world coordinates (KITTI poses are this).
* Pixels are ``(u, v)`` with the origin at the top-left pixel *centre* convention of OpenCV
  (pixel ``(0, 0)`` covers ``[-0.5, 0.5]²``), ``v`` pointing down; the camera looks along ``+z``,
  ``x`` right, ``y`` down.
* Images are ``float32`` HWC in ``[0, 1]``, RGB.
* Boxes are ``xyxy`` in pixels.

All containers are ``flax.struct`` dataclasses: frozen, usable as pytrees under ``jit``/``vmap``.
Fields that change the compiled program (image sizes) are static (``pytree_node=False``).
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from jaxtyping import Array, ArrayLike, Float, Int, UInt8

__all__ = ["Camera", "Trajectory", "PointCloud", "LineCloud", "Detections"]


@struct.dataclass
class Camera:
    """A pinhole camera (no distortion), optionally one half of a rectified stereo pair.

    Projection of a camera-frame point ``p_c = (x, y, z)``:
    ``u = fx·x/z + cx``, ``v = fy·y/z + cy``.  The right camera of a stereo pair sits at
    ``+baseline`` metres along the left camera's ``x`` axis (KITTI ``P1`` has
    ``P1[0, 3] = -fx·baseline``).
    """

    fx: float | Array
    """Focal length along ``u``, pixels."""
    fy: float | Array
    """Focal length along ``v``, pixels."""
    cx: float | Array
    """Principal point ``u``, pixels."""
    cy: float | Array
    """Principal point ``v``, pixels."""
    width: int = struct.field(pytree_node=False, default=0)
    """Image width in pixels (static)."""
    height: int = struct.field(pytree_node=False, default=0)
    """Image height in pixels (static)."""
    baseline: float | None = struct.field(pytree_node=False, default=None)
    """Stereo baseline in metres (right camera at ``+baseline`` along ``x``), or ``None``."""

    @property
    def K(self) -> Float[Array, "3 3"]:
        """The 3×3 intrinsic matrix."""
        z = jnp.zeros_like(jnp.asarray(self.fx, dtype=jnp.float32))
        return jnp.stack(
            [
                jnp.stack([z + self.fx, z, z + self.cx]),
                jnp.stack([z, z + self.fy, z + self.cy]),
                jnp.stack([z, z, z + 1.0]),
            ]
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    def project(self, p_c: Float[Array, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Pinhole projection of camera-frame points to pixels ``(u, v)`` (:func:`privslam_jax.geometry.projection.pinhole`)."""
        from privslam_jax.geometry.projection import pinhole

        return pinhole(jnp.asarray(p_c), self.fx, self.fy, self.cx, self.cy)

    def unproject(self, uv: Float[Array, "*batch 2"], depth: Float[Array, "*batch"]) -> Float[Array, "*batch 3"]:
        """Back-project pixels with their depth (``z``, not range) to camera-frame points."""
        x = (uv[..., 0] - self.cx) / self.fx * depth
        y = (uv[..., 1] - self.cy) / self.fy * depth
        return jnp.stack([x, y, depth], axis=-1)


@struct.dataclass
class Trajectory:
    """Timestamped camera poses ``T_w_c`` (camera-to-world), one per frame."""

    timestamps: Float[Array, " N"]
    """Seconds, strictly increasing."""
    poses: jaxlie.SE3
    """``T_w_c`` with batch axis ``N`` (``poses.wxyz_xyz`` has shape ``(N, 7)``)."""

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    @staticmethod
    def from_matrices(timestamps: ArrayLike, T_w_c: ArrayLike) -> "Trajectory":
        """Build from homogeneous ``(N, 4, 4)`` (or ``(N, 3, 4)``) camera-to-world matrices."""
        T = np.asarray(T_w_c, dtype=np.float64)
        t = np.asarray(timestamps, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)):
            raise ValueError(f"T_w_c must have shape (N, 4, 4) or (N, 3, 4), got {T.shape}")
        if t.shape != (T.shape[0],):
            raise ValueError(f"timestamps must have shape ({T.shape[0]},), got {t.shape}")
        if not np.all(np.isfinite(T)) or not np.all(np.isfinite(t)):
            raise ValueError("trajectory contains NaN or inf")
        poses = jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(T[:, :3, :3])), jnp.asarray(T[:, :3, 3])
        )
        return Trajectory(timestamps=jnp.asarray(t), poses=poses)

    def as_matrices(self) -> Float[Array, "N 4 4"]:
        """Homogeneous camera-to-world matrices."""
        return self.poses.as_matrix()

    @property
    def positions(self) -> Float[Array, "N 3"]:
        """Camera centres in the world frame."""
        return self.poses.translation()


@struct.dataclass
class PointCloud:
    """A set of 3D points in the world frame, with optional colours and observation counts."""

    xyz: Float[Array, "N 3"]
    """Positions, metres."""
    colors: Float[Array, "N 3"] | None = None
    """RGB in ``[0, 1]`` or ``None``."""
    observations: Int[Array, " N"] | None = None
    """How many keyframes observe each point (SLAM maps) or ``None``."""
    normals: Float[Array, "N 3"] | None = None
    """Unit mean viewing direction of each point (SLAM maps: from the observing cameras to the point,
    ORB-SLAM's map-point normal) or ``None``."""
    descriptors: UInt8[Array, "N D"] | None = None
    """One binary descriptor per point (SLAM maps: the 32-byte ORB descriptor the point was made
    from), what a device matches its keypoints against to localise; or ``None``."""

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


@struct.dataclass
class LineCloud:
    """A set of 3D lines in Plücker coordinates ``(d, m)``.

    ``d`` is the unit direction and ``m = p × d`` the moment for any point ``p`` on the line.
    The representation carries nothing but the line: it cannot tell which point of the line
    it was lifted from (DESIGN §5.4).  Line ``i`` corresponds to the point ``i`` it was lifted
    from, if any.
    """

    directions: Float[Array | np.ndarray, "N 3"]
    """Unit directions ``d`` (float64 numpy arrays for float64 lines while JAX runs in float32)."""
    moments: Float[Array | np.ndarray, "N 3"]
    """Moments ``m = p × d`` (orthogonal to ``d``)."""

    def __len__(self) -> int:
        return int(self.directions.shape[0])

    @property
    def closest_points(self) -> Float[Array, "N 3"]:
        """The point of each line closest to the origin, ``d × m`` (for unit ``d``)."""
        return jnp.cross(self.directions, self.moments)


@struct.dataclass
class Detections:
    """Object detections of one image: boxes in original-image pixels.

    Under ``jit`` detections are padded to a fixed ``max_det``; ``valid`` marks the real rows.
    Use :meth:`compact` on the host to drop padding.
    """

    boxes: Float[Array, "N 4"]
    """``xyxy`` pixel boxes."""
    scores: Float[Array, " N"]
    """Confidences in ``[0, 1]``."""
    class_ids: Int[Array, " N"]
    """COCO class ids (person 0, bicycle 1, car 2, motorcycle 3, bus 5, truck 7, …)."""
    valid: Array | None = None
    """Boolean ``(N,)`` mask of real detections, or ``None`` when every row is real."""

    def __len__(self) -> int:
        if self.valid is None:
            return int(self.boxes.shape[0])
        return int(np.asarray(self.valid).sum())

    def compact(self) -> "Detections":
        """Drop padded rows (host-side; returns numpy-backed detections)."""
        keep = np.ones(self.boxes.shape[0], bool) if self.valid is None else np.asarray(self.valid, bool)
        return Detections(
            boxes=np.asarray(self.boxes)[keep],
            scores=np.asarray(self.scores)[keep],
            class_ids=np.asarray(self.class_ids)[keep],
            valid=None,
        )
