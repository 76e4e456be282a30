"""Frame-level privacy filter: remove each masked object and fill the hole.

``filter_frame(image, masks, method)`` with ``masks (K, H, W)`` one per object (already dilated,
see :mod:`privslam_jax.inpaint.masks`). ``method`` is ``"edgeconnect"`` (crop-based inference
with an :class:`Inpainter`, see :mod:`privslam_jax.inpaint.crops`) or any baseline of
:mod:`privslam_jax.inpaint.baselines` (applied to the union mask). A frame without objects is
returned bit-identical. Pixels outside the union mask are never changed.

EdgeConnect inference on one ``S × S`` crop (official ``EdgeConnect.inpaint`` flow, with the
leak-free edges of :func:`~privslam_jax.inpaint.masks.safe_canny`):
``m`` = hole, ``b`` = hole grown by the edge band;
``e = G_edge([grey·(1−b) + b, edges·(1−b), b])``, ``ê = e·b + edges·(1−b)``;
``y = G_img([rgb·(1−m) + m, ê])``, output ``y·m + rgb·(1−m)``.  A checkpoint may add inference
settings (:class:`InpainterConfig`): the mean with the mirrored crop's mirrored fill
(``flip_average``, :func:`inpaint_inference`) and, on the frame, a blend with the prefill method run at
full resolution (``prefill_blend``, by distance to the visible pixels with ``prefill_blend_distance``
in frame or model pixels, ``prefill_blend_unit``: :func:`network_share`).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Shaped
from scipy import ndimage

from privslam_jax._xla import OPTIMISED
from privslam_jax.data.images import as_unit_image, like_input
from privslam_jax.inpaint import baselines
from privslam_jax.inpaint.crops import crop_box, extract, paste_back
from privslam_jax.inpaint.edgeconnect import CPU_WIDTH, EdgeGenerator, InpaintGenerator
from privslam_jax.inpaint.masks import safe_canny, to_grey

__all__ = ["EMBEDDED_INPAINTER", "EMBEDDED_REAL_INPAINTER", "EMBEDDED_TRADEOFF_INPAINTER", "FILTER_METHODS", "Inpainter",
           "InpainterConfig", "blend_distance", "edgeconnect_forward", "filter_frame", "hole_distance", "inpaint_inference",
           "network_share"]

INPAINTER_METHODS: tuple[str, ...] = ("edgeconnect", "tradeoff")
"""Filter methods run by an EdgeConnect :class:`Inpainter`: ``"tradeoff"`` is the same network with the
checkpoint trained for privacy and SLAM accuracy at once (:data:`EMBEDDED_TRADEOFF_INPAINTER`)."""
FILTER_METHODS: tuple[str, ...] = INPAINTER_METHODS + baselines.METHODS
EMBEDDED_INPAINTER = Path(__file__).resolve().parents[1] / "assets" / "inpainter_cpu16.npz"
"""The shipped CPU-preset checkpoint trained on the synthetic world (``docs/model_card_inpainter.md``)."""
EMBEDDED_REAL_INPAINTER = EMBEDDED_INPAINTER.with_name("inpainter_cpu16_real.npz")
"""The same network fine-tuned on real street frames, run at 96² crops (``docs/model_card_inpainter_real.md``)."""
EMBEDDED_TRADEOFF_INPAINTER = EMBEDDED_INPAINTER.with_name("inpainter_tradeoff.npz")
"""The synthetic-world checkpoint fine-tuned for privacy and SLAM accuracy at once, the chosen point of the
Pareto front (``train/tradeoff.py``, ``docs/model_card_inpainter_tradeoff.md``); ``method="tradeoff"``."""


@dataclasses.dataclass(frozen=True)
class InpainterConfig:
    """Architecture and inference settings of an EdgeConnect inpainter."""

    width: int = CPU_WIDTH
    """Channel width (official 64; CPU preset 16)."""
    inpaint_width: int = 0
    """The image generator's own channel width (0: :attr:`width`); a wider G2 than G1 is made by
    :func:`~privslam_jax.inpaint.widen.widen_inpaint_generator`."""
    num_residual_blocks: int = 8
    """Residual blocks of each generator (official 8)."""
    size: int = 64
    """Model resolution: every crop is resized to ``size × size`` (multiple of 4)."""
    crop_pad: float = 0.5
    """Context around the mask's bounding box, as a share of its larger side, on each side."""
    min_crop: int = 32
    """Smallest crop side in frame pixels."""
    sigma: float = 2.0
    """Canny σ (EdgeConnect: 2)."""
    prefill: str = "white"
    """What the image generator sees in the hole: ``"white"`` (official EdgeConnect: 1) or a
    deterministic privacy-safe fill of :mod:`~privslam_jax.inpaint.baselines` computed from the
    crop's outside pixels (``"telea"``, ``"ns"``, ``"gray"``, ``"black"``), so the network starts
    from that fill and learns a correction. Still independent of every hidden pixel."""
    residual: bool = False
    """If true, the image generator predicts a correction of the prefill instead of the pixels:
    ``y = clip(fill + tanh(logits), 0, 1)`` (official EdgeConnect: ``y = (tanh(logits) + 1) / 2``).
    The generator has no skip connections, so copying a good prefill through its 4× bottleneck
    is hard; as a residual, zero logits reproduce the prefill exactly."""
    flip_average: bool = False
    """Inference only (:func:`inpaint_inference`): the mean of the crop's fill and the mirror image of
    the mirrored crop's fill (test-time augmentation). ``train/inpaint.py`` trains without it; the trade-off
    trainer optimises the filter as it runs, with it."""
    prefill_blend: float = 1.0
    """Inference only: inside the hidden pixels of the frame, ``prefill_blend · y + (1 − prefill_blend) ·
    p``, where ``y`` is the network's pasted fill and ``p`` the :attr:`prefill` method run on the whole
    frame at full resolution (:func:`privslam_jax.inpaint.baselines.fill`, from the visible pixels only).
    Below 1 it mixes the two fills: the network's is right on average but blurred by the model size,
    the full-resolution prefill keeps fine detail, and their errors are partly independent. 1 keeps
    the network's fill. As :attr:`flip_average` for training. With :attr:`prefill_blend_distance` it
    is the network's share deep inside the hole only."""
    prefill_blend_distance: float = 0.0
    """Inference only, in frame pixels: if positive, the network's share of a hidden pixel at Euclidean
    distance ``d`` from the nearest visible pixel is ``prefill_blend · (1 − exp(−d / prefill_blend_distance))``
    (:func:`network_share`) instead of the constant ``prefill_blend``: next to the visible pixels the
    full-resolution prefill, which continues them, is the better estimate; deep inside the hole the
    network's. 0 keeps the constant share. A function of the masks only, so still independent of every
    hidden pixel."""
    prefill_blend_unit: str = "frame"
    """What :attr:`prefill_blend_distance` is measured in: ``"frame"`` pixels, or ``"model"`` pixels,
    i.e. frame pixels divided by the resize factor of the pixel's crop (its larger side / :attr:`size`;
    the mean over the crops of the objects covering the pixel). In model pixels the band where
    the full-resolution prefill beats the network grows with the object, as the network's fill,
    made at ``size × size`` and resized up, loses detail in proportion."""

    def __post_init__(self):
        if self.prefill not in PREFILLS:
            raise ValueError(f"prefill must be one of {PREFILLS}, got {self.prefill!r}")
        if self.inpaint_width < 0:
            raise ValueError(f"inpaint_width must be >= 0 (0: width), got {self.inpaint_width}")
        if not 0.0 <= self.prefill_blend <= 1.0:
            raise ValueError(f"prefill_blend must lie in [0, 1], got {self.prefill_blend}")
        if not 0.0 <= self.prefill_blend_distance < float("inf"):
            raise ValueError(f"prefill_blend_distance must be >= 0 pixels and finite, got {self.prefill_blend_distance}")
        if self.prefill_blend_unit not in ("frame", "model"):
            raise ValueError(f"prefill_blend_unit must be 'frame' or 'model', got {self.prefill_blend_unit!r}")
        if self.blends_prefill and self.prefill == "white":
            raise ValueError("prefill_blend < 1 or prefill_blend_distance > 0 needs a prefill method "
                             "(telea, ns, gray, black), not white")

    @property
    def blends_prefill(self) -> bool:
        """Whether inference blends the network's fill with the full-resolution prefill."""
        return self.prefill_blend != 1.0 or self.prefill_blend_distance > 0.0

    @property
    def g2_width(self) -> int:
        """The image generator's channel width."""
        return self.inpaint_width or self.width


