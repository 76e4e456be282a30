"""Point → line lifts that hide the points of a map (DESIGN §5.4).

* :func:`random_lift` — the source paper's lift (Speciale et al., CVPR 2019 "privacy-preserving
  image-based localisation"): every point ``p`` becomes the line through ``p`` with direction
  ``d = n/‖n‖, n ~ N(0, I₃)``, i.e. uniform on the unit sphere.
* :func:`paired_lift` — paired-point lifting (Lee et al., CVPR 2023, "Paired-Point Lifting for
  Enhanced Privacy-Preserving Visual Localization"): points are paired and each pair is lifted
  to the one line through both points, so every line holds two points and a density peak along
  a line no longer identifies one point.  **Pairing rule used here**: a uniformly random perfect
  matching (a random permutation from the key; consecutive entries are paired).  With an odd
  count the left-over point, and any pair closer than ``1e-9`` m, gets a random-direction line.
* :func:`ray_lift` — ray clouds (Moon et al., CVPR 2024, "Efficient Privacy-Preserving Visual
  Localization Using 3D Ray Clouds"): every point's line passes through one of a few *anchors*, so
  the lines of a map meet at the anchors and the density peaks that Line2Point looks for sit
  there, not at the points.  **Rules used here**: the anchors are the k-means centres of the map
  (``scipy.cluster.vq.kmeans2``, k-means++ start, seeded from the key), and each point is given a
  uniformly random anchor (not its nearest one: the nearest anchor would say in which region of the
  map the point lies).  The anchors themselves are public (any two lines of a cluster meet there):
  they reveal the map's coarse layout at ``num_anchors`` points, and nothing finer.
* :func:`sphere_lift` — sphere clouds (Moon et al., BMVC 2024, "Privacy-Preserving Visual
  Localization Using 3D Sphere Clouds"): every line passes through the map's centroid, so the
  cloud is a set of directions seen from one point (a panorama without depth).  The centroid is
  public.  What it leaks is the bearing of every point from the centroid; its weakness is depth
  recovery from neighbouring bearings (the attacks of issue 19 item 2).
* :func:`axial_lift` — axial clouds (this project; not from a paper): every line meets one vertical
  axis through the map's centroid at a right angle, i.e. line ``i`` is the horizontal line from the
  axis through ``p_i``.  It publishes each point's height and its bearing around the axis, and nothing
  about its distance from the axis: the cloud is a function of ``(h_i, θ_i)`` alone, so no attack on the
  lines themselves can do better than a prior on that distance.  As in a sphere cloud, every line meets
  every line of its height on the axis, so Line2Point and the gradient attack put the points there;
  unlike a sphere cloud it can be localised against from keypoints alone (the lines meet the axis at
  different heights: an axial, not a central, generalized camera, so the camera's distance is
  observable).  "Vertical" is the map's ``up``, e.g. the mean up axis of its keyframes
  (:func:`~privslam_jax.privacy.road.keyframe_up`), normal to the mean road under them, so that the
  lines of road points lie along the road and the ground-plane and road-surface attacks have nothing to
  cut them with.

For ray, sphere and axial clouds the direction is ``±(p − c)/‖p − c‖`` with a random sign (the sign must
not say on which side of its centre a point lies) and the moment is ``c × d``, computed from the
centre ``c``, so all lines of one centre meet there exactly; a point closer than ``1e-9`` m to its
centre gets a random-direction line through it.

The output is a :class:`~privslam_jax.types.LineCloud` in Plücker coordinates ``(d, m = p × d)``,
which carries nothing but the line: the original point is never stored.  Line ``i`` is the line
of point ``i`` (for paired lifting the two points of a pair share their line).

**Duplicate points.** Two lines through one point meet there, so a map that repeats a point
would publish it exactly (an attack recovers it to 1e-5 m). Both lifts therefore lift each
*distinct* point once and give every copy of it that same line (:func:`unique_points`): the
line cloud then says only that the point was repeated. Near-duplicates (distinct but close
points) are not merged.

**Precision.** Lifts compute in float64 on the host and return the input's precision: a float64
cloud (e.g. UTM coordinates, 1e7 m) gives float64 lines (numpy arrays when JAX runs in float32),
so line ``i`` passes within ~1e-15 relative of point ``i`` at any scale, and
:func:`privslam_jax.data.ply.save_line_cloud` keeps them float64; float32 clouds give float32 JAX
arrays as before.

**Keys.** A lift is only as secret as its randomness.  Without a key, the key is drawn from
the operating system's entropy (``os.urandom``, 64 bits), so two default lifts of the same
cloud differ; pass :func:`fixed_key` (an explicit seed) only for reproducible experiments.

**Host entry points and differentiable cores.**  The four lifts are host functions: they check the points (``ValueError``), merge repeated points and compute
in float64 numpy.  :func:`random_lift_core`, :func:`paired_lift_core`, :func:`ray_lift_core` and
:func:`sphere_lift_core` are the same lifts as pure JAX functions of ``(points, key)``: no checks, jit-able, differentiable in the points, in
the points' dtype.  They do **not** merge repeated points (copies get distinct lines that meet
at the point), so a published line cloud must come from the host functions; for a cloud without
repeated points they give the same lines (to rounding).  What is constant for the gradient: the
random directions, signs, pairing and anchor assignment (functions of the key only); a ray cloud's
anchors are an argument of its core (k-means runs on the host).
"""

