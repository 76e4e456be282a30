"""Map initialisation: two-view (monocular) and single-view with depth (stereo / RGB-D).

Monocular (after ORB-SLAM's ``Initializer``, with OpenCV's five-point solver instead of ORB-SLAM's
parallel H/F model selection — a deliberate simplification; a dominant plane is caught by the
parallax and triangulation-count checks instead):

1. match reference and current keypoints (Hamming ≤ TH_LOW, ratio 0.9, rotation consistency, flow
   shorter than ``max_flow`` px);
2. ``cv2.findEssentialMat`` (RANSAC, 1 px, p = 0.999) on correspondences shuffled by the run's
   seed, then ``cv2.recoverPose`` (cheirality);
3. triangulate the inliers; keep points in front of both cameras with ``χ² < 5.991·σ²`` and
   parallax; accept when at least ``min_points`` survive and the median parallax exceeds
   ``min_parallax_deg`` (ORB-SLAM: 50 points, 1°);
4. the caller runs a full BA and scales the map to median depth 1.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from privslam_jax.slam.frontend import TH_LOW, Features, match_descriptors
from privslam_jax.slam.mapping import CHI2_MONO, _triangulate, project
from privslam_jax.types import Camera

__all__ = ["InitConfig", "TwoViewResult", "initialize_two_view"]


@dataclasses.dataclass(frozen=True)
class InitConfig:
    """Monocular initialisation settings."""

    min_matches: int = 100
    """Matches needed to attempt the two-view geometry."""
    min_points: int = 80
    """Triangulated points needed to accept."""
    min_parallax_deg: float = 1.0
    """Median parallax needed to accept, degrees."""
    max_flow: float = 200.0
    """Largest keypoint displacement between the two views, pixels."""
    ransac_threshold: float = 1.0
    """Essential-matrix RANSAC threshold, pixels."""


@dataclasses.dataclass
class TwoViewResult:
    """A successful two-view initialisation (reference camera at the origin)."""

    T_cur_ref: np.ndarray
    """``(4, 4)`` pose of the current camera w.r.t. the reference (unit baseline)."""
    ref_kp: np.ndarray
    """``(M,)`` keypoint indices in the reference."""
    cur_kp: np.ndarray
    """``(M,)`` keypoint indices in the current frame."""
    xyz: np.ndarray
    """``(M, 3)`` triangulated points in the reference frame."""
    parallax_deg: float
    """Median parallax."""


def initialize_two_view(ref: Features, cur: Features, camera: Camera, seed: int,
                        cfg: InitConfig = InitConfig(), scale_factor: float = 1.2) -> TwoViewResult | None:
    """Two-view monocular initialisation; ``None`` when the views do not qualify."""
    pairs = match_descriptors(ref, cur, ratio=0.9, max_dist=TH_LOW, check_orientation=True)
    if len(pairs):
        flow = np.linalg.norm(ref.uv[pairs[:, 0]] - cur.uv[pairs[:, 1]], axis=1)
        pairs = pairs[flow < cfg.max_flow]
    if len(pairs) < cfg.min_matches:
        return None
    perm = np.random.default_rng(seed).permutation(len(pairs))
    pairs = pairs[perm]
    x1, x2 = ref.uv[pairs[:, 0]], cur.uv[pairs[:, 1]]
    K = np.asarray(camera.K, np.float64)
    try:
        E, mask = cv2.findEssentialMat(x1, x2, K, method=cv2.RANSAC, prob=0.999, threshold=cfg.ransac_threshold)
    except cv2.error:  # a degenerate sample (e.g. near-identical points) fails the five-point solver's
        return None    # polynomial root finding: these two views do not qualify
    if E is None or E.shape != (3, 3):
        return None
    _, R, t, mask2 = cv2.recoverPose(E, x1, x2, K, mask=mask.copy())
    inl = mask2.ravel() > 0
    if inl.sum() < cfg.min_points:
        return None
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t.ravel()
    pairs, x1, x2 = pairs[inl], x1[inl], x2[inl]
    X = _triangulate(np.eye(4), T, x1, x2, K)
    uv1, z1 = project(np.eye(4), X, camera)
    uv2, z2 = project(T, X, camera)
    s1 = scale_factor ** (2.0 * ref.octave[pairs[:, 0]])
    s2 = scale_factor ** (2.0 * cur.octave[pairs[:, 1]])
    C2 = -R.T @ t.ravel()
    r1, r2 = X, X - C2
    cosp = (r1 * r2).sum(1) / np.maximum(np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1), 1e-12)
    good = (z1 > 0) & (z2 > 0) & np.isfinite(X).all(1)
    good &= (((uv1 - x1) ** 2).sum(1) < CHI2_MONO * s1) & (((uv2 - x2) ** 2).sum(1) < CHI2_MONO * s2)
    good &= cosp < 0.99998
    if good.sum() < cfg.min_points:
        return None
    parallax = float(np.degrees(np.arccos(np.clip(np.median(cosp[good]), -1, 1))))
    if parallax < cfg.min_parallax_deg:
        return None
    order = np.argsort(pairs[good, 0], kind="stable")
    return TwoViewResult(T, pairs[good, 0][order], pairs[good, 1][order], X[good][order], parallax)
