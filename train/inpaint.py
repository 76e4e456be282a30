"""Train the EdgeConnect inpainter (edge → inpaint → joint) on CPU-scale data.

Thin entry point over :func:`privslam_jax.inpaint.train.train`. Data (one of):

* ``--synth-frames N``: render N synthetic frames in-process (seed ``--synth-seed``) and train on
  crops around their privacy objects with the object-free renders as targets;
* ``--sequence DIR``: a sequence written by ``privslam synth`` (``masks/`` + ``background/``);
* ``--folder DIR``: any image folder, random box and irregular masks;
* ``--real DIR [DIR ...] --shapes MASKDIR``: real frames with object-shaped holes moved onto
  other regions (answer known) and free-form holes, cropped as at inference; mixed with a
  synthetic source above with ``--real-weight`` (or alone).

``--init MODEL.npz`` fine-tunes from an inpainter (e.g. the embedded synthetic one).

Examples::

    python train/inpaint.py --synth-frames 200 --workdir runs/inpaint --export runs/inpaint/model.npz
    python train/inpaint.py --folder ../shared/data/inpainting/psv/images --steps 50,50,20 --workdir runs/psv
    python train/inpaint.py --real ../shared/data/real/kitti_raw_a/frames --shapes ../shared/data/real/kitti_raw_a/maskrcnn_masks \
        --init privslam_jax/assets/inpainter_cpu16.npz --stages edge_inpaint:2000 --workdir runs/real

``--devices N`` and ``--distributed`` (several processes or hosts) as in ``train/detector.py``
(docs/training.md); with ``--distributed`` process 0 extracts the crop bank and writes the outputs.

Rerunning the same command resumes from ``WORKDIR/checkpoints``. Writes PNG sample grids to
``WORKDIR/samples`` and the losses to ``WORKDIR/log.csv``; ``--export`` writes the generators as
an :class:`~privslam_jax.inpaint.filter.Inpainter` ``.npz`` usable by ``privslam filter``, with the
inference settings ``--export-flip-average``, ``--export-prefill-blend`` and
``--export-prefill-blend-distance`` (in ``--export-prefill-blend-unit``) in its config
(:class:`~privslam_jax.inpaint.filter.InpainterConfig`; the real-frame checkpoint's are on, 1 and 3
model pixels).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from privslam_jax._xla import configure_xla  # noqa: E402

configure_xla()


def main(argv: list[str] | None = None) -> int:
    from privslam_jax.argtypes import (nonnegative_float, nonnegative_int, open_unit_interval, positive_float,
                                                positive_int, seed_list, unit_interval)
    from privslam_jax.sharding import add_parallel_arguments, start_parallel

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = p.add_mutually_exclusive_group()
    src.add_argument("--synth-frames", type=positive_int, help="render this many synthetic frames")
    src.add_argument("--sequence", type=Path, help="sequence folder written by `privslam synth`")
    src.add_argument("--folder", type=Path, help="folder of images (random masks)")
    src.add_argument("--bank", type=Path, help="a crop bank .npz saved by an earlier run")
    p.add_argument("--real", type=Path, nargs="+", help="real frames: folders or image files (holes from --shapes)")
    p.add_argument("--shapes", type=Path, help="folder of binary object masks (255 = object) for --real")
    p.add_argument("--shape-files", help="use only these mask files, as a slice A:B of the sorted list "
                   "(keep the rest for evaluation)")
    p.add_argument("--real-weight", type=unit_interval, default=0.7, help="share of real samples when mixed")
    p.add_argument("--init", type=Path, help="fine-tune from this Inpainter .npz")
    p.add_argument("--prefill", default="white", help="what G2 sees in the hole: white (official), telea, ns, gray")
    p.add_argument("--residual", action="store_true", help="G2 predicts a correction of the prefill")
    p.add_argument("--hole-loss", default="l1", choices=("l1", "l1_hole", "l2_hole", "l2_blend"),
                   help="G2's reconstruction loss: l1 (official, whole crop), or inside the hole only")
    p.add_argument("--blend-distance", type=positive_float, default=3.0, metavar="PX",
                   help="tau of --hole-loss l2_blend in model pixels: the loss is taken on the blend with the prefill "
                   "whose network share is 1 - exp(-d / PX) at distance d from the visible pixels")
    p.add_argument("--synth-seed", type=nonnegative_int, default=0)
    p.add_argument("--synth-seeds", type=seed_list, help="several worlds: comma list or range A-B (overrides --synth-seed); "
                   "--synth-frames frames of each")
    p.add_argument("--frame-stride", type=positive_int, default=1)
    p.add_argument("--workdir", type=Path, required=True)
    p.add_argument("--export", type=Path, help="write the trained Inpainter .npz here")
    p.add_argument("--export-flip-average", action="store_true",
                   help="inference setting stored in the exported config: average each fill with the mirrored crop's")
    p.add_argument("--export-prefill-blend", type=unit_interval, default=1.0,
                   help="inference setting stored in the exported config: share of the network's fill in the hole, "
                   "the rest the prefill method at full resolution (1: the network's fill only)")
    p.add_argument("--export-prefill-blend-distance", type=nonnegative_float, default=0.0, metavar="PX",
                   help="inference setting stored in the exported config: if > 0, the network's share at distance d "
                   "(px) from the visible pixels is --export-prefill-blend * (1 - exp(-d / PX)) (0: constant share)")
    p.add_argument("--export-prefill-blend-unit", choices=("frame", "model"), default="frame",
                   help="what --export-prefill-blend-distance is measured in: frame pixels, or model pixels "
                   "(frame pixels / the crop's resize factor)")
    p.add_argument("--width", type=positive_int, default=16)
    p.add_argument("--inpaint-width", type=nonnegative_int, default=0,
                   help="the image generator's own width (0: --width); with --init, a wider one than the "
                   "checkpoint's (up to twice) starts as its function-preserving widening (Net2Net)")
    p.add_argument("--blocks", type=positive_int, default=8)
    p.add_argument("--size", type=positive_int, default=64, help="training crop size, multiple of 4")
    p.add_argument("--batch", type=positive_int, default=8)
    add_parallel_arguments(p)
    p.add_argument("--steps", default="2000,2000,1000", help="edge,inpaint,joint steps")
    p.add_argument("--stages", help="explicit schedule, e.g. edge:1500,edge_inpaint:5000 (overrides --steps; "
                   "edge_inpaint = official MODEL 3: G2 trained on the frozen edge model's output)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="model and data seed")
    p.add_argument("--checkpoint-every", type=positive_int, default=500)
    p.add_argument("--sample-every", type=nonnegative_int, default=500, help="0: never")
    p.add_argument("--max-steps", type=nonnegative_int, default=None)
    p.add_argument("--lr", type=positive_float, default=1e-4, help="generator Adam lr (official 1e-4)")
    p.add_argument("--inpaint-lr", type=positive_float, default=None, help="G2's own lr (default: --lr)")
    p.add_argument("--inpaint-beta1", type=open_unit_interval, default=None, help="G2's own Adam beta1 (default 0)")
    p.add_argument("--inpaint-lr-final", type=nonnegative_float, default=None,
                   help="cosine-decay G2's lr to this over its updates (default: constant)")
    p.add_argument("--inpaint-adv-weight", type=nonnegative_float, default=0.1,
                   help="adversarial weight of G2 (official 0.1; 0 = L1 only, D2 skipped)")
    a = p.parse_args(argv)
    if a.real and a.shapes is None:
        p.error("--real needs --shapes")
    if not a.real and all(x is None for x in (a.synth_frames, a.sequence, a.folder, a.bank)):
        p.error("give a data source: --synth-frames, --sequence, --folder, --bank and/or --real")
    if a.size % 4:
        p.error(f"argument --size: must be a multiple of 4, got {a.size}")
    primary = start_parallel(p, a, a.batch)
    shape_slice = slice(None)
    if a.shape_files is not None:
        lo, colon, hi = a.shape_files.partition(":")
        try:
            shape_slice = slice(int(lo) if lo else None, int(hi) if hi else None)
        except ValueError:
            colon = ""
        if not colon:
            p.error(f"argument --shape-files: must be a slice A:B of the sorted mask files, got {a.shape_files!r}")

    from tqdm import tqdm

    from privslam_jax.inpaint.data import CropBank, FolderData, Mixture, RealHoleData, image_paths, object_shapes
    from privslam_jax.inpaint.filter import PREFILLS, Inpainter, InpainterConfig
    from privslam_jax.inpaint.train import STAGES, TrainConfig, check_init, train

    if a.prefill not in PREFILLS:
        p.error(f"argument --prefill: invalid choice: {a.prefill!r} (choose from {', '.join(PREFILLS)})")
    if a.stages:
        try:
            stages = tuple((n, nonnegative_int(k)) for n, k in (x.split(":") for x in a.stages.split(",")))
        except (ValueError, argparse.ArgumentTypeError):
            p.error("argument --stages: needs name:steps pairs with steps >= 0, e.g. edge:1500,edge_inpaint:5000")
        for name, _ in stages:
            if name not in STAGES:
                p.error(f"argument --stages: unknown stage {name!r} (choose from {', '.join(STAGES)})")
    else:
        try:
            steps = [nonnegative_int(s) for s in a.steps.split(",")]
        except argparse.ArgumentTypeError:
            steps = []
        if len(steps) != 3:
            p.error(f"argument --steps: needs three comma-separated numbers >= 0 (edge,inpaint,joint), got {a.steps!r}")
        stages = tuple(zip(("edge", "inpaint", "joint"), steps, strict=True))
    cfg = TrainConfig(width=a.width, inpaint_width=a.inpaint_width, num_residual_blocks=a.blocks, size=a.size, batch_size=a.batch,
                      stages=stages, seed=a.seed,
                      lr=a.lr, inpaint_lr=a.inpaint_lr, inpaint_beta1=a.inpaint_beta1,
                      inpaint_lr_final=a.inpaint_lr_final,
                      inpaint_adv_weight=a.inpaint_adv_weight,
                      prefill=a.prefill, residual=a.residual, hole_loss=a.hole_loss, blend_distance=a.blend_distance, checkpoint_every=a.checkpoint_every, sample_every=a.sample_every,
                      devices=a.devices)
    inference = dict(flip_average=a.export_flip_average, prefill_blend=a.export_prefill_blend,
                     prefill_blend_distance=a.export_prefill_blend_distance, prefill_blend_unit=a.export_prefill_blend_unit)
    try:  # the exported inference settings, checked before any work
        InpainterConfig(prefill=a.prefill, **inference)
    except ValueError as err:
        p.error(f"argument --export-prefill-blend / --export-prefill-blend-distance: {err}")
    init = None
    if a.init is not None:  # before any work: a checkpoint that cannot start this training is refused
        try:
            init = Inpainter.load(a.init)
            check_init(init.config, cfg)
        except (OSError, ValueError) as err:
            p.error(f"argument --init: {err}")
    a.workdir.mkdir(parents=True, exist_ok=True)
    bank_path = a.workdir / "crop_bank.npz"
    data = None
    if a.folder is not None:
        data = FolderData(a.folder, a.size, seed=a.seed)
    elif a.bank is not None:
        data = CropBank.load(a.bank, seed=a.seed)
    elif bank_path.is_file():  # resume: reuse the crops extracted by the first run
        data = CropBank.load(bank_path, seed=a.seed)
    elif primary and (a.sequence is not None or a.synth_frames is not None):
        if a.sequence is not None:
            data = CropBank.from_kitti_layout(a.sequence, a.size, seed=a.seed, frame_stride=a.frame_stride)
        else:
            from privslam_jax.data.synthetic import SynthConfig, parse_seeds

            seeds = parse_seeds(a.synth_seeds) if a.synth_seeds else [a.synth_seed]
            data = CropBank.concat([
                CropBank.from_synthetic(SynthConfig(num_frames=a.synth_frames, seed=s), a.size, seed=a.seed,
                                        frame_stride=a.frame_stride, progress=len(seeds) == 1)
                for s in tqdm(seeds, desc="worlds", disable=len(seeds) == 1)], seed=a.seed)
        data.save(bank_path)
        print(f"{len(data)} object crops saved to {bank_path}")
    if a.distributed:  # one crop bank, extracted by process 0; the others load it
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("crop bank written")
        if data is None and bank_path.is_file():
            data = CropBank.load(bank_path, seed=a.seed)
    if a.real:
        masks = image_paths(a.shapes)[shape_slice]
        real = RealHoleData(image_paths(*a.real), object_shapes(masks), a.size, seed=a.seed)
        print(f"real frames: {len(real.paths)}, object shapes: {len(real.shapes)} from {len(masks)} mask files")
        data = real if data is None else Mixture([real, data], [a.real_weight, 1 - a.real_weight], seed=a.seed)
    trainer = train(cfg, data, a.workdir, max_steps=a.max_steps, init=init, progress=primary)
    if a.export is not None and primary:
        model = trainer.inpainter()
        Inpainter(*model.modules, dataclasses.replace(model.config, **inference)).save(a.export)
        print(f"inpainter written to {a.export}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
