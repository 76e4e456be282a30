"""Tracking: motion-model prediction, projection search, PnP-RANSAC fallback, pose-only refinement,
relocalisation (ORB-SLAM3 ``Tracking.cc``; Mur-Artal & Tardós 2017).

* ``track_motion_model``: ``T_pred = V·T_last`` with the constant velocity ``V = T_last·T_prev⁻¹``;
  the last frame's matched points are projected and searched within ``r·scale^octave`` pixels
  (r = 15 mono, 7 stereo/RGB-D; doubled once when fewer than 20 matches).
* ``track_local_map``: points of the covisible keyframes, inside the frustum, at a valid
  scale-invariance distance and viewing angle (cos > 0.5), are projected at the refined pose and
  searched with the radius ``r_local·scale^level`` at their predicted level ``level =
  ⌈log(d_max/d)/log s⌉``; the pose is refined again on all matches.
* ``pnp_ransac``: descriptor matching against a keyframe's map points, ``cv2.solvePnPRansac``
  (EPnP minimal sets); the correspondence order is shuffled by a seeded generator, which is the
  run's only randomness (OpenCV's RANSAC itself uses a fixed internal seed).
* ``refine_pose``: four rounds of Huber-robust pose-only Levenberg–Marquardt, re-classifying
  inliers by ``χ² = ‖r‖²/σ² < 5.991`` after each (ORB-SLAM ``PoseOptimization``), on the jitted JAX
  solver :func:`privslam_jax.slam.refine.refine_pose`.
"""

from __future__ import annotations

import dataclasses

import cv2
import jaxlie
import numpy as np

from privslam_jax.slam.frontend import TH_HIGH, TH_LOW, Features, match_descriptors, search_by_projection
from privslam_jax.slam.mapping import (
    Map,
    _matrices_from_se3,
    _se3_from_matrices,
    camera_center,
    project,
    stereo_u_right,
)
from privslam_jax.slam.refine import RefineConfig
from privslam_jax.slam.refine import refine_pose as _jax_refine_pose
from privslam_jax.types import Camera

__all__ = ["TrackingConfig", "Frame", "refine_pose", "pnp_ransac", "track_motion_model", "track_local_map",
           "track_keyframe_pnp", "relocalise", "relocalise_along_motion", "motion_deviation"]


@dataclasses.dataclass(frozen=True)
class TrackingConfig:
    """Tracking settings (ORB-SLAM3 defaults where they exist)."""

    motion_radius_mono: float = 15.0
    """Search radius (level-0 px, × scale^octave) around motion-model projections, monocular."""
    motion_radius_depth: float = 7.0
    """The same for stereo/RGB-D."""
    local_radius: float = 4.0
    """Search radius (× scale^level) for local-map points."""
    min_motion_matches: int = 20
    """Below this many motion-model matches the PnP fallback runs."""
    min_inliers: int = 20
    """Inliers needed to call a frame tracked (ORB-SLAM3: 30; 20 lets tracking resume after a fault
    where the map ahead is thin — the refined inliers pass a χ² test, and a frame relocalised along
    the motion model agrees with the prediction too; experiments/robustness.py)."""
    reloc_min_inliers: int = 50
    """Inliers needed to accept a relocalisation."""
    max_local_keyframes: int = 20
    """Covisible keyframes whose points form the local map."""
    pnp_threshold: float = 4.0
    """RANSAC reprojection threshold in pixels."""
    pnp_iterations: int = 200
    """RANSAC iterations."""
    reloc_candidates: int = 12
    """Keyframes tried by relocalisation (most recent first)."""
    reloc_motion_steps: int = 12
    """Relocalisation along the motion model: after a loss, the camera is assumed to have kept its
    velocity for 1…this many frames beyond the frames seen since (covering dropped frames too)."""
    reloc_motion_radius: float = 4.0
    """Search-radius multiplier of the local-map search around those predicted poses."""


@dataclasses.dataclass
class Frame:
    """One frame being tracked."""

    index: int
    feats: Features
    T_c_w: np.ndarray | None = None
    point_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.point_ids is None:
            self.point_ids = np.full(len(self.feats), -1, np.int64)

    @property
    def n_matches(self) -> int:
        return int((self.point_ids >= 0).sum())