PREFILLS: tuple[str, ...] = ("white", "gray", "black", "telea", "ns")


def edgeconnect_forward(
    edge_gen: EdgeGenerator,
    inpaint_gen: InpaintGenerator,
    rgb: Float[Array, "B S S 3"],
    grey: Float[Array, "B S S 1"],
    edges: Float[Array, "B S S 1"],
    hole: Float[Array, "B S S 1"],
    edge_hole: Float[Array, "B S S 1"],
    use_edge_model: bool = True,
    hole_fill: Float[Array, "B S S 3"] | None = None,
    residual: bool = False,
) -> tuple[Float[Array, "B S S 3"], Float[Array, "B S S 1"], Float[Array, "B S S 3"]]:
    """Both stages; returns ``(composited image, full edge map ê, raw generator output)``.

    ``hole_fill``: what G2 sees inside the hole (default 1, the official white; see
    :attr:`InpainterConfig.prefill`); ``residual``: G2 corrects that fill
    (:attr:`InpainterConfig.residual`).

    ``use_edge_model=False`` is an ablation: ê keeps only the edges outside the band (none drawn
    inside), to measure what the edge generator contributes."""
    b = edge_hole
    if use_edge_model:
        e = edge_gen(jnp.concatenate([grey * (1 - b) + b, edges * (1 - b), b], axis=-1))
    else:
        e = jnp.zeros_like(edges)
    e_full = e * b + edges * (1 - b)
    fill = 1.0 if hole_fill is None else hole_fill
    y = inpaint_gen(jnp.concatenate([rgb * (1 - hole) + fill * hole, e_full], axis=-1))
    if residual:
        y = residual_output(y, fill)
    return y * hole + rgb * (1 - hole), e_full, y


