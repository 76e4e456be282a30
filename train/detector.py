"""Train the YOLOv8 detector on a YOLO-format dataset (thin entry point).

Command: ``python train/detector.py --data DIR --num-classes N [--scale n] [--imgsz 640]
[--batch 16] [--epochs 100] [--ckpt-dir DIR] [--out model.npz]``

Runs :func:`privslam_jax.detect.train.train` (ultralytics recipe, Optax, orbax checkpoints;
re-running with the same ``--ckpt-dir`` resumes), then writes the EMA weights as a privslam
``.npz`` checkpoint usable by ``privslam detect --weights`` and, when ``--val-split`` is given,
prints P, R, mAP50 and mAP50-95 on it (ultralytics val settings; "rect" letterbox when
``--imgh`` is given).

Data parallelism: ``--devices N`` splits each batch over ``N`` devices of this process;
``--distributed`` runs one process per host or worker (start each with the same arguments plus
``--process-id``; ``--coordinator host:port`` of process 0, ``--num-processes``, or the environment
variables ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``): each process loads its
own rows of every batch, the checkpoints are shared (a run resumes with another process count) and
process 0 writes ``--out``.  On two processes of one machine::

    python train/detector.py ... --distributed --coordinator 127.0.0.1:12355 --num-processes 2 --process-id 0 &
    python train/detector.py ... --distributed --coordinator 127.0.0.1:12355 --num-processes 2 --process-id 1

``--synth-train-seeds A-B`` / ``--synth-val-seeds C-D`` first write the synthetic world as a YOLO
dataset into ``--data`` (splits ``train`` / ``val``, skipped when the split already exists;
:func:`privslam_jax.data.yolo.export_synthetic_yolo`, label rule
:class:`privslam_jax.data.yolo.SynthLabelRule`). ``--coco-names`` stores COCO class names
(ids 0..num_classes-1) in the checkpoint. The embedded detector was made with (docs/model_card_detector.md)::

    python train/detector.py --data DIR --num-classes 8 --coco-names \
        --synth-train-seeds 1-200 --synth-val-seeds 100001-100016 --synth-frames 16 --synth-stride 12 \
        --imgsz 640 --imgh 192 --batch 8 --epochs 16 --optimizer adamw --lr0 0.001 --momentum 0.9 ...
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

COCO_NAMES_8 = ("person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck")
"""COCO names of ids 0..7: an 8-class head covers the privacy classes 0, 1, 2, 3, 5, 7 with their COCO ids."""


def main(argv: list[str] | None = None) -> int:
    from privslam_jax.argtypes import (multiple_of_32, nonnegative_float, nonnegative_int, open_unit_interval,
                                                positive_float, positive_int, seed_list, unit_interval)
    from privslam_jax.detect.predict import Detector, DetectorConfig
    from privslam_jax.detect.train import TrainConfig, train
    from privslam_jax.detect.yolov8 import SCALES
    from privslam_jax.detect.weights import save_checkpoint
    from privslam_jax.metrics.detection import evaluate_yolo_folder
    from privslam_jax.sharding import add_parallel_arguments, start_parallel

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="YOLO dataset root")
    p.add_argument("--num-classes", type=positive_int, required=True)
    p.add_argument("--split", default="train")
    p.add_argument("--val-split", default=None)
    p.add_argument("--scale", choices=sorted(SCALES), default="n")
    p.add_argument("--imgsz", type=multiple_of_32, default=640)
    p.add_argument("--batch", type=positive_int, default=16)
    p.add_argument("--epochs", type=positive_int, default=100)
    p.add_argument("--lr0", type=positive_float, default=0.01)
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--ckpt-dir", default=None)
    p.add_argument("--ckpt-every", type=positive_int, default=100)
    p.add_argument("--out", type=Path, default=Path("detector.npz"))
    p.add_argument("--imgh", type=multiple_of_32, default=None, help="rect training canvas height (e.g. 192 with --imgsz 640)")
    p.add_argument("--optimizer", choices=("sgd", "adamw"), default="sgd")
    p.add_argument("--momentum", type=open_unit_interval, default=0.937)
    p.add_argument("--lrf", type=nonnegative_float, default=0.01)
    p.add_argument("--cos-lr", action="store_true")
    p.add_argument("--warmup-epochs", type=nonnegative_float, default=3.0)
    p.add_argument("--warmup-bias-lr", type=nonnegative_float, default=0.1,
                   help="bias lr at the start of warmup (use ~lr0 to fine-tune)")
    p.add_argument("--max-steps", type=nonnegative_int, default=None,
                   help="stop after this many steps (schedule still spans --epochs)")
    p.add_argument("--domain-rand", type=unit_interval, default=0.0,
                   help="probability of photometric domain randomisation per image")
    p.add_argument("--style", type=unit_interval, default=0.0,
                   help="probability per image of a real frame's low-frequency spectrum (Fourier domain adaptation)")
    p.add_argument("--style-frames", nargs="+", default=(), help="real frames (files or folders) for --style")
    p.add_argument("--style-beta", type=float, default=0.05, help="FDA window size, a fraction of the short side, in [0, 0.5)")
    p.add_argument("--init-weights", default=None, help="fine-tune from this .npz checkpoint (same scale and classes)")
    p.add_argument("--synth-randomize-camera", action="store_true",
                   help="per seed random camera height, focal length and object density in the synthetic export")
    p.add_argument("--domain", choices=("synthetic", "real", "unknown"), default="unknown",
                   help="what the training data was, recorded in the checkpoint (real: any real frames in it)")
    p.add_argument("--coco-names", action="store_true", help="store COCO class names in the checkpoint")
    add_parallel_arguments(p)
    p.add_argument("--synth-train-seeds", type=seed_list, default=None,
                   help="A-B: export synthetic seeds A..B as the train split first")
    p.add_argument("--synth-val-seeds", type=seed_list, default=None,
                   help="C-D: export synthetic seeds C..D as the val split first")
    p.add_argument("--synth-frames", type=positive_int, default=16, help="frames per synthetic seed")
    p.add_argument("--synth-stride", type=positive_int, default=12, help="frame stride within a synthetic seed")
    a = p.parse_args(argv)
    if a.imgh is not None and a.imgh > a.imgsz:
        p.error(f"argument --imgh: must be at most --imgsz ({a.imgsz}), got {a.imgh}")
    if not 0.0 <= a.style_beta < 0.5:
        p.error(f"argument --style-beta: must be in [0, 0.5), got {a.style_beta}")
    if a.style_frames and not a.style:
        p.error("argument --style-frames: has no effect without --style P > 0")
    if a.style and not a.style_frames:
        p.error("argument --style: needs --style-frames (real frames to take the spectra from)")
    if a.style:
        from privslam_jax.inpaint.data import image_paths

        try:
            image_paths(*a.style_frames)
        except (OSError, ValueError) as err:
            p.error(f"argument --style-frames: {err}")
    primary = start_parallel(p, a, a.batch)
    if a.coco_names and a.num_classes > len(COCO_NAMES_8):
        p.error(f"argument --coco-names: knows the first {len(COCO_NAMES_8)} COCO names, got --num-classes {a.num_classes}")
    for split, seeds in (("train", a.synth_train_seeds), ("val", a.synth_val_seeds)):
        if seeds and primary and not (Path(a.data) / "images" / split).is_dir():
            from privslam_jax.data.yolo import export_synthetic_yolo

            from privslam_jax.data.synthetic import parse_seeds

            n = export_synthetic_yolo(a.data, split, parse_seeds(seeds), a.synth_frames, a.synth_stride,
                                     randomize_camera=a.synth_randomize_camera)
            print(f"wrote {n} synthetic frames (seeds {seeds}) to {a.data}/images/{split}")
    if a.distributed:  # the other processes wait for process 0's dataset
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("dataset written")
    cfg = TrainConfig(data=a.data, num_classes=a.num_classes, split=a.split, scale=a.scale, imgsz=a.imgsz, imgh=a.imgh,
                      batch_size=a.batch, epochs=a.epochs, lr0=a.lr0, lrf=a.lrf, cos_lr=a.cos_lr, momentum=a.momentum,
                      warmup_epochs=a.warmup_epochs, warmup_bias_lr=a.warmup_bias_lr, optimizer=a.optimizer, seed=a.seed, ckpt_dir=a.ckpt_dir,
                      ckpt_every=a.ckpt_every, max_steps=a.max_steps,
                      domain_rand=a.domain_rand, style=a.style, style_frames=tuple(a.style_frames),
                      style_beta=a.style_beta, init_weights=a.init_weights, devices=a.devices)
    result = train(cfg, progress=primary)
    if not primary:
        return 0
    names = {i: COCO_NAMES_8[i] for i in range(a.num_classes)} if a.coco_names else None
    save_checkpoint(result.model, a.out, names, domain=a.domain)
    print(f"wrote {a.out} after {result.step} steps")
    if a.val_split:
        mode = "rect" if a.imgh else "square"
        det = Detector(result.model, DetectorConfig(imgsz=a.imgsz, mode=mode, conf=0.001, iou=0.7, multi_label=True))
        m = evaluate_yolo_folder(det, a.data, a.val_split)
        print(" ".join(f"{k} {v:.4f}" for k, v in m.as_dict().items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
