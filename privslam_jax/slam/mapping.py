"""The SLAM map: keyframes, map points with descriptors and observations, triangulation, culling,
and local bundle adjustment over a sliding keyframe window.

Host-side bookkeeping in growable numpy arrays (the map changes size every keyframe, which a
jitted pytree cannot do cheaply); the numerical work — local BA — goes to the jitted JAX solver
in :mod:`privslam_jax.slam.ba` through :func:`solve_local_ba`.

Follows ORB-SLAM3's ``LocalMapping`` (Campos et al. 2021; Mur-Artal & Tardós 2017):

* ``CreateNewMapPoints``: match unmatched keypoints of the new keyframe with its covisible
  neighbours (Hamming ≤ TH_LOW, ratio 0.6–0.8, rotation consistency), keep pairs within the
  epipolar band (``d² < 3.84·σ²``), triangulate (DLT), keep points in front of both cameras with
  reprojection ``χ² < 5.991·σ²`` in both, enough parallax (``cos < 0.9998``) and consistent scale.
* ``SearchInNeighbors`` (simplified): project the new keyframe's points into its neighbours and
  add observations to unmatched keypoints (no point merging).
* ``MapPointCulling``: a point younger than three keyframes is erased when found in fewer than
  25 % of the frames where it was visible, or when two keyframes later it has fewer than
  ``min_obs`` observations.
* ``LocalBundleAdjustment``: the new keyframe and its most covisible neighbours (the window) are
  optimised with all points they see; the other keyframes that see those points are fixed.
  Observations with ``χ² > 5.991·σ²`` after BA are removed.
  ``σ² = scale_factor^(2·octave)`` is the keypoint's pyramid variance.  Keypoints with a depth
  (stereo match, or RGB-D as a virtual stereo pair: ``u_r = u − f_x·b/z``) enter as 3-row stereo
  observations ``(u, v, u_r)`` with the 3-dof thresholds (``χ² > 7.815·σ²``), as ORB-SLAM's
  ``EdgeStereoSE3ProjectXYZ``; that ties the map's scale to the measured depths.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from privslam_jax.geometry.projection import pinhole
from privslam_jax.slam.ba import BAConfig, bundle_adjust
from privslam_jax.slam.frontend import TH_LOW, Features, match_descriptors, search_by_projection
from privslam_jax.types import Camera, PointCloud

__all__ = ["MappingConfig", "KeyFrame", "Map", "triangulate_new_points", "fuse_into_neighbours",
           "cull_points", "local_bundle_adjustment", "global_bundle_adjustment", "adjust_keyframes", "solve_local_ba", "project", "camera_center",
           "stereo_u_right"]

CHI2_MONO = 5.991
"""95 % χ² quantile, 2 DOF."""
CHI2_STEREO = 7.815
"""95 % χ² quantile, 3 DOF."""


@dataclasses.dataclass(frozen=True)
class MappingConfig:
    """Local-mapping settings."""

    n_neighbours: int = 6
    """Covisible keyframes used for triangulation and fusion."""
    window: int = 8
    """Keyframes optimised by local BA (the new one and its most covisible neighbours)."""
    max_fixed: int = 12
    """At most this many fixed keyframes (most covisible first) constrain local BA."""
    ba_iterations: int = 10
    """Levenberg–Marquardt iterations of local BA."""
    tri_ratio: float = 0.75
    """Ratio test for triangulation matches."""
    min_parallax_cos: float = 0.9998
    """Rays must differ by more than ``acos(min_parallax_cos)`` to triangulate (mono)."""
    min_obs: int = 2
    """Culling: observations a point needs two keyframes after its birth (ORB-SLAM: 2 mono, 3 stereo)."""
    found_ratio: float = 0.25
    """Culling: minimum found/visible ratio of young points."""


@dataclasses.dataclass
class KeyFrame:
    """A keyframe: pose, features, the map point of each keypoint (``-1`` if none) and the Atlas map
    it belongs to (ORB-SLAM3's ``KeyFrame::GetMap``; maps share one :class:`Map` store but no points)."""

    id: int
    frame: int
    T_c_w: np.ndarray
    feats: Features
    point_ids: np.ndarray
    map_id: int = 0

    @property
    def center(self) -> np.ndarray:
        return camera_center(self.T_c_w)


def camera_center(T_c_w: np.ndarray) -> np.ndarray:
    """Camera centre in the world frame, ``−Rᵀt``."""
    return -T_c_w[:3, :3].T @ T_c_w[:3, 3]


def project(T_c_w: np.ndarray, xyz: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(M, 2)`` and depths ``(M,)`` of world points in a camera."""
    p = xyz @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    z = p[:, 2]
    safe = np.concatenate([p[:, :2], np.where(np.abs(z) > 1e-9, z, 1e-9)[:, None]], axis=1)
    return pinhole(safe, camera.fx, camera.fy, camera.cx, camera.cy), z


class _Grow:
    """A growable numpy array (capacity doubling)."""

    def __init__(self, shape: tuple[int, ...], dtype, fill=0):
        self.data = np.full((64, *shape), fill, dtype)
        self.n = 0
        self.fill = fill

    def extend(self, values: np.ndarray) -> np.ndarray:
        m = len(values)
        while self.n + m > len(self.data):
            new = np.full((2 * len(self.data), *self.data.shape[1:]), self.fill, self.data.dtype)
            new[: self.n] = self.data[: self.n]
            self.data = new
        self.data[self.n: self.n + m] = values
        self.n += m
        return np.arange(self.n - m, self.n)

    @property
    def v(self) -> np.ndarray:
        return self.data[: self.n]


class Map:
    """Keyframes, map points and their observations (mutable, host side)."""

    def __init__(self, camera: Camera, scale_factor: float = 1.2, n_levels: int = 8):
        self.camera = camera
        self.scale_factor = scale_factor
        self.n_levels = n_levels
        self.keyframes: list[KeyFrame] = []
        self._xyz = _Grow((3,), np.float64)
        self._desc = _Grow((32,), np.uint8)
        self._n_obs = _Grow((), np.int64)
        self._visible = _Grow((), np.int64)
        self._found = _Grow((), np.int64)
        self._first_kf = _Grow((), np.int64)
        self._bad = _Grow((), bool)
        self._max_dist = _Grow((), np.float64)
        self._normal = _Grow((3,), np.float64)
        self._obs_kf = _Grow((), np.int64)
        self._obs_pt = _Grow((), np.int64)
        self._obs_kp = _Grow((), np.int64)
        self._obs_ok = _Grow((), bool)

    # ---- views
    @property
    def xyz(self) -> np.ndarray:
        return self._xyz.v

    @property
    def desc(self) -> np.ndarray:
        return self._desc.v

    @property
    def n_obs(self) -> np.ndarray:
        return self._n_obs.v

    @property
    def bad(self) -> np.ndarray:
        return self._bad.v

    @property
    def visible(self) -> np.ndarray:
        return self._visible.v

    @property
    def found(self) -> np.ndarray:
        return self._found.v

    @property
    def normal(self) -> np.ndarray:
        return self._normal.v

    @property
    def max_dist(self) -> np.ndarray:
        return self._max_dist.v

    @property
    def min_dist(self) -> np.ndarray:
        return self._max_dist.v / self.scale_factor ** (self.n_levels - 1)

    @property
    def n_points(self) -> int:
        return self._xyz.n

    def sigma2(self, octave: np.ndarray) -> np.ndarray:
        return self.scale_factor ** (2.0 * octave)

    def map_ids(self) -> np.ndarray:
        """``(K,)`` Atlas map of every keyframe."""
        return np.array([k.map_id for k in self.keyframes], np.int64)

    def keyframes_of(self, map_id: int) -> np.ndarray:
        """Ids of the keyframes of Atlas map ``map_id``, oldest first (the first one is its origin)."""
        return np.flatnonzero(self.map_ids() == map_id)

    # ---- edits
    def add_keyframe(self, frame: int, T_c_w: np.ndarray, feats: Features, point_ids: np.ndarray,
                     map_id: int = 0) -> KeyFrame:
        """Append a keyframe of Atlas map ``map_id`` and register the observations in ``point_ids`` (``-1`` = none)."""
        kf = KeyFrame(len(self.keyframes), frame, T_c_w.copy(), feats, np.full(len(feats), -1, np.int64), map_id)
        self.keyframes.append(kf)
        kp = np.flatnonzero(point_ids >= 0)
        pid = point_ids[kp]
        ok = ~self.bad[pid]
        # a point can be matched once per keyframe
        _, first = np.unique(pid[ok], return_index=True)
        self.add_observations(kf, pid[ok][first], kp[ok][first])
        return kf

    def add_points(self, xyz: np.ndarray, kf: KeyFrame, kp: np.ndarray) -> np.ndarray:
        """New points first seen in ``kf`` at keypoints ``kp``; returns their ids."""
        ids = self._xyz.extend(xyz)
        self._desc.extend(kf.feats.desc[kp])
        self._n_obs.extend(np.zeros(len(kp), np.int64))
        self._visible.extend(np.ones(len(kp), np.int64))
        self._found.extend(np.ones(len(kp), np.int64))
        self._first_kf.extend(np.full(len(kp), kf.id, np.int64))
        self._bad.extend(np.zeros(len(kp), bool))
        d = xyz - kf.center
        dist = np.linalg.norm(d, axis=1)
        self._max_dist.extend(dist * self.scale_factor ** kf.feats.octave[kp])
        self._normal.extend(d / np.maximum(dist, 1e-12)[:, None])
        self.add_observations(kf, ids, kp)
        return ids

    def add_observations(self, kf: KeyFrame, pid: np.ndarray, kp: np.ndarray) -> None:
        if len(pid) == 0:
            return
        self._obs_kf.extend(np.full(len(pid), kf.id, np.int64))
        self._obs_pt.extend(pid)
        self._obs_kp.extend(kp)
        self._obs_ok.extend(np.ones(len(pid), bool))
        kf.point_ids[kp] = pid
        np.add.at(self._n_obs.data, pid, 1)

    def erase_points(self, pid: np.ndarray) -> None:
        """Mark points bad and drop all their observations."""
        if len(pid) == 0:
            return
        self._bad.data[pid] = True
        rows = np.flatnonzero(self._obs_ok.v & self._bad.data[self._obs_pt.v])
        self._erase_obs_rows(rows)

    def replace_points(self, old: np.ndarray, new: np.ndarray) -> int:
        """Merge each point ``old[k]`` into ``new[k]`` (ORB-SLAM ``MapPoint::Replace``, loop fusion): its
        observations move to ``new[k]`` except in keyframes that see ``new[k]`` already; ``old[k]``
        becomes bad.  Returns the observations moved."""
        moved = 0
        for o, n in zip(np.asarray(old, np.int64), np.asarray(new, np.int64)):
            if o == n or self.bad[o] or self.bad[n]:
                continue
            rows = np.flatnonzero(self._obs_ok.v & (self._obs_pt.v == o))
            seen = set(self._obs_kf.v[self._obs_ok.v & (self._obs_pt.v == n)].tolist())
            keep = np.array([self._obs_kf.v[r] not in seen for r in rows], bool)
            self._erase_obs_rows(rows[~keep])
            for r in rows[keep]:
                self._obs_pt.data[r] = n
                self.keyframes[self._obs_kf.v[r]].point_ids[self._obs_kp.v[r]] = n
            self._n_obs.data[o] -= int(keep.sum())
            self._n_obs.data[n] += int(keep.sum())
            self._visible.data[n] += self.visible[o]
            self._found.data[n] += self.found[o]
            self._bad.data[o] = True
            moved += int(keep.sum())
        return moved

    def erase_observations(self, rows: np.ndarray) -> None:
        """Drop observation rows; points left without observations become bad."""
        self._erase_obs_rows(rows)
        pts = np.unique(self._obs_pt.v[rows])
        weak = pts[(self.n_obs[pts] < 1) & ~self.bad[pts]]
        self._bad.data[weak] = True

    def _erase_obs_rows(self, rows: np.ndarray) -> None:
        rows = rows[self._obs_ok.v[rows]]
        if len(rows) == 0:
            return
        self._obs_ok.data[rows] = False
        kf_ids = self._obs_kf.v[rows]
        kps = self._obs_kp.v[rows]
        for k in np.unique(kf_ids):
            sel = kf_ids == k
            self.keyframes[k].point_ids[kps[sel]] = -1
        np.add.at(self._n_obs.data, self._obs_pt.v[rows], -1)

    def observations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Valid observation rows as ``(kf, point, keypoint)`` arrays plus their row ids."""
        rows = np.flatnonzero(self._obs_ok.v)
        return rows, self._obs_kf.v[rows], self._obs_pt.v[rows]

    def covisible(self, point_ids: np.ndarray, exclude: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """Keyframes observing any of ``point_ids``, most shared points first: ``(ids, counts)``."""
        mask = np.zeros(self.n_points, bool)
        pid = point_ids[point_ids >= 0]
        mask[pid] = True
        sel = self._obs_ok.v & mask[self._obs_pt.v]
        counts = np.bincount(self._obs_kf.v[sel], minlength=len(self.keyframes))
        if 0 <= exclude < len(counts):
            counts[exclude] = 0
        ids = np.flatnonzero(counts)
        order = np.lexsort((-ids, -counts[ids]))  # most shared first, newer first on ties
        return ids[order], counts[ids][order]

    def point_cloud(self) -> PointCloud:
        """The good map points with their observation counts, viewing normals and ORB descriptors."""
        good = ~self.bad & (self.n_obs > 0)
        import jax.numpy as jnp

        return PointCloud(xyz=jnp.asarray(self.xyz[good], jnp.float32),
                          observations=jnp.asarray(self.n_obs[good], jnp.int32),
                          normals=jnp.asarray(self.normal[good], jnp.float32),
                          descriptors=jnp.asarray(self.desc[good]))


# ----------------------------------------------------------------------------------------------
def _fundamental(kf1: KeyFrame, kf2: KeyFrame, K: np.ndarray) -> np.ndarray:
    """``F₁₂`` with ``x₁ᵀ F₁₂ x₂ = 0`` (pixels of kf1 and kf2)."""
    T12 = kf1.T_c_w @ np.linalg.inv(kf2.T_c_w)
    R, t = T12[:3, :3], T12[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K)
    return Ki.T @ tx @ R @ Ki


def _triangulate(T1: np.ndarray, T2: np.ndarray, x1: np.ndarray, x2: np.ndarray, K: np.ndarray) -> np.ndarray:
    P1 = K @ T1[:3]
    P2 = K @ T2[:3]
    X = cv2.triangulatePoints(P1, P2, x1.T.astype(np.float64), x2.T.astype(np.float64))
    w = X[3]
    w = np.where(np.abs(w) > 1e-12, w, 1e-12)
    return (X[:3] / w).T


def triangulate_new_points(m: Map, kf: KeyFrame, neighbours: list[int], cfg: MappingConfig,
                           stereo: bool = False) -> int:
    """ORB-SLAM ``CreateNewMapPoints``: returns the number of points created."""
    cam = m.camera
    K = np.asarray(cam.K, np.float64)
    created = 0
    C1 = kf.center
    f1 = kf.feats
    for nid in neighbours:
        nb = m.keyframes[nid]
        base = np.linalg.norm(nb.center - C1)
        if stereo and cam.baseline is not None:
            if base < cam.baseline:
                continue
        else:
            valid = nb.point_ids[nb.point_ids >= 0]
            valid = valid[~m.bad[valid]]
            if len(valid) == 0:
                continue
            _, z = project(nb.T_c_w, m.xyz[valid], cam)
            if base / max(np.median(z), 1e-9) < 0.01:
                continue
        f2 = nb.feats
        pairs = match_descriptors(f1, f2, ratio=cfg.tri_ratio, max_dist=TH_LOW, check_orientation=True,
                                  mask_a=kf.point_ids < 0, mask_b=nb.point_ids < 0)
        if len(pairs) == 0:
            continue
        i1, i2 = pairs[:, 0], pairs[:, 1]
        x1, x2 = f1.uv[i1], f2.uv[i2]
        s1, s2 = m.sigma2(f1.octave[i1]), m.sigma2(f2.octave[i2])
        F = _fundamental(kf, nb, K)
        l2 = np.c_[x1, np.ones(len(x1))] @ F  # epipolar lines in image 2
        num = (l2 * np.c_[x2, np.ones(len(x2))]).sum(1)
        d2 = num**2 / np.maximum(l2[:, 0] ** 2 + l2[:, 1] ** 2, 1e-12)
        ok = d2 < 3.84 * s2
        i1, i2, x1, x2, s1, s2 = i1[ok], i2[ok], x1[ok], x2[ok], s1[ok], s2[ok]
        if len(i1) == 0:
            continue
        X = _triangulate(kf.T_c_w, nb.T_c_w, x1, x2, K)
        uv1, z1 = project(kf.T_c_w, X, cam)
        uv2, z2 = project(nb.T_c_w, X, cam)
        e1 = ((uv1 - x1) ** 2).sum(1)
        e2 = ((uv2 - x2) ** 2).sum(1)
        r1 = X - C1
        r2 = X - nb.center
        n1, n2 = np.linalg.norm(r1, axis=1), np.linalg.norm(r2, axis=1)
        cosp = (r1 * r2).sum(1) / np.maximum(n1 * n2, 1e-12)
        ratio_dist = n2 / np.maximum(n1, 1e-12)
        ratio_oct = m.scale_factor ** f1.octave[i1] / m.scale_factor ** f2.octave[i2]
        rf = 1.5 * m.scale_factor
        good = (z1 > 0) & (z2 > 0) & (e1 < CHI2_MONO * s1) & (e2 < CHI2_MONO * s2)
        good &= (cosp < cfg.min_parallax_cos) & (cosp > 0)
        good &= (ratio_dist * rf >= ratio_oct) & (ratio_dist <= ratio_oct * rf) & np.isfinite(X).all(1)
        if not good.any():
            continue
        ids = m.add_points(X[good], kf, i1[good])
        m.add_observations(nb, ids, i2[good])
        created += len(ids)
    return created


def fuse_into_neighbours(m: Map, kf: KeyFrame, neighbours: list[int]) -> int:
    """Project ``kf``'s points into neighbours; add observations on free matching keypoints."""
    pid_all = kf.point_ids[kf.point_ids >= 0]
    pid_all = pid_all[~m.bad[pid_all]]
    added = 0
    for nid in neighbours:
        nb = m.keyframes[nid]
        seen = np.zeros(m.n_points, bool)
        seen[nb.point_ids[nb.point_ids >= 0]] = True
        pid = pid_all[~seen[pid_all]]
        if len(pid) == 0:
            continue
        uv, z = project(nb.T_c_w, m.xyz[pid], m.camera)
        cam = m.camera
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        dist = np.linalg.norm(m.xyz[pid] - nb.center, axis=1)
        inside &= (dist >= 0.8 * m.min_dist[pid]) & (dist <= 1.2 * m.max_dist[pid])
        pid, uv, dist = pid[inside], uv[inside], dist[inside]
        if len(pid) == 0:
            continue
        level = np.clip(np.ceil(np.log(m.max_dist[pid] / dist) / np.log(m.scale_factor)), 0, m.n_levels - 1).astype(np.int64)
        radius = 3.0 * m.scale_factor**level
        kp, _ = search_by_projection(uv, m.desc[pid], radius, nb.feats, level - 1, level + 1, max_dist=TH_LOW,
                                     ratio=1.0, available=nb.point_ids < 0)
        ok = kp >= 0
        if ok.any():
            # reprojection gate
            e = ((nb.feats.uv[kp[ok]] - uv[ok]) ** 2).sum(1)
            g = e < CHI2_MONO * m.sigma2(nb.feats.octave[kp[ok]])
            m.add_observations(nb, pid[ok][g], kp[ok][g])
            added += int(g.sum())
    return added


def cull_points(m: Map, kf: KeyFrame, cfg: MappingConfig) -> int:
    """ORB-SLAM ``MapPointCulling`` over points born in the last three keyframes."""
    n = m.n_points
    first = m._first_kf.v
    young = (~m.bad) & (first >= kf.id - 3)
    ratio = m.found / np.maximum(m.visible, 1)
    bad = young & (ratio < cfg.found_ratio)
    bad |= young & (kf.id - first >= 2) & (m.n_obs < cfg.min_obs)
    bad |= (~m.bad) & (m.n_obs <= 0)
    ids = np.flatnonzero(bad[:n])
    m.erase_points(ids)
    return len(ids)


def solve_local_ba(
    T_c_w: np.ndarray, points: np.ndarray, obs_cam: np.ndarray, obs_pt: np.ndarray, obs_uv: np.ndarray,
    obs_sigma2: np.ndarray, fixed: np.ndarray, camera: Camera, iterations: int,
    obs_u_right: np.ndarray | None = None, bucket_growth: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Local BA adapter: ``(K,4,4)`` poses and ``(P,3)`` points in, optimised ones out.

    Huber-robust (δ² = 5.991; stereo rows ``obs_u_right ≥ 0``: 7.815) reprojection error weighted
    by ``1/σ²``.  The problem is padded to size buckets growing by ``bucket_growth``
    (:func:`_pad_ba_problem`).
    """
    n_real_cams, n_real_pts, n_real_obs = len(T_c_w), len(points), len(obs_cam)
    n_obs_in = len(obs_cam)
    T_c_w, points, obs_cam, obs_pt, obs_uv, obs_sigma2, fixed = _pad_ba_problem(
        T_c_w, points, obs_cam, obs_pt, obs_uv, obs_sigma2, fixed, camera, bucket_growth)
    ur = None
    if obs_u_right is not None:
        ur = np.full(len(obs_cam), -1.0, np.float32)
        ur[:n_obs_in] = obs_u_right
    res = bundle_adjust(_se3_from_matrices(T_c_w), points.astype(np.float32), obs_cam, obs_pt,
                        obs_uv.astype(np.float32), None, fixed, camera, BAConfig(max_iterations=iterations),
                        obs_inv_sigma2=(1.0 / obs_sigma2).astype(np.float32), obs_u_right=ur)
    T = _matrices_from_se3(np.asarray(res.T_c_w.wxyz_xyz, np.float64))[:n_real_cams]
    X = np.asarray(res.points, np.float64)[:n_real_pts]
    T_in, X_in = T_c_w[:n_real_cams], points[:n_real_pts]
    if not (np.isfinite(T).all() and np.isfinite(X).all()):
        return T_in, X_in
    T[fixed[:n_real_cams]] = T_in[fixed[:n_real_cams]]
    return T, X


def stereo_u_right(u: np.ndarray, depth: np.ndarray, camera: Camera) -> np.ndarray | None:
    """Right-image ``u_r = u − f_x·b/z`` of keypoints with a depth, ``−1`` elsewhere (ORB-SLAM's
    convention for monocular observations); ``None`` when no keypoint has a depth or the camera
    has no baseline."""
    ok = np.isfinite(depth) & (depth > 0)
    if not ok.any() or not camera.baseline:
        return None
    ur = u - camera.fx * float(camera.baseline) / np.where(ok, depth, 1.0)
    return np.where(ok & (ur >= 0), ur, -1.0)


def _se3_from_matrices(T: np.ndarray) -> "jaxlie.SE3":
    """``jaxlie.SE3`` (float32) from ``(M, 4, 4)`` matrices, converted on the host (no eager JAX ops)."""
    import jaxlie
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    wxyz_xyz = np.concatenate([q[:, 3:], q[:, :3], T[:, :3, 3]], axis=1).astype(np.float32)
    return jaxlie.SE3(wxyz_xyz=wxyz_xyz)


def _matrices_from_se3(wxyz_xyz: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = wxyz_xyz[..., :4]
    T = np.tile(np.eye(4), (len(q), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()
    T[:, :3, 3] = wxyz_xyz[:, 4:]
    return T


def _pow2(n: int, minimum: int = 8, growth: int = 4) -> int:
    """The smallest ``minimum·growth^k ≥ n`` (growth 4: coarse buckets, few compilations, ≤ 4× padding;
    growth 2: twice as many buckets, ≤ 2× padding)."""
    b = minimum
    while b < n:
        b *= growth
    return b


def _pad_ba_problem(T_c_w, points, obs_cam, obs_pt, obs_uv, obs_sigma2, fixed, camera, growth: int = 4):
    """Pad a BA problem with inert parts so that its padded sizes fall on buckets ``minimum·growth^k``.

    The BA solver pads cameras, points, observations and Schur pair-chunks to geometric buckets
    (steps of 1.5×/2×); a sliding-window BA hits many combinations, each a new compilation. Here
    dummy *fixed* cameras at the identity (at least 28, so that their pairs give enough distinct
    Schur segments), dummy points at ``(0, 0, 10)`` and exact (zero-residual) observations of them
    are appended: a dummy point seen by two dummy cameras adds one pair chunk, single observations
    fill the observation count, unobserved dummies the points.  They change nothing in the
    solution (zero residual, no variable shared with the real problem).

    ``growth`` trades compilations for work: a local BA runs at every keyframe, so it pads to buckets
    growing by 2 (a window of 6,600 observations of 2,100 points is solved as 16,384 of each instead
    of 32,768); the global BA runs once per loop closure or map merge, where a compilation costs
    more than the padding, so it keeps buckets growing by 4.
    """
    from privslam_jax.slam.ba import BAConfig as _C
    from privslam_jax.slam.ba import analyze

    chunk = _C().chunk
    m = len(T_c_w)
    n_cams = _pow2(m + 28, 64)
    dummy = np.arange(m, n_cams)
    ia, ib = np.triu_indices(len(dummy), 1)
    seg_a, seg_b = dummy[ia], dummy[ib]  # one Schur chunk per distinct dummy camera pair
    try:
        n_chunks = len(np.asarray(analyze(obs_cam, obs_pt, n_cams, len(obs_cam) + 1, chunk, pad=False).chunk_seg)) - 1
    except Exception:  # noqa: BLE001 - solver internals changed: skip the chunk padding
        n_chunks = None
    extra_pairs = 0
    if n_chunks is not None:
        extra_pairs = _pow2(n_chunks + 2, 512, growth) - 1 - n_chunks
        if extra_pairs > len(seg_a):
            extra_pairs = 0
    cam_a = np.concatenate([seg_a[:extra_pairs]])
    cam_b = np.concatenate([seg_b[:extra_pairs]])
    n_obs_after_pairs = len(obs_cam) + 2 * extra_pairs
    target_obs = _pow2(n_obs_after_pairs + 1, 8192, growth) - 1
    singles = target_obs - n_obs_after_pairs
    n_dummy_pts = extra_pairs + singles
    target_pts = _pow2(len(points) + n_dummy_pts, 8192, growth)
    T = np.concatenate([T_c_w, np.tile(np.eye(4), (n_cams - m, 1, 1))])
    fx = np.concatenate([fixed, np.ones(n_cams - m, bool)])
    X = np.concatenate([points, np.tile([0.0, 0.0, 10.0], (target_pts - len(points), 1))])
    p0 = len(points)
    pair_pts = p0 + np.arange(extra_pairs)
    single_pts = p0 + extra_pairs + np.arange(singles)
    oc = np.concatenate([obs_cam, cam_a, cam_b, np.full(singles, m)])
    op = np.concatenate([obs_pt, pair_pts, pair_pts, single_pts])
    n_new = 2 * extra_pairs + singles
    uv = np.concatenate([obs_uv, np.tile([camera.cx, camera.cy], (n_new, 1))])
    s2 = np.concatenate([obs_sigma2, np.ones(n_new)])
    return T, X, oc.astype(np.int64), op.astype(np.int64), uv, s2, fx


def local_bundle_adjustment(m: Map, kf: KeyFrame, cfg: MappingConfig, n_fixed_min: int = 1) -> dict:
    """Optimise the window around ``kf`` and drop outlier observations. Returns statistics."""
    pid_kf = kf.point_ids[kf.point_ids >= 0]
    cov, _ = m.covisible(pid_kf, exclude=kf.id)
    local = [kf.id] + [int(i) for i in cov[: cfg.window - 1]]
    window = list(local)
    local_set, _, okf, _, sel = _observations_of(m, window)
    fixed_cand = np.bincount(okf[sel & ~local_set[okf]], minlength=len(m.keyframes))
    fixed_ids = np.flatnonzero(fixed_cand)
    fixed_ids = fixed_ids[np.lexsort((-fixed_ids, -fixed_cand[fixed_ids]))][: cfg.max_fixed]
    fixed_list = [int(i) for i in fixed_ids]
    if len(fixed_list) < n_fixed_min:
        # gauge: fix the oldest keyframes of the window
        oldest = sorted(local)[: n_fixed_min - len(fixed_list)]
        local = [i for i in local if i not in oldest]
        fixed_list = fixed_list + oldest
    origin = int(m.keyframes_of(kf.map_id)[0])
    if origin in local:  # the first keyframe anchors its map
        local.remove(origin)
        fixed_list.append(origin)
    if not local:
        return {"ba_points": 0}
    return adjust_keyframes(m, local, fixed_list, cfg.ba_iterations, points_of=window)


def global_bundle_adjustment(m: Map, iterations: int = 10, map_id: int = 0) -> dict:
    """ORB-SLAM's global BA (after a loop closure or a map merge): every keyframe of Atlas map ``map_id``
    and every good point they see, the map's first keyframe fixed."""
    ids = [int(i) for i in m.keyframes_of(map_id)]
    if len(ids) < 2:
        return {"ba_points": 0}
    return adjust_keyframes(m, ids[1:], ids[:1], iterations, bucket_growth=4)


def _observations_of(m: Map, kf_ids: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(in_set (K,), rows, kf, point, sel)``: the valid observation rows, ``sel`` marking those of
    the good points that a keyframe of ``kf_ids`` observes."""
    in_set = np.zeros(len(m.keyframes), bool)
    in_set[kf_ids] = True
    rows, okf, opt = m.observations()
    pts_mask = np.zeros(m.n_points, bool)
    pts_mask[opt[in_set[okf]]] = True
    pts_mask &= ~m.bad
    return in_set, rows, okf, opt, pts_mask[opt]


def adjust_keyframes(m: Map, local: list[int], fixed_list: list[int], iterations: int,
                     points_of: list[int] | None = None, bucket_growth: int = 2) -> dict:
    """Bundle-adjust the keyframes ``local`` and every good point that a keyframe of ``points_of``
    (default ``local``) observes, with the keyframes ``fixed_list`` held constant (their observations of
    those points count too); then drop the observations with ``χ²`` above the 95 % threshold.
    ``bucket_growth``: see :func:`_pad_ba_problem`.  Returns statistics."""
    cams = list(local) + list(fixed_list)
    _, rows, okf, opt, sel = _observations_of(m, local if points_of is None else points_of)
    cam_index = np.full(len(m.keyframes), -1, np.int64)
    cam_index[cams] = np.arange(len(cams))
    sel &= cam_index[okf] >= 0
    rows, okf, opt = rows[sel], okf[sel], opt[sel]
    pids = np.unique(opt)
    pt_index = np.full(m.n_points, -1, np.int64)
    pt_index[pids] = np.arange(len(pids))
    okp = m._obs_kp.v[rows]
    uv = np.empty((len(rows), 2))
    oct_ = np.empty(len(rows), np.int64)
    depth = np.full(len(rows), np.nan)
    for k in np.unique(okf):
        s = okf == k
        f = m.keyframes[k].feats
        uv[s] = f.uv[okp[s]]
        oct_[s] = f.octave[okp[s]]
        if f.depth is not None:
            depth[s] = f.depth[okp[s]]
    s2 = m.sigma2(oct_)
    ur = stereo_u_right(uv[:, 0], depth, m.camera)
    poses = np.stack([m.keyframes[c].T_c_w for c in cams])
    fixed = np.zeros(len(cams), bool)
    fixed[len(local):] = True
    new_poses, new_pts = solve_local_ba(poses, m.xyz[pids], cam_index[okf], pt_index[opt], uv, s2, fixed,
                                        m.camera, iterations, obs_u_right=ur, bucket_growth=bucket_growth)
    for i, c in enumerate(local):
        m.keyframes[c].T_c_w = new_poses[i]
    good_pts = np.isfinite(new_pts).all(1)
    m._xyz.data[pids[good_pts]] = new_pts[good_pts]
    # outlier observations
    proj = np.empty((len(rows), 2))
    z = np.empty(len(rows))
    for k in np.unique(okf):
        s = okf == k
        proj[s], z[s] = project(m.keyframes[k].T_c_w, m.xyz[opt[s]], m.camera)
    err = ((proj - uv) ** 2).sum(1) / s2
    chi2 = np.full(len(rows), CHI2_MONO)
    if ur is not None:
        st = ur >= 0
        bf = m.camera.fx * float(m.camera.baseline)
        err_r = (proj[:, 0] - bf / np.where(z > 0, z, 1.0) - ur) ** 2 / s2
        err = np.where(st, err + err_r, err)
        chi2 = np.where(st, CHI2_STEREO, CHI2_MONO)
    out = (err > chi2) | (z <= 0)
    m.erase_observations(rows[out])
    # refresh viewing normals of the optimised points
    return {"ba_points": int(len(pids)), "ba_keyframes": len(local), "ba_fixed": len(fixed_list),
            "ba_outliers": int(out.sum())}