def inpaint_inference(
    edge_gen: EdgeGenerator,
    inpaint_gen: InpaintGenerator,
    rgb: Float[Array, "B S S 3"],
    grey: Float[Array, "B S S 1"],
    edges: Float[Array, "B S S 1"],
    hole: Float[Array, "B S S 1"],
    edge_hole: Float[Array, "B S S 1"],
    config: InpainterConfig,
    use_edge_model: bool = True,
    hole_fill: Float[Array, "B S S 3"] | None = None,
) -> Float[Array, "B S S 3"]:
    """The composited crops as the filter makes them: :func:`edgeconnect_forward`, with
    :attr:`InpainterConfig.flip_average` if ``config`` asks for it. Outside the hole it returns ``rgb``
    exactly."""
    def forward(flip: bool) -> Float[Array, "B S S 3"]:
        m = (lambda x: x[:, :, ::-1]) if flip else (lambda x: x)  # mirror the width axis
        fill = None if hole_fill is None else m(hole_fill)
        out = edgeconnect_forward(edge_gen, inpaint_gen, m(rgb), m(grey), m(edges), m(hole), m(edge_hole),
                                  use_edge_model, fill, config.residual)[0]
        return m(out)

    y = forward(False)
    return 0.5 * (y + forward(True)) if config.flip_average else y


def residual_output(y: Float[Array, "B S S 3"], fill: Float[Array, "B S S 3"] | float) -> Float[Array, "B S S 3"]:
    """``clip(fill + tanh(logits), 0, 1)`` from G2's ``y = (tanh(logits) + 1) / 2``."""
    return jnp.clip(fill + 2.0 * y - 1.0, 0.0, 1.0)


