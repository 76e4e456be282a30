"""Benchmark: jitted YOLOv8n forward latency (batch 1) at 192×640, 384×1248 and 640×640.

Command: ``python benchmarks/bench_detector.py [--weights PATH] [--runs 40] [--block 10] [--layers]``

Prints, per input size, the compile time of the jitted forward (network + DFL decode) and the
median / min latency of ``--runs`` runs after compilation. When ``torch`` and ``ultralytics`` are
importable, the ultralytics model (same checkpoint, ``eval()``, ``torch.inference_mode``, fused
Conv+BN as ultralytics' predictor uses it, input tensor made before the clock starts) is timed in
the same run, and two ratios ours/ultralytics are printed: of the medians (goal ≤ 1.0 on CPU) and
of the fastest runs, which a busy machine disturbs least.  Ours is timed as ``Detector`` runs it:
BatchNorm folded into the convolutions (``fuse_batchnorm``, as ultralytics fuses) and the stem on
the native kernel (``privslam_jax.detect.rgb_stem``; ``PRIVSLAM_NATIVE=0`` times XLA's convolution
instead).  The two are timed in alternating blocks of ``--block`` runs rather than run by run:
torch's OpenMP workers keep spinning for a while after each call and slowed the XLA call right
after it by ~40 % at 192×640 (and XLA's threads the torch call), which measured the hand-over, not
either library.
Without weights a randomly initialised YOLOv8n (80 classes) is timed (same compute).

``--layers`` adds, for the 384×1248 input, the median latency of every top-level block (ultralytics
layer index, our attribute name) timed alone, ours and ultralytics' on the inputs that block sees in
the ultralytics forward, to show where the two libraries differ.

XLA flags are set as the CLI sets them (``privslam_jax._xla``) before jax is imported.
On a shared machine the numbers are noisy: report the load alongside them.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from flax import nnx  # noqa: E402

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.detect.decode import decode_head  # noqa: E402
from privslam_jax.detect.rgb_stem import native_stem_available  # noqa: E402
from privslam_jax.detect.weights import load_ultralytics  # noqa: E402
from privslam_jax.detect.yolov8 import TORCH_LAYER_NAMES, YOLOv8Config, fuse_batchnorm, init_yolov8  # noqa: E402

SIZES = ((192, 640), (384, 1248), (640, 640))


def _ultralytics_model(weights: Path | None):
    try:
        import torch
        from ultralytics import YOLO
    except Exception as err:  # noqa: BLE001 - optional reference
        return None, f"ultralytics not importable ({type(err).__name__}: {err})"
    if weights is None:
        return None, "ultralytics reference needs --weights"
    model = YOLO(str(weights)).model.float().eval()
    model = model.fuse(verbose=False) if hasattr(model, "fuse") else model

    def prepare(x: np.ndarray):  # NHWC numpy -> NCHW tensor, outside the timed call (ours gets a device array)
        tensor = torch.from_numpy(x.transpose(0, 3, 1, 2).copy())

        def run():
            with torch.inference_mode():
                return model(tensor)

        return run

    return prepare, f"torch {torch.__version__}, {torch.get_num_threads()} threads"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default = shared_dir() / "weights" / "yolov8n.pt" if shared_dir() else None
    parser.add_argument("--weights", type=Path, default=default if default and default.exists() else None)
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--block", type=int, default=10, help="consecutive runs of one library before switching")
    parser.add_argument("--layers", action="store_true", help="per-block breakdown at 384x1248 (needs ultralytics)")
    args = parser.parse_args()

    model = load_ultralytics(args.weights)[0] if args.weights else init_yolov8(YOLOv8Config())
    model.eval()
    graphdef, state = nnx.split(fuse_batchnorm(model))
    forward = jax.jit(lambda st, x: decode_head(nnx.merge(graphdef, st)(x)))
    torch_prepare, torch_info = _ultralytics_model(args.weights)

    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, XLA_FLAGS={os.environ.get('XLA_FLAGS')!r}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"stem: {'native kernel (rgb_stem.cc)' if native_stem_available() else 'XLA convolution'}; reference: {torch_info}")
    print(f"weights: {args.weights or 'random init'}; batch 1; median of {args.runs} runs after compile\n")
    header = (f"{'input':>10} | {'compile s':>9} | {'ours ms (med/min)':>17} | {'ultralytics ms (med/min)':>24} | "
              f"{'ratio':>5} | {'ratio of mins':>13}")
    print(header)
    print("-" * len(header))
    rng = np.random.default_rng(0)
    for h, w in SIZES:
        x = rng.random((1, h, w, 3), np.float32)
        xj = jnp.asarray(x)
        t0 = time.perf_counter()
        forward.lower(state, xj).compile()
        compile_s = time.perf_counter() - t0
        forward(state, xj).block_until_ready()
        ours, ref = [], []
        torch_run = torch_prepare(x) if torch_prepare is not None else None
        if torch_run is not None:
            torch_run()  # warm-up
        for start in range(0, args.runs, args.block):  # alternating blocks: both see the same load
            for _ in range(min(args.block, args.runs - start)):
                t0 = time.perf_counter()
                forward(state, xj).block_until_ready()
                ours.append(time.perf_counter() - t0)
            for _ in range(min(args.block, args.runs - start) if torch_run is not None else 0):
                t0 = time.perf_counter()
                torch_run()
                ref.append(time.perf_counter() - t0)
        med = statistics.median(ours) * 1e3
        line = f"{h:>4}x{w:<5} | {compile_s:>9.2f} | {med:>8.1f} / {min(ours) * 1e3:>6.1f} |"
        if ref:
            rmed = statistics.median(ref) * 1e3
            line += f" {rmed:>15.1f} / {min(ref) * 1e3:>6.1f} | {med / rmed:>5.2f} | {min(ours) / min(ref):>13.2f}"
        else:
            line += f" {'-':>24} | {'-':>5} | {'-':>13}"
        print(line)
    if args.layers:
        _per_layer(fuse_batchnorm(model), args.weights, args.runs)


def _median_ms(fn, runs: int) -> float:
    fn()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def _per_layer(fused, weights: Path | None, runs: int, size: tuple[int, int] = (384, 1248)) -> None:
    """Time each top-level block alone, ours (jitted) and ultralytics', on the same inputs."""
    try:
        import torch
        from ultralytics import YOLO
    except Exception as err:  # noqa: BLE001 - optional reference
        print(f"\n--layers skipped: ultralytics not importable ({type(err).__name__})")
        return
    if weights is None:
        print("\n--layers skipped: needs --weights")
        return
    net = YOLO(str(weights)).model.float().eval().fuse(verbose=False)
    seen: dict[int, tuple] = {}
    hooks = [m.register_forward_pre_hook(lambda _m, a, i=i: seen.__setitem__(i, a)) for i, m in enumerate(net.model)]
    x = np.random.default_rng(0).random((1, *size, 3), np.float32)
    with torch.inference_mode():
        net(torch.from_numpy(x.transpose(0, 3, 1, 2).copy()))
    for hook in hooks:
        hook.remove()
    print(f"\nper block at {size[0]}x{size[1]} (median of {runs}, each block timed alone)")
    print(f"{'layer':>5} {'ours':<10} | {'ours ms':>7} | {'ultralytics ms':>14} | {'ratio':>5}")
    totals = [0.0, 0.0]
    for index, name in TORCH_LAYER_NAMES.items():
        args = seen[index]
        to_nhwc = lambda t: jnp.asarray(t.numpy().transpose(0, 2, 3, 1))  # noqa: E731
        xj = [to_nhwc(t) for t in args[0]] if isinstance(args[0], list) else to_nhwc(args[0])
        graphdef, state = nnx.split(getattr(fused, name))
        block = jax.jit(lambda st, v, g=graphdef: nnx.merge(g, st)(v))
        layer = net.model[index]

        def run_ref(layer=layer, args=args):
            with torch.inference_mode():
                layer(*args)

        ours = _median_ms(lambda: jax.block_until_ready(block(state, xj)), runs)
        ref = _median_ms(run_ref, runs)
        totals[0] += ours
        totals[1] += ref
        print(f"{index:>5} {name:<10} | {ours:>7.2f} | {ref:>14.2f} | {ours / ref:>5.2f}")
    print(f"{'sum':>5} {'':<10} | {totals[0]:>7.1f} | {totals[1]:>14.1f} | {totals[0] / totals[1]:>5.2f}")


if __name__ == "__main__":
    main()
