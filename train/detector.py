"""Train the YOLOv8 detector on a YOLO-format dataset (thin entry point).

Command: ``python train/detector.py --data DIR --num-classes N [--scale n] [--imgsz 640]
[--batch 16] [--epochs 100] [--ckpt-dir DIR] [--out model.npz]``

Runs :func:`privslam_jax.detect.train.train` (ultralytics recipe, Optax, orbax checkpoints;
re-running with the same ``--ckpt-dir`` resumes), then writes the EMA weights as a privslam
``.npz`` checkpoint usable by ``privslam detect --weights`` and, when ``--val-split`` is given,
prints P, R, mAP50 and mAP50-95 on it (ultralytics val settings).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()


def main(argv: list[str] | None = None) -> int:
    from privslam_jax.detect.predict import Detector, DetectorConfig
    from privslam_jax.detect.train import TrainConfig, train
    from privslam_jax.detect.weights import save_checkpoint
    from privslam_jax.metrics.detection import evaluate_yolo_folder

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="YOLO dataset root")
    p.add_argument("--num-classes", type=int, required=True)
    p.add_argument("--split", default="train")
    p.add_argument("--val-split", default=None)
    p.add_argument("--scale", default="n")
    p.add_argument("--imgsz", type=int, default=640)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--lr0", type=float, default=0.01)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--ckpt-dir", default=None)
    p.add_argument("--ckpt-every", type=int, default=100)
    p.add_argument("--out", type=Path, default=Path("detector.npz"))
    a = p.parse_args(argv)
    cfg = TrainConfig(data=a.data, num_classes=a.num_classes, split=a.split, scale=a.scale, imgsz=a.imgsz,
                      batch_size=a.batch, epochs=a.epochs, lr0=a.lr0, seed=a.seed, ckpt_dir=a.ckpt_dir,
                      ckpt_every=a.ckpt_every)
    result = train(cfg)
    save_checkpoint(result.model, a.out)
    print(f"wrote {a.out} after {result.step} steps")
    if a.val_split:
        det = Detector(result.model, DetectorConfig(imgsz=a.imgsz, mode="square", conf=0.001, iou=0.7, multi_label=True))
        m = evaluate_yolo_folder(det, a.data, a.val_split)
        print(" ".join(f"{k} {v:.4f}" for k, v in m.as_dict().items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
