r"""Loop closing as ORB-SLAM does it: place recognition, Sim(3) verification, correction, essential graph, global BA.

Follows ORB-SLAM2's ``LoopClosing`` (Mur-Artal & Tardós, T-RO 2017, §VI; ORB-SLAM3 keeps it for a
single map), run synchronously after local mapping for every new keyframe :math:`K_q`:

1. **Candidates** (``DetectLoop``): the bag-of-words vector of :math:`K_q`
   (:mod:`~privslam_jax.slam.vocabulary`) is scored against every keyframe at least ``min_gap``
   keyframes older that shares no map point with it; candidates score at least the lowest score of
   :math:`K_q`'s covisible keyframes (and ``min_score``).  Each candidate with its covisible
   keyframes forms a group; a group is *consistent* when it overlaps a group of the previous
   keyframe's candidates, and a candidate is verified only after ``consistency`` consecutive
   keyframes (ORB-SLAM: 3).
2. **Sim(3) verification** (``ComputeSim3``): descriptor matches between the map points of
   :math:`K_q` and of the candidate :math:`K_l` give 3-D/3-D pairs in the two cameras; RANSAC over
   minimal sets of three (Umeyama; scale only in monocular mode, SE(3) with a metric map) keeps the
   transform :math:`S_{ql}` under which most pairs reproject within :math:`\chi^2_{0.95}(2)\,\sigma^2`
   in *both* images; then the map points of :math:`K_l` and its covisible keyframes are projected into
   :math:`K_q` at :math:`S_{ql} T_{lw}` and searched (``SearchByProjection``); at least
   ``min_projection_matches`` accept the loop.
3. **Correction** (``CorrectLoop``): :math:`K_q` and its covisible keyframes :math:`K_i` get
   :math:`S_{iw}^{corr} = T_{iq} S_{ql} T_{lw}`; the points they see move with them
   (:math:`X \leftarrow (S_{iw}^{corr})^{-1} T_{iw} X`); the matched loop points replace
   :math:`K_q`'s duplicates (``MapPoint::Replace``).
4. **Essential graph** (``OptimizeEssentialGraph``): every keyframe a node, edges between consecutive
   keyframes (the spanning tree), between keyframes sharing ≥ ``covisibility_edge`` points, and the
   loop edges :math:`(K_i, K_l)`; measured by the poses before the correction except the loop edges;
   solved by :func:`~privslam_jax.slam.pose_graph.optimize_pose_graph` (Sim(3) monocular, SE(3)
   otherwise) with the first keyframe and :math:`K_l` fixed; every point then follows its first
   keyframe, and a keyframe's Sim(3) becomes the rigid pose :math:`[R \mid t/s]`.
5. **Global BA** over all keyframes and points (the first keyframe fixed).

**Atlas map merging** (ORB-SLAM3's ``MergeLocal``, simplified): keyframes belong to Atlas maps
(:attr:`~privslam_jax.slam.mapping.KeyFrame.map_id`); a new map starts when tracking stays lost
(:class:`~privslam_jax.slam.system.SlamConfig`).  Keyframes of *other* maps are candidates of every
new keyframe too, detected and verified as above (without the drift gate: the two maps' frames are
unrelated).  An accepted candidate merges the query's map :math:`A` into the candidate's map
:math:`B`: :math:`M = S_{qB}^{-1} T_{qA}`, with :math:`S_{qB} = S_{ql} T_{lB}`, maps :math:`A`'s world
frame into :math:`B`'s; every point of :math:`A` moves by :math:`M` (normals rotate, scale ranges
scale), every keyframe of :math:`A` becomes the rigid part of :math:`T_{iA} M^{-1}`, i.e.
:math:`[R_i R_M^\top \mid s_M t_i - R_i R_M^\top t_M]`, and joins :math:`B`; the matched points are
fused and :math:`B` gets a global BA.  :math:`A` moves as one rigid (stereo/RGB-D) or similarity
(mono) body: the drift inside it is not redistributed (ORB-SLAM3 follows with an essential-graph
optimisation; a loop closed later in the merged map does that here).

Determinism: RANSAC draws from ``numpy.random.default_rng(seed)``; nothing depends on timing.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from privslam_jax.geometry.align import umeyama_np
from privslam_jax.geometry.sim3 import Sim3
from privslam_jax.slam.frontend import TH_HIGH, TH_LOW, match_descriptors, search_by_projection
from privslam_jax.slam.mapping import CHI2_MONO, KeyFrame, Map, global_bundle_adjustment, project
from privslam_jax.slam.pose_graph import optimize_pose_graph
from privslam_jax.slam.vocabulary import Vocabulary, bow_scores
from privslam_jax.types import Camera

__all__ = ["LoopConfig", "LoopClosure", "LoopCloser", "estimate_sim3_ransac"]


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Settings of :class:`LoopCloser` (ORB-SLAM2's values where it has one)."""

    min_keyframes: int = 20
    """No detection before the map has this many keyframes."""
    min_gap: int = 30
    """Candidates are at least this many keyframes older than the query."""
    min_score: float = 0.0
    """Absolute floor on the bag-of-words score of a candidate."""
    candidates: int = 3
    """Best-scoring candidates kept per keyframe."""
    group_size: int = 10
    """Covisible keyframes of a candidate that form its group."""
    consistency: int = 3
    """Consecutive keyframes whose candidate groups overlap before a candidate is verified."""
    match_ratio: float = 0.75
    """Ratio test of the descriptor matches between the two keyframes."""
    min_matches: int = 20
    """Descriptor matches needed to run RANSAC."""
    ransac_iterations: int = 300
    min_inliers: int = 30
    """RANSAC inliers needed (ORB-SLAM: 20; more here, where every crossing has the same road markings)."""
    min_projection_matches: int = 40
    """Matches after the projection search needed to accept the loop (ORB-SLAM: 40)."""
    verify_neighbours: int = 2
    """The loop must also be found (``min_projection_matches``) in this many of the query's most
    covisible keyframes."""
    max_drift: float = 0.05
    """Stereo / RGB-D only: a loop may move the query camera by at most this fraction of the path
    travelled since the loop keyframe (plus ``drift_floor_m``); ORB-SLAM2's stereo drift on KITTI is ~1 %."""
    drift_floor_m: float = 1.0
    covisibility_edge: int = 100
    """Keyframes sharing this many points get an essential-graph edge (ORB-SLAM: 100)."""
    pose_graph_iterations: int = 20
    global_ba_iterations: int = 10


