"""Stereo disparities of ORB keypoints against the synthetic world's ground-truth depth, per octave,
for both SAD refinements (``SlamConfig.stereo_zero_mean_sad``).

For each frame, :func:`privslam_jax.slam.frontend.stereo_depths` matches the left keypoints in the
right image and refines them by SAD (patches minus their centre pixel, ORB-SLAM's, or minus their
mean); its disparity ``f_x·b / z`` is compared with the ground truth ``f_x·b / z_gt``, ``z_gt`` read
bilinearly at the keypoint from the renderer's depth map.  Keypoints within 6 px of a depth edge
(the ground-truth disparity varies by ≥ 1 px over a 13×13 window) are left out: there the patch
straddles two surfaces and neither SAD can be right.  Per octave: keypoints compared, median error
(px; negative = disparity short, depth too large) and the share within 0.5 px.

Command::

    python experiments/stereo_disparity.py [--worlds 0-3] [--frames 0,4,8,11]

Frames: ``SynthConfig(num_frames=12, seed=w, stereo=True)`` (640×192), as ``privslam synth --stereo``
renders them, 8-bit grey.  About a minute on 2 cores.  Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def disparity_errors(world: int, frames: list[int], zero_mean: bool):
    """``(octave, error px)`` of every matched keypoint away from depth edges in ``frames`` of ``world``."""
    import cv2
    import numpy as np

    from privslam_jax.data.synthetic import SynthConfig, make_sequence
    from privslam_jax.slam.frontend import extract_orb, stereo_depths, to_gray_u8
    from privslam_jax.slam.system import SlamConfig

    orb = SlamConfig(mode="stereo").orb
    seq = make_sequence(SynthConfig(num_frames=max(frames) + 1, seed=world, stereo=True))
    cam = seq.camera
    octaves, errors = [], []
    for i in frames:
        f = seq[i]
        left, right = to_gray_u8(f.image), to_gray_u8(f.image_right)
        fl = extract_orb(left, orb)
        d = stereo_depths(left, right, fl, extract_orb(right, orb), cam.fx, cam.baseline, orb.scale_factor,
                          zero_mean=zero_mean)
        gt = (cam.fx * cam.baseline / np.maximum(f.depth, 1e-6)).astype(np.float32)
        uv = np.asarray(fl.uv, np.float32)
        at = cv2.remap(gt, uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR)[:, 0]
        window = np.ones((13, 13), np.uint8)
        spread = cv2.remap(cv2.dilate(gt, window) - cv2.erode(gt, window), uv[:, :1], uv[:, 1:], cv2.INTER_NEAREST)[:, 0]
        ok = np.isfinite(d) & (spread < 1.0) & (at > 0.5)
        octaves.append(np.asarray(fl.octave)[ok])
        errors.append(cam.fx * cam.baseline / d[ok] - at[ok])
    return np.concatenate(octaves), np.concatenate(errors)


def main(argv: list[str] | None = None) -> int:
    import numpy as np

    from privslam_jax.argtypes import seed_list
    from privslam_jax.data.synthetic import parse_seeds

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--worlds", type=seed_list, default="0-3", help="synthetic world seeds (default 0-3)")
    p.add_argument("--frames", default="0,4,8,11", help="frame indices of each world (default 0,4,8,11)")
    a = p.parse_args(argv)
    try:
        frames = [int(x) for x in a.frames.split(",")]
    except ValueError:
        p.error(f"--frames must be comma-separated frame indices, got {a.frames!r}")
    if not frames or min(frames) < 0:
        p.error(f"--frames must be non-negative frame indices, got {a.frames!r}")
    worlds = parse_seeds(a.worlds)
    print(f"Worlds {a.worlds}, frames {a.frames}; disparity error = SAD-refined − ground truth (px)\n")
    print("| octave | keypoints | centre pixel: median | within 0.5 px | zero mean: median | within 0.5 px |")
    print("|---|---|---|---|---|---|")
    res = {}
    for zero_mean in (False, True):
        parts = [disparity_errors(w, frames, zero_mean) for w in worlds]
        res[zero_mean] = (np.concatenate([o for o, _ in parts]), np.concatenate([e for _, e in parts]))
    (oc, ec), (oz, ez) = res[False], res[True]
    for k in range(int(max(oc.max(), oz.max())) + 1):
        c, z = ec[oc == k], ez[oz == k]
        if len(c) == 0 or len(z) == 0:
            continue
        print(f"| {k} | {len(c)} / {len(z)} | {np.median(c):+.3f} | {np.mean(np.abs(c) < 0.5):.1%} | "
              f"{np.median(z):+.3f} | {np.mean(np.abs(z) < 0.5):.1%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
