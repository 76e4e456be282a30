"""Self-training data: pseudo-label the unlabelled real training frames and mix them with synthetic ones.

Command::

    python train/pseudo_labels.py --weights DETECTOR.npz --synthetic DIR/SPLIT --out DIR [--repeat 4]

Labels the real frames that ``../shared`` allows training on — ``data/real/kitti_raw_a/frames``
(two runs of 40 consecutive colour frames) and the grey KITTI odometry ``seq1`` and ``00`` — with
the detector's own confident boxes (:func:`privslam_jax.detect.pseudo.export_pseudo_yolo`: TTA,
propagation over consecutive frames, uncertain regions painted grey) into ``OUT/{images,labels}/real``,
then writes the split ``OUT/{images,labels}/mix``: symbolic links to every frame of the synthetic
split and ``--repeat`` links to each real frame (so real frames are seen that much more often).
Train on it with ``train/detector.py --data OUT --split mix --init-weights DETECTOR.npz``.
Never touches the evaluation sets (``kitti_object``, ``kitti_raw_b``, ``nuscenes_front``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()


def runs_of(folder: Path) -> list[list[Path]]:
    """PNG frames of ``folder`` split where the frame numbers jump."""
    paths = sorted(folder.glob("*.png"))
    runs: list[list[Path]] = []
    for p in paths:
        if runs and int(p.stem) == int(runs[-1][-1].stem) + 1:
            runs[-1].append(p)
        else:
            runs.append([p])
    return runs


def main(argv: list[str] | None = None) -> int:
    from privslam_jax._shared import shared_dir
    from privslam_jax.argtypes import positive_int, unit_interval
    from privslam_jax.data.yolo import link_mixed_split
    from privslam_jax.detect import PRIVACY_CLASSES, Detector, DetectorConfig
    from privslam_jax.detect.pseudo import PseudoLabelConfig, export_pseudo_yolo

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", required=True, help="the detector that labels (our .npz; never third-party weights)")
    p.add_argument("--synthetic", type=Path, required=True, help="synthetic YOLO split to mix in: ROOT/SPLIT")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--repeat", type=positive_int, default=4, help="links per real frame in the mix split")
    p.add_argument("--label-conf", type=unit_interval, default=0.5)
    a = p.parse_args(argv)
    shared = shared_dir()
    if shared is None:
        raise SystemExit("needs ../shared (the real training frames); set PRIVSLAM_SHARED")
    if not str(a.weights).endswith(".npz"):
        raise SystemExit("--weights must be one of our .npz checkpoints: third-party weights never teach shipped ones")
    det = Detector.from_weights(a.weights, DetectorConfig(classes=PRIVACY_CLASSES))
    runs = runs_of(shared / "data" / "real" / "kitti_raw_a" / "frames")
    for seq in ("seq1", "00"):
        runs += runs_of(shared / "data" / "kitti_odometry" / "sequences" / seq / "image_0")
    n, labels, ignored = export_pseudo_yolo(det, runs, a.out, "real", PseudoLabelConfig(label_conf=a.label_conf))
    print(f"pseudo-labelled {n} real frames: {labels} labels, {ignored} regions painted grey")

    n_mix = link_mixed_split(a.out, "mix", [(a.synthetic, 1), (a.out / "real", a.repeat)])
    print(f"wrote {a.out}/images/mix ({n_mix} images)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
