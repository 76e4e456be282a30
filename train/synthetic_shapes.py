"""Object silhouettes of the synthetic world as hole shapes for the real-frame inpainter.

Command::

    python train/synthetic_shapes.py --seeds 0-19 --frames 10,60 --out DIR

writes one binary mask image (255 = object) per privacy object of at least ``--min-area`` pixels in
the given frames of each synthetic world (``SynthConfig(num_frames=100, seed=s)``, 640 × 192), as
``DIR/synth_SEED_FRAME_INSTANCE.png``, each object on its own so that touching objects stay apart
(their union would be one blob). ``train/inpaint.py --shapes DIR`` reads every file of ``DIR``
(:func:`privslam_jax.inpaint.data.object_shapes`) and moves the shapes onto real frames near their
own relative row, scaled by the frame-width ratio; links to real mask files placed in ``DIR`` join
them (the recipe in ``docs/model_card_inpainter_real.md``). The synthetic held-out worlds 901–905
of ``experiments/inpaint_real.py`` are not among the default seeds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax.argtypes import positive_int, seed_list  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=seed_list, default="0-19", help="synthetic worlds, e.g. 0-19")
    p.add_argument("--frames", default="10,60", help="comma-separated frame indices (< 100) of each world")
    p.add_argument("--min-area", type=positive_int, default=200, help="smallest object in pixels")
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    try:
        frames = [int(f) for f in a.frames.split(",")]
    except ValueError:
        p.error(f"--frames: comma-separated integers, got {a.frames!r}")
    if not frames or not all(0 <= f < 100 for f in frames):
        p.error(f"--frames: indices in [0, 100), got {a.frames!r}")
    if a.out.exists() and not a.out.is_dir():
        p.error(f"--out: {a.out} is a file, not a folder")

    from privslam_jax.data.images import write_image_file
    from privslam_jax.data.synthetic import SynthConfig, make_sequence, parse_seeds

    a.out.mkdir(parents=True, exist_ok=True)
    written = 0
    for seed in parse_seeds(a.seeds):
        seq = make_sequence(SynthConfig(num_frames=100, seed=seed))
        for i in frames:
            ids = np.asarray(seq[i].instance_ids)
            for k in np.unique(ids[ids > 0]):
                mask = ids == k
                if mask.sum() >= a.min_area:
                    write_image_file(a.out / f"synth_{seed:02d}_{i:03d}_{k:03d}.png", mask.astype(np.uint8) * 255)
                    written += 1
    print(f"{written} object masks written to {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
