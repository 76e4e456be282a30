"""Table 1: detection quality (P, R, mAP50, mAP50-95) and size of the project's detectors.

Goal: measure, with the ultralytics-style metrics of ``privslam_jax.metrics.detection``, the
detectors the privacy filter can use:

* **ours (embedded)**: the YOLOv8n trained from scratch on the synthetic world and shipped in
  ``privslam_jax/assets`` (docs/model_card_detector.md), or ``--detector PATH``;
* **yolov8n (imported)**: the official ultralytics COCO YOLOv8n (``../shared/weights/yolov8n.pt``,
  AGPL, evaluation input only) loaded by our restricted unpickler; skipped when ``../shared`` is absent.

Data: (a) the synthetic held-out set — seeds ``--seeds`` (default 100001-100016, never used for
training; 16 frames each, every 12th frame, labels by the default
:class:`privslam_jax.data.yolo.SynthLabelRule`), written to ``--heldout`` (default: a temporary
folder) by :func:`privslam_jax.data.yolo.export_synthetic_yolo` unless it already exists there;
evaluated with the "rect" letterbox at 640 (the frames stay 640×192). (b) coco8 val and train
(``../shared/data/coco8``), square letterbox 640 as ``ultralytics val``. All rows: conf 0.001,
NMS IoU 0.7, multi-label — ultralytics' validation settings.

Command::

    python experiments/table1_detection.py [--detector PATH] [--heldout DIR] [--seeds 100001-100016]

Runtime: ≈ 3-5 min on the shared 2-core machine (256 synthetic frames written once, four
evaluations of 256 frames and two of coco8's 4+4 images). Writes ``results/table1_detection.md``.

Expected: the embedded detector reaches mAP50 ≥ 0.90, mAP50-95 ≥ 0.60 on the synthetic held-out
set but is weak on coco8 (real photos; it never saw one); the COCO YOLOv8n reproduces
ultralytics on coco8 (val mAP50-95 ≈ 0.61) and transfers only partly to the synthetic world.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()


def _privacy_subset(coco8: Path, out: Path) -> tuple[Path, list[str]]:
    """coco8 with only the labels of privacy classes (0, 1, 2, 3, 5, 7; images linked, not copied).

    Returns the folder and the splits that keep at least one label (coco8 train has none: its
    labels are giraffes, zebras, elephants, ...; a split without labels has no mAP to report).
    """
    import os
    import shutil

    from privslam_jax.detect import PRIVACY_CLASSES

    shutil.rmtree(out, ignore_errors=True)
    labelled = []
    for split in ("val", "train"):
        (out / "images" / split).mkdir(parents=True)
        (out / "labels" / split).mkdir(parents=True)
        for img in (coco8 / "images" / split).iterdir():
            os.symlink(img, out / "images" / split / img.name)
            lab = coco8 / "labels" / split / (img.stem + ".txt")
            lines = lab.read_text().splitlines() if lab.is_file() else []
            keep = [ln for ln in lines if ln.split() and int(float(ln.split()[0])) in PRIVACY_CLASSES]
            (out / "labels" / split / (img.stem + ".txt")).write_text("".join(k + "\n" for k in keep))
            if keep and split not in labelled:
                labelled.append(split)
    return out, labelled


def main(argv: list[str] | None = None) -> int:
    from privslam_jax._shared import shared_dir
    from privslam_jax.data.yolo import export_synthetic_yolo
    from privslam_jax.detect import EMBEDDED_WEIGHTS, Detector, DetectorConfig, count_parameters
    from privslam_jax.metrics.detection import evaluate_yolo_folder

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--detector", type=Path, default=EMBEDDED_WEIGHTS, help="our detector .npz (default: embedded)")
    p.add_argument("--heldout", type=Path, default=None, help="synthetic held-out YOLO folder (created if missing)")
    p.add_argument("--seeds", default="100001-100016", help="held-out synthetic seeds A-B")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "table1_detection.md")
    a = p.parse_args(argv)
    t0 = time.time()

    tmp = None
    heldout = a.heldout
    if heldout is None:
        tmp = tempfile.TemporaryDirectory(prefix="privslam_heldout_")
        heldout = Path(tmp.name)
    if not (heldout / "images" / "val").is_dir():
        lo, hi = (int(v) for v in a.seeds.split("-"))
        n = export_synthetic_yolo(heldout, "val", range(lo, hi + 1))
        print(f"wrote {n} held-out synthetic frames (seeds {lo}-{hi}) to {heldout}")
    n_syn = len(list((heldout / "images" / "val").iterdir()))

    detectors = []
    if a.detector.is_file():
        detectors.append((f"ours: YOLOv8n, synthetic world (`{a.detector.name}`)", a.detector))
    else:
        print(f"no detector at {a.detector}: skipping our row")
    shared = shared_dir()
    coco8 = None
    if shared is not None:
        detectors.append(("yolov8n.pt, ultralytics COCO (imported)", shared / "weights" / "yolov8n.pt"))
        coco8 = shared / "data" / "coco8"
        coco8_privacy, privacy_splits = _privacy_subset(coco8, Path(tempfile.mkdtemp(prefix="privslam_coco8p_")) / "coco8")
    else:
        print("../shared absent: no imported yolov8n row and no coco8 columns")

    val = dict(conf=0.001, iou=0.7, multi_label=True)
    rows = []
    for name, path in detectors:
        det = Detector.from_weights(path, DetectorConfig(imgsz=640, mode="rect", **val))
        params = count_parameters(det.model)
        evals = [("synthetic held-out", evaluate_yolo_folder(det, heldout, "val"))]
        if coco8 is not None:
            sq = det.with_config(DetectorConfig(imgsz=640, mode="square", **val))
            evals += [(f"coco8 {s}", evaluate_yolo_folder(sq, coco8, s)) for s in ("val", "train")]
            evals += [(f"coco8 {s}, privacy classes only", evaluate_yolo_folder(sq, coco8_privacy, s))
                      for s in privacy_splits]
        for data, m in evals:
            rows.append((name, data, m, params))
            print(f"{name} | {data}: P {m.precision:.3f} R {m.recall:.3f} mAP50 {m.map50:.3f} "
                  f"mAP50-95 {m.map50_95:.3f} ({params:,} params)")
    runtime = time.time() - t0

    lines = [
        "# Table 1: detection",
        "",
        f"Generated by `python experiments/table1_detection.py` in {runtime:.0f} s (shared 2-core CPU).",
        f"Synthetic held-out: {n_syn} frames of seeds {a.seeds} (unseen in training), 640×192, rect letterbox 640;",
        "coco8: square letterbox 640. Ultralytics val settings: conf 0.001, NMS IoU 0.7, multi-label;",
        "metrics as ultralytics (`privslam_jax.metrics.detection`).",
        "",
        "| detector | data | P | R | mAP50 | mAP50-95 | params |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, data, m, params in rows:
        lines.append(f"| {name} | {data} | {m.precision:.3f} | {m.recall:.3f} | {m.map50:.3f} | {m.map50_95:.3f} "
                     f"| {params:,} |")
    lines += ["", "coco8's labels are persons plus 11 classes outside the privacy set (dog, horse, elephant, ...);",
              "ours only knows the six privacy classes, and the mAP averages over every labelled class, so its",
              "plain coco8 rows are bounded by the person share. The 'privacy classes only' rows keep just the",
              "privacy-class labels (here: persons). They measure synthetic-to-real transfer; ours never saw a photo.",
              "coco8 train has no label of a privacy class at all (giraffes, zebras, elephants, ...), so it has no",
              "'privacy classes only' row."]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.out} ({runtime:.0f} s)")
    if tmp is not None:
        tmp.cleanup()
    if coco8 is not None:
        import shutil

        shutil.rmtree(coco8_privacy.parent, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