from __future__ import annotations

import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, UInt

from privslam_jax.geometry.plucker import lines_from_points_directions, safe_norm
from privslam_jax.types import LineCloud

__all__ = [
    "axial_lift",
    "axial_lift_core",
    "entropy_key",
    "fixed_key",
    "random_directions",
    "random_lift",
    "random_lift_core",
    "paired_lift",
    "paired_lift_core",
    "pairing",
    "ray_anchors",
    "ray_lift",
    "ray_lift_core",
    "sphere_lift",
    "sphere_lift_core",
    "unique_points",
]


def entropy_key() -> jax.Array:
    """A fresh ``jax.random`` key from 64 bits of OS entropy (``os.urandom``)."""
    words = np.frombuffer(os.urandom(8), dtype=np.uint32)
    return jax.random.wrap_key_data(jnp.asarray(words), impl="threefry2x32")


def fixed_key(seed: int) -> jax.Array:
    """A reproducible key from an explicit integer seed (experiments only: not secret)."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise ValueError(f"seed must be an int, got {seed!r}")
    return jax.random.key(int(seed), impl="threefry2x32")


def _as_points(points: ArrayLike) -> tuple[np.ndarray, np.dtype]:
    """``(points as float64 numpy, the float dtype to return)``, after checking shape and values."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {tuple(p.shape)}")
    dtype = p.dtype if np.issubdtype(p.dtype, np.floating) and p.dtype.itemsize >= 4 else np.dtype(np.float64)
    p = p.astype(np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError("points contain NaN or inf")
    return p, np.dtype(dtype)


def _lines(d: np.ndarray, m: np.ndarray, dtype: np.dtype) -> LineCloud:
    """A line cloud in ``dtype``: JAX arrays where JAX holds that precision, float64 numpy otherwise."""
    if dtype == np.float64 and jax.dtypes.canonicalize_dtype(np.float64) != np.float64:
        return LineCloud(directions=d, moments=m)
    return LineCloud(directions=jnp.asarray(d, dtype), moments=jnp.asarray(m, dtype))


def _raw_directions(key: jax.Array, n: int) -> Float[Array, "n 3"]:
    """The float32 draw of :func:`random_directions` for ``n`` lines (both lifts and both cores)."""
    return random_directions(key, jnp.zeros((n, 3), jnp.float32))


def _directions(key: jax.Array, n: int) -> np.ndarray:
    """:func:`random_directions` for ``n`` lines, renormalised in float64."""
    d = np.asarray(_raw_directions(key, n), np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def unique_points(points: Float[ArrayLike, "N 3"]) -> tuple[np.ndarray, np.ndarray]:
    """``(first, inverse)``: indices of the distinct rows in order of first appearance, and for
    every row the position of its distinct row in ``first`` (``points[first][inverse] == points``).

    A cloud without repeated points gives ``first = arange(N)``, so lifting it is unchanged.
    """
    arr = np.asarray(points)
    _, first, inverse = np.unique(arr, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[np.asarray(inverse).reshape(-1)]


@jax.jit
def random_directions(key: jax.Array, like: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """Unit directions ``n/‖n‖`` with ``n ~ N(0, I₃)``: uniform on the sphere (one per row of ``like``)."""
    n = jax.random.normal(key, like.shape, like.dtype)
    return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def random_lift(points: ArrayLike, key: jax.Array | None = None, ids: ArrayLike | None = None) -> LineCloud:
    """Lift each point to a line of uniformly random direction through it.

    Args:
      points: ``(N, 3)`` points.
      key: a ``jax.random`` key; ``None`` (default) draws one from OS entropy.
      ids: ``(N,)`` distinct non-negative integers naming the points (e.g. map-point ids).  With
        them, point ``ids[i]``'s direction is drawn from ``fold_in(key, ids[i])`` alone, so a map
        that grows and is lifted again with the same key keeps every old point's direction: two
        lifts of one point with independent directions would meet at the point (the edge server
        publishes its map this way, :mod:`privslam_jax.edge`).  ``None``: directions drawn by row.
    """
    p, dtype = _as_points(points)
    key = entropy_key() if key is None else key
    first, inverse = unique_points(p)
    if ids is None:
        d = _directions(key, len(first))
    else:
        ids = np.asarray(ids)
        if ids.shape != (len(p),) or not np.issubdtype(ids.dtype, np.integer) or (len(ids) and ids.min() < 0):
            raise ValueError(f"ids must be {len(p)} non-negative integers, got {ids.dtype} {ids.shape}")
        if len(np.unique(ids)) != len(ids):
            raise ValueError("ids must be distinct")
        padded = np.zeros(max(256, 1 << int(len(first) - 1).bit_length()), np.uint32)  # few shapes: few compilations
        padded[: len(first)] = ids[first]
        d = np.asarray(_keyed_directions(key, jnp.asarray(padded)), np.float64)[: len(first)]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[inverse]  # repeated points share one line (module docstring)
    return _lines(d, np.cross(p, d), dtype)


@jax.jit
def _keyed_directions(key: jax.Array, ids: UInt[Array, " N"]) -> Float[Array, "N 3"]:
    """Direction ``n/‖n‖``, ``n ~ N(0, I₃)`` from ``fold_in(key, id)``, per id."""
    n = jax.vmap(lambda i: jax.random.normal(jax.random.fold_in(key, i), (3,)))(ids)
    return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def random_lift_core(points: Float[Array, "N 3"], key: jax.Array) -> LineCloud:
    """:func:`random_lift` as a pure JAX function: jit-able, differentiable in ``points``.

    The directions are :func:`random_lift`'s draw for ``key`` (float32 normals) renormalised in
    the points' dtype; the moments are ``p × d``.  No checks and no merging of repeated points
    (module docstring): equal to :func:`random_lift` for distinct points, to rounding.  The
    directions do not depend on the points (zero gradient); ``∂m/∂p`` is ``v ↦ v × d``.
    """
    return lines_from_points_directions(points, _raw_directions(key, points.shape[0]).astype(points.dtype))


def _pairing_core(n: int, key: jax.Array) -> Int[Array, " n"]:
    """:func:`pairing` as a JAX array (jit-able for a static ``n``)."""
    perm = jax.random.permutation(key, n)
    a, b = perm[0 : n - n % 2 : 2], perm[1 : n - n % 2 : 2]
    return jnp.full(n, -1, dtype=perm.dtype).at[a].set(b).at[b].set(a)


def pairing(n: int, key: jax.Array) -> np.ndarray:
    """The random perfect matching of :func:`paired_lift`: ``partner[i]`` (``-1`` for the odd one out)."""
    return np.asarray(_pairing_core(n, key), dtype=np.int64)


def _pair_roles(partner, xp):
    """``(rep, other)``: the pair's representative (lower index; itself for the odd one out) and
    the other point of the pair (itself for the representative's partner and the odd one out),
    with ``xp`` = numpy or jax.numpy."""
    n = partner.shape[0]
    idx = xp.arange(n)
    lo = xp.minimum(idx, xp.where(partner < 0, n, partner))  # one representative per pair
    rep = xp.where(partner < 0, idx, lo)
    other = xp.where(partner < 0, idx, xp.where(rep == idx, partner, idx))
    return rep, other


def paired_lift(points: ArrayLike, key: jax.Array | None = None) -> LineCloud:
    """Paired-point lifting (Lee et al., CVPR 2023): one line through each random pair of points.

    Line ``i`` passes through point ``i`` and its partner (see :func:`pairing`); the direction
    is ``±(p_j − p_i)/‖p_j − p_i‖`` with a random sign, so the segment order leaks nothing.
    """
    p, dtype = _as_points(points)
    key = entropy_key() if key is None else key
    first, inverse = unique_points(p)
    if len(first) < p.shape[0]:  # pair the distinct points; copies share their line
        lines = paired_lift(p[first], key)
        d, m = np.asarray(lines.directions, np.float64), np.asarray(lines.moments, np.float64)
        return _lines(d[inverse], m[inverse], dtype)
    k_pair, k_sign, k_dir = jax.random.split(key, 3)
    n = p.shape[0]
    partner = pairing(n, k_pair)
    rep, other = _pair_roles(partner, np)
    diff = p[other] - p[rep]
    length = np.linalg.norm(diff, axis=-1, keepdims=True)
    rnd = _directions(k_dir, n)[rep]
    sign = np.where(np.asarray(jax.random.bernoulli(k_sign, 0.5, (n, 1))), 1.0, -1.0)[rep]
    degenerate = length < 1e-9
    d = np.where(degenerate, rnd, sign * diff / np.where(degenerate, 1.0, length))
    # the moment from the pair's representative point: both points get the bit-identical line
    return _lines(d, np.cross(p[rep], d), dtype)


def paired_lift_core(points: Float[Array, "N 3"], key: jax.Array) -> LineCloud:
    """:func:`paired_lift` as a pure JAX function: jit-able, differentiable in ``points``.

    The same pairing, signs and fallback directions as :func:`paired_lift` for ``key``; the
    direction of a pair ``±(p_j − p_i)/‖p_j − p_i‖`` and the moment ``p_rep × d`` are
    differentiated, the pairing, the sign and the degenerate-pair test (``< 1e-9`` m) are
    constants.  No checks and no merging of repeated points (module docstring): equal to
    :func:`paired_lift` for distinct points, to rounding.
    """
    n = points.shape[0]
    k_pair, k_sign, k_dir = jax.random.split(key, 3)
    rep, other = _pair_roles(_pairing_core(n, k_pair), jnp)
    diff = points[other] - points[rep]
    length = safe_norm(diff, keepdims=True)  # the odd point out has diff = 0: gradient 0, not NaN
    rnd = _raw_directions(k_dir, n).astype(points.dtype)
    rnd = (rnd / jnp.linalg.norm(rnd, axis=-1, keepdims=True))[rep]
    sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (n, 1)), 1.0, -1.0).astype(points.dtype)[rep]
    degenerate = length < 1e-9
    d = jnp.where(degenerate, rnd, sign * diff / jnp.where(degenerate, 1.0, length))
    return LineCloud(directions=d, moments=jnp.cross(points[rep], d))


def _signs(key: jax.Array, n: int) -> np.ndarray:
    """``±1`` per line, fair coin flips from ``key`` (``(n, 1)`` float64)."""
    return np.where(np.asarray(jax.random.bernoulli(key, 0.5, (n, 1))), 1.0, -1.0)


def _lines_through_centres(p: np.ndarray, centres: np.ndarray, key: jax.Array, dtype: np.dtype) -> LineCloud:
    """Line ``i`` through ``p[i]`` and ``centres[i]`` (random sign; moment from the centre; a point on
    its centre gets a random direction through the point), float64 numpy in, ``dtype`` out."""
    k_sign, k_dir = jax.random.split(key)
    diff = p - centres
    length = np.linalg.norm(diff, axis=-1, keepdims=True)
    degenerate = length < 1e-9
    d = np.where(degenerate, _directions(k_dir, len(p)), _signs(k_sign, len(p)) * diff / np.where(degenerate, 1.0, length))
    m = np.where(degenerate, np.cross(p, d), np.cross(centres, d))
    return _lines(d, m, dtype)


def _core_through_centres(points: Float[Array, "N 3"], centres: Float[Array, "N 3"], key: jax.Array) -> LineCloud:
    """:func:`_lines_through_centres` in JAX: differentiable in ``points`` and ``centres``."""
    n = points.shape[0]
    k_sign, k_dir = jax.random.split(key)
    diff = points - centres
    length = safe_norm(diff, keepdims=True)
    degenerate = length < 1e-9
    rnd = _raw_directions(k_dir, n).astype(points.dtype)
    rnd = rnd / jnp.linalg.norm(rnd, axis=-1, keepdims=True)
    sign = jnp.where(jax.random.bernoulli(k_sign, 0.5, (n, 1)), 1.0, -1.0).astype(points.dtype)
    d = jnp.where(degenerate, rnd, sign * diff / jnp.where(degenerate, 1.0, length))
    return LineCloud(directions=d, moments=jnp.cross(jnp.where(degenerate, points, centres), d))


def ray_anchors(points: ArrayLike, num_anchors: int, key: jax.Array) -> np.ndarray:
    """The anchors of :func:`ray_lift`: ``(k, 3)`` k-means centres (float64) of the distinct points,
    ``k = min(num_anchors, number of distinct points)``; k-means++ start seeded from ``key``."""
    from scipy.cluster.vq import kmeans2

    if not isinstance(num_anchors, (int, np.integer)) or isinstance(num_anchors, bool) or num_anchors < 1:
        raise ValueError(f"num_anchors must be a positive int, got {num_anchors!r}")
    p, _ = _as_points(points)
    distinct = p[unique_points(p)[0]]
    k = min(int(num_anchors), len(distinct))
    if k == len(distinct):
        return distinct.copy()
    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).astype(np.uint64))
    with warnings.catch_warnings():  # an emptied cluster keeps its previous centre: still an anchor
        warnings.filterwarnings("ignore", message="One of the clusters is empty")
        centres, _ = kmeans2(distinct, k, minit="++", seed=rng)
    return np.asarray(centres, np.float64)


