"""Procedural synthetic street world with full ground truth, rendered by a jitted JAX ray caster.

A Manhattan grid of city blocks (façades with windows, doors, shop fronts, bricks; paved sidewalks
with kerbs; asphalt roads with lane markings, parking bays and zebra crossings) is populated with
privacy-sensitive objects — standing and walking people with faces, parked and driving cars with
licence plates, buses, trucks, bicycles and motorcycles (COCO class ids) — and driven through by a
level camera at ``camera_height`` on the right-hand lane, along straight legs joined by rounded
90° left and right turns.

Per frame the renderer returns the RGB image, z-depth, per-pixel instance ids, tight boxes, the
**same frame without the privacy objects** (``background``; bit-identical to ``image`` outside
the instance masks because both come from the same static hit), and the ground-truth pose.

World frame (KITTI convention): the left camera of frame 0, i.e. ``x`` right, ``y`` down, ``z``
forward; the ground plane is ``y = +camera_height``; poses ``T_w_c`` map camera to world.
Intrinsics: ``fx = fy = fx_ratio·width`` (0.58 ≈ KITTI's 718.9/1241), principal point at the image
centre ``((W−1)/2, (H−1)/2)`` with pixel centres at integer ``(u, v)``.  How the casting works:
``_synth_trace`` (level camera ⇒ per-column 2.5-D casting); materials: ``_synth_shade``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from privslam_jax._xla import OPTIMISED
from privslam_jax.data import _synth_objects as so
from privslam_jax.data._synth_path import CityLayout, make_loop_path, make_path
from privslam_jax.data._synth_shade import object_color, static_color, static_fields, static_wall
from privslam_jax.data._synth_textures import channel, current_channel, sharing
from privslam_jax.data._synth_trace import trace
from privslam_jax.types import Camera, Trajectory

__all__ = ["SynthConfig", "SynthFrame", "SyntheticSequence", "make_sequence", "parse_seeds", "COCO_PRIVACY_CLASSES", "ROUTES"]

ROUTES: tuple[str, ...] = ("staircase", "loop")
"""The camera routes :class:`SynthConfig` offers."""

COCO_PRIVACY_CLASSES: dict[int, str] = {0: "person", 1: "bicycle", 2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
"""The privacy-sensitive COCO classes the world contains (id → name)."""


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    """Configuration of a synthetic sequence (everything is deterministic for a seed)."""

    width: int = 640
    """Image width in pixels."""
    height: int = 192
    """Image height in pixels."""
    num_frames: int = 100
    """Sequence length (frames)."""
    seed: int = 0
    """Seed of the street layout, the route, the objects and the textures."""
    stereo: bool = False
    """Also render the right camera (``+baseline`` along the left camera's ``x``)."""
    baseline: float = 0.54
    """Stereo baseline in metres (KITTI: 0.54)."""
    fps: float = 10.0
    """Frame rate; ``timestamps = i / fps``."""
    object_density: float = 1.0
    """Multiplier on the number of privacy objects (0 = empty streets)."""
    speed: float = 8.0
    """Camera speed along the road centre line, m/s (KITTI drives ≈ 10 m/s)."""
    camera_height: float = 1.65
    """Camera height above the road, metres (KITTI: 1.65)."""
    fx_ratio: float = 0.58
    """Focal length as a fraction of the width: ``fx = fy = fx_ratio·width`` (KITTI ≈ 0.58)."""
    max_objects: int = 24
    """At most this many objects (nearest in the view wedge) are rendered per frame."""
    dda_steps: int = 10
    """City-grid cells visited per image column (sets the far clip, ≈ 3–10 blocks)."""
    column_prisms: int = 12
    """Object boxes tested per pixel (the nearest that meet the pixel's column)."""
    column_ellipsoids: int = 16
    """Object ellipsoids tested per pixel (the nearest that meet the pixel's column)."""
    route: str = "staircase"
    """``staircase``: left and right turns, never the same street twice; ``loop``: laps around a
    rectangle of ``loop_blocks`` blocks (3 × 2: 463 m a lap, the camera passes its start again after
    58–60 s, frames ~580–600 at the defaults), for loop closing."""
    loop_blocks: tuple[int, int] = (3, 2)
    """Blocks of the loop route's rectangle along ``x`` and ``z`` (48 m each)."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        checks = [
            (self.width > 0, f"width must be > 0, got {self.width}"),
            (self.height > 0, f"height must be > 0, got {self.height}"),
            (self.num_frames > 0, f"num_frames must be > 0, got {self.num_frames}"),
            (self.fps > 0, f"fps must be > 0, got {self.fps}"),
            (self.baseline > 0, f"baseline must be > 0, got {self.baseline}"),
            (self.object_density >= 0, f"object_density must be >= 0, got {self.object_density}"),
            (self.speed >= 0, f"speed must be >= 0, got {self.speed}"),
            (0.2 < self.camera_height < 5.0, f"camera_height must be in (0.2, 5) m, got {self.camera_height}"),
            (self.fx_ratio > 0, f"fx_ratio must be > 0, got {self.fx_ratio}"),
            (self.max_objects > 0, f"max_objects must be > 0, got {self.max_objects}"),
            (self.dda_steps > 0 and self.column_prisms > 0 and self.column_ellipsoids > 0,
             "dda_steps, column_prisms and column_ellipsoids must be > 0"),
            (self.route in ROUTES, f"route must be one of {ROUTES}, got {self.route!r}"),
            (len(self.loop_blocks) == 2 and all(int(b) == b and b >= 1 for b in self.loop_blocks),
             f"loop_blocks must be two integers >= 1, got {self.loop_blocks}"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(f"SynthConfig: {msg}")
        if self.column_prisms > self.max_objects * so.NB or self.column_ellipsoids > self.max_objects * so.NE:
            raise ValueError("SynthConfig: column_prisms/column_ellipsoids exceed the primitives of max_objects")


@struct.dataclass
class SynthFrame:
    """One rendered frame (numpy arrays on the host)."""

    index: int
    """Frame index."""
    timestamp: float
    """Seconds (``index / fps``)."""
    image: np.ndarray
    """(H, W, 3) float32 RGB in [0, 1], left camera."""
    image_right: np.ndarray | None
    """(H, W, 3) right camera, or ``None`` when not stereo."""
    depth: np.ndarray
    """(H, W) float32 z-depth in metres (left camera); 0 where the ray hits nothing (sky)."""
    depth_right: np.ndarray | None
    """(H, W) right-camera depth, or ``None``."""
    instance_ids: np.ndarray
    """(H, W) int32: 0 = no privacy object, k > 0 = instance k (see ``instance_classes``)."""
    background: np.ndarray
    """(H, W, 3) the same frame rendered without privacy objects."""
    background_right: np.ndarray | None
    """(H, W, 3) object-free right image, or ``None``."""
    boxes: np.ndarray
    """(K, 4) float32 ``xyxy``: a mask covering pixel columns ``u0..u1`` gives ``x1 = u0``, ``x2 = u1 + 1``."""
    class_ids: np.ndarray
    """(K,) int32 COCO class of each box."""
    instance_of_box: np.ndarray
    """(K,) int32 instance id of each box."""
    T_w_c: np.ndarray
    """(4, 4) float64 camera-to-world pose of the left camera."""
    background_depth: np.ndarray | None = None
    """(H, W) float32 z-depth of the object-free scene (0 = sky)."""
    instance_ids_right: np.ndarray | None = None
    """(H, W) int32 instance ids of the right camera (same ids as ``instance_ids``), or ``None`` when
    not stereo."""


def parse_seeds(text: str) -> list[int]:
    """World seeds from a command-line list of seeds and inclusive ranges: ``"0-3,7"`` → ``[0, 1, 2, 3, 7]``."""
    out: list[int] = []
    for part in text.split(","):
        lo, sep, hi = part.partition("-")
        try:
            out += list(range(int(lo), int(hi) + 1)) if sep else [int(lo)]
        except ValueError:
            raise ValueError(f"bad seed list {text!r}: expected seeds and ranges like '0-3,7'") from None
    return out


def _salt(seed: int) -> np.uint32:
    x = np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x9E3779B1) + np.uint64(0x632BE5AB)
    return np.uint32(int(x) & 0xFFFFFFFF)


def _view(cam, intr, uu, vv, prisms, ells, salt, layout, steps, mb, me):
    """Render one level camera ``cam = (x, y, z, yaw)`` at pixel grid ``uu (C,)``, ``vv (R, C)``.

    Colour maps come back channel-first ``(3, R, C)``: shading runs one channel per iteration of a
    ``lax.map`` (see ``_synth_textures.channel``).
    """
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    o = cam[0:3]
    cos, sin = jnp.cos(cam[3]), jnp.sin(cam[3])
    xc = (uu - cx) / fx
    dxz = jnp.stack([xc * cos + sin, -xc * sin + cos], axis=1)
    yc = (vv - cy) / fy
    hit = trace(o, dxz, yc, prisms, ells, salt, layout, steps, mb, me)
    d = (jnp.broadcast_to(dxz[None, :, 0], yc.shape), yc, jnp.broadcast_to(dxz[None, :, 1], yc.shape))
    s_ok = jnp.isfinite(hit["t_static"])
    ts = jnp.where(s_ok, hit["t_static"], 1.0)
    obj = hit["t_obj"] < hit["t_static"]
    to = jnp.where(obj, hit["t_obj"], 1.0)
    table = jnp.concatenate([prisms, ells], axis=0)
    p_s = tuple(o[i] + ts * d[i] for i in range(3))
    p_o = tuple(o[i] + to * d[i] for i in range(3))

    # static fields once; façade colour in its own channel loop (XLA fuses a smaller loop better)
    fields_s = static_fields(p_s, d, hit, layout, fx, salt)

    def wall_channel(c):
        with channel(c):
            return static_wall(fields_s, salt)

    walls = jax.lax.map(wall_channel, jnp.arange(3, dtype=jnp.int32))

    def colors():
        wall = jax.lax.dynamic_index_in_dim(walls, current_channel(), keepdims=False)
        bg = jnp.clip(static_color(fields_s, layout, salt, wall), 0.0, 1.0)
        oc = jnp.clip(object_color(p_o, d, to, hit["o_row"], table, fx), 0.0, 1.0)
        return jnp.where(obj, oc, bg), bg

    # trace once to collect the channel-independent fields, then shade one channel per iteration
    with channel(jnp.int32(0)), sharing("record") as fields:
        colors()

    def shade(c):
        with channel(c), sharing("replay", fields):
            return colors()

    image, bg = jax.lax.map(shade, jnp.arange(3, dtype=jnp.int32))
    inst = jnp.round(jnp.take(table[:, 22], hit["o_row"], axis=0)).astype(jnp.int32)
    bg_depth = jnp.where(s_ok, hit["t_static"], 0.0)
    depth = jnp.where(obj, hit["t_obj"], bg_depth)
    return {"image": image, "depth": depth, "instance_ids": jnp.where(obj, inst, 0), "background": bg,
            "background_depth": bg_depth}


def _boxes(inst, slot_ids):
    """Tight ``xyxy`` boxes (pixel-edge convention) of each slot's mask and whether it is visible."""
    m = inst[None, :, :] == slot_ids[:, None, None]
    cols = jnp.any(m, axis=1)  # (K, W)
    rows = jnp.any(m, axis=2)  # (K, H)
    W, H = cols.shape[1], rows.shape[1]
    x1 = jnp.argmax(cols, axis=1)
    x2 = W - jnp.argmax(cols[:, ::-1], axis=1)
    y1 = jnp.argmax(rows, axis=1)
    y2 = H - jnp.argmax(rows[:, ::-1], axis=1)
    valid = jnp.any(cols, axis=1) & (slot_ids > 0)
    return jnp.stack([x1, y1, x2, y2], axis=1).astype(jnp.float32), valid


@functools.partial(jax.jit, static_argnames=("width", "height", "layout", "steps", "mb", "me"), compiler_options=OPTIMISED)
def render_views(cams, intr, prisms, ells, slot_ids, salt, *, width, height, layout, steps, mb, me):
    """Jitted core: render ``V`` level cameras ``cams (V, 4) = (x, y, z, yaw)`` in the city frame.

    Returns ``{"views": [per-view dict of maps], "boxes": (K, 4), "box_valid": (K,)}`` (boxes of
    the first view); colour maps are channel-first ``(3, H, W)``.  Compiled with XLA's optimisations
    even under ``jax_disable_most_optimizations`` (:data:`privslam_jax._xla.OPTIMISED`): rendering
    dominates whatever calls it, and the pixels stay those of the default compilation.
    """
    uu = jnp.arange(width, dtype=jnp.float32)
    vv = jnp.broadcast_to(jnp.arange(height, dtype=jnp.float32)[:, None], (height, width))
    views = [_view(cams[i], intr, uu, vv, prisms, ells, salt, layout, steps, mb, me) for i in range(cams.shape[0])]
    boxes, valid = _boxes(views[0]["instance_ids"], slot_ids)
    return {"views": views, "boxes": boxes, "box_valid": valid}


@functools.partial(jax.jit, static_argnames=("layout", "steps", "mb", "me"), compiler_options=OPTIMISED)
def _cast(cam, intr, uv, prisms, ells, salt, *, layout, steps, mb, me):
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    o = cam[0:3]
    cos, sin = jnp.cos(cam[3]), jnp.sin(cam[3])
    xc = (uv[:, 0] - cx) / fx
    dxz = jnp.stack([xc * cos + sin, -xc * sin + cos], axis=1)
    yc = ((uv[:, 1] - cy) / fy)[None, :]
    hit = trace(o, dxz, yc, prisms, ells, salt, layout, steps, mb, me)
    obj = hit["t_obj"] < hit["t_static"]
    t = jnp.minimum(hit["t_obj"], hit["t_static"])[0]
    table = jnp.concatenate([prisms, ells], axis=0)
    inst = jnp.round(table[hit["o_row"][0], 22]).astype(jnp.int32)
    return t, jnp.where(obj[0], inst, 0), hit["t_static"][0]


class SyntheticSequence:
    """A rendered-on-demand synthetic sequence (see the module docstring); build with :func:`make_sequence`."""

    def __init__(self, config: SynthConfig):
        config.validate()
        self.config = config
        self.layout = CityLayout()
        rng = np.random.default_rng(config.seed)
        duration = (config.num_frames - 1) / config.fps
        self._s0 = 3.0
        length = float(self._s0 + config.speed * duration + 120.0)
        if config.route == "loop":
            self.path = make_loop_path(rng, self.layout, length, tuple(int(b) for b in config.loop_blocks))
        else:
            self.path = make_path(rng, self.layout, length)
        self.objects = so.place_objects(rng, self.path, self.layout, self._s0, float(config.speed), float(duration),
                                        float(config.object_density))
        self.instance_classes: dict[int, int] = {i + 1: o.class_id for i, o in enumerate(self.objects)}
        self._classes = np.array([o.class_id for o in self.objects], np.int32)
        self._table = so.ObjectTable(self.objects)
        fx = config.fx_ratio * config.width
        self.camera = Camera(fx=fx, fy=fx, cx=(config.width - 1) / 2.0, cy=(config.height - 1) / 2.0,
                             width=config.width, height=config.height,
                             baseline=config.baseline if config.stereo else None)
        self._intr = np.array([fx, fx, (config.width - 1) / 2.0, (config.height - 1) / 2.0], np.float32)
        self._salt = _salt(config.seed)
        self.timestamps = np.arange(config.num_frames, dtype=np.float64) / config.fps
        s = self._s0 + config.speed * self.timestamps
        pos, tan = self.path.evaluate(s, self.layout.lane_offset)
        yaw = np.arctan2(tan[:, 0], tan[:, 1])
        self._cams = np.stack([pos[:, 0], np.full_like(yaw, -config.camera_height), pos[:, 1], yaw], axis=1)
        T = np.zeros((config.num_frames, 4, 4))
        c, sn = np.cos(yaw), np.sin(yaw)
        T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = c, sn, -sn, c
        T[:, 1, 1] = 1.0
        T[:, 3, 3] = 1.0
        T[:, :3, 3] = self._cams[:, :3]
        self._T_city_c = T
        self._T_w_city = np.linalg.inv(T[0])
        self._T_w_c = self._T_w_city @ T

    # -- host-side inputs ----------------------------------------------------------------------
    def __len__(self) -> int:
        return self.config.num_frames

    def _check(self, i: int | np.integer) -> int:
        i = int(i)
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame index {i} out of range for a sequence of {n} frames")
        return i % n

    def _cams_of(self, i: int) -> np.ndarray:
        cam = self._cams[i]
        if not self.config.stereo:
            return cam[None].astype(np.float32)
        b = self.config.baseline
        right = cam + np.array([b * np.cos(cam[3]), 0.0, -b * np.sin(cam[3]), 0.0])
        return np.stack([cam, right]).astype(np.float32)

    def frame_inputs(self, i: int | np.integer) -> dict:
        """Host-side inputs of the jitted renderer for frame ``i`` (cameras, intrinsics, object tables)."""
        i = self._check(i)
        cfg = self.config
        t = float(self.timestamps[i])
        s_cam = self._s0 + cfg.speed * t
        pos, yaw, base = so.object_poses(self._table, self.path, t, float(s_cam))
        cam = self._cams[i]
        tan_half = float((cfg.width / 2 + 2) / self._intr[0])
        sel = so.select_visible(pos, base, self._classes, cam[[0, 2]], float(cam[3]), tan_half, 250.0, cfg.max_objects,
                                float(cfg.baseline) if cfg.stereo else 0.0)
        prisms, ells, ids = so.frame_primitives(self._table, sel, pos, yaw, base, t, cfg.max_objects)
        return {"cams": self._cams_of(i), "intr": self._intr, "prisms": prisms, "ells": ells, "slot_ids": ids,
                "salt": self._salt}

    def _static_kw(self) -> dict:
        cfg = self.config
        return {"layout": self.layout, "steps": cfg.dda_steps, "mb": cfg.column_prisms, "me": cfg.column_ellipsoids}

    def render_device(self, i: int | np.integer) -> dict:
        """All maps of frame ``i`` as device arrays (no host transfer; used by the benchmark)."""
        cfg = self.config
        return render_views(**self.frame_inputs(i), width=cfg.width, height=cfg.height, **self._static_kw())

    def __getitem__(self, i: int | np.integer) -> SynthFrame:
        i = self._check(i)
        inputs = self.frame_inputs(i)
        cfg = self.config
        out = jax.device_get(render_views(**inputs, width=cfg.width, height=cfg.height, **self._static_kw()))
        valid = np.asarray(out["box_valid"])
        inst_of_box = inputs["slot_ids"][valid].astype(np.int32)
        stereo = cfg.stereo
        v = out["views"]

        def rgb(planes):
            return np.ascontiguousarray(np.moveaxis(np.asarray(planes), 0, -1), dtype=np.float32)

        return SynthFrame(
            index=i,
            timestamp=float(self.timestamps[i]),
            image=rgb(v[0]["image"]),
            image_right=rgb(v[1]["image"]) if stereo else None,
            depth=np.asarray(v[0]["depth"], np.float32),
            depth_right=np.asarray(v[1]["depth"], np.float32) if stereo else None,
            instance_ids=np.asarray(v[0]["instance_ids"], np.int32),
            background=rgb(v[0]["background"]),
            background_right=rgb(v[1]["background"]) if stereo else None,
            boxes=np.asarray(out["boxes"])[valid].astype(np.float32).reshape(-1, 4),
            class_ids=np.array([self.instance_classes[int(k)] for k in inst_of_box], np.int32),
            instance_of_box=inst_of_box,
            T_w_c=self._T_w_c[i].copy(),
            background_depth=np.asarray(v[0]["background_depth"], np.float32),
            instance_ids_right=np.asarray(v[1]["instance_ids"], np.int32) if stereo else None,
        )

    def __iter__(self) -> Iterator[SynthFrame]:
        for i in range(len(self)):
            yield self[i]

    @property
    def trajectory(self) -> Trajectory:
        """Ground-truth ``T_w_c`` of the left camera for every frame."""
        return Trajectory.from_matrices(self.timestamps, self._T_w_c)

    @property
    def poses(self) -> np.ndarray:
        """``(N, 4, 4)`` float64 ground-truth ``T_w_c`` (left camera)."""
        return self._T_w_c.copy()

    def cast(self, i: int | np.integer, uv: np.ndarray, right: bool = False) -> dict[str, np.ndarray]:
        """Cast rays through arbitrary sub-pixel positions ``uv (N, 2)`` of frame ``i``.

        Returns ``depth`` (z-depth, ``inf`` = sky), ``points_w`` (world-frame hit points),
        ``instance`` (0 = static surface) and ``static_depth`` (ignoring objects).  Ground truth
        for correspondences (e.g. the multi-view and stereo consistency tests).
        """
        i = self._check(i)
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        inp = self.frame_inputs(i)
        cams = inp["cams"]
        if right and not self.config.stereo:
            b = self.config.baseline
            cams = np.stack([cams[0], cams[0] + np.array([b * np.cos(cams[0, 3]), 0, -b * np.sin(cams[0, 3]), 0], np.float32)])
        cam = cams[1] if right else cams[0]
        t, inst, ts = jax.device_get(_cast(cam, inp["intr"], uv, inp["prisms"], inp["ells"], inp["salt"], **self._static_kw()))
        t = np.asarray(t, np.float64)
        fx, fy, cx, cy = self._intr.astype(np.float64)
        p_c = np.stack([(uv[:, 0] - cx) / fx * t, (uv[:, 1] - cy) / fy * t, t], axis=1)
        T = self._T_w_c[i].copy()
        if right:
            T = T @ np.array([[1, 0, 0, self.config.baseline], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        with np.errstate(invalid="ignore"):
            p_w = p_c @ T[:3, :3].T + T[:3, 3]
        return {"depth": t, "points_w": p_w, "instance": np.asarray(inst, np.int32), "static_depth": np.asarray(ts, np.float64)}


def make_sequence(config: SynthConfig = SynthConfig()) -> SyntheticSequence:
    """Build the synthetic sequence of ``config`` (host-side layout; frames render lazily)."""
    return SyntheticSequence(config)


def preview(frame: SynthFrame) -> np.ndarray:
    """A uint8 RGB contact sheet of one frame: image with boxes, instance mask, background, depth."""
    import cv2

    img = (np.clip(frame.image, 0, 1) * 255).round().astype(np.uint8)
    boxed = img.copy()
    for (x1, y1, x2, y2), c in zip(frame.boxes.astype(int), frame.class_ids):
        colour = (255, 40, 40) if c == 0 else (40, 220, 255)
        cv2.rectangle(boxed, (int(x1), int(y1)), (int(x2) - 1, int(y2) - 1), colour, 1)
    ids = frame.instance_ids
    rnd = np.random.default_rng(0).integers(60, 255, size=(int(ids.max()) + 1, 3)).astype(np.uint8)
    rnd[0] = 0
    mask = np.where(ids[..., None] > 0, rnd[ids], img // 3)
    bg = (np.clip(frame.background, 0, 1) * 255).round().astype(np.uint8)
    d = np.clip(frame.depth / 80.0, 0.0, 1.0)
    depth = cv2.applyColorMap(((1 - d) * 255).astype(np.uint8), cv2.COLORMAP_MAGMA)[..., ::-1]
    depth[frame.depth == 0] = 0
    return np.concatenate([boxed, mask, bg, depth], axis=0)


def main(argv: list[str] | None = None) -> int:
    """``python -m privslam_jax.data.synthetic --frame 60 --out preview.jpg``: write a contact sheet."""
    import argparse

    import cv2

    ap = argparse.ArgumentParser(description="Render one synthetic frame as a contact sheet "
                                             "(image + boxes, instance mask, object-free background, depth).")
    ap.add_argument("--frame", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="synthetic_preview.jpg")
    args = ap.parse_args(argv)
    seq = make_sequence(SynthConfig(num_frames=args.frame + 1, seed=args.seed))
    sheet = preview(seq[args.frame])
    cv2.imwrite(args.out, sheet[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
