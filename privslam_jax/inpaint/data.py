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
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from privslam_jax.inpaint.crops import crop_box
from privslam_jax.inpaint.masks import dilate, random_box_mask, random_irregular_mask

__all__ = ["CropBank", "FolderData", "IMAGE_SUFFIXES"]

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
        np.savez_compressed(path, images=self.images, holes=self.holes)

    @classmethod
    def load(cls, path: str | Path, seed: int = 0) -> CropBank:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"crop bank not found: {path}")
        with np.load(path) as d:
            return cls(d["images"], d["holes"], seed)

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


class FolderData:
    """Random crops of the images of a folder with random box / irregular masks."""

    def __init__(self, folder: str | Path, size: int, *, seed: int = 0, box_prob: float = 0.5,
                 cache: int = 512):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"image folder not found: {self.folder}")
        self.paths = sorted(p for p in self.folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise ValueError(f"no images ({', '.join(IMAGE_SUFFIXES)}) under {self.folder}")
        self.size, self.seed, self.box_prob = size, seed, box_prob
        self._cache: dict[int, np.ndarray] = {}
        self._cache_max = cache

    def _image(self, i: int) -> np.ndarray:
        if i not in self._cache:
            raw = cv2.imread(str(self.paths[i]), cv2.IMREAD_COLOR)
            if raw is None:
                raise ValueError(f"cannot decode image {self.paths[i]}")
            img = cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
            if len(self._cache) >= self._cache_max:
                self._cache.pop(next(iter(self._cache)))
            self._cache[i] = img
        return self._cache[i]

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