class Inpainter:
    """EdgeConnect generators in eval mode plus one jitted forward at the model resolution."""

    def __init__(self, edge_gen: EdgeGenerator, inpaint_gen: InpaintGenerator, config: InpainterConfig,
                 use_edge_model: bool = True):
        if config.size % 4:
            raise ValueError(f"model size must be a multiple of 4, got {config.size}")
        nets = (edge_gen.width, inpaint_gen.width, edge_gen.num_residual_blocks, inpaint_gen.num_residual_blocks)
        if nets != (config.width, config.g2_width, config.num_residual_blocks, config.num_residual_blocks):
            raise ValueError(f"generators of widths {nets[:2]} and {nets[2:]} residual blocks do not match the config's "
                             f"widths {(config.width, config.g2_width)} and {config.num_residual_blocks} blocks")
        self.config = config
        self.use_edge_model = use_edge_model
        edge_gen.eval()
        inpaint_gen.eval()
        self.graphdef, self.state = nnx.split((edge_gen, inpaint_gen))

        def run(state, rgb, grey, edges, hole, edge_hole, hole_fill):
            eg, ig = nnx.merge(self.graphdef, state)
            return inpaint_inference(eg, ig, rgb, grey, edges, hole, edge_hole, config, use_edge_model, hole_fill)

        self._run = jax.jit(run, compiler_options=OPTIMISED)  # run-bound (privslam_jax._xla.OPTIMISED)

    @classmethod
    def embedded(cls, domain: str = "synthetic") -> Inpainter:
        """A checkpoint shipped in the package, loaded once per process: ``domain="synthetic"``
        (:data:`EMBEDDED_INPAINTER`, trained on the synthetic world), ``"real"``
        (:data:`EMBEDDED_REAL_INPAINTER`, fine-tuned on real street frames) or ``"tradeoff"``
        (:data:`EMBEDDED_TRADEOFF_INPAINTER`, the synthetic one fine-tuned for privacy and SLAM accuracy)."""
        return _embedded(domain)

    def without_edge_model(self) -> Inpainter:
        """The same generators with the edge generator switched off (ablation, see
        :func:`edgeconnect_forward`)."""
        eg, ig = self.modules
        return Inpainter(eg, ig, self.config, use_edge_model=False)

    @classmethod
    def init(cls, config: InpainterConfig = InpainterConfig(), seed: int = 0) -> Inpainter:
        """Randomly initialised generators (N(0, 0.02)) — for tests and training."""
        rngs = nnx.Rngs(seed)
        eg = EdgeGenerator(num_residual_blocks=config.num_residual_blocks, width=config.width, rngs=rngs)
        ig = InpaintGenerator(num_residual_blocks=config.num_residual_blocks, width=config.g2_width, rngs=rngs)
        return cls(eg, ig, config)

    @property
    def modules(self) -> tuple[EdgeGenerator, InpaintGenerator]:
        return nnx.merge(self.graphdef, self.state)

    def save(self, path: str | Path) -> None:
        """Write the generators' state and config to one ``.npz`` (portable, no pickle)."""
        flat = {".".join(map(str, k)): np.asarray(v) for k, v in nnx.to_flat_state(self.state)}
        cfg = {f"config/{k}": np.asarray(v) for k, v in dataclasses.asdict(self.config).items()}
        from privslam_jax.data.files import write_npz

        write_npz(path, compressed=True, **flat, **cfg)

    @classmethod
    def load(cls, path: str | Path) -> Inpainter:
        """Read an ``.npz`` written by :meth:`save`.

        Anything else raises :class:`~privslam_jax.errors.InputError` naming the file (a missing
        file ``FileNotFoundError``): an archive :func:`~privslam_jax.data.npz.read_npz` refuses
        (truncated, corrupt, object arrays, sizes its headers cannot hold), config entries of the
        wrong type or out of range, missing or extra arrays, wrong shapes or dtypes, NaN or inf
        weights. The arrays' names and shapes are checked before the network is built, so a config
        claiming a huge width allocates nothing.
        """
        from privslam_jax.data.npz import check_finite, read_npz
        from privslam_jax.errors import input_error

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"inpainter checkpoint not found: {path}")
        arrays = read_npz(path)
        fields = {f.name: f.type for f in dataclasses.fields(InpainterConfig)}
        kw = {}
        for k, kind in fields.items():
            if f"config/{k}" in arrays:
                a = arrays.pop(f"config/{k}")
                v = a.item() if a.size == 1 and a.dtype.kind in "biufU" else None
                ok = {"int": isinstance(v, int) and not isinstance(v, bool),
                      "float": isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v),
                      "str": isinstance(v, str), "bool": isinstance(v, bool)}.get(kind, v is not None)
                if not ok:
                    raise input_error(path, f"config/{k} is not a single {kind} value ({a.dtype} {a.shape})")
                kw[k] = v if isinstance(v, str | bool) else float(v) if isinstance(v, float) else int(v)
        try:
            config = InpainterConfig(**kw)
        except (ValueError, TypeError) as err:
            raise input_error(path, "invalid inpainter config", err) from err
        if config.width < 1 or not 0 <= config.num_residual_blocks <= len(arrays):
            raise input_error(path, f"config width {config.width} / {config.num_residual_blocks} residual blocks "
                                    f"do not fit the {len(arrays)} arrays of the file")

        def shapes(width: int, g2_width: int) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
            state = cls.init(dataclasses.replace(config, width=width, inpaint_width=g2_width)).state
            return {".".join(map(str, k)): (v[...].shape, np.dtype(v[...].dtype)) for k, v in nnx.to_flat_state(state)}

        # Every dimension of each generator is affine in its width: derive the expected shapes from
        # tiny networks and check the file against them before building the real one.
        try:
            one, two, two_g2 = shapes(1, 1), shapes(2, 1), shapes(1, 2)
        except (ValueError, TypeError) as err:
            raise input_error(path, "invalid inpainter config", err) from err
        for name, (s1, dtype) in one.items():
            want = tuple(a + (b - a) * (config.width - 1) + (c - a) * (config.g2_width - 1)
                         for a, b, c in zip(s1, two[name][0], two_g2[name][0]))
            if name not in arrays:
                raise input_error(path, f"missing {name}")
            if arrays[name].shape != want or arrays[name].dtype != dtype:
                raise input_error(path, f"{name} is {arrays[name].dtype} {arrays[name].shape}, expected {dtype} {want}")
        extra = sorted(set(arrays) - set(one))
        if extra:
            raise input_error(path, f"unexpected arrays {extra[:3]}")
        check_finite(path, arrays)
        model = cls.init(config)  # names, shapes and dtypes were checked above
        new = [(key, var.replace(jnp.asarray(arrays[".".join(map(str, key))])))
               for key, var in nnx.to_flat_state(model.state)]
        model.state = nnx.from_flat_state(new)
        return model

    def inpaint_crop(self, rgb: np.ndarray, hole: np.ndarray) -> Float[np.ndarray, "S S 3"]:
        """Inpaint one ``(S, S, 3)`` crop whose ``hole`` pixels are already zeroed (float ``[0, 1]`` or uint8)."""
        cfg = self.config
        rgb = as_unit_image(rgb, "inpaint_crop image")
        grey = to_grey(rgb)
        edges, edge_hole = safe_canny(grey, hole, sigma=cfg.sigma)
        f = lambda x: jnp.asarray(x, jnp.float32)[None, ..., None]  # noqa: E731
        fill = baselines.fill(rgb, np.asarray(hole, bool), cfg.prefill)
        out = self._run(self.state, jnp.asarray(rgb)[None], f(grey), f(edges), f(hole), f(edge_hole),
                        jnp.asarray(fill)[None])
        return np.asarray(out[0])


