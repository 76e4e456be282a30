"""The SLAM system: monocular, stereo and RGB-D tracking with synchronous local mapping.

:class:`Slam` runs ORB-SLAM3's tracking and local-mapping loop frame by frame (mapping runs
synchronously right after a keyframe is chosen, so results do not depend on thread timing):

* **Initialisation** — monocular: two-view geometry (:mod:`.initializer`), full BA, median scene
  depth scaled to 1; stereo/RGB-D: the first frame with ≥ ``min_init_points`` keypoints with
  depth becomes a keyframe with one map point per such keypoint.
* **Tracking** (:mod:`.tracking`) — constant-velocity prediction + projection search, PnP-RANSAC
  against the reference keyframe when that fails, then the local map; when lost, relocalisation
  along the motion model (the recent keyframes' points searched around the constant-velocity
  poses, frames possibly dropped) and then by appearance against recent keyframes.  A lost frame gets the motion-model prediction and ``tracked=False``.
* **Keyframes** (ORB-SLAM ``NeedNewKeyFrame``): a frame becomes a keyframe when it tracks fewer
  than ``ratio × `` the reference keyframe's well-observed points (0.9 mono, 0.75 stereo/RGB-D) or
  ``max_frames_between_kf`` frames passed, and (stereo/RGB-D) when it tracks fewer than 100 close
  points but sees more than 70 untracked close ones; not while the mapper is busy
  (``mapper_busy_frames`` after a keyframe; stereo/RGB-D only when tracking is weak), as ORB-SLAM's
  tracking thread waits for an idle local-mapping thread.
* **Mapping** (:mod:`.mapping`) — culling, triangulation, fusion, local BA.
* **Loop closing** (:mod:`.loop_closing`, with ``SlamConfig.loop_closing``) — after local mapping:
  bag-of-words candidates, Sim(3)/SE(3) verification, correction, essential graph, global BA.
* **Atlas** (ORB-SLAM3's multi-map system) — when tracking stays lost for ``new_map_after`` frames, a
  new map is initialised (its own world frame; monocular: its own scale) and tracking, relocalisation
  and local mapping work in it; the earlier maps are kept.  With ``merge_maps``, every new keyframe is
  also matched by place recognition against the other maps' keyframes, and an accepted match moves
  the active map into the matched one (Sim(3) mono, SE(3) otherwise) and merges the two
  (:mod:`.loop_closing`).  Every frame keeps a pose; ``SlamResult.frame_maps`` says in which map
  (the frames lost before a new map is initialised are put in it once it is; ``-1``: none, when the
  run ends before a map was initialised).
* **Output** — like ORB-SLAM's ``SaveTrajectory``, each frame's pose is stored relative to its
  reference keyframe and composed with that keyframe's final (bundle-adjusted) pose.

Determinism: tracking and mapping run in one thread (:func:`run_slam` extracts the next
:data:`PREFETCH_FRAMES` frames' features in a second one; they do not depend on the map), OpenCV's
fixed-seed RANSAC, and correspondence order shuffled by ``numpy.random.default_rng(seed + …)``: the
same input and seed give bit-identical trajectories.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from privslam_jax.slam.frontend import OrbConfig, extract_orb, rgbd_depths, stereo_depths, to_gray_u8
from privslam_jax.slam.initializer import InitConfig, initialize_two_view
from privslam_jax.slam.loop_closing import LoopClosure, LoopCloser, LoopConfig
from privslam_jax.slam.mapping import (
    KeyFrame,
    Map,
    MappingConfig,
    cull_points,
    fuse_into_neighbours,
    local_bundle_adjustment,
    triangulate_new_points,
)
from privslam_jax.slam.tracking import (
    Frame,
    TrackingConfig,
    motion_deviation,
    relocalise,
    relocalise_along_motion,
    track_keyframe_pnp,
    track_local_map,
    track_motion_model,
)
from privslam_jax.slam.vocabulary import load_vocabulary
from privslam_jax.types import Camera, PointCloud, Trajectory

__all__ = ["SlamConfig", "SlamResult", "Slam", "run_slam", "MODES"]

MODES = ("mono", "stereo", "rgbd")

EMBEDDED_VOCABULARY = str(Path(__file__).resolve().parents[1] / "assets" / "orb_vocabulary_1k.npz")
"""The shipped ORB vocabulary (``train/vocabulary.py``)."""


@dataclasses.dataclass(frozen=True)
class SlamConfig:
    """Settings of the whole system."""

    mode: str = "mono"
    """``"mono"``, ``"stereo"`` or ``"rgbd"``."""
    seed: int = 0
    """Seed of the RANSAC correspondence shuffling (the only randomness)."""
    orb: OrbConfig = OrbConfig()
    """Feature extraction."""
    tracking: TrackingConfig = TrackingConfig()
    """Tracking."""
    mapping: MappingConfig = MappingConfig()
    """Local mapping."""
    init: InitConfig = InitConfig()
    """Monocular initialisation."""
    kf_ratio_mono: float = 0.9
    """Keyframe when tracked < ratio × reference-keyframe points (monocular)."""
    kf_ratio_depth: float = 0.75
    """The same for stereo/RGB-D."""
    max_frames_between_kf: int = 10
    """A keyframe at least this often (ORB-SLAM: the frame rate)."""
    mapper_busy_frames: int = 1
    """ORB-SLAM's tracking inserts no keyframe while local mapping is still busy with the previous one
    (stereo/RGB-D: unless tracking is weak, fewer than a quarter of the reference keyframe's points, or
    close points are needed).  Deterministic stand-in: the mapper counts as busy for this many frames
    after each keyframe (``0``: an always-idle mapper, the behaviour before 2026-12-04; 1: local
    mapping takes 100-150 ms per keyframe on 2 CPU cores, about one frame at KITTI's 10 Hz)."""
    close_depth_baselines: float = 40.0
    """Stereo: points closer than this many baselines are "close" (ORB-SLAM ``ThDepth``)."""
    stereo_max_depth_baselines: float = math.inf
    """Stereo: a keypoint whose stereo depth is this many baselines or more keeps no depth and is used
    as a monocular keypoint everywhere (map points from triangulation between keyframes, no
    right-image residual); ``inf`` (default) keeps every depth, as ORB-SLAM does.  80 (43 m on KITTI)
    lowers the stereo ATE of the unfiltered synthetic worlds (loop worlds with loop closing, median
    share of the path: 0.056 → 0.038 %, held-out worlds 0.079 → 0.035 %) but raises it on
    privacy-filtered frames (Table 4's EdgeConnect and Telea rows, median SE(3) ATE 0.211 → 0.426 m and
    0.267 → 0.427 m), so it is not the default; docs/slam.md, "Far stereo points"."""
    stereo_zero_mean_sad: bool = True
    """Stereo: refine each match by SAD of zero-mean patches (default) instead of ORB-SLAM's patches
    minus their centre pixel, which gives the keypoints of pyramid levels ≥ 1 disparities a few
    hundredths of a pixel short (``frontend._sad_refine``); ``False`` is ORB-SLAM's, the default before
    2026-12-06.  Zero mean is more accurate on 13 of 15 unfiltered worlds without loops, reaches
    ≤ 0.1 % of the path with loop closing on all ten loop worlds measured (``loop_closing.py``, worlds
    7, 11-14 and 15-19), and, with masked features, is more accurate than the old default on 18 of 25
    privacy-filtered runs (Table 4, worlds 0-4 and 15-24); without masked features it lost tracking
    on one filtered world where the filter's fill covers most of the frame, so filtered stereo frames
    are run with masked features (``privslam run``, Table 4; docs/slam.md, "Stereo disparities of
    coarse keypoints")."""
    rgbd_close_depth: float = 20.0
    """RGB-D: close-point depth threshold, metres."""
    min_init_points: int = 300
    """Stereo/RGB-D: keypoints with depth needed to initialise."""
    rgbd_baseline: float = 0.08
    """RGB-D: baseline (m) of the virtual stereo pair ``u_r = u − f_x·b/z`` used in pose refinement and
    local BA when the camera has none (ORB-SLAM: ``Camera.bf / f_x``; a camera baseline is used as is)."""
    loop_closing: bool = False
    """Detect and close loops after local mapping (:mod:`.loop_closing`: place recognition with the
    ORB vocabulary, Sim(3)/SE(3) verification, essential graph, global BA)."""
    loop: LoopConfig = LoopConfig()
    """Loop-closing settings."""
    vocabulary: str | None = None
    """Bag-of-words vocabulary ``.npz`` for loop closing (``None``: the embedded one,
    ``privslam_jax/assets/orb_vocabulary_1k.npz``)."""
    new_map_after: int = 50
    """Atlas: start a new map after this many consecutive lost frames (ORB-SLAM3: 5 s, i.e. 50 frames
    at KITTI's 10 Hz); ``0`` keeps relocalising in the one map forever."""
    merge_maps: bool = True
    """Atlas: merge maps that place recognition finds to overlap (uses ``vocabulary``)."""
    motion_check_ratio: float = 0.3
    """When the motion model keeps fewer than this fraction of the last frame's inliers (e.g. the onset
    of a turn, where the constant-velocity guess is off and repetitive texture gives a few wrong
    matches), PnP against the reference keyframe is tried as well and the pose with more inliers kept."""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.new_map_after < 0:
            raise ValueError(f"new_map_after must be >= 0 (0: never start a new map), got {self.new_map_after}")
        if self.mapper_busy_frames < 0:
            raise ValueError(f"mapper_busy_frames must be >= 0 (0: an always-idle mapper), got {self.mapper_busy_frames}")
        if not self.stereo_max_depth_baselines > 0:
            raise ValueError(f"stereo_max_depth_baselines must be > 0 (inf: keep every depth), got "
                             f"{self.stereo_max_depth_baselines}")


@dataclasses.dataclass
class SlamResult:
    """Everything a run produces."""

    trajectory: Trajectory
    """``T_w_c`` of every frame."""
    tracked: np.ndarray
    """``(N,)`` bool: the frame's pose came from tracking (not a motion-model guess)."""
    keyframe_indices: np.ndarray
    """``(K,)`` frame index of each keyframe."""
    keyframe_poses: np.ndarray
    """``(K, 4, 4)`` keyframe ``T_w_c``."""
    map: PointCloud
    """Map points with their keyframe-observation counts."""
    timings: dict[str, np.ndarray]
    """Per-frame seconds of each stage (``nan`` where the stage did not run)."""
    inliers: np.ndarray
    """``(N,)`` pose inliers per frame."""
    events: list[str]
    """Initialisation, loss, relocalisation and loop messages."""
    loops: list[LoopClosure] = dataclasses.field(default_factory=list)
    """The loops closed and the Atlas maps merged (``LoopClosure.merged``), in order."""
    frame_maps: np.ndarray | None = None
    """``(N,)`` Atlas map of each frame's pose (``-1``: in none, when the run ended before a map was
    initialised); poses of different maps are in different world frames."""
    keyframe_maps: np.ndarray | None = None
    """``(K,)`` Atlas map of each keyframe."""

    @property
    def n_maps(self) -> int:
        """Atlas maps at the end of the run (merged maps count once)."""
        return int(len(np.unique(self.keyframe_maps))) if self.keyframe_maps is not None else 1


class Slam:
    """Frame-by-frame SLAM (mutable; use :func:`run_slam` for a whole sequence)."""

    def __init__(self, camera: Camera, config: SlamConfig = SlamConfig()):
        if config.mode == "stereo" and not camera.baseline:
            raise ValueError("stereo mode needs camera.baseline")
        if camera.width <= 0 or camera.height <= 0:
            raise ValueError("camera.width and camera.height must be set")
        if config.mode == "rgbd" and not camera.baseline:
            camera = camera.replace(baseline=float(config.rgbd_baseline))
        self.camera = camera
        self.cfg = config
        self.map = Map(camera, config.orb.scale_factor, config.orb.n_levels)
        self.frames_rel: list[tuple[int, np.ndarray]] = []  # (ref kf id or -1, T_c_ref or T_c_w)
        self.tracked: list[bool] = []
        self.inliers: list[int] = []
        self.timings: list[dict[str, float]] = []
        self.events: list[str] = []
        self.initialized = False
        self._pending: list[Frame] = []
        self._last: Frame | None = None
        self._last_good: Frame | None = None
        self._velocity: np.ndarray | None = None
        self._ref_kf: KeyFrame | None = None
        self._frames_since_kf = 0
        self._lost_since = 0
        self._init_ref: Frame | None = None
        self.active_map = 0
        """Atlas map that tracking and mapping work in."""
        self._next_map = 1
        self._loop: LoopCloser | None = None
        self._mapping_due: tuple[Frame, int] | None = None
        """A keyframe whose insertion and local mapping :meth:`track` deferred (``defer_mapping``)."""
        if config.loop_closing or (config.merge_maps and config.new_map_after > 0):
            vocab = load_vocabulary(config.vocabulary or EMBEDDED_VOCABULARY)
            self._loop = LoopCloser(vocab, config.loop, with_scale=config.mode == "mono",
                                    detect_loops=config.loop_closing)

    # ------------------------------------------------------------------ helpers
    @property
    def depth_mode(self) -> bool:
        return self.cfg.mode in ("stereo", "rgbd")

    def _close_depth(self) -> float:
        if self.cfg.mode == "stereo":
            return self.cfg.close_depth_baselines * float(self.camera.baseline)
        return self.cfg.rgbd_close_depth

    def _record(self, frame: Frame, tracked: bool, n: int) -> None:
        i = frame.index
        while len(self.frames_rel) <= i:
            self.frames_rel.append((-1, np.eye(4)))
            self.tracked.append(False)
            self.inliers.append(0)
        ref = self._ref_kf
        if ref is None:
            self.frames_rel[i] = (-1, frame.T_c_w.copy())
        else:
            self.frames_rel[i] = (ref.id, frame.T_c_w @ np.linalg.inv(ref.T_c_w))
        self.tracked[i] = tracked
        self.inliers[i] = n

    def _active_keyframes(self) -> np.ndarray:
        return self.map.keyframes_of(self.active_map)

    def _start_new_map(self, frame: Frame) -> None:
        """Atlas: keep the current map and initialise a new one from the next frames."""
        self.events.append(f"new map {self._next_map} started after frame {frame.index} "
                           f"({self._lost_since} frames lost in map {self.active_map})")
        self.active_map = self._next_map
        self._next_map += 1
        self.initialized = False
        self._pending = []
        self._init_ref = None
        self._ref_kf = None
        self._velocity = None
        self._lost_since = 0

    def _pose_now(self, frame: Frame) -> np.ndarray:
        """Current estimate of a past frame's ``T_c_w`` via its reference keyframe."""
        ref, T = self.frames_rel[frame.index]
        return T @ self.map.keyframes[ref].T_c_w if ref >= 0 else T

    # ------------------------------------------------------------------ main entry
    def track(self, image: np.ndarray, right: np.ndarray | None = None, depth: np.ndarray | None = None,
              ignore: np.ndarray | None = None, defer_mapping: bool = False) -> tuple[np.ndarray, bool]:
        """Process the next frame; returns its ``T_w_c`` estimate and whether it was tracked.

        ``ignore``: ``(H, W)`` bool, no keypoint of the (left) image is extracted where it is True.
        ``defer_mapping``: when the frame becomes a keyframe, return its tracked pose at once and leave
        the keyframe's insertion and local mapping to :meth:`finish_mapping`, which the next
        :meth:`track` or :meth:`result` calls first; the results are those of the inline order
        (the returned pose of such a frame is the tracked one, before local BA refines it).  The
        edge server answers a frame this way and maps while the next one is on its way.
        """
        return self.track_frame(*self.features(len(self.timings), image, right, depth, ignore), defer_mapping)

    def features(self, idx: int, image: np.ndarray, right: np.ndarray | None = None,
                 depth: np.ndarray | None = None, ignore: np.ndarray | None = None) -> tuple[Frame, dict[str, float]]:
        """The first half of :meth:`track`: frame ``idx``'s ORB features (with stereo / RGB-D depth) and
        the seconds they took.  Depends only on the images and the configuration, never on the map, so
        :func:`run_slam` computes frame ``t + 1``'s while frame ``t`` is tracked and mapped."""
        tim: dict[str, float] = {}
        t0 = time.perf_counter()
        gray = to_gray_u8(image)
        if gray.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"frame {idx}: image shape {gray.shape} != camera (height, width) {self.camera.shape}")
        feats = extract_orb(gray, self.cfg.orb, ignore)
        tim["extract"] = time.perf_counter() - t0
        if self.cfg.mode == "stereo":
            if right is None:
                raise ValueError(f"frame {idx}: stereo mode needs a right image")
            t1 = time.perf_counter()
            gr = to_gray_u8(right)
            if gr.shape != gray.shape:
                raise ValueError(f"frame {idx}: right image shape {gr.shape} != left {gray.shape}")
            fr = extract_orb(gr, self.cfg.orb)
            feats.depth = stereo_depths(gray, gr, feats, fr, self.camera.fx, float(self.camera.baseline),
                                        self.cfg.orb.scale_factor, zero_mean=self.cfg.stereo_zero_mean_sad)
            if math.isfinite(self.cfg.stereo_max_depth_baselines):  # far keypoints as monocular ones
                far = feats.depth >= self.cfg.stereo_max_depth_baselines * float(self.camera.baseline)
                feats.depth = np.where(far, np.nan, feats.depth)
            tim["stereo"] = time.perf_counter() - t1
        elif self.cfg.mode == "rgbd":
            if depth is None:
                raise ValueError(f"frame {idx}: rgbd mode needs a depth image")
            depth = np.asarray(depth)
            if depth.shape[:2] != gray.shape:
                raise ValueError(f"frame {idx}: depth shape {depth.shape} != image {gray.shape}")
            feats.depth = rgbd_depths(depth, feats)
        tim["total"] = time.perf_counter() - t0
        return Frame(idx, feats), tim

    def track_frame(self, frame: Frame, tim: dict[str, float], defer_mapping: bool = False) -> tuple[np.ndarray, bool]:
        """The second half of :meth:`track`: track (and map) a frame from :meth:`features`; ``tim`` are
        its timings so far (``total`` grows by the tracking and mapping time).  Frames must come in
        index order."""
        self.finish_mapping()
        if frame.index != len(self.timings):
            raise ValueError(f"frame {frame.index} out of order: expected frame {len(self.timings)}")
        self.timings.append(tim)
        t1 = time.perf_counter()
        if not self.initialized:
            self._initialize(frame)
        else:
            self._track(frame, defer_mapping)
        tim["track"] = time.perf_counter() - t1 - tim.get("mapping", 0.0)
        tim["total"] += time.perf_counter() - t1
        rel = self.frames_rel[frame.index]
        T_c_w = rel[1] @ self.map.keyframes[rel[0]].T_c_w if rel[0] >= 0 else rel[1]
        return np.linalg.inv(T_c_w), self.tracked[frame.index]

    # ------------------------------------------------------------------ initialisation
    def _initialize(self, frame: Frame) -> None:
        if self.depth_mode:
            ok = np.isfinite(frame.feats.depth) & (frame.feats.depth > 0)
            if ok.sum() >= self.cfg.min_init_points:
                frame.T_c_w = np.eye(4)
                kf = self.map.add_keyframe(frame.index, frame.T_c_w, frame.feats, frame.point_ids, self.active_map)
                self._create_depth_points(kf, all_points=True)
                frame.point_ids = kf.point_ids.copy()
                self._after_init(frame, kf, f"initialised at frame {frame.index} from depth "
                                            f"({int(ok.sum())} points)")
            else:
                frame.T_c_w = np.eye(4)
                self._pending.append(frame)
                self._record(frame, False, 0)
            return
        if self._init_ref is None or len(frame.feats) <= 100:
            # ORB-SLAM: a frame with more than 100 keypoints becomes the reference, one with fewer resets it
            frame.T_c_w = np.eye(4)
            self._init_ref = frame if len(frame.feats) > 100 else None
            self._pending.append(frame)
            self._record(frame, False, 0)
            return
        ref = self._init_ref
        res = initialize_two_view(ref.feats, frame.feats, self.camera, self.cfg.seed, self.cfg.init,
                                  self.cfg.orb.scale_factor)
        if res is None:
            frame.T_c_w = np.eye(4)
            self._pending.append(frame)
            self._record(frame, False, 0)
            if frame.index - ref.index > 30:  # ORB-SLAM resets the reference when it gets stale
                self._init_ref = frame
            return
        m = self.map
        ref.T_c_w = np.eye(4)
        kf0 = m.add_keyframe(ref.index, np.eye(4), ref.feats, np.full(len(ref.feats), -1, np.int64), self.active_map)
        kf1 = m.add_keyframe(frame.index, res.T_cur_ref, frame.feats, np.full(len(frame.feats), -1, np.int64),
                             self.active_map)
        ids = m.add_points(res.xyz, kf0, res.ref_kp)
        m.add_observations(kf1, ids, res.cur_kp)
        # global BA of the two-view map, then scale to median depth 1
        stats = local_bundle_adjustment(m, kf1, dataclasses.replace(self.cfg.mapping, ba_iterations=20))
        good = kf0.point_ids[kf0.point_ids >= 0]
        zmed = float(np.median(m.xyz[good][:, 2])) if len(good) else 1.0
        if not np.isfinite(zmed) or zmed <= 0:
            zmed = 1.0
        m._xyz.data[ids[0]: m.n_points] /= zmed  # the new map's points (the only ones before a new Atlas map)
        kf1.T_c_w[:3, 3] /= zmed
        frame.T_c_w = kf1.T_c_w.copy()
        frame.point_ids = kf1.point_ids.copy()
        self._after_init(frame, kf1, f"initialised at frames {ref.index}-{frame.index}: {len(good)} points, "
                                     f"parallax {res.parallax_deg:.2f} deg, BA outliers {stats.get('ba_outliers', 0)}")

    def _after_init(self, frame: Frame, kf: KeyFrame, message: str) -> None:
        self.initialized = True
        self.events.append(message)
        self._ref_kf = kf
        self._frames_since_kf = 0
        # poses for frames seen before the map existed
        for p in self._pending:
            if p.index == frame.index:
                continue
            kf_match = [k.id for k in self.map.keyframes if k.frame == p.index]
            if kf_match:
                self._ref_kf = self.map.keyframes[kf_match[0]]
                p.T_c_w = self._ref_kf.T_c_w.copy()
                self._record(p, True, int((self._ref_kf.point_ids >= 0).sum()))
                continue
            n = track_keyframe_pnp(p, [kf.id], self.map, self.cfg.seed + p.index, self.cfg.tracking)
            ok = n >= self.cfg.tracking.min_inliers
            if not ok:
                p.T_c_w = self.map.keyframes[self._active_keyframes()[0]].T_c_w.copy()
            self._ref_kf = kf
            self._record(p, ok, n)
        self._ref_kf = kf
        self._pending = []
        self._record(frame, True, frame.n_matches)
        self._last = frame
        self._last_good = frame
        self._velocity = None
        self._lost_since = 0

    def _create_depth_points(self, kf: KeyFrame, all_points: bool = False) -> int:
        z = kf.feats.depth
        free = (kf.point_ids < 0) & np.isfinite(z) & (z > 0)
        idx = np.flatnonzero(free)
        if not all_points and len(idx):
            order = idx[np.argsort(z[idx], kind="stable")]
            close = z[order] < self._close_depth()
            keep = np.maximum(close.sum(), min(100, len(order)))
            idx = np.sort(order[:keep])
        if len(idx) == 0:
            return 0
        p_c = np.c_[(kf.feats.uv[idx, 0] - self.camera.cx) / self.camera.fx * z[idx],
                    (kf.feats.uv[idx, 1] - self.camera.cy) / self.camera.fy * z[idx], z[idx]]
        T_w_c = np.linalg.inv(kf.T_c_w)
        xyz = p_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]
        self.map.add_points(xyz, kf, idx)
        return len(idx)

    # ------------------------------------------------------------------ tracking
    def finish_mapping(self) -> None:
        """Insert the keyframe :meth:`track` deferred and run its local mapping (no-op without one)."""
        if self._mapping_due is None:
            return
        frame, n = self._mapping_due
        self._mapping_due = None
        t = time.perf_counter()
        self._insert_keyframe(frame)
        self.timings[frame.index]["mapping"] = time.perf_counter() - t
        self._record(frame, True, n)

    def _track(self, frame: Frame, defer_mapping: bool = False) -> None:
        cfg, m, tim = self.cfg, self.map, self.timings[-1]
        tcfg = cfg.tracking
        seed = cfg.seed + 7919 * frame.index
        last = self._last_good
        T_last = self._pose_now(last)
        gap = frame.index - last.index
        n, along_motion = 0, False
        t = time.perf_counter()
        if len(frame.feats) >= 10:
            if self._velocity is not None and self._lost_since <= 5:
                T_pred = np.linalg.matrix_power(self._velocity, gap) @ T_last
                radius = tcfg.motion_radius_depth if self.depth_mode else tcfg.motion_radius_mono
                last.point_ids = np.where(m.bad[np.maximum(last.point_ids, 0)], -1, last.point_ids)
                n = track_motion_model(frame, last, T_pred, m, radius * (1 if gap == 1 else 2), tcfg)
                n_last = self.inliers[last.index] if last.index < len(self.inliers) else 0
                if tcfg.min_motion_matches <= n < cfg.motion_check_ratio * n_last:
                    # suspicious drop (turn onset): compare with PnP against the reference keyframe
                    keep = (frame.T_c_w, frame.point_ids.copy())
                    frame.point_ids[:] = -1
                    n_pnp = track_keyframe_pnp(frame, [self._ref_kf.id], m, seed, tcfg)
                    if n_pnp <= n:
                        frame.T_c_w, frame.point_ids = keep
                    else:
                        self.events.append(f"frame {frame.index}: PnP ({n_pnp} inliers) replaced the "
                                           f"motion model ({n} inliers)")
                        n = n_pnp
            tim["motion"] = time.perf_counter() - t
            if n < tcfg.min_motion_matches and self._lost_since == 0:
                t = time.perf_counter()
                frame.point_ids[:] = -1
                n = track_keyframe_pnp(frame, [self._ref_kf.id], m, seed, tcfg)
                tim["pnp"] = time.perf_counter() - t
            if (n < tcfg.min_inliers and 0 < self._lost_since <= tcfg.reloc_motion_steps
                    and self._velocity is not None):
                t = time.perf_counter()
                keep = (n, frame.T_c_w, frame.point_ids.copy())
                n_motion = relocalise_along_motion(frame, m, T_last, self._velocity, gap, tcfg,
                                                   self._active_keyframes())
                if n_motion > n:
                    n, along_motion = n_motion, True
                else:
                    n, frame.T_c_w, frame.point_ids = keep
                tim["reloc_motion"] = time.perf_counter() - t
            if n < 10 and self._lost_since > 0:
                t = time.perf_counter()
                frame.point_ids[:] = -1
                n = relocalise(frame, m, seed, tcfg, self._active_keyframes())
                tim["reloc"] = time.perf_counter() - t
                if n >= tcfg.reloc_min_inliers:
                    note = ""
                    if self._velocity is not None:  # how well the motion prior agrees: a check on aliasing
                        ratio, deg = motion_deviation(frame.T_c_w, T_last, self._velocity, gap, tcfg.reloc_motion_steps)
                        note = f"; {ratio:.2f} × the predicted travel and {deg:.0f}° from the motion prediction"
                    self.events.append(f"relocalised at frame {frame.index} ({n} inliers{note})")
            if frame.T_c_w is None:  # no stage estimated a pose: nothing to search the local map with
                n = 0
            if n >= 10:
                t = time.perf_counter()
                n = track_local_map(frame, m, tcfg)
                tim["local_map"] = time.perf_counter() - t
        tracked = n >= tcfg.min_inliers
        if tracked and along_motion:
            self.events.append(f"relocalised along the motion model at frame {frame.index} ({n} inliers)")
            self._frames_since_kf = cfg.max_frames_between_kf  # a keyframe: new points where the map is thin
        if tracked:
            if self._lost_since > 0:
                self.events.append(f"tracking resumed at frame {frame.index} after {self._lost_since} lost frames "
                                   f"({n} inliers)")
            if gap == 1 and self._lost_since == 0:
                self._velocity = frame.T_c_w @ np.linalg.inv(T_last)
            elif self._velocity is None and gap == 1:
                self._velocity = frame.T_c_w @ np.linalg.inv(T_last)
            self._lost_since = 0
            # reference keyframe: the most covisible one
            kfs, _ = m.covisible(frame.point_ids[frame.point_ids >= 0])
            if len(kfs):
                self._ref_kf = m.keyframes[int(kfs[0])]
            self._frames_since_kf += 1
            if self._need_keyframe(frame, n):
                if defer_mapping:
                    self._mapping_due = (frame, n)
                else:
                    t = time.perf_counter()
                    self._insert_keyframe(frame)
                    tim["mapping"] = time.perf_counter() - t
            self._record(frame, True, n)
            self._last_good = frame
        else:
            if self._lost_since == 0:
                self.events.append(f"tracking lost at frame {frame.index} ({n} inliers)")
            self._lost_since += 1
            V = self._velocity if self._velocity is not None else np.eye(4)
            frame.T_c_w = np.linalg.matrix_power(V, gap) @ T_last
            frame.point_ids[:] = -1
            self._record(frame, False, n)
            if 0 < cfg.new_map_after <= self._lost_since:
                self._start_new_map(frame)
        self._last = frame

    def _need_keyframe(self, frame: Frame, n_tracked: int) -> bool:
        m, cfg = self.map, self.cfg
        ref = self._ref_kf
        n_kf = len(self._active_keyframes())
        min_obs = 2 if n_kf <= 2 else 3
        pid = ref.point_ids[ref.point_ids >= 0]
        n_ref = int(((m.n_obs[pid] >= min_obs) & ~m.bad[pid]).sum())
        ratio = cfg.kf_ratio_depth if self.depth_mode else cfg.kf_ratio_mono
        if n_kf < 2:
            ratio = 0.4
        c1 = self._frames_since_kf >= cfg.max_frames_between_kf
        need_close = False
        if self.depth_mode:
            z = frame.feats.depth
            close = np.isfinite(z) & (z > 0) & (z < self._close_depth())
            tracked_close = int((close & (frame.point_ids >= 0)).sum())
            untracked_close = int((close & (frame.point_ids < 0)).sum())
            need_close = tracked_close < 100 and untracked_close > 70
        c2 = (n_tracked < ratio * n_ref or need_close) and n_tracked > 15
        if self._frames_since_kf <= cfg.mapper_busy_frames:  # the mapper is busy
            weak = self.depth_mode and (n_tracked < 0.25 * n_ref or need_close)
            return bool(weak and n_tracked > 15)
        return bool(c2 or (c1 and n_tracked > 15))

    def _insert_keyframe(self, frame: Frame) -> None:
        m, cfg = self.map, self.cfg
        kf = m.add_keyframe(frame.index, frame.T_c_w, frame.feats, frame.point_ids, self.active_map)
        self._ref_kf = kf
        self._frames_since_kf = 0
        if self.depth_mode:
            self._create_depth_points(kf)
        cull_points(m, kf, cfg.mapping)
        nbs, _ = m.covisible(kf.point_ids[kf.point_ids >= 0], exclude=kf.id)
        nbs = [int(i) for i in nbs[: cfg.mapping.n_neighbours]]
        triangulate_new_points(m, kf, nbs, cfg.mapping, stereo=self.depth_mode)
        fuse_into_neighbours(m, kf, nbs)
        local_bundle_adjustment(m, kf, cfg.mapping)
        if self._loop is not None and (cfg.loop_closing or self._next_map > 1):
            t = time.perf_counter()
            moving = self._active_keyframes()
            loop = self._loop.process(m, kf, cfg.seed + 104729 * kf.id)
            self.timings[-1]["loop"] = time.perf_counter() - t
            if loop is not None and loop.merged:
                self._after_merge(moving, loop)
                self.events.append(
                    f"map {loop.query_map} merged into map {loop.match_map} at frame {frame.index}: keyframe "
                    f"{loop.query} with keyframe {loop.match} (frame {m.keyframes[loop.match].frame}), {loop.inliers} "
                    f"inliers, {loop.matches} matches, scale {1.0 / loop.scale:.3f}")
            elif loop is not None:
                self.events.append(
                    f"loop closed at frame {frame.index}: keyframe {loop.query} with keyframe {loop.match} "
                    f"(frame {m.keyframes[loop.match].frame}), {loop.inliers} Sim(3) inliers, {loop.matches} "
                    f"matches, scale {loop.scale:.3f}, camera moved {loop.correction_m:.2f}")
        frame.T_c_w = kf.T_c_w.copy()
        frame.point_ids = kf.point_ids.copy()

    def _after_merge(self, moved: np.ndarray, loop: LoopClosure) -> None:
        """The keyframes ``moved`` were scaled by ``1 / loop.scale`` into ``loop.match_map``: so are the
        frame poses stored relative to them, and the motion model."""
        s = 1.0 / loop.scale
        if s != 1.0:
            in_moved = np.zeros(len(self.map.keyframes), bool)
            in_moved[moved] = True
            for i, (ref, T) in enumerate(self.frames_rel):
                if ref >= 0 and in_moved[ref]:
                    T = T.copy()
                    T[:3, 3] *= s
                    self.frames_rel[i] = (ref, T)
            if self._velocity is not None:
                self._velocity = self._velocity.copy()
                self._velocity[:3, 3] *= s
        self.active_map = loop.match_map

    # ------------------------------------------------------------------ results
    def result(self, timestamps: np.ndarray | None = None) -> SlamResult:
        """Trajectory (every frame), keyframes, map and timings so far."""
        self.finish_mapping()
        n = len(self.frames_rel)
        if n == 0:
            raise ValueError("no frames were processed")
        T_c_w = np.stack([T @ self.map.keyframes[r].T_c_w if r >= 0 else T for r, T in self.frames_rel])
        T_w_c = np.linalg.inv(T_c_w)
        ts = np.arange(n, dtype=np.float64) if timestamps is None else np.asarray(timestamps, np.float64)[:n]
        keys = sorted({k for t in self.timings for k in t})
        timings = {k: np.array([t.get(k, np.nan) for t in self.timings]) for k in keys}
        kfs = self.map.keyframes
        kf_maps = self.map.map_ids()
        frame_maps = np.array([kf_maps[r] if r >= 0 else -1 for r, _ in self.frames_rel], np.int64)
        return SlamResult(
            trajectory=Trajectory.from_matrices(ts, T_w_c),
            tracked=np.array(self.tracked, bool),
            keyframe_indices=np.array([k.frame for k in kfs], np.int64),
            keyframe_poses=np.stack([np.linalg.inv(k.T_c_w) for k in kfs]) if kfs else np.zeros((0, 4, 4)),
            map=self.map.point_cloud(),
            timings=timings,
            inliers=np.array(self.inliers, np.int64),
            events=list(self.events),
            loops=list(self._loop.loops) if self._loop is not None else [],
            frame_maps=frame_maps,
            keyframe_maps=kf_maps,
        )


