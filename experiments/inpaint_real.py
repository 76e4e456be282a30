"""Inpainting on real frames: each EdgeConnect checkpoint against OpenCV Telea and Navier–Stokes.

Holes whose answer is known (:func:`privslam_jax.inpaint.evaluate.real_hole_cases`): real object
silhouettes (the Mask R-CNN masks of ``../shared/data/real/kitti_raw_a/maskrcnn_masks`` files
32–39, which the real-domain inpainter never trained on; it used files 0–31) are moved onto other
regions of real frames that no model was trained on, three objects per frame, dilated by 4 px as
the filter dilates, placed twice per frame with different seeds:

* ``kitti_raw_a`` run 2 (frames 220–259; one placement per frame, seed 7): the **validation** set the
  training recipe was chosen on (the real-domain inpainter trained on run 1, frames 0–39);
* ``kitti_raw_b``: 31 KITTI raw colour frames (1242×375) of another drive (evaluation only);
* ``nuscenes_front``: 20 nuScenes front-camera frames (1600×900, Boston; evaluation only);
* the synthetic held-out worlds 901–905 (25 frames each, every privacy object hidden, scored
  against the object-free render) — the synthetic-only checkpoint's model-card setting.

Every method fills the same holes through :func:`~privslam_jax.inpaint.filter.filter_frame`;
inside the holes: PSNR, SSIM, L1 and edge F1 (Canny σ = 2 of output vs truth, pixel-exact, as
EdgeConnect's EdgeAccuracy), and the **paired** per-case PSNR difference to Telea (median and IQR;
"wins" = share of cases where the method beats Telea).

Command::

    python experiments/inpaint_real.py [--model NAME=PATH ...] [--out results/inpaint_real.md]

Default models: the embedded real-domain checkpoint (with its inference settings: the mean of the
fill and the mirrored crop's mirrored fill, blended with Telea at full resolution, the network's share
a · (1 − exp(−d / τ)) at distance d from the visible pixels, a and τ read from the checkpoint's config
and printed in the results header), the same weights without
them ("plain inference"), and the synthetic-only checkpoint. Runtime ≈ 5 min on
2 cores. Needs ``../shared`` (exits with a message without it).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.data.files import write_atomic  # noqa: E402
from privslam_jax.inpaint.data import image_paths, object_shapes  # noqa: E402
from privslam_jax.inpaint.evaluate import evaluate_cases, evaluate_frames, real_hole_cases  # noqa: E402
from privslam_jax.inpaint.filter import EMBEDDED_INPAINTER, EMBEDDED_REAL_INPAINTER, Inpainter  # noqa: E402
from privslam_jax.report import markdown_table  # noqa: E402

BASELINES = ("telea", "ns")


def inference_settings(cfg) -> str:
    """The checkpoint's inference settings in words, from its :class:`~privslam_jax.inpaint.filter.InpainterConfig`."""
    parts = ["flip average"] if cfg.flip_average else []
    prefill = cfg.prefill.upper() if cfg.prefill == "ns" else cfg.prefill.capitalize()
    if cfg.prefill_blend_distance > 0.0:
        unit = "model pixels, i.e. frame pixels / the crop's resize factor" if cfg.prefill_blend_unit == "model" \
            else "frame pixels"
        parts.append(f"{prefill} blend with the network's share {cfg.prefill_blend:g} · (1 − exp(−d / "
                     f"{cfg.prefill_blend_distance:g})) at distance d from the visible pixels in {unit}")
    elif cfg.prefill_blend < 1.0:
        parts.append(f"{prefill} blend with the network's share {cfg.prefill_blend:g}")
    return ", ".join(parts) or "none"


def summarize(res: dict[str, dict[str, np.ndarray]]) -> list[list[str]]:
    """Rows: method, cases, PSNR median, ΔPSNR vs Telea paired median [IQR], wins, SSIM, L1, edge F1."""
    ref = res["telea"]["psnr"]
    rows = []
    for name, d in res.items():
        dp = d["psnr"] - ref
        rows.append([name, str(len(dp)), f"{np.median(d['psnr']):.2f}",
                     f"{np.median(dp):+.2f} [{np.percentile(dp, 25):+.2f}, {np.percentile(dp, 75):+.2f}]",
                     "–" if name == "telea" else f"{np.mean(dp > 0):.0%}",
                     f"{np.median(d['ssim']):.3f}", f"{np.mean(d['l1']):.4f}", f"{np.median(d['edge_f1']):.3f}"])
    return rows


HEADER = ["method", "cases", "PSNR median (dB)", "ΔPSNR vs Telea, paired median [IQR]", "wins vs Telea",
          "SSIM median", "L1 mean", "edge F1 median"]


