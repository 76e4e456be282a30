"""Localise a camera against a line cloud (issue 19 item 3): 2D keypoints matched to 3D map lines.

A keypoint ``u`` of the query image matched to map line ``(d, m)`` says that the camera ray through
``u`` meets the line.  Seen as rays, this is generalized relative pose (Pless, CVPR 2003; Speciale et
al., CVPR 2019): the map lines are the rays of a generalized camera, the query is a pinhole camera,
and 6 correspondences determine the pose.

1. **Minimal solver**: PoseLib's ``gen_relpose_6pt`` (Stewénius et al.'s 6-point generalized
   relative pose).  PoseLib filters its solutions by cheirality (the point must lie *ahead* on both
   rays), while a map line has no forward direction; each line is therefore passed as the ray from
   ``a − L d`` along ``d`` (``a`` its closest point to the origin, ``L`` = 1000 × the map's extent), so
   every point of the line within the map lies ahead of it.
2. **LO-RANSAC** (Chum et al., 2003) over 6-samples: a pose's inliers are the correspondences whose
   keypoint lies within ``threshold`` pixels of the image of its line; each new best pose is refined
   on its inliers (local optimisation), and the final pose on the final inliers.
3. **Refinement** on the project's least-squares core (:func:`~privslam_jax.solvers.levenberg_marquardt`,
   Huber loss, pose as ``jaxlie.SE3``): the residual of keypoint ``u`` and line ``(d, m)`` is the signed
   pixel distance from ``u`` to the line's image ``l = K⁻ᵀ m_c`` (``m_c = R m + t × R d``, the line's
   moment in the camera frame: the projected line in normalised coordinates).

4. **Matching** (:func:`localize_image`): a query image's ORB features (the SLAM front end's
   extractor, :func:`~privslam_jax.slam.frontend.extract_orb`) are matched to the descriptors that
   travel with the lines (``privslam lift`` keeps a SLAM map's ORB descriptors, row ``i`` for line
   ``i``): brute-force Hamming, Lowe's ratio test, one keypoint per line.  Descriptors are what a
   line cloud must publish to be localised against, and they are an attack surface of their own
   (feature inversion, Pittaluga et al., CVPR 2019); the line cloud hides only the geometry.

A sphere cloud cannot be localised against this way: all its lines meet at the centroid, so the map is
a central camera and the query's distance from the centroid is not observable (the sphere-cloud paper
takes it from a depth sensor); :func:`localize_against_lines` refuses it.

:func:`localize_against_points` is the baseline on the unprotected map: PoseLib's P3P LO-RANSAC with
its own refinement, on the same correspondences.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float

from privslam_jax.solvers import DenseSystem, LMParams, dense_damped_solve, huber_rho, huber_weight, levenberg_marquardt
from privslam_jax.types import LineCloud

__all__ = ["Localization", "localize_against_lines", "localize_against_points", "localize_image", "match_to_map",
           "line_reprojection_errors"]


@dataclasses.dataclass(frozen=True)
class Localization:
    """A localisation: ``T_c_w`` (world → camera) and its inliers; ``success`` false when no pose had
    ``min_inliers`` inliers (then the pose is the identity and means nothing)."""

    T_c_w: np.ndarray
    """``(4, 4)`` world → camera."""
    inliers: np.ndarray
    """``(M,)`` bool."""
    iterations: int
    success: bool


def _pixel_lines(T: jaxlie.SE3, d: Float[Array, "M 3"], m: Float[Array, "M 3"], K: Float[Array, "3 3"]) -> Float[Array, "M 3"]:
    """Image lines (pixel coordinates, homogeneous) of the 3D lines ``(d, m)`` under ``T = T_c_w``."""
    R, t = T.rotation().as_matrix(), T.translation()
    dc = d @ R.T
    mc = m @ R.T + jnp.cross(t[None, :], dc)
    return mc @ jnp.linalg.inv(K)  # l_px = K^-T m_c, as rows


def _signed_distances(T: jaxlie.SE3, uv, d, m, K) -> Float[Array, " M"]:
    lp = _pixel_lines(T, d, m, K)
    return (lp[:, 0] * uv[:, 0] + lp[:, 1] * uv[:, 1] + lp[:, 2]) / jnp.sqrt(lp[:, 0] ** 2 + lp[:, 1] ** 2 + 1e-30)


def line_reprojection_errors(T_c_w: np.ndarray, uv: np.ndarray, lines: LineCloud, K: np.ndarray) -> np.ndarray:
    """Pixel distance from each keypoint to the image of its line (numpy, float64)."""
    d = np.asarray(lines.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    m = np.asarray(lines.moments, np.float64)
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    dc = d @ R.T
    mc = m @ R.T + np.cross(t[None, :], dc)
    lp = mc @ np.linalg.inv(K)
    return np.abs(np.sum(lp[:, :2] * uv, axis=1) + lp[:, 2]) / np.linalg.norm(lp[:, :2], axis=1)


@jax.jit
def _refine(T0: jaxlie.SE3, uv, d, m, K, weights, delta):
    """Huber LM on the signed pixel distances of the correspondences with ``weights`` 1."""

    def cost(T):
        r = _signed_distances(T, uv, d, m, K)
        return 0.5 * jnp.sum(weights * huber_rho(r * r, delta))

    def linearise(T):
        r = _signed_distances(T, uv, d, m, K)
        J = jax.jacfwd(lambda xi: _signed_distances(jaxlie.SE3.exp(xi) @ T, uv, d, m, K))(jnp.zeros(6, uv.dtype))
        w = weights * huber_weight(r * r, delta)
        H = jnp.einsum("n,ni,nj->ij", w, J, J)
        g = jax.grad(lambda xi: cost(jaxlie.SE3.exp(xi) @ T))(jnp.zeros(6, uv.dtype))
        return DenseSystem(H=H, g=g, cost=cost(T))

    params = LMParams.of(uv.dtype, 30, 1e-4, 1e-10, step_tolerance=1e-10)
    T, _, summary = levenberg_marquardt(T0, linearise, dense_damped_solve, cost, lambda T, xi: jaxlie.SE3.exp(xi) @ T,
                                        params)
    return T, summary


def _to_se3(R: np.ndarray, t: np.ndarray) -> jaxlie.SE3:
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(R)), jnp.asarray(t))


def localize_against_lines(
    uv: Float[np.ndarray, "M 2"], lines: LineCloud, K: Float[np.ndarray, "3 3"], *, threshold: float = 2.0,
    max_iterations: int = 2000, confidence: float = 0.9999, min_inliers: int = 12, seed: int = 0,
) -> Localization:
    """Pose of the camera that saw keypoints ``uv`` (pixels) of map lines ``lines`` (line ``j`` matched to
    keypoint ``j``), intrinsics ``K`` (module docstring).  ``threshold``: inlier distance in pixels."""
    import poselib

    uv = np.asarray(uv, np.float64)
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    K = np.asarray(K, np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or d.shape != (len(uv), 3) or m.shape != d.shape or K.shape != (3, 3):
        raise ValueError(f"need keypoints (M, 2) and M lines (M, 3), K (3, 3); got {uv.shape}, {d.shape}, {m.shape}, {K.shape}")
    if len(uv) < 6:
        raise ValueError(f"localisation needs at least 6 correspondences, got {len(uv)}")
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(d)) and np.all(np.isfinite(m)) and np.all(np.isfinite(K))):
        raise ValueError("keypoints, lines or intrinsics contain NaN or inf")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    lines64 = LineCloud(directions=d, moments=m)
    a = np.cross(d, m)
    # one point shared by most lines (a sphere cloud)? the least-squares point nearest all lines, O(M)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    common = np.linalg.lstsq(P.sum(0), np.einsum("nij,nj->i", P, a), rcond=None)[0]
    through = np.linalg.norm(np.cross(common - a, d), axis=1) <= 1e-6 * (1.0 + float(np.abs(a).max()))
    if np.mean(through) > 0.5:
        raise ValueError(f"{np.mean(through):.0%} of the lines meet at one point (a sphere cloud): seen from one "
                         "point, the map fixes the camera's rotation and the direction of its position, not its distance; "
                         "localising against it needs the distance from elsewhere (e.g. a depth sensor)")
    far = 1e3 * (1.0 + float(np.abs(a).max()))
    origins = a - far * d
    rays = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    zero = np.zeros(3)
    rng = np.random.default_rng(seed)
    best_T, best_in, it, needed = None, np.zeros(len(uv), bool), 0, max_iterations
    with jax.enable_x64(True):
        # padded to a power of two with weight-0 rows (a line through the origin along z): one compiled
        # refinement per size bucket, not per correspondence count
        size = 1 << max(6, int(np.ceil(np.log2(len(uv)))))
        pad = size - len(uv)
        args = tuple(jnp.asarray(x) for x in (np.concatenate([uv, np.zeros((pad, 2))]),
                                              np.concatenate([d, np.tile([0.0, 0.0, 1.0], (pad, 1))]),
                                              np.concatenate([m, np.zeros((pad, 3))]), K))

        def refine(T: np.ndarray, inl: np.ndarray) -> np.ndarray:
            w = np.zeros(len(args[0]))
            w[: len(inl)] = inl
            Tr, _ = _refine(_to_se3(T[:3, :3], T[:3, 3]), *args, jnp.asarray(w), jnp.asarray(threshold))
            return np.asarray(Tr.as_matrix())

        while it < min(needed, max_iterations):
            it += 1
            s = rng.choice(len(uv), 6, replace=False)
            for pose in poselib.gen_relpose_6pt(origins[s], d[s], np.repeat(zero[None], 6, 0), rays[s]):
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = pose.R, pose.t
                inl = line_reprojection_errors(T, uv, lines64, K) < threshold
                if inl.sum() > best_in.sum() and inl.sum() >= 6:
                    T = refine(T, inl)  # local optimisation of a new best
                    inl2 = line_reprojection_errors(T, uv, lines64, K) < threshold
                    best_T, best_in = (T, inl2) if inl2.sum() >= inl.sum() else (T, inl)
                    w = best_in.mean()
                    needed = int(np.ceil(np.log(1 - confidence) / np.log(max(1e-12, 1 - w**6)))) if w < 1 else 1
        if best_T is None or best_in.sum() < min_inliers:
            return Localization(T_c_w=np.eye(4), inliers=np.zeros(len(uv), bool), iterations=it, success=False)
        best_T = refine(best_T, best_in)
    inl = line_reprojection_errors(best_T, uv, lines64, K) < threshold
    return Localization(T_c_w=best_T, inliers=inl, iterations=it, success=bool(inl.sum() >= min_inliers))


def localize_against_points(
    uv: Float[np.ndarray, "M 2"], points: Float[np.ndarray, "M 3"], K: Float[np.ndarray, "3 3"], *,
    threshold: float = 2.0, min_inliers: int = 12,
) -> Localization:
    """The baseline on the unprotected map: PoseLib's P3P LO-RANSAC + refinement on 2D–3D points."""
    import poselib

    K = np.asarray(K, np.float64)
    h = 2 * max(K[0, 2], K[1, 2])
    cam = {"model": "PINHOLE", "width": int(h), "height": int(h), "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}
    pose, info = poselib.estimate_absolute_pose(np.asarray(uv, np.float64), np.asarray(points, np.float64), cam,
                                                {"max_reproj_error": threshold}, {})
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = pose.R, pose.t
    inl = np.asarray(info["inliers"], bool)
    return Localization(T_c_w=T, inliers=inl, iterations=int(info["iterations"]), success=bool(inl.sum() >= min_inliers))


def match_to_map(query: np.ndarray, map_descriptors: np.ndarray, *, ratio: float = 0.8, max_distance: int = 64
                 ) -> np.ndarray:
    """``(M, 2)`` pairs ``(keypoint, map row)``: each query descriptor's nearest map descriptor (Hamming) if it
    is within ``max_distance`` bits and closer than ``ratio`` × the second nearest; one keypoint per map row."""
    from privslam_jax.slam.frontend import ratio_matches

    q, md = np.asarray(query), np.asarray(map_descriptors)
    if q.dtype != np.uint8 or md.dtype != np.uint8 or q.ndim != 2 or md.ndim != 2 or q.shape[1] != md.shape[1]:
        raise ValueError(f"descriptors must be uint8 (N, D) with one D; got {q.dtype} {q.shape} and {md.dtype} {md.shape}")
    pairs = ratio_matches(q, md, ratio, max_distance)
    return pairs[np.argsort(pairs[:, 0], kind="stable")]


def localize_image(
    image: np.ndarray, lines: LineCloud, descriptors: np.ndarray, K: Float[np.ndarray, "3 3"], *,
    n_features: int = 2000, ratio: float = 0.8, max_distance: int = 64, **ransac,
) -> tuple[Localization, np.ndarray, np.ndarray]:
    """Localise one image against a line cloud whose line ``i`` carries ``descriptors[i]``.

    Returns ``(localization, uv, line_ids)``: the matched keypoints (pixels) and their lines
    (``localization.inliers`` indexes them).  ``ransac``: keyword arguments of :func:`localize_against_lines`.
    Fewer than 6 matches give ``success=False`` (nothing to solve), not an error: the image may show
    another place.
    """
    from privslam_jax.slam.frontend import OrbConfig, extract_orb, to_gray_u8

    desc = np.asarray(descriptors)
    if len(desc) != len(lines):
        raise ValueError(f"{len(desc)} descriptors for {len(lines)} lines")
    feats = extract_orb(to_gray_u8(image), OrbConfig(n_features=n_features))
    pairs = match_to_map(feats.desc, desc, ratio=ratio, max_distance=max_distance)
    uv, ids = feats.uv[pairs[:, 0]], pairs[:, 1]
    if len(ids) < max(6, ransac.get("min_inliers", 12)):
        return Localization(T_c_w=np.eye(4), inliers=np.zeros(len(ids), bool), iterations=0, success=False), uv, ids
    sub = LineCloud(directions=np.asarray(lines.directions, np.float64)[ids], moments=np.asarray(lines.moments, np.float64)[ids])
    return localize_against_lines(uv, sub, K, **ransac), uv, ids
