"""Train the ORB bag-of-words vocabulary for loop closing (:mod:`privslam_jax.slam.vocabulary`).

Command (the shipped ``privslam_jax/assets/orb_vocabulary_1k.npz``)::

    python train/vocabulary.py --out privslam_jax/assets/orb_vocabulary_1k.npz

Descriptors: the SLAM front end's ORB (:func:`privslam_jax.slam.frontend.extract_orb`, default
settings) on every ``--stride``-th frame of the synthetic staircase worlds ``--synth-seeds`` (never
the loop worlds of Table 4) and, when ``../shared`` is present, on the real frames it allows training
on: ``data/real/kitti_raw_a/frames`` and KITTI ``seq1`` / ``00`` (grey).  The evaluation sets
(``kitti_object``, ``kitti_raw_b``, ``nuscenes_front``) are never read.  ``--no-real`` leaves the real
frames out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax.argtypes import nonnegative_int, positive_int, seed_list  # noqa: E402


def real_training_frames() -> list[Path]:
    """The real frames ``../shared`` allows training on (empty when it is absent)."""
    from privslam_jax._shared import shared_dir

    root = shared_dir()
    if root is None:
        return []
    data = root / "data"
    paths = sorted((data / "real" / "kitti_raw_a" / "frames").glob("*.png"))
    for seq in ("seq1", "00"):
        paths += sorted((data / "kitti_odometry" / "sequences" / seq / "image_0").glob("*.png"))
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path, help="output .npz")
    ap.add_argument("--words", type=positive_int, default=1024, help="vocabulary size K (default 1024)")
    ap.add_argument("--iterations", type=positive_int, default=10, help="k-majority iterations (default 10)")
    ap.add_argument("--synth-seeds", type=seed_list, default="1-30", help="synthetic worlds (default 1-30)")
    ap.add_argument("--synth-frames", type=positive_int, default=150, help="frames per synthetic world (default 150)")
    ap.add_argument("--stride", type=positive_int, default=10, help="use every N-th synthetic frame (default 10)")
    ap.add_argument("--real-stride", type=positive_int, default=2, help="use every N-th real frame (default 2)")
    ap.add_argument("--no-real", action="store_true", help="synthetic frames only")
    ap.add_argument("--seed", type=nonnegative_int, default=0, help="clustering seed (default 0)")
    args = ap.parse_args(argv)
    if args.words < 2:
        ap.error(f"--words must be at least 2, got {args.words}")

    import cv2
    import numpy as np
    from tqdm import tqdm

    from privslam_jax.data.synthetic import SynthConfig, make_sequence, parse_seeds
    from privslam_jax.slam.frontend import OrbConfig, extract_orb, to_gray_u8
    from privslam_jax.slam.vocabulary import train_vocabulary

    t0 = time.perf_counter()
    orb = OrbConfig()
    descs: list[np.ndarray] = []
    for seed in tqdm(parse_seeds(args.synth_seeds), desc="synthetic worlds", unit="world"):
        seq = make_sequence(SynthConfig(num_frames=args.synth_frames, seed=seed))
        for i in range(0, args.synth_frames, args.stride):
            descs.append(extract_orb(to_gray_u8(seq[i].image), orb).desc)
    n_synth = len(descs)
    real = [] if args.no_real else real_training_frames()[:: args.real_stride]
    for path in tqdm(real, desc="real frames", unit="frame", disable=not real):
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            ap.error(f"{path}: not a readable image")
        descs.append(extract_orb(img, orb).desc)
    vocab = train_vocabulary(descs, k=args.words, iterations=args.iterations, seed=args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    vocab.save(args.out)
    print(f"wrote {args.out}: {vocab.size} words from {sum(len(d) for d in descs)} descriptors of {n_synth} "
          f"synthetic and {len(real)} real images, {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