@functools.lru_cache(maxsize=3)
def _embedded(domain: str) -> Inpainter:
    paths = {"synthetic": EMBEDDED_INPAINTER, "real": EMBEDDED_REAL_INPAINTER, "tradeoff": EMBEDDED_TRADEOFF_INPAINTER}
    if domain not in paths:
        raise ValueError(f"domain must be one of {sorted(paths)}, got {domain!r}")
    if not paths[domain].is_file():
        raise FileNotFoundError(f"the embedded {domain} inpainter {paths[domain]} is missing; pass a model path")
    return Inpainter.load(paths[domain])


def network_share(masks: Bool[np.ndarray, "K H W"], config: InpainterConfig) -> Float[np.ndarray, "H W"] | float:
    """The network's share ``w`` of each hidden pixel in the blend ``w · y + (1 − w) · p`` with the
    full-resolution prefill ``p`` (:attr:`InpainterConfig.prefill_blend`): the constant ``a =
    prefill_blend``, or, with ``τ = prefill_blend_distance > 0``, ``a · (1 − exp(−d / τ))`` with ``d``
    the pixel's :func:`blend_distance`. Chosen on the validation frames of the real-frame checkpoint
    (``experiments/inpaint_blend_scan.py``, ``docs/model_card_inpainter_real.md``)."""
    a, tau = config.prefill_blend, config.prefill_blend_distance
    if tau <= 0.0:
        return a
    return (a * -np.expm1(-blend_distance(masks, config) / tau)).astype(np.float32)


