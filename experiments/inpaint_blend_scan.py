"""How the real-frame inpainter's fill is blended with OpenCV Telea, chosen on the validation frames only.

On the validation set of ``experiments/inpaint_real.py`` (``kitti_raw_a`` run 2, frames 220–259, one
placement of three held-out silhouettes per frame, seed 7; the evaluation sets are never read here),
the checkpoint's network fill ``y`` (its flip average, no blend) and Telea of the whole frame ``p``
are computed once per case; then, inside the holes, with ``d`` each hidden pixel's Euclidean distance
to the nearest visible pixel in frame pixels or in model pixels (divided by the resize factor of the
pixel's crop; :func:`~privslam_jax.inpaint.filter.blend_distance`):

1. the pooled least-squares share of the network per distance band, ``w* = Σ (y − p)(x − p) / Σ (y − p)²``
   over the band's pixels (``x`` the truth): how far from the visible pixels the network beats Telea;
2. the grid ``w = a · (1 − exp(−d / τ))`` (``τ = 0``: the constant ``a``) in both units, scored by the
   mean per-case PSNR (the quantity a per-case median of PSNR gains is robust to) and, for reading, the
   paired median PSNR gain over Telea. The best grid point is what ``InpainterConfig.prefill_blend``,
   ``prefill_blend_distance`` and ``prefill_blend_unit`` of the shipped checkpoint hold
   (``docs/model_card_inpainter_real.md``).

Command::

    python experiments/inpaint_blend_scan.py [--model PATH] [--size N]

``--size`` runs the network at another model resolution than the checkpoint's (a multiple of 4;
the model card's question whether weights trained at 64² gain from larger crops without training).

Runtime ≈ 20 s on 2 cores. Needs ``../shared``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.argtypes import positive_int  # noqa: E402
from privslam_jax.inpaint import baselines  # noqa: E402
from privslam_jax.inpaint.data import image_paths, object_shapes  # noqa: E402
from privslam_jax.inpaint.evaluate import real_hole_cases  # noqa: E402
from privslam_jax.inpaint.filter import EMBEDDED_REAL_INPAINTER, Inpainter, blend_distance, filter_frame  # noqa: E402

BANDS = {"frame": (0.0, 2.0, 4.0, 8.0, 16.0, 32.0, np.inf), "model": (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, np.inf)}
SHARES = np.round(np.arange(0.70, 1.001, 0.05), 2)
DISTANCES = {"frame": (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0),
             "model": (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0)}


def _psnr(a: np.ndarray, b: np.ndarray) -> float:  # numpy: metrics.image.psnr would compile once per hole size
    return float(10.0 * np.log10(1.0 / np.mean((a.astype(np.float64) - b) ** 2)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", type=Path, default=EMBEDDED_REAL_INPAINTER, help="inpainter checkpoint (default: the real-frame one)")
    p.add_argument("--size", type=positive_int, help="model resolution to run at (default: the checkpoint's)")
    a = p.parse_args(argv)
    if a.size is not None and a.size % 4:
        p.error(f"--size: must be a multiple of 4, got {a.size}")
    try:  # checked before any work and before ../shared is needed
        model = Inpainter.load(a.model)
    except (OSError, ValueError) as err:
        p.error(f"--model {a.model}: {err}")
    cfg = dataclasses.replace(model.config, prefill_blend=1.0, prefill_blend_distance=0.0, prefill_blend_unit="frame",
                              size=a.size or model.config.size)
    if cfg.prefill == "white":
        p.error(f"--model {a.model}: its prefill is white; there is no prefill to blend with")
    shared = shared_dir()
    if shared is None:
        print("needs ../shared (real frames and object masks); nothing to do")
        return 1
    plain = Inpainter(*model.modules, cfg)
    real = shared / "data" / "real"
    shapes = object_shapes(image_paths(real / "kitti_raw_a" / "maskrcnn_masks")[32:])
    frames = sorted((real / "kitti_raw_a" / "frames").glob("00000002[2-5]?.png"))
    cases = []
    for image, target, masks in real_hole_cases(frames, shapes, objects=3, repeats=1, seed=7):
        hidden = masks.any(axis=0)
        cases.append({"y": filter_frame(image, masks, inpainter=plain)[hidden],
                      "p": baselines.fill(image, hidden, cfg.prefill)[hidden], "x": target[hidden],
                      **{unit: blend_distance(masks, dataclasses.replace(cfg, prefill_blend_unit=unit))[hidden]
                         .astype(np.float64) for unit in BANDS}})
    print(f"validation: {len(cases)} cases of {len(frames)} kitti_raw_a frames (run 2), checkpoint {a.model.name}")
    for unit, bands in BANDS.items():
        print(f"\nnetwork share per distance band, {unit} pixels (pooled least squares)")
        for lo, hi in zip(bands[:-1], bands[1:]):
            num = den = 0.0
            for c in cases:
                m = (c[unit] >= lo) & (c[unit] < hi)
                diff = c["y"][m] - c["p"][m]
                num += float(np.sum(diff * (c["x"][m] - c["p"][m])))
                den += float(np.sum(diff * diff))
            print(f"  d in [{lo:g}, {hi:g}) px: w* = {num / den:+.3f}")
    print("\nshare a·(1 − exp(−d/τ)) (τ = 0: constant a): mean per-case PSNR, median paired gain over Telea")
    best = None
    for unit, taus in DISTANCES.items():
        for share in SHARES:
            for tau in taus:
                gains, psnrs = [], []
                for c in cases:
                    w = np.full_like(c[unit], share) if tau == 0 else share * -np.expm1(-c[unit] / tau)
                    out = w[:, None] * c["y"] + (1.0 - w[:, None]) * c["p"]
                    psnrs.append(_psnr(out, c["x"]))
                    gains.append(psnrs[-1] - _psnr(c["p"], c["x"]))
                row = (float(np.mean(psnrs)), float(share), tau, float(np.median(gains)), unit)
                best = row if best is None or row[0] > best[0] else best
                print(f"  a {share:.2f}  τ {tau:4g} {unit} px: mean PSNR {row[0]:.3f} dB, median gain {row[3]:+.3f} dB")
    print(f"\nbest by mean per-case PSNR: a = {best[1]:.2f}, τ = {best[2]:g} {best[4]} px (mean PSNR {best[0]:.3f} dB, "
          f"median gain over Telea {best[3]:+.3f} dB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