@dataclasses.dataclass(frozen=True)
class LoopClosure:
    """One accepted loop."""

    query: int
    """Keyframe id of :math:`K_q` (the new keyframe)."""
    match: int
    """Keyframe id of :math:`K_l` (the old one)."""
    score: float
    """Bag-of-words score between them."""
    inliers: int
    """RANSAC inliers of the Sim(3)."""
    matches: int
    """Matches after the projection search."""
    scale: float
    """Scale of :math:`S_{ql}` (1 for SE(3))."""
    correction_m: float
    """How far the loop moved :math:`K_q`'s camera centre, in map units (a merge: how far the global BA
    after the merge moved it)."""
    merged: bool = False
    """An Atlas merge: :math:`K_q`'s map ``query_map`` was moved into :math:`K_l`'s map ``match_map``
    (scaled by ``1 / scale``) and the two became one."""
    query_map: int = 0
    """Atlas map of :math:`K_q` when the loop was found."""
    match_map: int = 0
    """Atlas map of :math:`K_l`."""


def _sim(R: np.ndarray, t: np.ndarray, s: float) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = s * R
    M[:3, 3] = t
    return M


def _sim_inv(M: np.ndarray) -> np.ndarray:
    sR = M[:3, :3]
    s2 = np.linalg.det(sR) ** (2.0 / 3.0)
    inv = np.eye(4)
    inv[:3, :3] = sR.T / s2
    inv[:3, 3] = -inv[:3, :3] @ M[:3, 3]
    return inv


def _reproj_ok(X_c: np.ndarray, uv: np.ndarray, sigma2: np.ndarray, cam: Camera) -> np.ndarray:
    z = X_c[:, 2]
    zs = np.where(z > 1e-9, z, 1e-9)
    proj = np.c_[cam.fx * X_c[:, 0] / zs + cam.cx, cam.fy * X_c[:, 1] / zs + cam.cy]
    return (z > 0) & (((proj - uv) ** 2).sum(1) < CHI2_MONO * sigma2)


