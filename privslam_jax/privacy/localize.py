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
   on its inliers (local optimisation), and the final pose is refined and its inliers re-classified in
   turn until neither changes (at most 10 rounds): the returned pose minimises the robust cost over the
   returned inliers.  (One refinement on the inliers of the pose before it was not a fixed point: the
   re-classified inliers moved the optimum by up to 6 cm on the synthetic map.)
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

5. **With query depth** (``depth=``: the metric z of each keypoint, from a depth sensor or stereo): the
   keypoints become 3D points ``X`` of the query camera, and the pose is the one that puts each ``X`` on
   its map line: generalized *absolute* pose, the map lines again the rays of a generalized camera and
   the query points its scene (PoseLib's ``gp3p``, 3-point samples, the same far-back ray origins; it
   returns camera → world).  Inliers and refinement use the point-to-line distance
   ``‖(R X + t − a) × d‖`` scaled by ``f / z`` — the pixels it spans at the point's depth — so the same
   ``threshold`` applies.  This is how the sphere-cloud paper localises (Moon et al., "Depth-guided
   privacy-preserving visual localization using 3D sphere clouds", BMVC 2024: absolute depth from an
   on-device time-of-flight sensor).

An axial cloud (:func:`~privslam_jax.privacy.lift.axial_lift`) can be localised against from keypoints
alone, but only up to a two-fold symmetry: the half-turn about its axis maps every one of its lines onto
itself, so a pose and its half-turned twin (180° apart in heading, mirrored across the axis) explain every
correspondence equally well.  A heading prior good to ±90° tells them apart (``rotation_prior=``: a
compass, or the rotation of the map keyframe that image retrieval returns); :func:`localize_against_lines`
refuses an axial cloud without one (more than half of the lines perpendicular to one line and meeting
it), as it refuses a sphere cloud without depth.

A sphere cloud cannot be localised against from keypoints alone: all its lines meet at the centroid, so
the map is a central camera and the query's distance from the centroid is not observable;
:func:`localize_against_lines` refuses it unless ``depth`` is given.

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
           "line_reprojection_errors", "point_line_errors", "keypoint_depths"]


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


def _point_line_offsets(T_w_c: jaxlie.SE3, X, d, a, scale) -> Float[Array, "M 3"]:
    """``(R X + t − a) × d`` per correspondence, times ``scale`` (``f / z``): its norm is the distance of the
    query point from its line in pixels at the point's depth."""
    Xw = X @ T_w_c.rotation().as_matrix().T + T_w_c.translation()[None, :]
    return jnp.cross(Xw - a, d) * scale[:, None]


def _huber_lm(T0: jaxlie.SE3, residuals, weights, delta):
    """Huber LM over a pose (left increments ``exp(ξ) T``) on ``residuals(T)`` (``(M, k)``: one row per
    correspondence, Huber on its norm), counting the rows with ``weights`` 1."""

    def cost(T):
        r = residuals(T)
        return 0.5 * jnp.sum(weights * huber_rho(jnp.sum(r * r, axis=1), delta))

    def linearise(T):
        r = residuals(T)
        zero = jnp.zeros(6, r.dtype)
        J = jax.jacfwd(lambda xi: residuals(jaxlie.SE3.exp(xi) @ T))(zero)
        w = weights * huber_weight(jnp.sum(r * r, axis=1), delta)
        H = jnp.einsum("n,nki,nkj->ij", w, J, J)
        g = jax.grad(lambda xi: cost(jaxlie.SE3.exp(xi) @ T))(zero)
        return DenseSystem(H=H, g=g, cost=cost(T))

    params = LMParams.of(T0.wxyz_xyz.dtype, 30, 1e-4, 1e-10, step_tolerance=1e-10)
    T, _, summary = levenberg_marquardt(T0, linearise, dense_damped_solve, cost, lambda T, xi: jaxlie.SE3.exp(xi) @ T,
                                        params)
    return T, summary


