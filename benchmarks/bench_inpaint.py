"""Inpainting benchmark: EdgeConnect train-step time and per-frame privacy-filter time.

Command: ``python benchmarks/bench_inpaint.py [--repeats 20] [--full-repeats 3] [--skip-full] [--parts train,full,filter]``

* train step (edge G + D, inpaint G + D, i.e. one "joint" step) for the CPU preset (width 16,
  8 residual blocks) at 64², batch 8, and for the official full width (64) at 256², batch 1;
* per-frame filter time (CPU preset, 64² crops) for 640×192 and KITTI-size 1241×376 frames with
  1, 2, 3 objects, against OpenCV Telea on the same frames (the reference, same run).

Prints medians after compilation; compile (first call) time separately. Goal (issue 4):
≤ 150 ms per 640×192 frame with ≤ 3 objects, CPU preset, 2 cores.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import jax  # noqa: E402
import numpy as np  # noqa: E402


def _time(fn, repeats: int) -> tuple[float, float]:
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return first, statistics.median(runs)


def bench_train(width: int, size: int, batch: int, repeats: int) -> tuple[float, float]:
    from privslam_jax.inpaint.masks import random_box_mask
    from privslam_jax.inpaint.train import InpaintTrainer, TrainConfig, prepare_batch

    cfg = TrainConfig(width=width, size=size, batch_size=batch)
    trainer = InpaintTrainer(cfg)
    rng = np.random.default_rng(0)
    imgs = rng.random((batch, size, size, 3)).astype(np.float32)
    holes = np.stack([random_box_mask(rng, size, size) for _ in range(batch)])
    b = prepare_batch(imgs, holes)

    def step():
        logs, outs = trainer.step("joint", b)
        jax.block_until_ready(outs)

    return _time(step, repeats)


def _frame(h: int, w: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(k)
    img = np.clip(rng.random((h, w, 3)) * 0.2 + np.linspace(0.2, 0.8, w)[None, :, None], 0, 1).astype(np.float32)
    masks = np.zeros((k, h, w), bool)
    for j in range(k):  # car-/person-sized boxes spread over the frame
        bh, bw = int(h * (0.25 + 0.1 * j)), int(w * (0.08 + 0.04 * j))
        v0, u0 = h // 2 - bh // 4, int((j + 0.5) * w / (k + 0.5))
        masks[j, v0:v0 + bh, u0:u0 + bw] = True
    return img, masks


def bench_filter(repeats: int) -> list[tuple[str, int, float, float, float]]:
    from privslam_jax.inpaint.filter import Inpainter, InpainterConfig, filter_frame

    inp = Inpainter.init(InpainterConfig())
    rows = []
    for h, w in ((192, 640), (376, 1241)):
        for k in (1, 2, 3):
            img, masks = _frame(h, w, k)
            first, ours = _time(lambda: filter_frame(img, masks, "edgeconnect", inpainter=inp), repeats)
            _, telea = _time(lambda: filter_frame(img, masks, "telea"), repeats)
            rows.append((f"{w}x{h}", k, first, ours, telea))
    return rows


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--full-repeats", type=int, default=3, help="repeats of the slow full-width step")
    p.add_argument("--skip-full", action="store_true")
    p.add_argument("--parts", default="train,full,filter", help="subset of train,full,filter")
    a = p.parse_args()
    parts = set(a.parts.split(","))
    if a.skip_full:
        parts.discard("full")
    print(f"jax {jax.__version__}, devices {jax.devices()}, repeats {a.repeats}")
    print("\n| train step (joint: edge G+D, inpaint G+D) | compile+first (s) | median (s) |")
    print("|---|---|---|")
    if "train" in parts:
        first, med = bench_train(16, 64, 8, a.repeats)
        print(f"| CPU preset width 16, 64², batch 8 | {first:.1f} | {med:.3f} |")
    if "full" in parts:
        first, med = bench_train(64, 256, 1, a.full_repeats)
        print(f"| full width 64, 256², batch 1 ({a.full_repeats} runs) | {first:.1f} | {med:.3f} |")
    if "filter" not in parts:
        return
    print("\n| frame | objects | compile+first (s) | EdgeConnect CPU preset (ms) | OpenCV Telea (ms) |")
    print("|---|---|---|---|---|")
    for size, k, first, ours, telea in bench_filter(a.repeats):
        print(f"| {size} | {k} | {first:.1f} | {ours * 1e3:.1f} | {telea * 1e3:.1f} |")


if __name__ == "__main__":
    main()