def estimate_sim3_ransac(
    X1: np.ndarray, X2: np.ndarray, uv1: np.ndarray, uv2: np.ndarray, s2_1: np.ndarray, s2_2: np.ndarray,
    camera: Camera, with_scale: bool, iterations: int, rng: np.random.Generator,
) -> tuple[np.ndarray | None, np.ndarray]:
    """RANSAC ``X1 ≈ S₁₂ X2`` over 3-point Umeyama fits; a pair is an inlier when it reprojects within
    ``χ²(2)·σ²`` in both cameras.  Returns ``(S₁₂ as a 4×4 [sR | t], inlier mask)`` (``None`` if no fit)."""
    n = len(X1)
    best, best_inl = None, np.zeros(n, bool)
    if n < 3:
        return None, best_inl

    def inliers(S: np.ndarray) -> np.ndarray:
        X2in1 = X2 @ S[:3, :3].T + S[:3, 3]
        Si = _sim_inv(S)
        X1in2 = X1 @ Si[:3, :3].T + Si[:3, 3]
        return _reproj_ok(X2in1, uv1, s2_1, camera) & _reproj_ok(X1in2, uv2, s2_2, camera)

    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        try:
            R, t, s = umeyama_np(X2[idx], X1[idx], with_scale)
        except ValueError:
            continue
        if not np.isfinite(s) or s <= 0:
            continue
        inl = inliers(_sim(R, t, s))
        if inl.sum() > best_inl.sum():
            best, best_inl = _sim(R, t, s), inl
    if best is not None and best_inl.sum() >= 3:  # refit on the inliers
        R, t, s = umeyama_np(X2[best_inl], X1[best_inl], with_scale)
        refined = _sim(R, t, s)
        inl = inliers(refined)
        if inl.sum() >= best_inl.sum():
            best, best_inl = refined, inl
    return best, best_inl


