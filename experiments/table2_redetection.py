"""Table 2 of the source paper: how many privacy objects a detector still finds after filtering.

Goal: for every privacy-filter method (the baselines of ``privslam_jax.inpaint.baselines`` and our
EdgeConnect inpainter), the share of privacy objects found in the original frame that are found
again in the filtered frame (same class, IoU ≥ 0.5 with a detection of the filtered frame). The
masks are the real filter's: the detector's own boxes on the original frame, dilated by 4 px, as
``privslam filter --masks detect`` does. Filtered frames are quantised to 8 bits (as written to
disk) before re-detection.

(a) synthetic held-out frames (worlds ``--seeds``, never used to train the inpainter) with the
    project's embedded detector (``--detector``: default the ``privslam_jax/assets`` checkpoint);
(b) the real KITTI frames of ``../shared`` (``seq1`` and ``00``, grey) with the imported ultralytics
    YOLOv8n (``../shared/weights/yolov8n.pt``) as an independent detector; skipped with a message
    when ``../shared`` is absent.

Both use the paper's detector setting (privacy classes, confidence 0.4, NMS IoU 0.7). The noise
methods are seeded per frame (one run; the other methods are deterministic).

Command::

    python experiments/table2_redetection.py [--detector PATH] [--seeds 901-905] [--frames 25]

Runtime: 2.5 min on an idle 2-core machine, 7.1 min at load ≈ 7 (125 synthetic frames at 640×192 and 56 KITTI
frames at 1226×370, 12 methods each). Writes ``results/table2_redetection.md``.

Expected: ours ≤ 5 % (measured: 0 % in both parts); blur, pixelation and gaussian_add
(functions of the hidden pixels) leak; black and Gaussian fills are re-detected by the synthetic-trained detector (13 %).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()

from privslam_jax._shared import shared_dir  # noqa: E402
from privslam_jax.detect import Detector  # noqa: E402
from privslam_jax.data.synthetic import parse_seeds  # noqa: E402
from privslam_jax.inpaint.baselines import LEAKY_METHODS  # noqa: E402
from privslam_jax.inpaint.filter import FILTER_METHODS, Inpainter, filter_frame  # noqa: E402
from privslam_jax.inpaint.masks import boxes_to_masks  # noqa: E402
from privslam_jax.metrics.redetection import detection_arrays, privacy_config, refound  # noqa: E402

DILATION = 4


def redetection(frames, detector: Detector, methods, inpainter, grey: bool, desc: str):
    """``{method: (refound, total)}`` and the number of frames with ≥ 1 original detection."""
    counts = {m: [0, 0] for m in methods}
    used = 0
    for i, image in enumerate(tqdm(frames, desc=desc)):
        orig = detector.detect([image])[0]
        boxes, _ = detection_arrays(orig)
        if len(boxes) == 0:
            continue
        used += 1
        h, w = image.shape[:2]
        masks = boxes_to_masks(boxes, h, w, DILATION)
        outs = []
        for m in methods:
            out = filter_frame(image, masks, m, inpainter=inpainter, seed=i)
            if grey:  # the filter writes grey sequences' first channel
                out = np.repeat(out[..., :1], 3, axis=-1)
            outs.append(np.clip(np.rint(out * 255), 0, 255).astype(np.uint8))
        for m, det in zip(methods, detector.detect(outs), strict=True):
            counts[m][0] += refound(orig, det)
            counts[m][1] += len(boxes)
    return {m: tuple(v) for m, v in counts.items()}, used


def synthetic_frames(seeds, n):
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    for s in seeds:
        seq = make_sequence(SynthConfig(num_frames=n, seed=s))
        for i in range(len(seq)):
            yield seq[i].image


def kitti_frames(shared: Path):
    from privslam_jax.data.images import read_image

    for name in ("seq1", "00"):
        for p in sorted((shared / "data" / "kitti_odometry" / "sequences" / name / "image_0").glob("*.png")):
            yield read_image(p)  # grey repeated to 3 channels


def default_detector() -> Path | None:
    from privslam_jax.detect.predict import EMBEDDED_WEIGHTS

    return EMBEDDED_WEIGHTS if EMBEDDED_WEIGHTS.is_file() else None


def table(res, used, label) -> str:
    lines = [f"{label}: {used} frames with detections, {next(iter(res.values()))[1]} objects found in the originals.",
             "", "| method | re-detected | share |", "|---|---|---|"]
    for m, (k, n) in res.items():
        name = "**ours (EdgeConnect)**" if m == "edgeconnect" else m + (" (leaks)" if m in LEAKY_METHODS else "")
        lines.append(f"| {name} | {k} / {n} | {100 * k / max(n, 1):.1f} % |")
    return "\n".join(lines)


def _sha(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()[:12]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--detector", type=Path, help="project detector for (a) (default: the embedded one)")
    p.add_argument("--model", type=Path, help="Inpainter .npz (default: the embedded one)")
    p.add_argument("--seeds", default="901-905", help="held-out synthetic worlds")
    p.add_argument("--frames", type=int, default=25, help="frames per world")
    p.add_argument("--methods", default=",".join(FILTER_METHODS))
    p.add_argument("--kitti-frames", type=int, default=None, help="use only the first N KITTI frames (smoke runs)")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "table2_redetection.md")
    a = p.parse_args(argv)
    methods = [m for m in a.methods.split(",") if m]
    inpainter = None
    if "edgeconnect" in methods:
        inpainter = Inpainter.load(a.model) if a.model else Inpainter.embedded()
    t0 = time.time()
    parts = []
    det_path = a.detector or default_detector()
    if det_path is None:
        msg = "(a) skipped: no project detector (pass --detector PATH; none in privslam_jax/assets)."
        print(msg)
        parts.append(msg)
    else:
        det = Detector.from_weights(det_path)
        det = det.with_config(privacy_config(det))
        res, used = redetection(synthetic_frames(parse_seeds(a.seeds), a.frames), det, methods, inpainter, False,
                                "(a) synthetic")
        parts.append(table(res, used, f"(a) Synthetic held-out worlds {a.seeds} ({a.frames} frames each, 640×192), "
                                      f"project detector `{det_path.relative_to(ROOT) if det_path.is_relative_to(ROOT) else det_path}` "
                                      f"sha256 {_sha(det_path)} (classes {det.config.classes}, conf 0.4)"))
        print(parts[-1])
    shared = shared_dir()
    yolo = None if shared is None else shared / "weights" / "yolov8n.pt"
    if yolo is None or not yolo.is_file():
        msg = "(b) skipped: ../shared (KITTI frames and yolov8n.pt) is absent."
        print(msg)
        parts.append(msg)
    else:
        det = Detector.from_weights(yolo)
        det = det.with_config(privacy_config(det))
        import itertools

        frames = itertools.islice(kitti_frames(shared), a.kitti_frames)
        res, used = redetection(frames, det, methods, inpainter, True, "(b) KITTI")
        parts.append(table(res, used, "(b) Real KITTI frames (`seq1` 51 + `00` 5, grey 1226×370), independent "
                                      "detector: ultralytics YOLOv8n (`../shared/weights/yolov8n.pt` through our "
                                      "loader, COCO privacy classes, conf 0.4)"))
        print(parts[-1])
    minutes = (time.time() - t0) / 60
    header = ("# Table 2: re-detection after privacy filtering\n\n"
              "Share of privacy objects detected in the original frame (same class, IoU ≥ 0.5) that the same "
              "detector finds again in the filtered frame; masks = the detector's boxes dilated by 4 px. "
              f"Generated by `python experiments/table2_redetection.py` ({minutes:.1f} min on the shared 2-core "
              "machine). Goal (issue 4): ours ≤ 5 % and no worse than the best fill baseline. "
              "`blur`, `pixelate` and `gaussian_add` are functions of the hidden pixels (they leak).\n")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(header + "\n" + "\n\n".join(parts) + "\n")
    print(f"written {a.out} in {minutes:.1f} min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
