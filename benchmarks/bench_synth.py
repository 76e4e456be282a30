"""Benchmark: synthetic street world rendering speed and compile time.

Command: ``python benchmarks/bench_synth.py [--width 640 --height 192 --runs 20]``

Measures, at the given resolution, after compilation (median of ``--runs`` frames):

* ``device``: the jitted renderer alone (image + depth + instance ids + object-free background +
  boxes: one full SynthFrame's device work), host inputs prepared beforehand;
* ``host inputs``: the per-frame numpy work (object poses, culling, primitive tables);
* ``frame``: ``seq[i]`` end to end (host inputs + device + transfer to numpy + SynthFrame);
* ``device CPU time``: process CPU time of the device render summed over threads — on a shared,
  overloaded machine this is the stabler number (an idle 2-core machine renders in roughly
  CPU time / 1.5–2 of wall time);

for the monocular and the stereo configuration, plus the compile time of each.  Goal: ≥ 30 FPS
(DESIGN/issue 2).  Prints a Markdown table.  The machine may be shared: say so when quoting.

``--level0`` runs under ``jax_disable_most_optimizations`` (as most tests do, ``tests/conftest.py``)
and adds, beside the renderer as shipped (compiled with :data:`privslam_jax._xla.OPTIMISED`), the
same function jitted without that pin: what level 0 would cost the renderer.
"""

from __future__ import annotations

import argparse
import statistics
import time

from privslam_jax._xla import configure_xla

configure_xla()

import jax  # noqa: E402

from privslam_jax.data.synthetic import SynthConfig, make_sequence, render_views  # noqa: E402


def _median_ms(fn, n, clock=time.perf_counter):
    ts = []
    for i in range(n):
        t = clock()
        fn(i)
        ts.append(clock() - t)
    return 1000 * statistics.median(ts)


def bench(stereo: bool, width: int, height: int, runs: int, render=render_views) -> dict:
    seq = make_sequence(SynthConfig(width=width, height=height, num_frames=max(runs, 2), seed=0, stereo=stereo))
    kw = {"width": width, "height": height, **seq._static_kw()}
    inputs = [seq.frame_inputs(i) for i in range(runs)]
    t = time.perf_counter()
    jax.block_until_ready(render(**inputs[0], **kw))
    compile_s = time.perf_counter() - t
    device = _median_ms(lambda i: jax.block_until_ready(render(**inputs[i], **kw)), runs)
    device_cpu = _median_ms(lambda i: jax.block_until_ready(render(**inputs[i], **kw)), runs, time.process_time)
    host = _median_ms(lambda i: seq.frame_inputs(i), runs)
    frame = _median_ms(lambda i: seq[i], runs)
    return {"compile_s": compile_s, "device_ms": device, "device_cpu_ms": device_cpu, "host_ms": host, "frame_ms": frame}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--level0", action="store_true", help="under jax_disable_most_optimizations, with and without the pin")
    args = ap.parse_args()
    renders = {"": render_views}
    if args.level0:
        jax.config.update("jax_disable_most_optimizations", True)
        renders = {" (shipped, optimised)": render_views, " (level 0)": jax.jit(
            render_views.__wrapped__, static_argnames=("width", "height", "layout", "steps", "mb", "me"))}
    print(f"Synthetic world rendering at {args.width}×{args.height}, median of {args.runs} frames "
          f"({jax.devices()[0].platform}, {jax.__version__})\n")
    print("| cameras | compile (s) | device render (ms) | device FPS | device CPU time (ms, all threads) "
          "| host inputs (ms) | frame incl. transfer (ms) | FPS |")
    print("|---|---|---|---|---|---|---|---|")
    for stereo in (False, True):
        for label, render in renders.items():
            r = bench(stereo, args.width, args.height, args.runs, render)
            print(f"| {'stereo' if stereo else 'mono'}{label} | {r['compile_s']:.1f} | {r['device_ms']:.1f} | "
                  f"{1000 / r['device_ms']:.1f} | {r['device_cpu_ms']:.1f} | {r['host_ms']:.2f} | {r['frame_ms']:.1f} | "
                  f"{1000 / r['frame_ms']:.1f} |")


if __name__ == "__main__":
    main()