@jax.jit
def _refine(T0: jaxlie.SE3, uv, d, m, K, weights, delta):
    """Huber LM on the signed pixel distances of the correspondences with ``weights`` 1 (``T = T_c_w``)."""
    return _huber_lm(T0, lambda T: _signed_distances(T, uv, d, m, K)[:, None], weights, delta)


@jax.jit
def _refine_with_depth(T0: jaxlie.SE3, X, d, a, scale, weights, delta):
    """Huber LM on the point-to-line offsets of the correspondences with ``weights`` 1 (``T = T_w_c``)."""
    return _huber_lm(T0, lambda T: _point_line_offsets(T, X, d, a, scale), weights, delta)


def _to_se3(R: np.ndarray, t: np.ndarray) -> jaxlie.SE3:
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(R)), jnp.asarray(t))


def _matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def point_line_errors(T_c_w: np.ndarray, X: np.ndarray, lines: LineCloud, f: float) -> np.ndarray:
    """Distance of each query point ``X`` (camera frame, ``(M, 3)``) from its line under ``T_c_w``, in pixels
    at the point's depth: ``f · ‖(X_w − a) × d‖ / z`` (numpy, float64)."""
    d = np.asarray(lines.directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    a = np.cross(d, np.asarray(lines.moments, np.float64))
    R, t = T_c_w[:3, :3], T_c_w[:3, 3]
    Xw = (X - t) @ R  # Rᵀ (X − t), row-wise
    return f * np.linalg.norm(np.cross(Xw - a, d), axis=1) / X[:, 2]


def _lo_ransac(n: int, size: int, solve, errors, refine, threshold: float, max_iterations: int, confidence: float,
               rng: np.random.Generator) -> tuple[np.ndarray | None, np.ndarray, int]:
    """LO-RANSAC (Chum et al., 2003) over ``size``-samples of ``n`` correspondences: ``solve(sample)`` gives
    candidate ``T_c_w``, ``errors(T)`` the ``(n,)`` inlier distances, ``refine(T, inliers)`` the local
    optimisation of each new best.  Returns ``(T, inliers, iterations)`` (``T`` None when nothing had
    ``size`` inliers)."""
    best_T, best_in, it, needed = None, np.zeros(n, bool), 0, max_iterations
    while it < min(needed, max_iterations):
        it += 1
        for T in solve(rng.choice(n, size, replace=False)):
            inl = errors(T) < threshold
            if inl.sum() > best_in.sum() and inl.sum() >= size:
                T = refine(T, inl)
                inl2 = errors(T) < threshold
                best_T, best_in = (T, inl2) if inl2.sum() >= inl.sum() else (T, inl)
                w = best_in.mean()
                needed = int(np.ceil(np.log(1 - confidence) / np.log(max(1e-12, 1 - w**size)))) if w < 1 else 1
    return best_T, best_in, it


def _is_rotation(R: np.ndarray) -> bool:
    """Whether ``R`` is a finite ``(3, 3)`` rotation matrix: ``R Rᵀ = I`` (to 1e-6) and ``det R = +1``."""
    R = np.asarray(R, np.float64)
    return bool(R.shape == (3, 3) and np.all(np.isfinite(R)) and np.allclose(R @ R.T, np.eye(3), atol=1e-6)
                and np.linalg.det(R) > 0)


def _agreeing(solve, R_prior: np.ndarray, max_angle: float):
    """``solve`` keeping only the candidate ``T_c_w`` whose rotation is within ``max_angle`` degrees of
    ``R_prior``: ``(tr(R R_priorᵀ) − 1) / 2 ≥ cos(max_angle)``."""
    cos_max = np.cos(np.radians(max_angle))
    return lambda s: [T for T in solve(s) if (np.trace(T[:3, :3] @ R_prior.T) - 1) / 2 >= cos_max]


def _axial_share(d: np.ndarray, a: np.ndarray) -> float:
    """Share of the lines (unit directions ``d``, closest points ``a``) perpendicular to one common line and
    meeting it — an axial cloud's axis — in O(M): ``u``, the direction most nearly perpendicular to every
    line, is the axis's; in the plane normal to ``u`` the perpendicular lines are 2D lines, and the axis is
    the least-squares point nearest them all."""
    u = np.linalg.eigh(d.T @ d)[1][:, 0]
    tol = 1e-6 * (1.0 + float(np.abs(a).max()))
    perp = np.abs(d @ u) <= 1e-6
    if perp.sum() < 2:
        return 0.0
    ap = a[perp] - np.outer(a[perp] @ u, u)
    P = (np.eye(3) - np.outer(u, u))[None] - d[perp, :, None] * d[perp, None, :]
    # the sum is singular along u: pin the axis point's u-component to 0
    axis = np.linalg.lstsq(P.sum(0) + len(P) * np.outer(u, u), np.einsum("nij,nj->i", P, ap), rcond=None)[0]
    return float(np.sum(np.linalg.norm(np.cross(axis - ap, d[perp]), axis=1) <= tol) / len(d))


def _padded(n: int) -> int:
    """Rows of a padded refinement problem: one compiled program per power-of-two bucket (≥ 64), not per
    correspondence count."""
    return 1 << max(6, int(np.ceil(np.log2(n))))


def localize_against_lines(
    uv: Float[np.ndarray, "M 2"], lines: LineCloud, K: Float[np.ndarray, "3 3"], *,
    depth: np.ndarray | None = None, threshold: float = 2.0, max_iterations: int = 2000,
    confidence: float = 0.9999, min_inliers: int = 12, seed: int = 0,
    rotation_prior: np.ndarray | None = None, max_prior_angle: float = 90.0,
) -> Localization:
    """Pose of the camera that saw keypoints ``uv`` (pixels) of map lines ``lines`` (line ``j`` matched to
    keypoint ``j``), intrinsics ``K`` (module docstring).  ``depth``: ``(M,)`` the keypoints' metric z
    (module docstring, 5.; needed for sphere clouds).  ``threshold``: inlier distance in pixels; with
    depth, a depth error ``σ_z`` moves a point by up to ``f σ_z / z`` pixels (1 % noise: ``0.01 f``), so
    noisy depth needs a larger threshold.  ``rotation_prior``: a rough ``R_c_w`` ``(3, 3)`` (a compass, the
    retrieved keyframe's); candidate poses more than ``max_prior_angle`` degrees from it are discarded —
    needed for axial clouds, which the half-turn about their axis maps onto themselves (module docstring)."""
    import poselib

    uv = np.asarray(uv, np.float64)
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    K = np.asarray(K, np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or d.shape != (len(uv), 3) or m.shape != d.shape or K.shape != (3, 3):
        raise ValueError(f"need keypoints (M, 2) and M lines (M, 3), K (3, 3); got {uv.shape}, {d.shape}, {m.shape}, {K.shape}")
    size = 6 if depth is None else 3
    if len(uv) < size:
        raise ValueError(f"localisation needs at least {size} correspondences, got {len(uv)}")
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(d)) and np.all(np.isfinite(m)) and np.all(np.isfinite(K))):
        raise ValueError("keypoints, lines or intrinsics contain NaN or inf")
    if depth is not None:
        depth = np.asarray(depth, np.float64)
        if depth.shape != (len(uv),) or not np.all(np.isfinite(depth)) or np.any(depth <= 0):
            raise ValueError(f"depth must be ({len(uv)},), finite and > 0 (drop keypoints without depth), got "
                             f"{depth.shape} with {int(np.sum(~(np.isfinite(depth) & (depth > 0))))} bad values")
    if rotation_prior is not None:
        rotation_prior = np.asarray(rotation_prior, np.float64)
        if not _is_rotation(rotation_prior):
            raise ValueError(f"rotation_prior must be a finite (3, 3) rotation matrix (orthonormal, det +1), got "
                             f"shape {rotation_prior.shape}")
        if not 0.0 < max_prior_angle <= 180.0:
            raise ValueError(f"max_prior_angle must be in (0, 180] degrees, got {max_prior_angle}")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    lines64 = LineCloud(directions=d, moments=m)
    a = np.cross(d, m)
    if depth is None:
        # one point shared by most lines (a sphere cloud)? the least-squares point nearest all lines, O(M)
        P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        common = np.linalg.lstsq(P.sum(0), np.einsum("nij,nj->i", P, a), rcond=None)[0]
        through = np.linalg.norm(np.cross(common - a, d), axis=1) <= 1e-6 * (1.0 + float(np.abs(a).max()))
        if np.mean(through) > 0.5:
            raise ValueError(f"{np.mean(through):.0%} of the lines meet at one point (a sphere cloud): seen from one "
                             "point, the map fixes the camera's rotation and the direction of its position, not its "
                             "distance; localising against it needs the keypoints' depth (depth=, from a depth sensor)")
    axial = 0.0 if rotation_prior is not None else _axial_share(d, a)
    if axial > 0.5:
        raise ValueError(f"{axial:.0%} of the lines are perpendicular to one line and meet it (an axial "
                         "cloud): the half-turn about that axis maps the cloud onto itself, so every pose has a twin "
                         "turned 180 degrees that fits as well; localising against it needs a heading prior "
                         "(rotation_prior=, good to 90 degrees)")
    # every point of a line within the map lies ahead of its ray (module docstring, 1.)
    far = 1e3 * (1.0 + float(np.abs(a).max()))
    origins = a - far * d
    rays = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ np.linalg.inv(K).T
    pad = _padded(len(uv)) - len(uv)
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        if depth is None:
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            zeros = np.zeros((6, 3))
            # weight-0 padding rows: a line through the origin along z
            args = tuple(jnp.asarray(x) for x in (np.concatenate([uv, np.zeros((pad, 2))]),
                                                  np.concatenate([d, np.tile([0.0, 0.0, 1.0], (pad, 1))]),
                                                  np.concatenate([m, np.zeros((pad, 3))]), K))

            def solve(s):
                return [_matrix(p.R, p.t) for p in poselib.gen_relpose_6pt(origins[s], d[s], zeros, rays[s])]

            def errors(T):
                return line_reprojection_errors(T, uv, lines64, K)

            def refine(T, inl):
                w = np.zeros(len(args[0]))
                w[: len(inl)] = inl
                Tr, _ = _refine(_to_se3(T[:3, :3], T[:3, 3]), *args, jnp.asarray(w), jnp.asarray(threshold))
                return np.asarray(Tr.as_matrix())
        else:
            X = rays * depth[:, None]  # the keypoints in the query camera (z = depth)
            f = 0.5 * (K[0, 0] + K[1, 1])
            args = tuple(jnp.asarray(x) for x in (np.concatenate([X, np.tile([0.0, 0.0, 1.0], (pad, 1))]),
                                                  np.concatenate([d, np.tile([0.0, 0.0, 1.0], (pad, 1))]),
                                                  np.concatenate([a, np.zeros((pad, 3))]),
                                                  np.concatenate([f / depth, np.zeros(pad)])))

            def solve(s):  # gp3p: origins + λ d = R X + t, i.e. camera → world
                return [np.linalg.inv(_matrix(p.R, p.t)) for p in poselib.gp3p(origins[s], d[s], X[s])]

            def errors(T):
                return point_line_errors(T, X, lines64, f)

            def refine(T, inl):
                w = np.zeros(len(args[0]))
                w[: len(inl)] = inl
                T = np.linalg.inv(T)
                Tr, _ = _refine_with_depth(_to_se3(T[:3, :3], T[:3, 3]), *args, jnp.asarray(w), jnp.asarray(threshold))
                return np.linalg.inv(np.asarray(Tr.as_matrix()))

        if rotation_prior is not None:
            solve = _agreeing(solve, rotation_prior, max_prior_angle)
        best_T, best_in, it = _lo_ransac(len(uv), size, solve, errors, refine, threshold, max_iterations, confidence, rng)
        if best_T is None or best_in.sum() < min_inliers:
            return Localization(T_c_w=np.eye(4), inliers=np.zeros(len(uv), bool), iterations=it, success=False)
        for _ in range(10):  # refine and re-classify to a fixed point of both
            best_T = refine(best_T, best_in)
            inl = errors(best_T) < threshold
            if (inl == best_in).all():
                break
            best_in = inl
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
    T = _matrix(pose.R, pose.t)
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