def run_set(cases_fn, models: dict[str, Inpainter], **kw) -> dict[str, dict[str, np.ndarray]]:
    """All baselines, then each model under its own name, on the same cases."""
    res = evaluate_cases(cases_fn(), BASELINES, progress=False, **kw)
    for name, model in models.items():
        res[name] = evaluate_cases(cases_fn(), ["edgeconnect"], inpainter=model, progress=False, **kw)["edgeconnect"]
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                   help="an EdgeConnect checkpoint to compare (repeatable; default: the two embedded ones)")
    p.add_argument("--objects", type=int, default=3, help="object holes per real frame")
    p.add_argument("--repeats", type=int, default=2, help="placements per frame of the evaluation sets")
    p.add_argument("--synthetic-frames", type=int, default=25, help="frames per held-out world (0: skip)")
    p.add_argument("--without-edge-model", action="store_true",
                   help="also run every model with its edge generator switched off (ablation: no edges drawn "
                   "inside the hole, Inpainter.without_edge_model)")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "inpaint_real.md")
    a = p.parse_args(argv)
    specs = a.model or [f"edgeconnect (real-domain)={EMBEDDED_REAL_INPAINTER}",
                        f"edgeconnect (synthetic-only)={EMBEDDED_INPAINTER}"]
    models = {}
    for spec in specs:  # checked before any work and before ../shared is needed
        name, sep, path = spec.partition("=")
        if not sep:
            p.error(f"--model needs NAME=PATH, got {spec!r}")
        try:
            models[name] = Inpainter.load(path)
        except (OSError, ValueError) as err:
            p.error(f"--model {spec}: {err}")
    shared = shared_dir()
    if shared is None:
        print("needs ../shared (real frames and object masks); nothing to do")
        return 1
    if not a.model:  # what the checkpoint's inference settings (flip average, Telea blend) add
        real_model = models["edgeconnect (real-domain)"]
        models = {"edgeconnect (real-domain)": real_model,
                  "edgeconnect (real-domain, plain inference)": Inpainter(*real_model.modules, dataclasses.replace(
                      real_model.config, flip_average=False, prefill_blend=1.0, prefill_blend_distance=0.0,
                      prefill_blend_unit="frame")),
                  "edgeconnect (synthetic-only)": models["edgeconnect (synthetic-only)"]}
    if a.without_edge_model:
        models |= {f"{name}, no edge generator": model.without_edge_model() for name, model in models.items()}
    real = shared / "data" / "real"
    shapes = object_shapes(image_paths(real / "kitti_raw_a" / "maskrcnn_masks")[32:])
    sets = {"kitti_raw_a run 2, validation": (sorted((real / "kitti_raw_a" / "frames").glob("00000002[2-5]?.png")),
                                              1, 7),
            "kitti_raw_b": (image_paths(real / "kitti_raw_b" / "frames"), a.repeats, 0),
            "nuscenes_front": (image_paths(real / "nuscenes_front" / "images"), a.repeats, 0)}
    md = ["# Inpainting on real frames (and the synthetic held-out worlds)", "",
          f"`python experiments/inpaint_real.py` ({time.strftime('%Y-%m-%d')}); {len(shapes)} held-out object "
          f"silhouettes, {a.objects} per frame, {a.repeats} placements per frame, dilation 4 px. "
          "Models: " + ", ".join(f"{n} = `{Path(q).name}`" for n, q in
                                 (s.partition('=')[::2] for s in specs)) + "."
          + ("" if a.model else " The real-domain checkpoint runs with its inference settings (" + inference_settings(
              models["edgeconnect (real-domain)"].config) + "); 'plain inference' is the same weights without them."),
          ""]
    t0 = time.perf_counter()
    for set_name, (paths, repeats, seed) in sets.items():
        res = run_set(lambda paths=paths, repeats=repeats, seed=seed: real_hole_cases(
            paths, shapes, objects=a.objects, repeats=repeats, seed=seed), models)
        md += [f"## {set_name} ({len(paths)} frames)", "", *markdown_table(HEADER, summarize(res)), ""]
        print("\n".join(md[-(len(res) + 4):]), flush=True)
    if a.synthetic_frames:
        from privslam_jax.data.synthetic import SynthConfig, make_sequence

        seqs = [make_sequence(SynthConfig(num_frames=a.synthetic_frames, seed=s)) for s in range(901, 906)]
        frames = lambda: (s[i] for s in seqs for i in range(len(s)))  # noqa: E731
        res = evaluate_frames(frames(), BASELINES, progress=False)
        for name, model in models.items():
            res[name] = evaluate_frames(frames(), ["edgeconnect"], inpainter=model, progress=False)["edgeconnect"]
        md += [f"## synthetic held-out worlds 901–905 ({a.synthetic_frames} frames each)", "",
               *markdown_table(HEADER, summarize(res)), ""]
        print("\n".join(md[-(len(res) + 4):]), flush=True)
    md += [f"Wall time {time.perf_counter() - t0:.0f} s on this machine."]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(a.out, "\n".join(md) + "\n")
    print(f"written to {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