def blend_distance(masks: Bool[np.ndarray, "K H W"], config: InpainterConfig) -> Float[np.ndarray, "H W"]:
    """Each pixel's distance to the nearest pixel outside the union of ``masks``
    (:func:`hole_distance`), in the unit of :attr:`InpainterConfig.prefill_blend_unit`: frame pixels,
    or model pixels, i.e. divided by the resize factor ``s`` of the pixel's crop (the crop's larger
    side / ``size``, :func:`~privslam_jax.inpaint.crops.crop_box`), averaged over the masks covering the
    pixel as their fills are (``s = 1`` outside every mask, where the distance is 0)."""
    masks = np.asarray(masks, bool)
    d = hole_distance(masks.any(axis=0))
    if config.prefill_blend_unit == "frame":
        return d
    total = np.zeros(d.shape, np.float64)
    count = np.zeros(d.shape, np.int32)
    for m in masks[masks.any(axis=(1, 2))]:
        box = crop_box(m, config.crop_pad, config.min_crop)
        total[m] += max(box.height, box.width) / config.size
        count[m] += 1
    return (d / np.where(count > 0, total / np.maximum(count, 1), 1.0)).astype(np.float32)


def hole_distance(hidden: Shaped[np.ndarray, "H W"]) -> Float[np.ndarray, "H W"]:
    """Each pixel's exact Euclidean distance in pixels to the nearest pixel outside ``hidden (H, W)``
    (0 outside; ``scipy.ndimage.distance_transform_edt``, Maurer et al. 2003; deterministic, where
    OpenCV's multithreaded precise transform varied in the last bits from call to call)."""
    hidden = np.asarray(hidden, bool)
    if hidden.all():  # no visible pixel: every distance is infinite (the share is a)
        return np.full(hidden.shape, np.inf, np.float32)
    return ndimage.distance_transform_edt(hidden).astype(np.float32)


def filter_frame(
    image: np.ndarray,
    masks: np.ndarray,
    method: str = "edgeconnect",
    *,
    inpainter: Inpainter | None = None,
    seed: int = 0,
) -> Shaped[np.ndarray, "H W 3"]:
    """Hide every object of ``masks (K, H, W)`` in ``image (H, W, 3)`` (see module docstring).

    ``image`` is uint8 (0–255), uint16 or float in ``[0, 1]``
    (:func:`privslam_jax.data.images.as_unit_image`; anything else is refused) and the result has
    its dtype. ``method="edgeconnect"`` without ``inpainter`` uses the embedded default checkpoint,
    ``method="tradeoff"`` the embedded trade-off checkpoint."""
    original = image
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) RGB, got shape {image.shape}")
    h, w = image.shape[:2]
    masks = np.asarray(masks)
    if masks.dtype != np.bool_ or masks.ndim != 3 or masks.shape[1:] != (h, w):
        raise ValueError(f"masks must be bool (K, {h}, {w}), got {masks.dtype} {masks.shape}")
    if method not in FILTER_METHODS:
        raise ValueError(f"unknown filter method {method!r}; choose from {', '.join(FILTER_METHODS)}")
    image = as_unit_image(image, "filter_frame image")
    masks = masks[masks.any(axis=(1, 2))]
    if len(masks) == 0:
        return like_input(image.copy(), original)
    hidden = masks.any(axis=0)
    if method not in INPAINTER_METHODS:
        return like_input(baselines.fill(image, hidden, method, seed=seed), original)
    if inpainter is None:
        inpainter = Inpainter.embedded("tradeoff" if method == "tradeoff" else "synthetic")
    cfg = inpainter.config
    acc = np.zeros((h, w, 3), np.float64)
    cnt = np.zeros((h, w), np.int32)
    for m in masks:
        box = crop_box(m, cfg.crop_pad, cfg.min_crop)
        rgb_s, hole_s = extract(image, hidden, box, cfg.size)
        out = paste_back(inpainter.inpaint_crop(rgb_s, hole_s), box)
        sl = (slice(box.v0, box.v1), slice(box.u0, box.u1))
        own = m[sl]
        acc[sl][own] += out[own]
        cnt[sl][own] += 1
    res = image.copy()
    res[hidden] = (acc[hidden] / cnt[hidden][:, None]).astype(np.float32)
    if cfg.blends_prefill:
        base = baselines.fill(image, hidden, cfg.prefill)
        share = network_share(masks, cfg)
        share = share if np.isscalar(share) else share[hidden][:, None]
        res[hidden] = share * res[hidden] + (1.0 - share) * base[hidden]
    return like_input(res, original)