def keypoint_depths(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``(M,)`` float64: the ``(H, W)`` depth map at each keypoint's nearest pixel (0 or non-finite where the
    map has no depth; keypoints off the image take the nearest border pixel)."""
    depth = np.asarray(depth, np.float64)
    h, w = depth.shape
    px = np.clip(np.rint(np.asarray(uv)).astype(np.int64), 0, [w - 1, h - 1])
    return depth[px[:, 1], px[:, 0]]


def localize_image(
    image: np.ndarray, lines: LineCloud, descriptors: np.ndarray, K: Float[np.ndarray, "3 3"], *,
    depth: np.ndarray | None = None, n_features: int = 2000, ratio: float = 0.8, max_distance: int = 64, **ransac,
) -> tuple[Localization, np.ndarray, np.ndarray]:
    """Localise one image against a line cloud whose line ``i`` carries ``descriptors[i]``.

    ``depth``: the image's ``(H, W)`` z-depth map in metres (0 or non-finite where unknown), e.g. from a
    time-of-flight sensor: each keypoint takes the depth of its pixel, keypoints without one are dropped,
    and the pose is solved with depth (module docstring, 5.; what a sphere cloud needs).
    Returns ``(localization, uv, line_ids)``: the matched keypoints (pixels) and their lines
    (``localization.inliers`` indexes them).  ``ransac``: keyword arguments of :func:`localize_against_lines`.
    Too few matches (fewer than ``min_inliers``) give ``success=False`` (nothing to solve), not an error:
    the image may show another place.
    """
    from privslam_jax.slam.frontend import OrbConfig, extract_orb, to_gray_u8

    desc = np.asarray(descriptors)
    if len(desc) != len(lines):
        raise ValueError(f"{len(desc)} descriptors for {len(lines)} lines")
    image = np.asarray(image)
    if depth is not None:
        depth = np.asarray(depth, np.float64)
        if depth.shape != image.shape[:2]:
            raise ValueError(f"depth map {depth.shape} does not match the image {image.shape[:2]}")
    feats = extract_orb(to_gray_u8(image), OrbConfig(n_features=n_features))
    pairs = match_to_map(feats.desc, desc, ratio=ratio, max_distance=max_distance)
    uv, ids = feats.uv[pairs[:, 0]], pairs[:, 1]
    z = None
    if depth is not None:
        z = keypoint_depths(depth, uv)
        keep = np.isfinite(z) & (z > 0)
        uv, ids, z = uv[keep], ids[keep], z[keep]
    if len(ids) < max(6 if z is None else 3, ransac.get("min_inliers", 12)):
        return Localization(T_c_w=np.eye(4), inliers=np.zeros(len(ids), bool), iterations=0, success=False), uv, ids
    sub = LineCloud(directions=np.asarray(lines.directions, np.float64)[ids], moments=np.asarray(lines.moments, np.float64)[ids])
    return localize_against_lines(uv, sub, K, depth=z, **ransac), uv, ids