def _assignment(key: jax.Array, n: int, k: int) -> jax.Array:
    """A uniformly random anchor index per point."""
    return jax.random.randint(key, (n,), 0, k)


def ray_lift(points: ArrayLike, key: jax.Array | None = None, num_anchors: int = 8) -> LineCloud:
    """Ray-cloud lifting (Moon et al., CVPR 2024): line ``i`` passes through point ``i`` and a uniformly
    random one of ``num_anchors`` anchors, the k-means centres of the map (:func:`ray_anchors`).

    Args:
      points: ``(N, 3)`` points.
      key: a ``jax.random`` key; ``None`` (default) draws one from OS entropy.
      num_anchors: how many anchors (fewer if the map has fewer distinct points).
    """
    p, dtype = _as_points(points)
    key = entropy_key() if key is None else key
    k_anchor, k_assign, k_line = jax.random.split(key, 3)
    first, inverse = unique_points(p)
    anchors = ray_anchors(p, num_anchors, k_anchor)
    assign = np.asarray(_assignment(k_assign, len(first), len(anchors)))
    lines = _lines_through_centres(p[first], anchors[assign], k_line, np.dtype(np.float64))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    return _lines(d[inverse], m[inverse], dtype)  # repeated points share their line


def ray_lift_core(points: Float[Array, "N 3"], anchors: Float[Array, "K 3"], key: jax.Array) -> LineCloud:
    """:func:`ray_lift` as a pure JAX function of the points and the anchors: jit-able, differentiable in
    both.  ``ray_lift_core(p, ray_anchors(p, k, k_anchor), key)`` equals ``ray_lift(p, key, k)`` (to
    rounding) for a cloud without repeated points, where ``k_anchor`` is the first of
    ``jax.random.split(key, 3)``; the assignment and signs are functions of the key only."""
    _, k_assign, k_line = jax.random.split(key, 3)
    assign = _assignment(k_assign, points.shape[0], anchors.shape[0])
    return _core_through_centres(points, anchors.astype(points.dtype)[assign], k_line)


