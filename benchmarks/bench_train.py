"""Benchmark: training throughput (images/s) on 1 device, 2 devices of one process, 2 processes.

Command: ``python benchmarks/bench_train.py [--steps 8] [--detector-imgsz 256] [--inpaint-size 64] [--batch 8]
[--trainers detector,inpainter,tradeoff]``

For each trainer — the YOLOv8n detector (``privslam_jax.detect.train``, random textured 8-class
YOLO dataset), the EdgeConnect CPU preset (``privslam_jax.inpaint.train``, ``edge_inpaint``
stage on random crops) and the privacy/accuracy trade-off (``privslam_jax.tradeoff.train``, the
embedded filter and detector on pairs of synthetic 320×96 frames, ``--batch`` pairs a step; an
"image" is a pair) — each configuration runs in its own process (the device count is fixed
when JAX starts): ``1 device``; ``2 devices`` (``XLA_FLAGS=--xla_force_host_platform_device_count=2``,
one process, the batch split); ``2 processes`` (``jax.distributed`` on loopback, one device each,
each loading its own half of every batch).  A process first trains 2 steps
(compilation), then times ``--steps`` steps of a fresh run on the compiled step, data loading
included.  Scaling efficiency = images/s ÷ (devices × the 1-device images/s).

On a CPU host the "devices" share the same cores (one device already uses every core through
XLA's thread pool), so expect an efficiency near 1 / devices there: the table measures the
overhead of the data-parallel program, not a speed-up.  On a GPU/TPU host run the same command:
``--devices`` then counts accelerators (set nothing), and the 2-process rows need one process per
host (see docs/training.md).  Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _worker(a: argparse.Namespace) -> None:
    from privslam_jax._xla import configure_xla

    configure_xla()
    from privslam_jax.sharding import initialize_distributed

    if a.processes > 1:
        initialize_distributed(f"127.0.0.1:{a.port}", a.processes, a.process_id)
    import dataclasses

    import jax
    import numpy as np

    devices = jax.device_count()
    if a.trainer == "detector":
        from privslam_jax.detect.train import TrainConfig, train

        cfg = TrainConfig(data=a.data, num_classes=8, scale="n", imgsz=a.detector_imgsz, batch_size=a.batch,
                          epochs=1000, warmup_epochs=0.0, devices=devices)
        train(dataclasses.replace(cfg, max_steps=2), progress=False)  # compile
        t = time.perf_counter()
        train(dataclasses.replace(cfg, max_steps=a.steps), progress=False)
    elif a.trainer == "tradeoff":
        from privslam_jax.detect.predict import EMBEDDED_WEIGHTS
        from privslam_jax.detect.weights import load_detector
        from privslam_jax.inpaint.filter import Inpainter
        from privslam_jax.tradeoff import DetectorModel
        from privslam_jax.tradeoff.train import TradeoffConfig, train_tradeoff

        detector, det_params = DetectorModel.split(load_detector(EMBEDDED_WEIGHTS)[0])
        cfg = TradeoffConfig(batch_size=a.batch, devices=devices, steps=10_000, checkpoint_every=10**9)
        work = Path(a.data).parent / f"tradeoff-{a.processes}x{devices}"  # shared by the processes (orbax)
        init = Inpainter.embedded("synthetic")
        train_tradeoff(cfg, init, det_params, detector, work / "warm", max_steps=2, progress=False)
        t = time.perf_counter()
        train_tradeoff(cfg, init, det_params, detector, work / "timed", max_steps=a.steps, progress=False)
    else:
        from privslam_jax.inpaint.train import TrainConfig, train

        s = a.inpaint_size

        def data(step: int, batch: int):
            rng = np.random.default_rng(step)
            holes = np.zeros((batch, s, s), bool)
            holes[:, s // 4: 3 * s // 4, s // 3: 2 * s // 3] = True
            return rng.random((batch, s, s, 3), np.float32), holes

        cfg = TrainConfig(size=s, batch_size=a.batch, stages=(("edge_inpaint", 10_000),), checkpoint_every=10**9,
                          sample_every=0, devices=devices)
        work = Path(a.data).parent / f"inpaint-{a.processes}x{devices}"  # shared by the processes (orbax)
        train(cfg, data, work / "warm", max_steps=2, progress=False)
        t = time.perf_counter()
        train(cfg, data, work / "timed", max_steps=a.steps, progress=False)
    seconds = time.perf_counter() - t
    if jax.process_index() == 0:
        print(json.dumps({"devices": devices, "seconds": seconds, "images_per_s": a.steps * a.batch / seconds}))


def _write_dataset(root: Path, n: int, size: int) -> None:
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    for sub in ("images", "labels"):
        (root / sub / "train").mkdir(parents=True, exist_ok=True)
    for i in range(n):
        img = cv2.GaussianBlur(rng.integers(0, 255, (size, size, 3)).astype(np.uint8), (5, 5), 1.5)
        lines = []
        for _ in range(4):
            c = int(rng.integers(0, 8))
            w, h = (int(v) for v in rng.integers(size // 10, size // 3, 2))
            x, y = int(rng.integers(0, size - w)), int(rng.integers(0, size - h))
            img[y:y + h, x:x + w] = rng.integers(0, 255, 3)
            lines.append(f"{c} {(x + w / 2) / size} {(y + h / 2) / size} {w / size} {h / size}")
        cv2.imwrite(str(root / "images" / "train" / f"{i:04d}.png"), img)
        (root / "labels" / "train" / f"{i:04d}.txt").write_text("\n".join(lines) + "\n")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _run(trainer: str, devices: int, processes: int, a: argparse.Namespace, data: str) -> dict:
    base = [sys.executable, __file__, "--worker", trainer, "--data", data, "--steps", str(a.steps), "--batch",
            str(a.batch), "--detector-imgsz", str(a.detector_imgsz), "--inpaint-size", str(a.inpaint_size)]
    env = dict(os.environ)
    if devices > 1:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=")
                            + f" --xla_force_host_platform_device_count={devices}")
    port = _free_port()
    procs = [subprocess.Popen(base + ["--processes", str(processes), "--process-id", str(i), "--port", str(port)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
             for i in range(processes)]
    outs = [p.communicate(timeout=3600) for p in procs]
    for p, (_, err) in zip(procs, outs):
        if p.returncode:
            raise RuntimeError(f"{trainer} worker failed:\n{err[-3000:]}")
    return json.loads(outs[0][0].strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=8, help="timed steps per configuration")
    ap.add_argument("--batch", type=int, default=8, help="global batch (a multiple of 2)")
    ap.add_argument("--detector-imgsz", type=int, default=256)
    ap.add_argument("--inpaint-size", type=int, default=64)
    ap.add_argument("--trainers", default="detector,inpainter,tradeoff")
    ap.add_argument("--worker", choices=("detector", "inpainter", "tradeoff"), help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    ap.add_argument("--processes", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--process-id", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        a.trainer = a.worker
        _worker(a)
        return
    configs = dict.fromkeys(("detector", "inpainter", "tradeoff"), [(1, 1), (2, 1), (1, 2)])
    if unknown := set(a.trainers.split(",")) - set(configs):
        ap.error(f"--trainers: unknown {sorted(unknown)}; choose from {sorted(configs)}")
    with tempfile.TemporaryDirectory() as tmp:
        _write_dataset(Path(tmp) / "ds", 4 * a.batch, a.detector_imgsz)
        what = {"detector": f"detector {a.detector_imgsz}² YOLOv8n", "inpainter": f"inpainter {a.inpaint_size}² crops "
                "(CPU preset)", "tradeoff": "trade-off pairs of 320×96 frames (embedded filter and detector)"}
        print(f"{a.steps} timed steps, global batch {a.batch}; "
              + ", ".join(what[t] for t in a.trainers.split(",")) + f"; {os.cpu_count()} CPU cores\n")
        print("| trainer | configuration | devices | images/s | scaling efficiency |")
        print("|---|---|---|---|---|")
        for trainer in a.trainers.split(","):
            one = None
            for devices, processes in configs[trainer]:
                r = _run(trainer, devices, processes, a, str(Path(tmp) / "ds"))
                one = one or r["images_per_s"]
                name = "1 device" if r["devices"] == 1 else (f"{devices} devices, 1 process" if processes == 1
                                                            else f"{processes} processes, 1 device each")
                eff = r["images_per_s"] / (r["devices"] * one)
                print(f"| {trainer} | {name} | {r['devices']} | {r['images_per_s']:.3g} | {eff:.2f} |", flush=True)


if __name__ == "__main__":
    main()