def _search_sim3(m: Map, kf: KeyFrame, S_cw: np.ndarray, pts: np.ndarray) -> dict[int, int]:
    """Map points ``pts`` projected into ``kf`` at the similarity ``S_cw`` and searched around their
    projections (ORB-SLAM ``SearchByProjection`` for loops): ``{keypoint: point}``."""
    uv, z = project(S_cw, m.xyz[pts], m.camera)
    cam = m.camera
    vis = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    pts, uv = pts[vis], uv[vis]
    if len(pts) == 0:
        return {}
    scale = np.cbrt(np.linalg.det(S_cw[:3, :3]))
    center = -S_cw[:3, :3].T @ S_cw[:3, 3] / scale**2
    dist = np.linalg.norm(m.xyz[pts] - center, axis=1)
    level = np.clip(np.ceil(np.log(np.maximum(m.max_dist[pts], 1e-9) / np.maximum(dist, 1e-9))
                            / np.log(m.scale_factor)), 0, m.n_levels - 1).astype(np.int64)
    kp, _ = search_by_projection(uv, m.desc[pts], 10.0 * m.scale_factor**level, kf.feats, level - 1, level + 1,
                                 max_dist=TH_HIGH // 2, ratio=0.9)
    ok = kp >= 0
    return {int(k): int(p) for k, p in zip(kp[ok], pts[ok])}


def _fuse(m: Map, kf: KeyFrame, found: dict[int, int]) -> None:
    """The loop points found in ``kf`` (``{keypoint: point}``) replace its duplicates (``MapPoint::Replace``)."""
    for k, p in found.items():
        cur = int(kf.point_ids[k])
        if cur < 0:
            if not np.any((kf.point_ids == p)):
                m.add_observations(kf, np.array([p]), np.array([k]))
        elif cur != p:
            m.replace_points(np.array([cur]), np.array([p]))


class LoopCloser:
    """Loop detection and correction over a :class:`~privslam_jax.slam.mapping.Map` (see the module docstring)."""

    def __init__(self, vocabulary: Vocabulary, config: LoopConfig = LoopConfig(), with_scale: bool = True,
                 detect_loops: bool = True):
        self.vocab = vocabulary
        self.cfg = config
        self.with_scale = with_scale
        self.detect_loops = detect_loops
        """``False``: only Atlas merges (candidates in other maps), no loops inside a map."""
        self._bow: list[np.ndarray] = []
        self._groups: list[tuple[frozenset[int], int]] = []
        self.loops: list[LoopClosure] = []

    # ---------------------------------------------------------------- detection
    def _candidates(self, m: Map, kf: KeyFrame) -> list[tuple[int, float]]:
        cfg = self.cfg
        while len(self._bow) < len(m.keyframes):
            self._bow.append(self.vocab.transform(m.keyframes[len(self._bow)].feats.desc))
        if kf.id < cfg.min_keyframes:
            return []
        V = np.stack(self._bow)
        v = V[kf.id]
        conn, counts = m.covisible(kf.point_ids[kf.point_ids >= 0], exclude=kf.id)
        near = conn[counts >= 15]
        min_score = float(bow_scores(v, V[near]).min()) if len(near) else 0.0
        maps = m.map_ids()
        eligible = maps != kf.map_id  # other Atlas maps: merge candidates
        if self.detect_loops:  # the same map: loop candidates at least min_gap keyframes older
            eligible[: max(kf.id - cfg.min_gap, 0)] |= maps[: max(kf.id - cfg.min_gap, 0)] == kf.map_id
        eligible[conn] = False
        old = np.flatnonzero(eligible)
        if len(old) == 0:
            self._groups = []
            return []
        sc = bow_scores(v, V[old])
        ok = sc >= max(min_score, cfg.min_score)
        order = np.argsort(-sc[ok], kind="stable")[: cfg.candidates]
        cands = [(int(old[ok][i]), float(sc[ok][i])) for i in order]
        # consistency over consecutive keyframes
        groups, enough = [], []
        for c, score in cands:
            cov, _ = m.covisible(m.keyframes[c].point_ids[m.keyframes[c].point_ids >= 0], exclude=c)
            g = frozenset([c, *[int(i) for i in cov[: cfg.group_size]]])
            count = 1 + max((n for prev, n in self._groups if prev & g), default=0)
            groups.append((g, count))
            if count >= cfg.consistency:
                enough.append((c, score))
        self._groups = groups
        return enough

    # ---------------------------------------------------------------- verification
    def _verify(self, m: Map, kf: KeyFrame, c: int, seed: int) -> tuple[np.ndarray, int, dict[int, int]] | None:
        cfg = self.cfg
        lk = m.keyframes[c]
        good_q = (kf.point_ids >= 0) & ~m.bad[np.maximum(kf.point_ids, 0)]
        good_l = (lk.point_ids >= 0) & ~m.bad[np.maximum(lk.point_ids, 0)]
        pairs = match_descriptors(kf.feats, lk.feats, ratio=cfg.match_ratio, max_dist=TH_LOW,
                                  mask_a=good_q, mask_b=good_l)
        if len(pairs) < cfg.min_matches:
            return None
        Tq, Tl = kf.T_c_w, lk.T_c_w
        Pq, Pl = m.xyz[kf.point_ids[pairs[:, 0]]], m.xyz[lk.point_ids[pairs[:, 1]]]
        X1 = Pq @ Tq[:3, :3].T + Tq[:3, 3]
        X2 = Pl @ Tl[:3, :3].T + Tl[:3, 3]
        s2q = m.sigma2(kf.feats.octave[pairs[:, 0]])
        s2l = m.sigma2(lk.feats.octave[pairs[:, 1]])
        S_ql, inl = estimate_sim3_ransac(X1, X2, kf.feats.uv[pairs[:, 0]], lk.feats.uv[pairs[:, 1]], s2q, s2l,
                                         m.camera, self.with_scale, cfg.ransac_iterations,
                                         np.random.default_rng(seed))
        if S_ql is None or inl.sum() < cfg.min_inliers:
            return None
        # search the loop keyframe's neighbourhood in K_q at the corrected pose ...
        cov, _ = m.covisible(lk.point_ids[good_l], exclude=c)
        group = [c, *[int(i) for i in cov[: cfg.group_size]]]
        pts = np.unique(np.concatenate([m.keyframes[g].point_ids for g in group]))
        pts = pts[(pts >= 0)]
        pts = pts[~m.bad[pts]]
        S_qw = S_ql @ Tl
        found = _search_sim3(m, kf, S_qw, pts)
        if len(found) < cfg.min_projection_matches:
            return None
        if not self.with_scale and lk.map_id == kf.map_id:
            # a metric map drifts by a few percent of the distance travelled: a larger correction is a
            # different place that looks the same (e.g. the road markings of every crossing)
            centres = np.stack([k.center for k in m.keyframes[c: kf.id + 1]])
            travelled = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
            S_inv = _sim_inv(S_qw)
            if np.linalg.norm(S_inv[:3, 3] - kf.center) > cfg.max_drift * travelled + cfg.drift_floor_m:
                return None
        # ... and in K_q's most covisible keyframes, each at its pose relative to K_q (ORB-SLAM3's
        # verification of a place in the keyframes around it): repetitive texture fools one view, rarely three
        nbs, _ = m.covisible(kf.point_ids[good_q], exclude=kf.id)
        T_q_inv = np.linalg.inv(Tq)
        confirmed = 0
        for i in [int(n) for n in nbs[: cfg.verify_neighbours]]:
            ki = m.keyframes[i]
            if len(_search_sim3(m, ki, ki.T_c_w @ T_q_inv @ S_qw, pts)) >= cfg.min_projection_matches:
                confirmed += 1
        if confirmed < min(cfg.verify_neighbours, len(nbs)):
            return None
        return S_ql, int(inl.sum()), found

    # ---------------------------------------------------------------- correction
    def _correct(self, m: Map, kf: KeyFrame, c: int, S_ql: np.ndarray, found: dict[int, int]) -> float:
        cfg = self.cfg
        n_kf = len(m.keyframes)
        mine = m.keyframes_of(kf.map_id)  # the loop's Atlas map; the other maps stay fixed and unlinked
        old_T = np.stack([k.T_c_w for k in m.keyframes])
        conn, _ = m.covisible(kf.point_ids[kf.point_ids >= 0], exclude=kf.id)
        group = [kf.id, *[int(i) for i in conn if int(i) != c and abs(int(i) - c) > cfg.min_gap // 2]]
        S_qw = S_ql @ m.keyframes[c].T_c_w
        S0 = old_T.copy()  # every keyframe's Sim(3) before the pose graph (the corrected group, the rest as is)
        T_q_inv = np.linalg.inv(old_T[kf.id])
        for i in group:
            S0[i] = old_T[i] @ T_q_inv @ S_qw
        # points move with the first group keyframe that sees them (their reference keyframe from now on)
        ref = m._first_kf.v.copy()
        moved = np.zeros(m.n_points, bool)
        for i in group:
            pid = m.keyframes[i].point_ids
            pid = np.unique(pid[(pid >= 0)])
            pid = pid[~moved[pid] & ~m.bad[pid]]
            C = _sim_inv(S0[i]) @ old_T[i]
            m._xyz.data[pid] = m.xyz[pid] @ C[:3, :3].T + C[:3, 3]
            moved[pid] = True
            ref[pid] = i
        # covisibility before the fusion: links the fusion creates between the two sides are loop edges
        rows, okf, opt = m.observations()
        inc = np.zeros((n_kf, m.n_points), bool)
        inc[okf, opt] = True
        shared = inc.astype(np.int32) @ inc.T.astype(np.int32)
        _fuse(m, kf, found)
        # essential graph
        edges, Z = [], []
        for a, b in zip(mine[1:].tolist(), mine[:-1].tolist()):
            edges.append((a, b))
        ii, jj = np.nonzero(np.triu(shared >= cfg.covisibility_edge, k=2))  # (never across maps)
        edges.extend(zip(ii.tolist(), jj.tolist()))
        n_tree = len(edges)
        for i in group:
            edges.append((i, c))
        edges_arr = np.asarray(edges, np.int64)
        for k, (i, j) in enumerate(edges_arr):  # loop edges from the corrected poses, the rest as they were
            Z.append(S0[i] @ _sim_inv(S0[j]) if k >= n_tree else old_T[i] @ np.linalg.inv(old_T[j]))
        fixed = np.ones(n_kf, bool)
        fixed[mine] = False
        fixed[[mine[0], c]] = True
        with jax.enable_x64(True):
            res = optimize_pose_graph(Sim3.from_matrix(jnp.asarray(S0)), edges_arr, Sim3.from_matrix(jnp.asarray(np.stack(Z))),
                                      fixed=fixed, with_scale=self.with_scale, max_iterations=cfg.pose_graph_iterations)
            S_new = np.asarray(res.poses.as_matrix(), np.float64)
        # every point follows its reference keyframe; keyframes become rigid again
        for i in mine.tolist():
            C = _sim_inv(S_new[i]) @ S0[i]
            pid = np.flatnonzero((ref == i) & ~m.bad)
            m._xyz.data[pid] = m.xyz[pid] @ C[:3, :3].T + C[:3, 3]
            s = np.cbrt(np.linalg.det(S_new[i][:3, :3]))
            T = np.eye(4)
            T[:3, :3] = S_new[i][:3, :3] / s
            T[:3, 3] = S_new[i][:3, 3] / s
            m.keyframes[i].T_c_w = T
        before = -old_T[kf.id][:3, :3].T @ old_T[kf.id][:3, 3]
        global_bundle_adjustment(m, cfg.global_ba_iterations, kf.map_id)
        return float(np.linalg.norm(m.keyframes[kf.id].center - before))

    # ---------------------------------------------------------------- Atlas merge
    def _merge(self, m: Map, kf: KeyFrame, c: int, S_ql: np.ndarray, found: dict[int, int]) -> float:
        """Move ``kf``'s map into ``c``'s (module docstring), fuse, global BA; returns how far the BA moved ``kf``."""
        a, b = kf.map_id, m.keyframes[c].map_id
        M = _sim_inv(S_ql @ m.keyframes[c].T_c_w) @ kf.T_c_w  # map a's world -> map b's world
        s = float(np.cbrt(np.linalg.det(M[:3, :3])))
        R = M[:3, :3] / s
        ids = m.keyframes_of(a)
        pts = np.flatnonzero(np.isin(m._first_kf.v, ids))  # a point belongs to the map of its first keyframe
        m._xyz.data[pts] = m.xyz[pts] @ M[:3, :3].T + M[:3, 3]
        m._normal.data[pts] = m.normal[pts] @ R.T
        m._max_dist.data[pts] *= s
        for i in ids.tolist():
            k = m.keyframes[i]
            T = np.eye(4)
            T[:3, :3] = k.T_c_w[:3, :3] @ R.T
            T[:3, 3] = s * k.T_c_w[:3, 3] - T[:3, :3] @ M[:3, 3]
            k.T_c_w = T
            k.map_id = b
        before = kf.center
        _fuse(m, kf, found)
        global_bundle_adjustment(m, self.cfg.global_ba_iterations, b)
        return float(np.linalg.norm(m.keyframes[kf.id].center - before))

    # ---------------------------------------------------------------- entry
    def process(self, m: Map, kf: KeyFrame, seed: int) -> LoopClosure | None:
        """Detect, verify and (when accepted) correct a loop ending at the new keyframe ``kf``, or merge
        its Atlas map into another one."""
        for c, score in self._candidates(m, kf):
            found = self._verify(m, kf, c, seed)
            if found is None:
                continue
            S_ql, n_inl, matches = found
            q_map, l_map = kf.map_id, m.keyframes[c].map_id
            merge = q_map != l_map
            shift = (self._merge if merge else self._correct)(m, kf, c, S_ql, matches)
            self._groups = []
            loop = LoopClosure(query=kf.id, match=c, score=score, inliers=n_inl, matches=len(matches),
                               scale=float(np.cbrt(np.linalg.det(S_ql[:3, :3]))), correction_m=shift,
                               merged=merge, query_map=q_map, match_map=l_map)
            self.loops.append(loop)
            return loop
        return None
