"""Training data for the inpainter: callables ``data(step, batch) -> (images, holes)``.

Every batch is a pure function of ``(seed, step)`` (``np.random.default_rng((seed, step))``), so
training resumed after a kill sees exactly the batches it would have seen.

* :class:`CropBank` — ``S × S`` crops around the privacy objects of synthetic frames: target = the
  object-free render (``background``), hole = every pixel that the union of the dilated instance
  masks reaches after resampling. Built from an in-process render
  (:meth:`CropBank.from_synthetic`) or from a sequence written by ``privslam synth``
  (:meth:`CropBank.from_kitti_layout`, needs its ``masks/`` and ``background/`` extras).
* :class:`FolderData` — any folder of images: a random square crop resized to ``S``, with a
  random box (probability ``box_prob``) or irregular brush-stroke mask.
* :class:`RealHoleData` — real frames with holes whose answer is known: real object *shapes*
  (:func:`object_shapes`, e.g. Mask R-CNN masks of other frames) moved onto other image regions,
  cropped exactly as the filter crops at inference (:mod:`privslam_jax.inpaint.crops`), or a
  free-form mask on a random crop; colour frames are turned grey with probability ``grey_prob``.
* :class:`Mixture` — several sources in fixed proportions (e.g. real + synthetic crops).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Bool
from tqdm import tqdm

from privslam_jax.data.files import write_npz
from privslam_jax.data.images import read_raw, read_rgb8
from privslam_jax.inpaint.crops import CropBox, crop_box
from privslam_jax.inpaint.masks import dilate, random_box_mask, random_irregular_mask

__all__ = [
    "IMAGE_SUFFIXES",
    "CropBank",
    "FolderData",
    "Mixture",
    "ObjectShape",
    "RealHoleData",
    "image_paths",
    "object_shapes",
    "place_shape",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm")


def _resize(x: np.ndarray, size: int) -> np.ndarray:
    shrink = x.shape[0] > size or x.shape[1] > size
    return cv2.resize(x, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def _crops_of_frame(
    background: np.ndarray, instance_ids: np.ndarray, size: int, dilation: int, min_area: int, pad: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    ids = np.unique(instance_ids[instance_ids > 0])
    union = dilate(instance_ids > 0, dilation)
    imgs, holes = [], []
    for i in ids:
        m = instance_ids == i
        if m.sum() < min_area:
            continue
        box = crop_box(dilate(m, dilation), pad, 32)
        sl = (slice(box.v0, box.v1), slice(box.u0, box.u1))
        imgs.append((np.clip(_resize(background[sl], size), 0, 1) * 255 + 0.5).astype(np.uint8))
        holes.append(_resize(union[sl].astype(np.float32), size) > 0)
    return imgs, holes


@dataclasses.dataclass
class CropBank:
    """Pre-extracted object crops (uint8 targets, bool holes) sampled per step."""

    images: np.ndarray
    """``(N, S, S, 3)`` uint8 object-free targets."""
    holes: np.ndarray
    """``(N, S, S)`` bool holes."""
    seed: int = 0
    """Data seed (batch composition and flips)."""

    def __post_init__(self):
        if len(self.images) == 0:
            raise ValueError("the crop bank is empty (no privacy objects large enough in the frames)")

    def __len__(self) -> int:
        return len(self.images)

    def __call__(self, step: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng((self.seed, step))
        idx = rng.integers(0, len(self.images), batch)
        flip = rng.random(batch) < 0.5
        imgs = self.images[idx].astype(np.float32) / np.float32(255)
        holes = self.holes[idx].copy()
        imgs[flip] = imgs[flip, :, ::-1]
        holes[flip] = holes[flip, :, ::-1]
        return imgs, holes

    def save(self, path: str | Path) -> None:
        write_npz(path, compressed=True, images=self.images, holes=self.holes)

    @classmethod
    def load(cls, path: str | Path, seed: int = 0) -> CropBank:
        """Read an ``.npz`` written by :meth:`save`: ``images`` ``(N, S, S, 3)`` uint8, ``holes`` ``(N, S, S)`` bool.

        Anything else (an archive :func:`~privslam_jax.data.npz.read_npz` refuses, missing or extra
        arrays, other shapes or dtypes, no crops) raises :class:`~privslam_jax.errors.InputError`
        naming the file; a missing file ``FileNotFoundError``.
        """
        from privslam_jax.data.npz import read_npz
        from privslam_jax.errors import input_error

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"crop bank not found: {path}")
        d = read_npz(path)
        if set(d) != {"images", "holes"}:
            raise input_error(path, f"a crop bank holds the arrays 'images' and 'holes', this file {sorted(d)[:4]}")
        images, holes = d["images"], d["holes"]
        if images.dtype != np.uint8 or images.ndim != 4 or images.shape[3] != 3 or images.shape[1] != images.shape[2]:
            raise input_error(path, f"images must be uint8 (N, S, S, 3), got {images.dtype} {images.shape}")
        if holes.dtype != np.bool_ or holes.shape != images.shape[:3]:
            raise input_error(path, f"holes must be bool {images.shape[:3]}, got {holes.dtype} {holes.shape}")
        if len(images) == 0:
            raise input_error(path, "the crop bank is empty")
        return cls(images, holes, seed)

    @classmethod
    def concat(cls, banks: list[CropBank], seed: int = 0) -> CropBank:
        """One bank holding the crops of several (e.g. one per synthetic world)."""
        if not banks:
            raise ValueError("concat needs at least one crop bank")
        return cls(np.concatenate([b.images for b in banks]), np.concatenate([b.holes for b in banks]), seed)

    @classmethod
    def from_frames(
        cls,
        frames,
        size: int,
        *,
        seed: int = 0,
        dilation: int = 4,
        min_area: int = 64,
        pad: float = 0.5,
    ) -> CropBank:
        """From an iterable of objects with ``background`` and ``instance_ids`` attributes."""
        imgs: list[np.ndarray] = []
        holes: list[np.ndarray] = []
        for f in frames:
            if f.background is None or f.instance_ids is None:
                raise ValueError("frames need background and instance_ids (synthetic ground truth)")
            a, b = _crops_of_frame(f.background, f.instance_ids, size, dilation, min_area, pad)
            imgs += a
            holes += b
        if not imgs:
            raise ValueError("no privacy object of at least min_area pixels in the frames")
        return cls(np.stack(imgs), np.stack(holes), seed)

    @classmethod
    def from_synthetic(cls, synth_config, size: int, *, seed: int = 0, frame_stride: int = 1,
                       progress: bool = True, **kw) -> CropBank:
        """Render ``privslam_jax.data.synthetic`` frames in-process (every ``frame_stride``-th)."""
        from privslam_jax.data.synthetic import make_sequence

        seq = make_sequence(synth_config)
        idx = range(0, len(seq), frame_stride)
        frames = (seq[i] for i in tqdm(idx, desc="render", disable=not progress))
        return cls.from_frames(frames, size, seed=seed, **kw)

    @classmethod
    def from_kitti_layout(cls, sequence_dir: str | Path, size: int, *, seed: int = 0, frame_stride: int = 1,
                          progress: bool = True, **kw) -> CropBank:
        """From a sequence written by ``privslam synth`` (``masks/`` and ``background/`` extras)."""
        from privslam_jax.data.kitti import KittiSequence

        seq = KittiSequence(sequence_dir)
        if not (seq.has_extra("masks") and seq.has_extra("background")):
            raise ValueError(f"{sequence_dir}: needs the masks/ and background/ folders of `privslam synth`")
        idx = range(0, len(seq), frame_stride)
        frames = (seq[i] for i in tqdm(idx, desc="read", disable=not progress))
        return cls.from_frames(frames, size, seed=seed, **kw)


def image_paths(*sources: str | Path) -> list[Path]:
    """Image files (any of :data:`IMAGE_SUFFIXES`): each source is an image file or a folder
    (its images, sorted, recursively), in the order given."""
    out: list[Path] = []
    for src in map(Path, sources):
        if src.is_file():
            if src.suffix.lower() not in IMAGE_SUFFIXES:
                raise ValueError(f"not an image file ({', '.join(IMAGE_SUFFIXES)}): {src}")
            out.append(src)
            continue
        if not src.is_dir():
            raise FileNotFoundError(f"image file or folder not found: {src}")
        found = sorted(p for p in src.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not found:
            raise ValueError(f"no images ({', '.join(IMAGE_SUFFIXES)}) under {src}")
        out += found
    return out


class _ImageCache:
    """``cache(i)``: the decoded RGB uint8 image ``paths[i]``, at most ``size`` kept (oldest dropped)."""

    def __init__(self, paths: list[Path], size: int):
        self.paths, self.size = paths, size
        self._images: dict[int, np.ndarray] = {}

    def __call__(self, i: int) -> np.ndarray:
        if i not in self._images:
            if len(self._images) >= self.size:
                self._images.pop(next(iter(self._images)))
            self._images[i] = read_rgb8(self.paths[i])
        return self._images[i]


@dataclasses.dataclass(frozen=True)
class ObjectShape:
    """One object's binary silhouette (tight bounding box) and where it sat in its frame."""

    mask: np.ndarray
    """``(h, w)`` bool silhouette."""
    v_center: float
    """Row of its centre as a share of the frame height (keeps perspective when moved)."""
    frame_width: int
    """Width of the frame it came from (scales the shape to other cameras)."""