def sphere_lift(points: ArrayLike, key: jax.Array | None = None) -> LineCloud:
    """Sphere-cloud lifting (Moon et al., BMVC 2024): line ``i`` passes through point ``i`` and the
    centroid of the map's distinct points.

    Args:
      points: ``(N, 3)`` points.
      key: a ``jax.random`` key (the signs, and directions of points on the centroid); ``None``
        (default) draws one from OS entropy.
    """
    p, dtype = _as_points(points)
    key = entropy_key() if key is None else key
    first, inverse = unique_points(p)
    centre = p[first].mean(axis=0, keepdims=True)
    lines = _lines_through_centres(p[first], np.repeat(centre, len(first), axis=0), key, np.dtype(np.float64))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    return _lines(d[inverse], m[inverse], dtype)


def sphere_lift_core(points: Float[Array, "N 3"], key: jax.Array) -> LineCloud:
    """:func:`sphere_lift` as a pure JAX function: jit-able, differentiable in ``points`` (through the
    centroid too); equal to :func:`sphere_lift` for a cloud without repeated points, to rounding."""
    centre = jnp.broadcast_to(jnp.mean(points, axis=0, keepdims=True), points.shape)
    return _core_through_centres(points, centre, key)


def _unit_up(up: np.ndarray | jax.Array | tuple | list) -> np.ndarray:
    u = np.asarray(up, np.float64)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
        raise ValueError(f"up must be a finite non-zero (3,) vector, got {u}")
    return u / np.linalg.norm(u)


