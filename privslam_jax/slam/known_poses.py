"""A map from images with known poses: ORB features matched between frames and triangulated.

Structure from known motion, for building a map that localisation can be tested against (e.g. the
ground-truth poses of a KITTI sequence): every frame's grid-distributed ORB features
(:func:`~privslam_jax.slam.frontend.extract_orb`) are matched to those of the frames ``gaps`` later in
the list (:func:`~privslam_jax.slam.frontend.match_descriptors`: ratio test, orientation check),
triangulated linearly (``cv2.triangulatePoints``, DLT), and kept if they lie ``depth_range`` in front
of both cameras, reproject within ``max_reprojection`` pixels in both, and are seen under a parallax of at
least ``min_parallax_deg``.  Points closer than ``voxel`` metres to an earlier one (same voxel) are
dropped, so a surface point seen in several pairs is kept once.  Each point carries the descriptor of
the earlier frame's keypoint and its viewing direction from that frame (``PointCloud.normals``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from privslam_jax.slam.frontend import OrbConfig, extract_orb, match_descriptors, to_gray_u8
from privslam_jax.types import PointCloud

__all__ = ["KnownPoseMapConfig", "map_from_known_poses"]


@dataclasses.dataclass(frozen=True)
class KnownPoseMapConfig:
    """Settings of :func:`map_from_known_poses`."""

    n_features: int = 10000
    """ORB features per image."""
    gaps: tuple[int, ...] = (1, 2, 3)
    """Image ``k`` is matched to images ``k + g`` (list positions)."""
    max_reprojection: float = 1.5
    """Pixels, in both images."""
    min_parallax_deg: float = 1.0
    """Angle between the two viewing rays, degrees."""
    depth_range: tuple[float, float] = (1.0, 80.0)
    """Metres in front of both cameras."""
    voxel: float = 0.05
    """One point per voxel of this size, metres."""


def map_from_known_poses(images: Sequence[np.ndarray], T_w_c: Float[np.ndarray, "N 4 4"], K: Float[np.ndarray, "3 3"],
                         config: KnownPoseMapConfig = KnownPoseMapConfig()) -> PointCloud:
    """Triangulate a map with descriptors and viewing directions from ``images`` taken at poses ``T_w_c``
    (camera → world) with intrinsics ``K`` (module docstring).  ``ValueError`` for mismatched inputs or a
    map without points."""
    T_w_c = np.asarray(T_w_c, np.float64)
    K = np.asarray(K, np.float64)
    if T_w_c.shape != (len(images), 4, 4) or K.shape != (3, 3) or not np.all(np.isfinite(T_w_c)):
        raise ValueError(f"need one finite 4x4 pose per image and a 3x3 K; got {len(images)} images, poses "
                         f"{T_w_c.shape}, K {K.shape}")
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be finite with positive focal lengths, got {K.tolist()}")
    T_c_w = np.linalg.inv(T_w_c)
    feats = [extract_orb(to_gray_u8(im), OrbConfig(n_features=config.n_features)) for im in images]
    near, far = config.depth_range
    pts, descs, views = [], [], []
    for i in range(len(images)):
        for j in (i + g for g in config.gaps if i + g < len(images)):
            pairs = match_descriptors(feats[i], feats[j], ratio=0.8)
            if len(pairs) == 0:
                continue
            uv = (feats[i].uv[pairs[:, 0]], feats[j].uv[pairs[:, 1]])
            P = (K @ T_c_w[i][:3], K @ T_c_w[j][:3])
            X = cv2.triangulatePoints(P[0], P[1], uv[0].T.copy(), uv[1].T.copy())
            with np.errstate(divide="ignore", invalid="ignore"):
                X = (X[:3] / X[3]).T
            ok = np.all(np.isfinite(X), axis=1)
            X = np.where(ok[:, None], X, 0.0)
            rays = []
            for k, c in enumerate((i, j)):
                z = X @ T_c_w[c][2, :3] + T_c_w[c][2, 3]
                proj = np.c_[X, np.ones(len(X))] @ P[k].T
                with np.errstate(divide="ignore", invalid="ignore"):
                    err = np.linalg.norm(proj[:, :2] / proj[:, 2:] - uv[k], axis=1)
                ok &= (z > near) & (z < far) & (err <= config.max_reprojection)
                rays.append(X - T_w_c[c][:3, 3])
            cos = np.sum(rays[0] * rays[1], 1) / np.maximum(np.linalg.norm(rays[0], axis=1) * np.linalg.norm(rays[1], axis=1), 1e-12)
            ok &= cos <= np.cos(np.deg2rad(config.min_parallax_deg))
            pts.append(X[ok])
            descs.append(feats[i].desc[pairs[ok, 0]])
            views.append(rays[0][ok] / np.linalg.norm(rays[0][ok], axis=1, keepdims=True))
    if not pts or sum(len(p) for p in pts) == 0:
        raise ValueError("no point passed the triangulation checks (too few images, too little parallax, or wrong poses)")
    p, d, v = np.concatenate(pts), np.concatenate(descs), np.concatenate(views)
    _, keep = np.unique(np.floor(p / config.voxel).astype(np.int64), axis=0, return_index=True)
    keep = np.sort(keep)
    return PointCloud(xyz=jnp.asarray(p[keep]), normals=jnp.asarray(v[keep]), descriptors=jnp.asarray(d[keep]))