# ---------------------------------------------------------------------------------------------
_REFINE_CONFIG = RefineConfig()
_REFINE_BUCKETS = (512, 2048, 8192)
"""Few, coarse padding sizes: one or two compilations per run (a 2,048-row solve costs a few ms)."""


def refine_pose(T_c_w: np.ndarray, xyz: np.ndarray, uv: np.ndarray, octave: np.ndarray, camera: Camera,
                scale_factor: float = 1.2, u_right: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM ``PoseOptimization`` on the jitted JAX solver: refined ``T_c_w`` and inlier mask.

    ``u_right`` (``< 0`` = monocular) adds ORB-SLAM's stereo residual; ``camera.baseline`` must be set.
    """
    n = len(xyz)
    if n < 4:
        return T_c_w, np.zeros(n, bool)
    inv_s2 = scale_factor ** (-2.0 * octave)
    T0 = jaxlie.SE3(_se3_from_matrices(T_c_w[None]).wxyz_xyz[0])
    res = _jax_refine_pose(T0, xyz.astype(np.float32), uv.astype(np.float32), None, camera, _REFINE_CONFIG,
                           u_right=None if u_right is None else u_right.astype(np.float32),
                           inv_sigma2=inv_s2.astype(np.float32), buckets=_REFINE_BUCKETS)
    T = _matrices_from_se3(np.asarray(res.T_c_w.wxyz_xyz, np.float64)[None])[0]
    if not np.isfinite(T).all():
        return T_c_w, np.zeros(n, bool)
    return T, np.asarray(res.inliers, bool)


def pnp_ransac(xyz: np.ndarray, uv: np.ndarray, camera: Camera, seed: int, cfg: TrackingConfig
               ) -> tuple[bool, np.ndarray, np.ndarray]:
    """``cv2.solvePnPRansac`` on shuffled correspondences: ``(ok, T_c_w, inlier mask)``."""
    n = len(xyz)
    if n < 6:
        return False, np.eye(4), np.zeros(n, bool)
    perm = np.random.default_rng(seed).permutation(n)
    K = np.asarray(camera.K, np.float64)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        xyz[perm].astype(np.float64), uv[perm].astype(np.float64), K, None,
        iterationsCount=cfg.pnp_iterations, reprojectionError=cfg.pnp_threshold, confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    mask = np.zeros(n, bool)
    if not ok or inl is None:
        return False, np.eye(4), mask
    mask[perm[inl.ravel()]] = True
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return True, T, mask


# ---------------------------------------------------------------------------------------------
def _optimise_frame(frame: Frame, m: Map, T0: np.ndarray) -> int:
    """Refine ``frame`` on its matches, drop outliers; returns the inlier count."""
    idx = np.flatnonzero(frame.point_ids >= 0)
    if len(idx) < 4:
        frame.T_c_w = T0
        return 0
    pid = frame.point_ids[idx]
    ur = None
    cam = m.camera
    if frame.feats.depth is not None:
        ur = stereo_u_right(frame.feats.uv[idx, 0], frame.feats.depth[idx], cam)
    T, inl = refine_pose(T0, m.xyz[pid], frame.feats.uv[idx], frame.feats.octave[idx], cam, m.scale_factor, ur)
    frame.T_c_w = T
    frame.point_ids[idx[~inl]] = -1
    return int(inl.sum())


def track_motion_model(frame: Frame, last: Frame, T_pred: np.ndarray, m: Map, radius: float,
                       cfg: TrackingConfig) -> int:
    """Search the last frame's points around their predicted projections, then refine.

    Returns the inliers of the refined pose, or 0 — with no pose set and no matches kept — when
    fewer than ``cfg.min_motion_matches`` points were found (10-19 matches without a pose once sent
    a lost frame to the local-map search with ``T_c_w = None``).
    """
    idx = np.flatnonzero(last.point_ids >= 0)
    pid = last.point_ids[idx]
    good = ~m.bad[pid]
    idx, pid = idx[good], pid[good]
    uv, z = project(T_pred, m.xyz[pid], m.camera)
    front = z > 0
    idx, pid, uv = idx[front], pid[front], uv[front]
    octv = last.feats.octave[idx]
    for scale in (1.0, 2.0):
        r = radius * scale * m.scale_factor**octv
        kp, _ = search_by_projection(uv, m.desc[pid], r, frame.feats, octv - 1, octv + 1, max_dist=TH_HIGH, ratio=0.9)
        if (kp >= 0).sum() >= cfg.min_motion_matches:
            break
    frame.point_ids[:] = -1
    ok = kp >= 0
    if ok.sum() < cfg.min_motion_matches:  # no pose was estimated: report no inliers, keep no matches
        return 0
    frame.point_ids[kp[ok]] = pid[ok]
    return _optimise_frame(frame, m, T_pred)


def track_keyframe_pnp(frame: Frame, kf_ids: list[int], m: Map, seed: int, cfg: TrackingConfig,
                       T_prior: np.ndarray | None = None) -> int:
    """PnP-RANSAC against the map points of keyframes ``kf_ids``, then refine. Returns inliers."""
    best = 0
    for k in kf_ids:
        kf = m.keyframes[k]
        has = kf.point_ids >= 0
        has[has] &= ~m.bad[kf.point_ids[has]]
        if has.sum() < 15:
            continue
        pairs = match_descriptors(frame.feats, kf.feats, ratio=0.75, max_dist=TH_LOW + 20, check_orientation=True,
                                  mask_b=has)
        if len(pairs) < 15:
            continue
        pid = kf.point_ids[pairs[:, 1]]
        ok, T, inl = pnp_ransac(m.xyz[pid], frame.feats.uv[pairs[:, 0]], m.camera, seed + k, cfg)
        if not ok or inl.sum() < 10:
            continue
        frame.point_ids[:] = -1
        frame.point_ids[pairs[inl, 0]] = pid[inl]
        n = _optimise_frame(frame, m, T)
        if n >= 10:
            return n
        best = max(best, n)
    frame.point_ids[:] = -1
    return 0


def track_local_map(frame: Frame, m: Map, cfg: TrackingConfig, radius_scale: float = 1.0,
                    kf_ids: np.ndarray | None = None) -> int:
    """Project the local map at ``frame.T_c_w``, search, refine. Returns inliers.

    The local map is the points of the keyframes covisible with the frame's matches, or of
    ``kf_ids`` when given (a frame without matches yet).
    """
    cur = frame.point_ids[frame.point_ids >= 0]
    if kf_ids is None:
        kf_ids, _ = m.covisible(cur)
    kf_ids = np.asarray(kf_ids, np.int64)[: cfg.max_local_keyframes]
    if len(kf_ids) == 0:
        return _optimise_frame(frame, m, frame.T_c_w)
    pts = np.concatenate([m.keyframes[k].point_ids for k in kf_ids])
    pts = np.unique(pts[pts >= 0])
    mine = np.zeros(m.n_points, bool)
    mine[cur] = True
    pts = pts[~m.bad[pts] & ~mine[pts]]
    cam = m.camera
    uv, z = project(frame.T_c_w, m.xyz[pts], cam)
    C = camera_center(frame.T_c_w)
    d = m.xyz[pts] - C
    dist = np.linalg.norm(d, axis=1)
    cosv = (d * m.normal[pts]).sum(1) / np.maximum(dist, 1e-12)
    vis = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    vis &= (dist >= 0.8 * m.min_dist[pts]) & (dist <= 1.2 * m.max_dist[pts]) & (cosv > 0.5)
    pts, uv, dist, cosv = pts[vis], uv[vis], dist[vis], cosv[vis]
    m._visible.data[pts] += 1
    m._visible.data[cur] += 1
    if len(pts):
        level = np.clip(np.ceil(np.log(m.max_dist[pts] / dist) / np.log(m.scale_factor)), 0, m.n_levels - 1)
        level = level.astype(np.int64)
        r = np.where(cosv > 0.998, 0.625, 1.0) * cfg.local_radius * radius_scale * m.scale_factor**level
        kp, _ = search_by_projection(uv, m.desc[pts], r, frame.feats, level - 1, level, max_dist=TH_HIGH,
                                     ratio=0.8, available=frame.point_ids < 0)
        ok = kp >= 0
        frame.point_ids[kp[ok]] = pts[ok]
    n = _optimise_frame(frame, m, frame.T_c_w)
    inl = frame.point_ids[frame.point_ids >= 0]
    m._found.data[inl] += 1
    return n


def relocalise_along_motion(frame: Frame, m: Map, T_last: np.ndarray, velocity: np.ndarray, gap: int,
                            cfg: TrackingConfig, keyframes: np.ndarray | None = None) -> int:
    """Relocalise a frame after a short loss by searching the recent keyframes' points around the
    poses the constant-velocity model predicts ``gap + j`` frames after ``T_last``, j = 0…
    ``reloc_motion_steps − 1`` (``gap`` frames were seen since; the extra steps cover frames that
    never arrived), with ``reloc_motion_radius`` × the local-map radius; keeps the pose with the most
    refined inliers.  Appearance-based :func:`relocalise` needs descriptor matches that survive a
    ratio test against a whole keyframe, which fail after a few metres of forward motion; the
    prediction narrows the search instead.  ``keyframes``: the ids to search (ascending; default all,
    i.e. the active Atlas map's).  Returns the inliers (0: no pose set, no matches kept).
    """
    ids = np.arange(len(m.keyframes)) if keyframes is None else np.asarray(keyframes, np.int64)
    recent = ids[::-1][: cfg.max_local_keyframes]
    best: tuple[int, np.ndarray | None, np.ndarray | None] = (0, None, None)
    for j in range(cfg.reloc_motion_steps):
        frame.T_c_w = np.linalg.matrix_power(velocity, gap + j) @ T_last
        frame.point_ids[:] = -1
        n = track_local_map(frame, m, cfg, radius_scale=cfg.reloc_motion_radius, kf_ids=recent)
        if n > best[0]:
            best = (n, frame.T_c_w, frame.point_ids.copy())
    frame.T_c_w, frame.point_ids = best[1], best[2] if best[2] is not None else np.full(len(frame.feats), -1)
    return best[0]


def motion_deviation(T_c_w: np.ndarray, T_last: np.ndarray, velocity: np.ndarray, gap: int,
                     steps: int) -> tuple[float, float]:
    """How far a pose ``T_c_w`` is from the constant-velocity prediction after a loss.

    The prediction ``j`` frames on is ``velocity^j · T_last`` (all ``(4, 4)`` world-to-camera).
    Returns the distance from ``T_c_w``'s camera centre to the nearest predicted centre for
    ``j = gap … gap + max(steps, 1) − 1`` (frames that never arrived, as in :func:`relocalise_along_motion`)
    over the distance the prediction travels in ``gap`` frames — scale-free, so a monocular map needs
    no metric scale — and the rotation from the prediction ``gap`` frames on, in degrees.
    """
    T_pred = np.linalg.matrix_power(velocity, gap) @ T_last
    travel = float(np.linalg.norm(camera_center(T_pred) - camera_center(T_last)))
    c, T_j, dev = camera_center(T_c_w), T_pred, np.inf
    for _ in range(max(steps, 1)):
        dev = min(dev, float(np.linalg.norm(c - camera_center(T_j))))
        T_j = velocity @ T_j
    cos = (np.trace(T_c_w[:3, :3] @ T_pred[:3, :3].T) - 1.0) / 2.0
    return dev / max(travel, 1e-12), float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def relocalise(frame: Frame, m: Map, seed: int, cfg: TrackingConfig, keyframes: np.ndarray | None = None) -> int:
    """PnP against candidate keyframes (most recent first; of ``keyframes``, ascending ids, when given),
    then the local map. Returns inliers."""
    ids = np.arange(len(m.keyframes)) if keyframes is None else np.asarray(keyframes, np.int64)
    for k in ids[::-1][: cfg.reloc_candidates].tolist():
        n = track_keyframe_pnp(frame, [k], m, seed, cfg)
        if n < 10:
            continue
        n = track_local_map(frame, m, cfg, radius_scale=2.0)
        if n >= cfg.reloc_min_inliers:
            return n
    frame.point_ids[:] = -1
    return 0
