r"""A bag-of-words vocabulary of ORB descriptors for place recognition (loop closing, relocalisation).

ORB-SLAM recognises places with DBoW2 (Gálvez-López & Tardós, *Bags of binary words for fast place
recognition in image sequences*, T-RO 2012): descriptors are quantised to visual words, an image
becomes a tf-idf weighted, L1-normalised word histogram :math:`v`, and two images score

.. math:: s(v_1, v_2) = 1 - \tfrac12 \lVert v_1 - v_2 \rVert_1 \in [0, 1].

This module keeps that score and weighting with a *flat* vocabulary (one level of ``K`` words instead
of DBoW2's tree of ``k^L``): with ``K`` = 1024 words and ~2,000 descriptors per keyframe the exact
nearest word is one brute-force Hamming search (OpenCV), so the tree's approximate descent buys
nothing at this scale.

Training (:func:`train_vocabulary`) is *k-majority* clustering (Grana et al., *A fast approach for
integrating ORB descriptors in the bag of words model*, 2013): k-means in Hamming space where a
centre is the bitwise majority of its members, seeded by k-means++ (Arthur & Vassilvitskii 2007).
The inverse document frequency of word :math:`w` is :math:`\mathrm{idf}_w = \log(N / n_w)` over the
``N`` training images, ``n_w`` of which contain it (words in no image get :math:`\log N`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from privslam_jax.data.files import write_npz
from privslam_jax.data.npz import read_npz
from privslam_jax.errors import input_error

__all__ = ["Vocabulary", "train_vocabulary", "load_vocabulary", "bow_scores"]


@dataclasses.dataclass(frozen=True)
class Vocabulary:
    """``K`` binary visual words and their idf weights."""

    words: np.ndarray
    """``(K, 32)`` uint8 word centres (256-bit, like ORB descriptors)."""
    idf: np.ndarray
    """``(K,)`` float64 inverse document frequencies."""

    def __post_init__(self) -> None:
        w, idf = np.asarray(self.words), np.asarray(self.idf)
        if w.ndim != 2 or w.shape[1] != 32 or w.dtype != np.uint8 or len(w) < 2:
            raise ValueError(f"words must be (K >= 2, 32) uint8, got {w.dtype} {w.shape}")
        if idf.shape != (len(w),) or not np.all(np.isfinite(idf)) or np.any(idf < 0):
            raise ValueError(f"idf must be ({len(w)},), finite and >= 0, got {idf.shape}")

    @property
    def size(self) -> int:
        return len(self.words)

    def quantise(self, desc: np.ndarray) -> np.ndarray:
        """``(N,)`` index of the nearest word (Hamming) of each ``(N, 32)`` uint8 descriptor."""
        desc = np.ascontiguousarray(desc, np.uint8)
        if desc.ndim != 2 or desc.shape[1] != 32:
            raise ValueError(f"descriptors must be (N, 32) uint8, got {desc.shape}")
        if len(desc) == 0:
            return np.zeros(0, np.int64)
        matches = cv2.BFMatcher(cv2.NORM_HAMMING).match(desc, self.words)
        out = np.empty(len(desc), np.int64)
        for m in matches:
            out[m.queryIdx] = m.trainIdx
        return out

    def transform(self, desc: np.ndarray) -> np.ndarray:
        """The tf-idf word histogram of one image, L1-normalised: ``(K,)`` float64 (zeros without descriptors)."""
        words = self.quantise(desc)
        v = np.bincount(words, minlength=self.size).astype(np.float64) * self.idf
        total = v.sum()
        return v / total if total > 0 else v

    def save(self, path: str | Path) -> None:
        """Write ``words`` and ``idf`` to an ``.npz`` atomically."""
        write_npz(path, compressed=True, words=self.words, idf=self.idf)


def load_vocabulary(path: str | Path) -> Vocabulary:
    """Read a vocabulary written by :meth:`Vocabulary.save` (``FileNotFoundError`` / ``InputError`` /
    ``ValueError`` naming what is wrong for a missing, damaged or malformed file)."""
    arrays = read_npz(path, ("words", "idf"))
    missing = [k for k in ("words", "idf") if k not in arrays]
    if missing:
        raise input_error(Path(path), f"not a vocabulary: no {', '.join(missing)} array")
    try:
        return Vocabulary(words=arrays["words"], idf=arrays["idf"])
    except ValueError as err:
        raise input_error(Path(path), f"not a vocabulary: {err}") from err


def bow_scores(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """DBoW2's L1 score ``1 − ½‖q − d‖₁`` of one ``(K,)`` vector against ``(M, K)`` vectors: ``(M,)``."""
    return 1.0 - 0.5 * np.abs(np.asarray(database) - np.asarray(query)[None, :]).sum(axis=1)


def _hamming_to(desc: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``(N,)`` Hamming distance of each descriptor to its nearest centre."""
    matches = cv2.BFMatcher(cv2.NORM_HAMMING).match(desc, centres)
    d = np.empty(len(desc))
    for m in matches:
        d[m.queryIdx] = m.distance
    return d


def train_vocabulary(
    images_desc: list[np.ndarray],
    k: int = 1024,
    iterations: int = 10,
    seed: int = 0,
    max_descriptors: int = 200_000,
) -> Vocabulary:
    """k-majority clustering of the descriptors of training images (see the module docstring).

    ``images_desc``: one ``(N_i, 32)`` uint8 array per image (the idf needs the image split);
    at most ``max_descriptors`` (drawn at random) take part in the clustering.
    """
    if len(images_desc) < 2:
        raise ValueError(f"need descriptors of at least 2 images, got {len(images_desc)}")
    all_desc = np.concatenate([np.asarray(d, np.uint8).reshape(-1, 32) for d in images_desc])
    if len(all_desc) < k:
        raise ValueError(f"need at least k = {k} descriptors, got {len(all_desc)}")
    rng = np.random.default_rng(seed)
    data = all_desc[rng.choice(len(all_desc), min(max_descriptors, len(all_desc)), replace=False)]
    bits = np.unpackbits(data, axis=1)
    # k-means++ seeding in Hamming space (distances to the nearest chosen centre, updated per batch)
    centres = [data[rng.integers(len(data))]]
    dist = _hamming_to(data, np.stack(centres)) ** 2
    while len(centres) < k:
        batch = rng.choice(len(data), size=min(32, k - len(centres)), p=dist / dist.sum() if dist.sum() > 0 else None)
        centres.extend(data[batch])
        dist = np.minimum(dist, _hamming_to(data, data[batch]) ** 2)
    words = np.stack(centres[:k])
    for _ in range(iterations):
        assign = Vocabulary(words, np.ones(k)).quantise(data)
        counts = np.bincount(assign, minlength=k)
        sums = np.zeros((k, 256), np.int64)
        np.add.at(sums, assign, bits)
        majority = np.packbits((2 * sums > counts[:, None]).astype(np.uint8), axis=1)
        filled = counts > 0
        if np.array_equal(words[filled], majority[filled]):
            break
        words = np.where(filled[:, None], majority, words)
    vocab = Vocabulary(words, np.ones(k))
    n_docs = np.zeros(k)
    for d in images_desc:
        if len(d):
            n_docs[np.unique(vocab.quantise(d))] += 1
    idf = np.log(len(images_desc) / np.maximum(n_docs, 1.0))
    return Vocabulary(words, idf)
