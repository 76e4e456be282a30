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
import numpy as np

from privslam_jax.slam.frontend import TH_HIGH, TH_LOW, Features, match_descriptors, search_by_projection
from privslam_jax.slam.mapping import CHI2_MONO, Map, camera_center, project
from privslam_jax.types import Camera

__all__ = ["TrackingConfig", "Frame", "refine_pose", "pnp_ransac", "track_motion_model", "track_local_map",
           "track_keyframe_pnp", "relocalise"]


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
    min_inliers: int = 30
    """Inliers needed to call a frame tracked."""
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
def _se3_exp(xi: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    R, _ = cv2.Rodrigues(xi[:3].reshape(3, 1))
    T[:3, :3] = R
    T[:3, 3] = xi[3:]
    return T


def _refine_backend(T_c_w: np.ndarray, xyz: np.ndarray, uv: np.ndarray, w: np.ndarray, valid: np.ndarray,
                    camera: Camera, huber: bool, iterations: int = 10) -> np.ndarray:
    """One Huber-LM pose refinement on the valid correspondences (weights ``w = 1/σ``)."""
    # numpy Gauss-Newton with IRLS Huber weights (stand-in until refine.py is available)
    T = T_c_w.copy()
    idx = np.flatnonzero(valid)
    if len(idx) < 4:
        return T
    X, x, ww = xyz[idx], uv[idx], w[idx]
    delta = np.sqrt(CHI2_MONO)
    lam = 1e-3
    cost_prev = None
    for _ in range(iterations):
        p = X @ T[:3, :3].T + T[:3, 3]
        z = np.maximum(p[:, 2], 1e-6)
        r = np.stack([camera.fx * p[:, 0] / z + camera.cx - x[:, 0], camera.fy * p[:, 1] / z + camera.cy - x[:, 1]], 1)
        r = r * ww[:, None]
        e = np.sqrt((r**2).sum(1))
        hw = np.where(e <= delta, 1.0, delta / np.maximum(e, 1e-12)) if huber else np.ones_like(e)
        cost = float((np.where(e <= delta, 0.5 * e**2, delta * e - 0.5 * delta**2) if huber else 0.5 * e**2).sum())
        if cost_prev is not None and cost > cost_prev:
            T = T_prev
            lam *= 10
        else:
            lam = max(lam / 10, 1e-7)
            cost_prev, T_prev = cost, T.copy()
        p = X @ T[:3, :3].T + T[:3, 3]
        z = np.maximum(p[:, 2], 1e-6)
        r = np.stack([camera.fx * p[:, 0] / z + camera.cx - x[:, 0], camera.fy * p[:, 1] / z + camera.cy - x[:, 1]], 1)
        r = r * ww[:, None]
        e = np.sqrt((r**2).sum(1))
        hw = np.where(e <= delta, 1.0, delta / np.maximum(e, 1e-12)) if huber else np.ones_like(e)
        iz = 1.0 / z
        J = np.zeros((len(idx), 2, 6))
        # left perturbation T ← exp(ξ) T, ξ = (ω, v): dp = −[p]× ω + v
        fx, fy = camera.fx, camera.fy
        J_p = np.zeros((len(idx), 2, 3))
        J_p[:, 0, 0] = fx * iz
        J_p[:, 0, 2] = -fx * p[:, 0] * iz**2
        J_p[:, 1, 1] = fy * iz
        J_p[:, 1, 2] = -fy * p[:, 1] * iz**2
        px = np.zeros((len(idx), 3, 3))
        px[:, 0, 1], px[:, 0, 2], px[:, 1, 0] = -p[:, 2], p[:, 1], p[:, 2]
        px[:, 1, 2], px[:, 2, 0], px[:, 2, 1] = -p[:, 0], -p[:, 1], p[:, 0]
        J[:, :, :3] = -J_p @ px
        J[:, :, 3:] = J_p
        J = J * ww[:, None, None]
        Jw = J * hw[:, None, None]
        H = np.einsum("nai,naj->ij", Jw, J)
        g = np.einsum("nai,na->i", Jw, r)
        H = H + lam * np.diag(np.diag(H) + 1e-9)
        xi = -np.linalg.solve(H, g)
        T = _se3_exp(xi) @ T
        if np.linalg.norm(xi) < 1e-10:
            break
    return T


def refine_pose(T_c_w: np.ndarray, xyz: np.ndarray, uv: np.ndarray, octave: np.ndarray, camera: Camera,
                scale_factor: float = 1.2, rounds: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM ``PoseOptimization``: returns the refined ``T_c_w`` and the inlier mask."""
    n = len(xyz)
    inl = np.ones(n, bool)
    if n < 4:
        return T_c_w, np.zeros(n, bool)
    s2 = scale_factor ** (2.0 * octave)
    w = 1.0 / np.sqrt(s2)
    T = T_c_w
    for it in range(rounds):
        T = _refine_backend(T, xyz, uv, w, inl, camera, huber=it < 2)
        p_uv, z = project(T, xyz, camera)
        chi2 = ((p_uv - uv) ** 2).sum(1) / s2
        inl = (chi2 < CHI2_MONO) & (z > 0)
        if inl.sum() < 10:
            break
    return T, inl


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
    T, inl = refine_pose(T0, m.xyz[pid], frame.feats.uv[idx], frame.feats.octave[idx], m.camera, m.scale_factor)
    frame.T_c_w = T
    frame.point_ids[idx[~inl]] = -1
    return int(inl.sum())


def track_motion_model(frame: Frame, last: Frame, T_pred: np.ndarray, m: Map, radius: float,
                       cfg: TrackingConfig) -> int:
    """Search the last frame's points around their predicted projections, then refine."""
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
    frame.point_ids[kp[ok]] = pid[ok]
    if ok.sum() < cfg.min_motion_matches:
        return int(ok.sum())
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


def track_local_map(frame: Frame, m: Map, cfg: TrackingConfig, radius_scale: float = 1.0) -> int:
    """Project the local map at ``frame.T_c_w``, search, refine. Returns inliers."""
    cur = frame.point_ids[frame.point_ids >= 0]
    kf_ids, _ = m.covisible(cur)
    kf_ids = kf_ids[: cfg.max_local_keyframes]
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


def relocalise(frame: Frame, m: Map, seed: int, cfg: TrackingConfig) -> int:
    """PnP against candidate keyframes (most recent first), then the local map. Returns inliers."""
    n_kf = len(m.keyframes)
    cands = list(range(n_kf - 1, max(-1, n_kf - 1 - cfg.reloc_candidates), -1))
    for k in cands:
        n = track_keyframe_pnp(frame, [k], m, seed, cfg)
        if n < 10:
            continue
        n = track_local_map(frame, m, cfg, radius_scale=2.0)
        if n >= cfg.reloc_min_inliers:
            return n
    frame.point_ids[:] = -1
    return 0
