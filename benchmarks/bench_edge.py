"""The edge split under load, on loopback: N = 1, 2, 4, 8 clients streaming to one ``privslam serve``.

Command:  python benchmarks/bench_edge.py [--frames 60] [--clients 1,2,4,8] [--mode mono] [--window 1] [--rate HZ]

One synthetic world (640×192, seed 0, ``--frames`` frames, rendered once) is streamed by every
client as its own session (ids ``n<N>-c<i>``) as fast as the server acknowledges it, with at most
``--window`` frames unacknowledged (1: each frame is sent when the previous pose came back, so the
latency is the server's time for that frame, not a queue), or at most ``--rate`` frames/s per client
(a camera's rate; then the total offered load is N × rate, and client ``i`` starts ``i / (N · rate)``
seconds after the first, as independent devices are not in step).  The server is a ``privslam serve``
subprocess on a free port with a temporary store; a first session compiles its JAX programs and
is not timed.  Printed per N: frames/s per client (median over clients) and in total (N·frames /
wall time), p50 and p99 pose latency over every frame, bytes per frame up and down, frames lost
(acknowledged but not stored, or never acknowledged: must be 0) and reconnections.

Reference in the same run: the same frames through ``run_slam`` in this process (one session,
no split): frames/s.  Goal (issue 20 item 5, 2-core machine): ≥ 10 frames/s in total with 4
clients, p99 latency ≤ 500 ms, 0 frames lost.  The clients run in this process and share the two
cores with the server: numbers on a shared machine are noisy; say so when quoting them.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

import numpy as np  # noqa: E402


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--clients", default="1,2,4,8", help="comma-separated client counts")
    p.add_argument("--mode", choices=("mono", "stereo"), default="mono")
    p.add_argument("--window", type=int, default=1, help="unacknowledged frames per client (default 1)")
    p.add_argument("--rate", type=float, default=None, help="frames/s per client (default: as fast as acknowledged)")
    a = p.parse_args()

    from privslam_jax.data.images import grey_as_read
    from privslam_jax.data.synthetic import SynthConfig, make_sequence
    from privslam_jax.edge.client import calibration_message, frame_message, run_session
    from privslam_jax.slam.system import SlamConfig, run_slam

    stereo = a.mode == "stereo"
    world = make_sequence(SynthConfig(num_frames=a.frames, seed=0, stereo=stereo))
    u8 = [(np.clip(np.rint(f.image * 255), 0, 255).astype(np.uint8),
           np.clip(np.rint(f.image_right * 255), 0, 255).astype(np.uint8) if stereo else None) for f in world]
    frames = [frame_message(i, i / 10.0, left, right=right) for i, (left, right) in enumerate(u8)]
    print(f"{a.frames} frames of a synthetic world, 640x192, {a.mode}; window {a.window}; "
          f"rate {'as fast as acknowledged' if a.rate is None else f'{a.rate} frames/s'} per client; "
          f"{os.cpu_count()} CPUs", flush=True)

    # reference: the same frames in one process, no split (second run: compiled)
    items = [grey_as_read(left) if not stereo else (grey_as_read(left), grey_as_read(right)) for left, right in u8]
    run_slam(items, world.camera, SlamConfig(mode=a.mode))
    t0 = time.perf_counter()
    run_slam(items, world.camera, SlamConfig(mode=a.mode))
    ref_fps = a.frames / (time.perf_counter() - t0)

    store = Path(tempfile.mkdtemp(prefix="privslam-bench-edge-"))
    port = _free_port()
    server = subprocess.Popen([sys.executable, "-m", "privslam_jax.cli", "serve", "--store", str(store), "--listen",
                               f"127.0.0.1:{port}", "--max-sessions", "8"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    addr = f"127.0.0.1:{port}"
    try:
        t0 = time.perf_counter()
        run_session(addr, calibration_message("warmup", world.camera, a.mode), frames, want_map=False)
        print(f"warm-up session (server start and compilation): {time.perf_counter() - t0:.1f} s", flush=True)
        rows = []
        for n in (int(x) for x in a.clients.split(",")):
            results: list = [None] * n
            walls = [0.0] * n

            def client(i: int, n: int = n) -> None:
                if a.rate is not None:
                    time.sleep(i / (n * a.rate))
                t = time.perf_counter()
                results[i] = run_session(addr, calibration_message(f"n{n}-c{i}", world.camera, a.mode), frames,
                                         window=a.window, want_map=False, rate_hz=a.rate)
                walls[i] = time.perf_counter() - t

            threads = [threading.Thread(target=client, args=(i,)) for i in range(n)]
            t0 = time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.perf_counter() - t0
            lat = np.concatenate([r.latency_s for r in results]) * 1e3
            stored = [len(list((store / f"n{n}-c{i}" / "frames").glob("*.json"))) for i in range(n)]
            lost = sum(a.frames - s for s in stored) + int(np.isnan(lat).sum())
            rows.append((n, float(np.median([a.frames / w for w in walls])), n * a.frames / wall,
                         float(np.nanpercentile(lat, 50)), float(np.nanpercentile(lat, 99)),
                         sum(r.bytes_up for r in results) / (n * a.frames), sum(r.bytes_down for r in results) / (n * a.frames),
                         lost, sum(r.reconnects for r in results)))
            print(f"  {n} clients done in {wall:.1f} s", flush=True)
    finally:
        server.terminate()
        server.wait(timeout=60)
    print()
    print("| clients | frames/s per client (median) | frames/s total | latency p50 ms | latency p99 ms | "
          "bytes/frame up | bytes/frame down | lost | reconnects |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n, per, total, p50, p99, up, down, lost, rec in rows:
        print(f"| {n} | {per:.1f} | {total:.1f} | {p50:.0f} | {p99:.0f} | {up:,.0f} | {down:,.0f} | {lost} | {rec} |")
    print(f"| reference: run_slam in one process | {ref_fps:.1f} | {ref_fps:.1f} | | | | | | |")


if __name__ == "__main__":
    main()
