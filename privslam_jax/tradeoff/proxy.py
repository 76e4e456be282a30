"""Does the accuracy proxy predict SLAM?  The pieces of ``experiments/proxy_vs_slam.py`` (issue 18, item 1).

The differentiable accuracy proxy :func:`~privslam_jax.tradeoff.objectives.accuracy_loss` (direct
photometric two-frame alignment, geodesic error to the ground-truth relative pose) is only useful
for training a filter if it ranks filters as real SLAM does.  This module gives the experiment its
reusable, tested parts:

* :func:`render_world` — a synthetic world rendered in memory, its frames quantised to 8 bits as
  ``privslam synth`` writes them (``image_2/*.png``; with a stereo config also ``image_3/*.png`` and
  the right camera's instance ids; the object-free ``background/*.png`` always);
* :func:`filter_world` — every frame filtered with the ground-truth instance masks (dilation 4), as
  ``privslam filter --masks gt`` writes them (same masks, same per-frame seed ``seed + i``, same
  8-bit rounding); ``right=True`` filters the right frames with the right camera's masks the same
  way (``privslam filter --masks gt`` leaves right frames alone: it has no right masks);
* :func:`~privslam_jax.data.images.grey_as_read` (not here) gives a frame as ``privslam slam``
  reads it, so that SLAM in memory sees the same pixels as SLAM on the files;
* :func:`sequence_proxy` — the proxy of a (filtered) sequence: ``accuracy_loss`` of the frame pairs
  ``(t, t + gap)``, ``t = 0, stride, 2·stride, …``, at the frames' 2×2 box-averaged size (640×192 →
  320×96, the size of ``tests/test_tradeoff_objectives.py``), averaged over the pairs whose solve
  converged to a finite value (the others are counted);
* :func:`paired_changes`, :func:`summarize_changes`, :func:`spearman` — the paired change of a
  filter against the unfiltered frames of the same world, per-filter medians and Spearman's rank
  correlation (``scipy.stats.spearmanr``).

Proxy inputs per pair: target ``y_{t+gap}``, reference ``y_t`` (both the filtered 8-bit RGB frames
divided by 255, box-averaged), the reference's ground-truth z-depth (the frame *with* its objects,
as the trade-off tests use it) reduced to the smaller size by :func:`downsample_depth`, intrinsics
``f/s``, ``(c + ½)/s − ½`` (:func:`scale_intrinsics`) and ``T_gt = T_w_{t+gap}⁻¹ T_w_t``
(reference camera → target camera, :func:`relative_pose`); identity start.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Float, Shaped

from privslam_jax.tradeoff.objectives import geodesic_distance
from privslam_jax.tradeoff.photometric import PhotometricConfig, align_photometric
from privslam_jax.types import Camera

__all__ = ["ProxyResult", "ProxySettings", "World", "box_downsample", "downsample_depth", "filter_world", "frame_pairs",
           "pair_loss", "paired_changes", "relative_pose", "render_world", "scale_intrinsics", "sequence_proxy",
           "spearman", "summarize_changes"]

_DEFAULT_ALIGNMENT = PhotometricConfig()


# --- frames as the command-line tools see them ------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class World:
    """A synthetic world rendered in memory (what ``privslam synth`` writes, without the files)."""

    seed: int
    rgb8: np.ndarray
    """``(N, H, W, 3)`` uint8 RGB, the ``image_2/*.png`` frames."""
    depth: np.ndarray
    """``(N, H, W)`` float32 z-depth in metres (0 = sky), of the frames with their objects."""
    instance_ids: np.ndarray
    """``(N, H, W)`` uint16 instance ids (0 = no object), the ``masks/*.png`` maps."""
    poses: np.ndarray
    """``(N, 4, 4)`` float64 ground-truth ``T_w_c``."""
    timestamps: np.ndarray
    """``(N,)`` seconds."""
    camera: Camera
    """The camera as ``privslam slam`` reads it from ``calib.txt`` (mono: the baseline is not used)."""
    background_rgb8: np.ndarray
    """``(N, H, W, 3)`` uint8 RGB of the left frames rendered without the privacy objects (``background/*.png``)."""
    right_rgb8: np.ndarray | None = None
    """``(N, H, W, 3)`` uint8 RGB of the right camera (``image_3/*.png``), or ``None`` when not stereo."""
    right_instance_ids: np.ndarray | None = None
    """``(N, H, W)`` uint16 instance ids of the right camera (same ids as the left), or ``None`` when not stereo."""

    def __len__(self) -> int:
        return len(self.rgb8)

    @property
    def intrinsics(self) -> np.ndarray:
        """``(fx, fy, cx, cy)`` float64 of the full-size frames."""
        c = self.camera
        return np.array([c.fx, c.fy, c.cx, c.cy], np.float64)


def render_world(config: Any) -> World:
    """Render every frame of the synthetic world ``config`` (a :class:`~privslam_jax.data.synthetic.SynthConfig`);
    with ``config.stereo`` also the right frames and their instance ids."""
    from privslam_jax.data.images import as_unit_image, like_input
    from privslam_jax.data.synthetic import make_sequence

    def u8(image: np.ndarray) -> np.ndarray:
        return like_input(as_unit_image(image), np.zeros(0, np.uint8))  # write_rgb's rounding

    def ids16(ids: np.ndarray) -> np.ndarray:
        if ids.size and int(ids.max()) > 65535:
            raise ValueError("instance ids beyond 16 bits")
        return ids

    seq = make_sequence(config)
    n, h, w = len(seq), config.height, config.width
    stereo = bool(config.stereo)
    rgb8 = np.empty((n, h, w, 3), np.uint8)
    background8 = np.empty((n, h, w, 3), np.uint8)
    depth = np.empty((n, h, w), np.float32)
    ids = np.empty((n, h, w), np.uint16)
    right8 = np.empty((n, h, w, 3), np.uint8) if stereo else None
    right_ids = np.empty((n, h, w), np.uint16) if stereo else None
    for i in range(n):
        f = seq[i]
        rgb8[i] = u8(f.image)
        background8[i] = u8(f.background)
        depth[i] = f.depth
        ids[i] = ids16(f.instance_ids)
        if right8 is not None and right_ids is not None:
            right8[i] = u8(f.image_right)
            right_ids[i] = ids16(f.instance_ids_right)
    cam = dataclasses.replace(seq.camera, baseline=float(config.baseline))
    return World(seed=int(config.seed), rgb8=rgb8, depth=depth, instance_ids=ids,
                 poses=np.asarray(seq.poses, np.float64), timestamps=np.asarray(seq.timestamps, np.float64), camera=cam,
                 background_rgb8=background8, right_rgb8=right8, right_instance_ids=right_ids)


def frame_masks(instance_ids: np.ndarray, dilation: int = 4) -> np.ndarray:
    """``(K, H, W)`` dilated ground-truth masks of one frame, as ``privslam filter --masks gt`` builds them."""
    from privslam_jax.inpaint.masks import instance_masks

    ids = sorted(int(x) for x in np.unique(instance_ids[instance_ids > 0]))
    return instance_masks(instance_ids, np.asarray(ids, np.int64), dilation)


def filter_world(world: World, method: str, inpainter: Any = None, seed: int = 0, dilation: int = 4,
                 progress: Callable[[int], None] | None = None, right: bool = False) -> np.ndarray:
    """``(N, H, W, 3)`` uint8: every frame filtered with ``method`` on its ground-truth masks, as
    ``privslam filter --masks gt --method METHOD`` writes it (frame ``i`` filtered with seed ``seed + i``,
    rounded to 8 bits).  ``method="none"``: the frames themselves.  ``right``: the right frames, each
    filtered on the right camera's ground-truth masks in the same way (a stereo world only)."""
    from privslam_jax.inpaint.sequence import iter_filtered

    if right:
        if world.right_rgb8 is None or world.right_instance_ids is None:
            raise ValueError("right=True needs a stereo world (render_world of a SynthConfig with stereo=True)")
        frames, instance_ids = world.right_rgb8, world.right_instance_ids
    else:
        frames, instance_ids = world.rgb8, world.instance_ids
    if method == "none":
        return frames

    def masks_of(i: int, k: int) -> tuple[np.ndarray, list[int]]:
        masks = frame_masks(instance_ids[i], dilation)
        return masks, list(range(1, len(masks) + 1))

    out = np.empty_like(frames)
    for f in iter_filtered(frames, method, masks_of, inpainter=inpainter, seed=seed):
        out[f.index] = f.left
        if progress is not None:
            progress(f.index)
    return out


# --- the proxy --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ProxySettings:
    """Which pairs the proxy sees and at which size."""

    gap: int = 1
    """``k``: pairs ``(t, t + k)``."""
    stride: int = 10
    """Every ``stride``-th ``t``."""
    factor: int = 2
    """Box-downsampling factor (640×192 → 320×96)."""
    config: PhotometricConfig = _DEFAULT_ALIGNMENT
    """Alignment settings (``accuracy_loss``'s default)."""
    rotation_scale: float = 1.0
    """``ℓ`` of :func:`~privslam_jax.tradeoff.objectives.geodesic_distance` (metres per radian)."""


def box_downsample(image: Float[np.ndarray, "H W *C"], factor: int) -> Float[np.ndarray, "h w *C"]:
    """Mean of ``factor × factor`` blocks (the photometric pyramid's reduction), float32."""
    h, w = image.shape[:2]
    if h % factor or w % factor:
        raise ValueError(f"image {w}x{h} is not divisible by {factor}")
    x = np.asarray(image, np.float64)
    x = x.reshape(h // factor, factor, w // factor, factor, *x.shape[2:]).mean(axis=(1, 3))
    return x.astype(np.float32)


def downsample_depth(depth: Float[np.ndarray, "H W"], factor: int, depth_jump: float = 0.1
                     ) -> Float[np.ndarray, "h w"]:
    """Depth of ``factor × factor`` blocks: the inverse of their mean inverse depth (as the photometric
    pyramid reduces depth), 0 (not used) where a block holds sky (depth 0) or an occlusion boundary
    (``max/min > 1 + depth_jump``)."""
    h, w = depth.shape
    if h % factor or w % factor:
        raise ValueError(f"depth {w}x{h} is not divisible by {factor}")
    d = np.asarray(depth, np.float64).reshape(h // factor, factor, w // factor, factor).transpose(0, 2, 1, 3)
    d = d.reshape(h // factor, w // factor, factor * factor)
    lo, hi = d.min(axis=-1), d.max(axis=-1)
    ok = (lo > 0) & np.isfinite(hi) & (hi <= (1.0 + depth_jump) * lo)
    inv = np.mean(1.0 / np.where(ok[..., None], d, 1.0), axis=-1)
    return np.where(ok, 1.0 / inv, 0.0).astype(np.float32)


def scale_intrinsics(intrinsics: Float[np.ndarray, " 4"], factor: int) -> Float[np.ndarray, " 4"]:
    """``(fx, fy, cx, cy)`` of the ``factor``-times smaller image: ``f/s``, ``(c + ½)/s − ½``."""
    k = np.asarray(intrinsics, np.float64)
    return np.concatenate([k[:2] / factor, (k[2:] + 0.5) / factor - 0.5])


def relative_pose(T_w_ref: Float[np.ndarray, "4 4"], T_w_tgt: Float[np.ndarray, "4 4"]) -> Float[np.ndarray, "4 4"]:
    """``T_t_r = T_w_t⁻¹ T_w_r``: reference-camera coordinates → target-camera coordinates."""
    return np.linalg.inv(np.asarray(T_w_tgt, np.float64)) @ np.asarray(T_w_ref, np.float64)


def frame_pairs(n: int, gap: int, stride: int) -> list[tuple[int, int]]:
    """``(t, t + gap)`` for ``t = 0, stride, 2·stride, …`` while ``t + gap < n``."""
    if gap < 1 or stride < 1:
        raise ValueError(f"gap and stride must be >= 1, got {gap}, {stride}")
    return [(t, t + gap) for t in range(0, max(n - gap, 0), stride)]


@functools.cache
def pair_loss(config: PhotometricConfig = _DEFAULT_ALIGNMENT, rotation_scale: float = 1.0) -> Callable[..., Any]:
    """The jitted per-pair proxy ``(target, reference, depth, intrinsics, T_gt (4, 4)) → (L_acc, converged)``.

    ``L_acc`` is :func:`~privslam_jax.tradeoff.objectives.accuracy_loss` (the same two calls: the
    alignment, then the geodesic distance), with the solver's ``converged`` flag, which
    ``accuracy_loss`` does not return.  One function per settings: compiled once per input shape
    and dtype."""

    def f(target, reference, depth, intrinsics, T_gt):
        T_est, summary = align_photometric(target, reference, depth, intrinsics, None, config)
        T_gt = jaxlie.SE3.from_matrix(jnp.asarray(T_gt, T_est.wxyz_xyz.dtype))
        return geodesic_distance(T_est, T_gt, rotation_scale), summary.converged

    return jax.jit(f)


@dataclasses.dataclass(frozen=True)
class ProxyResult:
    """The proxy of one sequence."""

    mean: float
    """Mean ``L_acc`` over the valid pairs (converged and finite); NaN without any."""
    values: np.ndarray
    """``(P,)`` ``L_acc`` of every pair (NaN where the solve returned NaN)."""
    converged: np.ndarray
    """``(P,)`` bool: the finest-level solve converged."""
    pairs: list[tuple[int, int]]

    @property
    def valid(self) -> np.ndarray:
        """``(P,)`` bool: converged and finite (the pairs in :attr:`mean`)."""
        return self.converged & np.isfinite(self.values)

    @property
    def failed(self) -> int:
        """Pairs left out of the mean (not converged, or NaN)."""
        return int((~self.valid).sum())

    @property
    def median(self) -> float:
        v = self.values[self.valid]
        return float(np.median(v)) if v.size else math.nan


def sequence_proxy(rgb8: Shaped[np.ndarray, "N H W 3"], depth: Float[np.ndarray, "N H W"],
                   poses: Float[np.ndarray, "N 4 4"], intrinsics: Float[np.ndarray, " 4"],
                   settings: ProxySettings = ProxySettings(), dtype: Any = np.float32) -> ProxyResult:
    """The proxy of a (filtered) sequence (module docstring): ``accuracy_loss`` of every pair of
    :func:`frame_pairs`, at the frames' size divided by ``settings.factor``, in ``dtype``."""
    s = settings.factor
    K = jnp.asarray(scale_intrinsics(intrinsics, s), dtype)
    f = pair_loss(settings.config, settings.rotation_scale)
    pairs = frame_pairs(len(rgb8), settings.gap, settings.stride)

    def image(i: int) -> jax.Array:
        return jnp.asarray(box_downsample(np.asarray(rgb8[i]).astype(np.float32) / np.float32(255), s), dtype)

    values, converged = [], []
    for t, u in pairs:
        d = jnp.asarray(downsample_depth(depth[t], s, settings.config.depth_jump), dtype)
        loss, ok = f(image(u), image(t), d, K, jnp.asarray(relative_pose(poses[t], poses[u]), dtype))
        values.append(float(loss))
        converged.append(bool(ok))
    values_a = np.asarray(values, np.float64).reshape(-1)
    conv = np.asarray(converged, bool).reshape(-1)
    valid = conv & np.isfinite(values_a)
    mean = float(values_a[valid].mean()) if valid.any() else math.nan
    return ProxyResult(mean=mean, values=values_a, converged=conv, pairs=pairs)


# --- paired changes and rank correlation ------------------------------------------------------------


def paired_changes(records: Sequence[dict], ate: str = "ate", proxy: str = "proxy") -> list[dict]:
    """Per (filter, world) with a ``"none"`` record of the same world: the filtered value minus the
    unfiltered one.

    ``records``: dicts with ``filter``, ``world`` and the values ``ate`` and ``proxy`` (NaN or
    missing: failed).  Returns, for every filter other than ``"none"``, dicts with ``filter``,
    ``world``, ``d_ate`` (m), ``d_ate_pct`` (``100 · d_ate / ATE_none``) and ``d_proxy``; a change
    whose two values are not both finite is NaN.
    """
    base = {r["world"]: r for r in records if r["filter"] == "none"}
    out = []
    for r in records:
        if r["filter"] == "none" or r["world"] not in base:
            continue
        b = base[r["world"]]
        a0, a1 = float(b.get(ate, math.nan)), float(r.get(ate, math.nan))
        p0, p1 = float(b.get(proxy, math.nan)), float(r.get(proxy, math.nan))
        out.append({"filter": r["filter"], "world": r["world"], "d_ate": a1 - a0,
                    "d_ate_pct": 100.0 * (a1 - a0) / a0 if a0 != 0 else math.nan, "d_proxy": p1 - p0})
    return out


def summarize_changes(changes: Sequence[dict], keys: Sequence[str] = ("d_ate", "d_ate_pct", "d_proxy")
                      ) -> dict[str, dict[str, Any]]:
    """Per filter (first-seen order): for each of ``keys`` the median, min and max over the worlds of
    its finite values (NaN without any), and ``n`` the number of worlds with every key finite."""
    by: dict[str, list[dict]] = {}
    for c in changes:
        by.setdefault(c["filter"], []).append(c)
    out: dict[str, dict[str, Any]] = {}
    for name, cs in by.items():
        row: dict[str, Any] = {"worlds": len(cs),
                               "n": sum(all(np.isfinite(c[k]) for k in keys) for c in cs)}
        for k in keys:
            v = np.asarray([c[k] for c in cs], np.float64)
            v = v[np.isfinite(v)]
            row[k] = float(np.median(v)) if v.size else math.nan
            row[k + "_min"] = float(v.min()) if v.size else math.nan
            row[k + "_max"] = float(v.max()) if v.size else math.nan
        out[name] = row
    return out


def spearman(x: Sequence[float | int] | np.ndarray, y: Sequence[float | int] | np.ndarray) -> tuple[float, float, int]:
    """Spearman's ``(ρ, two-sided p, n)`` of ``scipy.stats.spearmanr`` over the pairs where both are
    finite; ``(NaN, NaN, n)`` when fewer than 3 remain or either side is constant (undefined)."""
    from scipy.stats import spearmanr

    a, b = np.asarray(x, np.float64).reshape(-1), np.asarray(y, np.float64).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"x and y differ in length: {a.shape} vs {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = int(a.size)
    if n < 3 or np.all(a == a[0]) or np.all(b == b[0]):
        return math.nan, math.nan, n
    res = spearmanr(a, b)
    return float(res.statistic), float(res.pvalue), n
