"""Fine-tune the EdgeConnect filter for privacy and SLAM accuracy at once (issue 18).

Thin entry point over :func:`privslam_jax.tradeoff.train.train_tradeoff`:
``L = L_fid + λ_p·L_priv + λ_a·L_acc`` on pairs of consecutive frames of synthetic worlds
(``docs/tradeoff.md``), Adam, orbax checkpoints in ``WORKDIR/checkpoints`` (rerunning the same
command resumes), the losses in ``WORKDIR/log.csv``, a progress bar.

Example::

    python train/tradeoff.py --privacy-weight 1 --accuracy-weight 1 --steps 400 --workdir runs/tradeoff \\
        --export runs/tradeoff/filter.npz

Defaults: the embedded synthetic-world inpainter as the start (``--init``), the embedded
synthetic-world YOLOv8n as the privacy critic (``--detector``; it is then not an independent judge
of the result), worlds 1000-1009 of 60 frames at 320×96, one pair per step (``--batch``).

``--devices N`` and ``--distributed`` (several processes or hosts) as in ``train/detector.py``
(docs/training.md): the batch split across devices and processes, each process making only its own
pairs; process 0 writes the log and ``--export``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()


def _size(text: str) -> tuple[int, int] | None:
    """``HxW`` (two positive integers) or ``frame``."""
    if text == "frame":
        return None
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(x.isdigit() and int(x) > 0 for x in parts):
        raise argparse.ArgumentTypeError(f"expected HxW (e.g. 192x640) or 'frame', got {text!r}")
    return int(parts[0]), int(parts[1])


def main(argv: list[str] | None = None) -> int:
    from privslam_jax.argtypes import nonnegative_float, nonnegative_int, positive_float, positive_int, seed_list
    from privslam_jax.data.synthetic import parse_seeds
    from privslam_jax.detect.predict import EMBEDDED_WEIGHTS
    from privslam_jax.detect.weights import load_detector
    from privslam_jax.inpaint.filter import Inpainter
    from privslam_jax.sharding import add_parallel_arguments, start_parallel
    from privslam_jax.tradeoff import DetectorModel
    from privslam_jax.tradeoff.train import TradeoffConfig, train_tradeoff

    d = TradeoffConfig()
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--privacy-weight", type=nonnegative_float, default=d.privacy_weight, help="λ_p")
    p.add_argument("--accuracy-weight", type=nonnegative_float, default=d.accuracy_weight, help="λ_a")
    p.add_argument("--steps", type=positive_int, default=d.steps)
    p.add_argument("--lr", type=positive_float, default=d.learning_rate)
    p.add_argument("--worlds", type=seed_list, default="1000-1009", help="training world seeds, e.g. 1000-1009")
    p.add_argument("--frames", type=positive_int, default=d.frames_per_world, help="frames per world")
    p.add_argument("--width", type=positive_int, default=d.width, help="frame width of the training worlds")
    p.add_argument("--height", type=positive_int, default=d.height, help="frame height of the training worlds")
    p.add_argument("--detector-input", type=_size, default=d.detector_input_hw,
                   help="HxW the filtered frame is resized to for the privacy critic, or 'frame' (as it is; "
                        "default %(default)s)")
    p.add_argument("--checkpoint-every", type=positive_int, default=d.checkpoint_every)
    p.add_argument("--seed", type=nonnegative_int, default=d.seed, help="order of the training pairs")
    p.add_argument("--init", type=Path, default=None, help="inpainter .npz to start from (default: embedded synthetic)")
    p.add_argument("--detector", type=Path, default=EMBEDDED_WEIGHTS, help="YOLOv8 .npz of the privacy loss")
    p.add_argument("--workdir", type=Path, required=True)
    p.add_argument("--export", type=Path, default=None, help="write the fine-tuned inpainter here (.npz)")
    p.add_argument("--batch", type=positive_int, default=d.batch_size, help="frame pairs per step")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_parallel_arguments(p)
    a = p.parse_args(argv)
    primary = start_parallel(p, a, a.batch)

    config = dataclasses.replace(d, privacy_weight=a.privacy_weight, accuracy_weight=a.accuracy_weight, steps=a.steps,
                                 learning_rate=a.lr, world_seeds=tuple(parse_seeds(a.worlds)), frames_per_world=a.frames,
                                 checkpoint_every=a.checkpoint_every, seed=a.seed, batch_size=a.batch,
                                 width=a.width, height=a.height, detector_input_hw=a.detector_input,
                                 devices=a.devices)
    if config.frames_per_world <= config.gap:
        p.error(f"--frames must exceed the pair gap {config.gap}")
    try:
        inpainter = Inpainter.embedded("synthetic") if a.init is None else Inpainter.load(a.init)
    except (OSError, ValueError) as err:  # missing, damaged or not an inpainter checkpoint
        p.error(f"argument --init: {err}")
    try:
        detector, detector_params = DetectorModel.split(load_detector(a.detector)[0])
    except (OSError, ValueError) as err:
        p.error(f"argument --detector: {err}")
    trained = train_tradeoff(config, inpainter, detector_params, detector, a.workdir, progress=not a.quiet)
    if not primary:
        return 0
    print(f"trained {config.steps} steps of {config.batch_size} pairs (λ_p {config.privacy_weight}, "
          f"λ_a {config.accuracy_weight}); losses per step in {a.workdir / 'log.csv'}")
    if a.export is not None:
        trained.save(a.export)
        print(f"wrote {a.export}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