def object_shapes(mask_paths: list[Path], min_area: int = 200) -> list[ObjectShape]:
    """Connected components of ``min_area``+ pixels of binary mask images (non-zero = object)."""
    shapes = []
    for p in mask_paths:
        m = read_raw(p)
        m = m if m.ndim == 2 else m[..., 0]
        n, lab, stats, cent = cv2.connectedComponentsWithStats((m > 127).astype(np.uint8))
        for k in range(1, n):
            u0, v0, w, h, area = stats[k]
            if area >= min_area:
                shapes.append(ObjectShape(lab[v0:v0 + h, u0:u0 + w] == k, float(cent[k][1] / m.shape[0]),
                                          m.shape[1]))
    if not shapes:
        raise ValueError(f"no object of at least {min_area} px in {len(mask_paths)} mask images")
    return shapes


def place_shape(
    rng: np.random.Generator, shape: ObjectShape, height: int, width: int, scale: tuple[float, float] = (0.6, 1.4),
    v_jitter: float = 0.1,
) -> Bool[np.ndarray, "H W"]:
    """``shape`` moved onto a ``height × width`` frame: scaled by the frame-width ratio times a random
    factor, at a random column and near its original relative row (± ``v_jitter`` of the height)."""
    f = width / shape.frame_width * rng.uniform(*scale)
    h, w = shape.mask.shape
    f = min(f, 0.9 * height / h, 0.9 * width / w)
    sh, sw = max(round(h * f), 2), max(round(w * f), 2)
    m = cv2.resize(shape.mask.astype(np.uint8), (sw, sh), interpolation=cv2.INTER_NEAREST).astype(bool)
    vc = (shape.v_center + rng.uniform(-v_jitter, v_jitter)) * height
    v0 = int(np.clip(round(vc - sh / 2), 0, height - sh))
    u0 = int(rng.integers(0, width - sw + 1))
    out = np.zeros((height, width), dtype=bool)
    out[v0:v0 + sh, u0:u0 + sw] = m
    return out


