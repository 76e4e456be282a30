"""Real training frames for the detector: hand-drawn keyframe boxes carried to neighbouring frames.

Command::

    python train/real_labels.py --synthetic DIR/SPLIT --out DIR [--window 3] [--repeat 3] [--paste-copies 0]
        [--paste-synthetic-seeds 5001-5080 --paste-synthetic-frames 8 --paste-match-light 1]

``train/data/real_boxes.json`` holds boxes the developers drew by eye on keyframes of the real
frames that ``../shared`` allows training on (``data/real/kitti_raw_a`` and the KITTI odometry
``seq1`` and ``00``; never the evaluation sets ``kitti_object``, ``kitti_raw_b``,
``nuscenes_front``), with no detector involved; the shipped real-frame detector was trained on it.
``--boxes train/data/real_boxes_v2.json`` has the same keyframes with the parked cars that version 1
left out. Each keyframe's boxes are carried to the
``--window`` frames before and after it by dense optical flow
(:func:`privslam_jax.detect.temporal.box_flow`, frame by frame), and those frames are written as
the YOLO split ``OUT/{images,labels}/real``. With ``--paste-copies N``, the split
``OUT/{images,labels}/real_paste`` holds ``N`` copies of each real frame into which 1 to
``--paste-max`` objects cut from the keyframes are pasted on the ground plane
(:mod:`privslam_jax.detect.copy_paste`; mattes from ``kitti_raw_a``'s Mask R-CNN masks, or soft
ellipses with ``--paste-real-matte ellipse``, which a licence-clean detector needs: the masks are a
third-party model's output; people and riders are drawn ``--paste-person-weight``
times as often as other objects, cars are not pasted: they are plenty). ``--paste-synthetic-seeds``
adds to that bank the people, bicycles and motorcycles of synthetic worlds rendered at the real
frames' size (1242 × 375, KITTI's camera height and focal length, object density 2; frames 0, 12,
… of each seed), cut by their instance masks and photometrically randomised
(:func:`privslam_jax.detect.copy_paste.synthetic_instances`). ``OUT/{images,labels}/mix``
then links every frame of the synthetic split, ``--repeat`` copies of each real frame and the
pasted copies. Train with ``train/detector.py --data OUT --split mix``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv: list[str] | None = None) -> int:
    import cv2

    from privslam_jax._shared import shared_dir
    from privslam_jax.argtypes import nonnegative_int, positive_int
    from privslam_jax.data.images import read_rgb8, write_image_file
    from privslam_jax.data.yolo import cxcywhn_to_xyxy, link_mixed_split, read_yolo_labels, write_yolo_labels
    from privslam_jax.data.synthetic import SynthConfig, make_sequence, parse_seeds
    from privslam_jax.detect.copy_paste import PasteConfig, cut_instance, object_groups, paste_instances, synthetic_instances
    from privslam_jax.detect.domain_rand import DomainRandConfig
    from privslam_jax.detect.temporal import box_flow, dense_flow, flow_grey

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--synthetic", type=Path, required=True, help="synthetic YOLO split to mix in: ROOT/SPLIT")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--window", type=nonnegative_int, default=3, help="frames before and after each keyframe that get its boxes")
    p.add_argument("--repeat", type=positive_int, default=3, help="links per real frame in the mix split")
    p.add_argument("--boxes", type=Path, default=ROOT / "train" / "data" / "real_boxes.json")
    p.add_argument("--paste-copies", type=nonnegative_int, default=0, help="copy-paste copies per real frame")
    p.add_argument("--paste-max", type=positive_int, default=3, help="objects pasted into one copy, at most")
    p.add_argument("--paste-person-weight", type=float, default=4.0, help="sampling weight of people and riders")
    p.add_argument("--paste-real-matte", choices=("maskrcnn", "ellipse"), default="maskrcnn",
                   help="matte of the real cut objects: kitti_raw_a's Mask R-CNN masks where they exist (a third-party "
                        "model's output) or always the soft ellipse (licence-clean)")
    p.add_argument("--paste-synthetic-seeds", default="", help="synthetic worlds whose objects join the paste bank, e.g. 5001-5080")
    p.add_argument("--paste-synthetic-frames", type=positive_int, default=8, help="frames cut per synthetic world")
    p.add_argument("--paste-match-light", type=float, default=0.0, help="brightness match of pasted patches, 0..1")
    p.add_argument("--paste-retexture", type=float, default=0.0,
                   help="probability that a synthetic object takes a real frame's texture under its shading")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    a = p.parse_args(argv)
    for name in ("paste_match_light", "paste_retexture"):
        if not 0.0 <= getattr(a, name) <= 1.0:
            p.error(f"--{name.replace('_', '-')} must be in [0, 1], got {getattr(a, name)}")
    try:
        synth_seeds = parse_seeds(a.paste_synthetic_seeds) if a.paste_synthetic_seeds else []
    except ValueError as err:
        p.error(f"--paste-synthetic-seeds: {err}")
    if a.paste_synthetic_seeds and not synth_seeds:
        p.error(f"--paste-synthetic-seeds {a.paste_synthetic_seeds!r} names no seed (a range A-B needs A <= B)")
    if synth_seeds and not a.paste_copies:
        p.error("--paste-synthetic-seeds needs --paste-copies N > 0 (the objects are pasted into those copies)")
    if a.paste_retexture > 0 and not synth_seeds:
        p.error("--paste-retexture applies to synthetic objects: give --paste-synthetic-seeds too")
    shared = shared_dir()
    if shared is None:
        raise SystemExit("needs ../shared (the real training frames); set PRIVSLAM_SHARED")
    try:
        boxes = json.loads(a.boxes.read_text())["boxes"]
        if not all(isinstance(b, list) and all(len(x) == 5 for x in b) for b in boxes.values()):
            raise ValueError("every entry must be a list of [x1, y1, x2, y2, class]")
    except (ValueError, KeyError, AttributeError) as err:
        raise SystemExit(f"{a.boxes}: not a keyframe box file ({err})") from None
    img_dir, lab_dir = a.out / "images" / "real", a.out / "labels" / "real"
    written: dict[str, int] = {}  # frame name -> distance to the keyframe that labelled it

    def write(path: Path, img: np.ndarray, b: np.ndarray, cls: np.ndarray, dist: int) -> None:
        name = f"{path.parent.parent.name}_{path.parent.name}_{path.stem}"
        if written.get(name, a.window + 1) <= dist:
            return  # a nearer keyframe labelled this frame
        h, w = img.shape[:2]
        c = np.clip(b, 0, [w, h, w, h])
        keep = ((c[:, 2] - c[:, 0]) >= 4) & ((c[:, 3] - c[:, 1]) >= 4)
        write_image_file(img_dir / f"{name}.png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        write_yolo_labels(lab_dir / f"{name}.txt", cls[keep], c[keep], w, h)
        written[name] = dist

    for rel, kb in boxes.items():
        key = shared / rel
        b0 = np.asarray(kb, np.float64).reshape(-1, 5)
        cls = b0[:, 4].astype(np.int32)
        first = read_rgb8(key)
        write(key, first, b0[:, :4], cls, 0)
        for step in (1, -1):
            cur, prev = b0[:, :4], first
            for dist in range(1, a.window + 1):
                path = key.parent / f"{int(key.stem) + step * dist:0{len(key.stem)}d}.png"
                if not path.is_file():
                    break
                img = read_rgb8(path)
                flow = dense_flow(flow_grey(prev, 0.5), flow_grey(img, 0.5))
                cur = np.array([box_flow(b, flow, 0.5) for b in cur]).reshape(-1, 4)
                write(path, img, cur, cls, dist)
                prev = img
    print(f"wrote {len(written)} real frames ({len(boxes)} keyframes, window {a.window}) to {img_dir}")

    sources = [(a.synthetic, 1), (a.out / "real", a.repeat)]
    if a.paste_copies:
        bank, weight = [], []
        for rel, kb in boxes.items():
            key = shared / rel
            b0 = np.asarray(kb, np.float64).reshape(-1, 5)
            mask_file = key.parent.parent / "maskrcnn_masks" / key.name
            use = a.paste_real_matte == "maskrcnn" and mask_file.is_file()
            matte = cv2.imread(str(mask_file), cv2.IMREAD_GRAYSCALE) if use else None
            img = read_rgb8(key)
            for g in object_groups(b0[:, :4], b0[:, 4].astype(np.int32), skip=(2,)):
                inst = cut_instance(img, b0[g, :4], b0[g, 4].astype(np.int32), matte)
                if inst is not None:
                    bank.append(inst)
                    weight.append(a.paste_person_weight if 0 in inst.class_ids else 1.0)
        rng = np.random.default_rng(a.seed)
        n_real = len(bank)
        look = DomainRandConfig(grey=0.0, vignette=0.0)
        textures = [read_rgb8(f) for f in sorted(img_dir.glob("*.png"))] if a.paste_retexture > 0 else None
        for seed in synth_seeds:
            seq = make_sequence(SynthConfig(seed=seed, width=1242, height=375, num_frames=12 * a.paste_synthetic_frames,
                                            object_density=2.0))
            for i in range(0, len(seq), 12):
                for inst in synthetic_instances(seq[i], rng, photometric=look, textures=textures,
                                                retexture=a.paste_retexture):
                    bank.append(inst)
                    weight.append(a.paste_person_weight if 0 in inst.class_ids else 1.0)
        if not bank:
            p.error("the paste bank is empty: no keyframe object or synthetic object could be cut")
        prob = np.asarray(weight) / np.sum(weight)
        paste_cfg = PasteConfig(match_light=a.paste_match_light)
        pimg, plab = a.out / "images" / "real_paste", a.out / "labels" / "real_paste"
        for f in sorted(img_dir.glob("*.png")):
            img = read_rgb8(f)
            h, w = img.shape[:2]
            cls, cxcywh = read_yolo_labels(lab_dir / f"{f.stem}.txt", missing_ok=True)
            xyxy = cxcywhn_to_xyxy(cxcywh, w, h)
            for k in range(a.paste_copies):
                picks = [bank[i] for i in rng.choice(len(bank), int(rng.integers(1, a.paste_max + 1)), p=prob)]
                out, pb, pc = paste_instances(img, xyxy, cls, picks, rng, paste_cfg)
                write_image_file(pimg / f"p{k}_{f.name}", cv2.cvtColor(out, cv2.COLOR_RGB2BGR))
                write_yolo_labels(plab / f"p{k}_{f.stem}.txt", pc, np.clip(pb, 0, [w, h, w, h]), w, h)
        print(f"wrote {a.paste_copies} pasted copies of each real frame from {len(bank)} cut objects "
              f"({n_real} real, {len(bank) - n_real} synthetic; {sum(0 in i.class_ids for i in bank)} with a person) "
              f"to {pimg}")
        sources.append((a.out / "real_paste", 1))
    n_mix = link_mixed_split(a.out, "mix", sources)
    print(f"wrote {a.out}/images/mix ({n_mix} images)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