PREFETCH_FRAMES = 3
"""Frames :func:`run_slam` reads and extracts ahead of tracking.  Local mapping after a keyframe takes
about as long as five extractions on KITTI, so a worker that stays several frames ahead keeps the
second core busy while the tracking thread maps, and the frames after a keyframe find their
features ready."""


def run_slam(
    frames: Iterable[Any],
    camera: Camera,
    config: SlamConfig = SlamConfig(),
    timestamps: np.ndarray | None = None,
    progress: bool = False,
    total: int | None = None,
    ignore: Iterable[np.ndarray | None] | None = None,
) -> SlamResult:
    """Run SLAM over ``frames`` and return every frame's pose, the keyframes and the map.

    ``frames`` yields images (mono), ``(left, right)`` pairs (stereo) or ``(image, depth)`` pairs
    (RGB-D); images are float ``[0, 1]`` HWC RGB / HW grey or uint8 grey.  ``ignore`` yields, per
    frame, a ``(H, W)`` bool mask of the left image where no keypoint is extracted (or None), e.g.
    the regions a privacy filter filled in.
    """
    cv2.setRNGSeed(config.seed)
    slam = Slam(camera, config)
    items = iter(frames)
    masks = iter(ignore) if ignore is not None else None
    end = object()

    failed = False

    def features(k: int):
        """Frame ``k``'s features (worker thread): read the frame and its mask, extract.  After a frame
        that could not be read or extracted, nothing more is read."""
        nonlocal failed
        if failed:
            return end
        try:
            item = next(items, end)
            if item is end:
                return end
            mask = next(masks, False) if masks is not None else None
            if mask is False:
                raise ValueError(f"ignore has fewer masks than frames (none for frame {k})")
            if config.mode == "mono":
                return slam.features(k, item, ignore=mask)
            first, second = item
            if config.mode == "stereo":
                return slam.features(k, first, right=second, ignore=mask)
            return slam.features(k, first, depth=second, ignore=mask)
        except BaseException:
            failed = True
            raise

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"slam ({config.mode})", unit="frame")
    # One worker reads and extracts the next PREFETCH_FRAMES frames, in order, while this thread tracks
    # and maps frame k: extraction does not depend on the map, so the results are those of the plain
    # loop (only the order of work on the two cores changes).
    try:
        with ThreadPoolExecutor(1, thread_name_prefix="slam-features") as pool:
            pending = collections.deque(pool.submit(features, k) for k in range(PREFETCH_FRAMES))
            k = PREFETCH_FRAMES
            while (out := pending.popleft().result()) is not end:
                pending.append(pool.submit(features, k))
                k += 1
                slam.track_frame(*out)
                if bar is not None:
                    bar.update()
                    bar.set_postfix(kf=len(slam.map.keyframes), pts=int((~slam.map.bad).sum()),
                                    lost=int(len(slam.tracked) - sum(slam.tracked)))
    finally:
        if bar is not None:
            bar.close()
    return slam.result(timestamps)