class RealHoleData:
    """Real frames with known-answer holes, cropped as at inference (see module docstring).

    Per sample: a random frame (colour frames grey with probability ``grey_prob``); with
    probability ``free_prob`` a random square crop with a free-form mask (as :class:`FolderData`),
    otherwise a random shape of ``shapes`` placed by :func:`place_shape`, dilated by
    ``dilation`` px, the crop = :func:`~privslam_jax.inpaint.crops.crop_box` around it, target =
    the frame's crop resized to ``size``, hole = every model pixel the mask reaches. Horizontal
    flips. Pure function of ``(seed, step)``.
    """

    def __init__(self, paths: list[Path], shapes: list[ObjectShape], size: int, *, seed: int = 0,
                 free_prob: float = 0.25, grey_prob: float = 0.3, dilation: int = 4, pad: float = 0.5,
                 min_crop: int = 32, cache: int = 256):
        if not paths:
            raise ValueError("RealHoleData needs at least one image")
        if not shapes:
            raise ValueError("RealHoleData needs at least one object shape")
        self.paths, self.shapes, self.size, self.seed = list(paths), list(shapes), size, seed
        self.free_prob, self.grey_prob, self.dilation = free_prob, grey_prob, dilation
        self.pad, self.min_crop = pad, min_crop
        self._image = _ImageCache(self.paths, cache)

    def sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One ``(target (S, S, 3) float32, hole (S, S) bool)``."""
        s = self.size
        img = self._image(int(rng.integers(len(self.paths))))
        if rng.random() < self.grey_prob:
            img = np.repeat(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=-1)
        h, w = img.shape[:2]
        if rng.random() < self.free_prob:
            side = int(rng.integers(min(s, h, w), min(h, w) + 1))
            v0, u0 = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
            box = CropBox(v0, v0 + side, u0, u0 + side)
            mk = random_box_mask if rng.random() < 0.3 else random_irregular_mask
            hole = mk(rng, s, s)
        else:
            mask = dilate(place_shape(rng, self.shapes[int(rng.integers(len(self.shapes)))], h, w), self.dilation)
            box = crop_box(mask, self.pad, self.min_crop)
            hole = _resize(mask[box.v0:box.v1, box.u0:box.u1].astype(np.float32), s) > 0
        crop = _resize(img[box.v0:box.v1, box.u0:box.u1], s).astype(np.float32) / np.float32(255)
        if rng.random() < 0.5:
            crop, hole = crop[:, ::-1], hole[:, ::-1]
        return np.ascontiguousarray(crop), np.ascontiguousarray(hole)

    def __call__(self, step: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng((self.seed, step))
        imgs, holes = zip(*(self.sample(rng) for _ in range(batch)), strict=True)
        return np.stack(imgs), np.stack(holes)


class Mixture:
    """Samples from several sources in fixed proportions: per step, each of the ``batch`` samples
    picks a source with probabilities ``weights``; each source is then asked for its count at the
    same step (so the mixture stays a pure function of the step)."""

    def __init__(self, sources: list, weights: list[float], *, seed: int = 0):
        if not sources or len(sources) != len(weights) or min(weights) < 0 or sum(weights) <= 0:
            raise ValueError(f"need one non-negative weight per source (sum > 0), got {weights}")
        self.sources, self.seed = list(sources), seed
        self.p = np.asarray(weights, dtype=np.float64) / np.sum(weights)

    def __call__(self, step: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng((self.seed, step, 1))
        counts = np.bincount(rng.choice(len(self.sources), batch, p=self.p), minlength=len(self.sources))
        parts = [src(step, int(n)) for src, n in zip(self.sources, counts, strict=True) if n]
        return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])


class FolderData:
    """Random crops of the images of a folder with random box / irregular masks."""

    def __init__(self, folder: str | Path, size: int, *, seed: int = 0, box_prob: float = 0.5,
                 cache: int = 512):
        self.folder = Path(folder)
        self.paths = image_paths(self.folder)
        self.size, self.seed, self.box_prob = size, seed, box_prob
        self._image = _ImageCache(self.paths, cache)

    def __call__(self, step: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng((self.seed, step))
        s = self.size
        imgs, holes = [], []
        for _ in range(batch):
            img = self._image(int(rng.integers(len(self.paths))))
            h, w = img.shape[:2]
            side = int(rng.integers(min(s, h, w), min(h, w) + 1))
            v0, u0 = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
            crop = _resize(img[v0:v0 + side, u0:u0 + side], s).astype(np.float32) / np.float32(255)
            if rng.random() < 0.5:
                crop = crop[:, ::-1]
            imgs.append(crop)
            mk = random_box_mask if rng.random() < self.box_prob else random_irregular_mask
            holes.append(mk(rng, s, s))
        return np.stack(imgs).astype(np.float32), np.stack(holes)