def _axis_feet(points, centre, up):
    """Each point's foot on the axis through ``centre`` ``(1, 3)`` along unit ``up``: ``c + ((p − c)·u) u``."""
    return centre + ((points - centre) @ up)[:, None] * up[None, :]


def axial_lift(points: ArrayLike, up: np.ndarray | jax.Array | tuple | list, key: jax.Array | None = None) -> LineCloud:
    """Axial-cloud lifting (module docstring): line ``i`` passes through point ``i`` and meets the axis
    through the centroid of the distinct points along ``up`` at a right angle (random sign); a point on
    the axis (within 1e-9 m) gets a random-direction line through it.

    Args:
      points: ``(N, 3)`` points.
      up: ``(3,)`` the map's up axis (need not be unit length), e.g.
        :func:`~privslam_jax.privacy.road.keyframe_up` of its keyframes.
      key: a ``jax.random`` key (the signs); ``None`` (default) draws one from OS entropy.
    """
    p, dtype = _as_points(points)
    u = _unit_up(up)
    key = entropy_key() if key is None else key
    first, inverse = unique_points(p)
    q = p[first]
    lines = _lines_through_centres(q, _axis_feet(q, q.mean(axis=0, keepdims=True), u), key, np.dtype(np.float64))
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    return _lines(d[inverse], m[inverse], dtype)


def axial_lift_core(points: Float[Array, "N 3"], up: Float[Array, "3"], key: jax.Array) -> LineCloud:
    """:func:`axial_lift` as a pure JAX function: jit-able, differentiable in ``points`` (through the
    centroid too) and ``up``; equal to :func:`axial_lift` for a cloud without repeated points, to rounding."""
    u = up.astype(points.dtype) / jnp.linalg.norm(up)
    return _core_through_centres(points, _axis_feet(points, jnp.mean(points, axis=0, keepdims=True), u), key)
