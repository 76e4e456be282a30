"""Write tests/data/synth_frame_320x96.npz: one frame of the synthetic street world with the
frame rendered without its privacy objects and one dilated mask per object.

    python tests/data/make_synth_frame.py

Arrays: ``image``, ``background`` (uint8 (96, 320, 3), RGB), ``masks`` (bool (K, 96, 320)):
``SynthConfig(seed=424242, num_frames=1, width=320, height=96)`` frame 0 (a seed never used in
training), every instance of at least 20 pixels, dilated by a 5×5 square.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from privslam_jax.data.synthetic import SynthConfig, make_sequence


def to8(x: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float → uint8, rounded."""
    return np.round(np.clip(x, 0, 1) * 255).astype(np.uint8)


def main() -> None:
    f = make_sequence(SynthConfig(seed=424242, num_frames=1, width=320, height=96))[0]
    ids = [i for i in np.unique(f.instance_ids) if i > 0 and np.sum(f.instance_ids == i) >= 20]
    kernel = np.ones((5, 5), np.uint8)
    masks = np.stack([cv2.dilate((f.instance_ids == i).astype(np.uint8), kernel) > 0 for i in ids])
    out = Path(__file__).with_name("synth_frame_320x96.npz")
    np.savez_compressed(out, image=to8(f.image), background=to8(f.background), masks=masks)
    print(f"{out}: {len(masks)} objects, {int(masks.any(0).sum())} masked pixels")


if __name__ == "__main__":
    main()
