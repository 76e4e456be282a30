"""Compare privacy-filter methods inside the privacy masks against the object-free render.

``python -m privslam_jax.inpaint.evaluate SEQUENCE [SEQUENCE ...] [--model M.npz] [--methods edgeconnect,telea,...]
[--ablate-edges] [--out R.md]``

Each ``SEQUENCE`` is a sequence written by ``privslam synth`` (``masks/`` + ``background/``). For every
frame with privacy objects, the ground-truth instance masks (dilated by ``--dilation``) are
filtered with each method and PSNR, SSIM and L1 are measured **inside the union mask** against
the ``background`` render (the scene without the objects). The per-frame values are summarised
by mean, median and the inter-quartile range; a Markdown table is printed (and written to
``--out``). ``edgeconnect`` uses ``--model`` or, without it, the embedded checkpoint;
``--ablate-edges`` adds a row with the edge generator switched off (ê = the edges outside the hole
only). The last column is the paired per-frame PSNR difference to ``telea`` (when evaluated).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from privslam_jax.data.files import write_atomic
from privslam_jax.data.images import read_rgb8
from privslam_jax.inpaint.data import ObjectShape, place_shape
from privslam_jax.inpaint.filter import Inpainter, filter_frame
from privslam_jax.inpaint.masks import dilate, instance_masks, safe_canny, to_grey
from privslam_jax.metrics.image import edge_precision_recall, l1, psnr, ssim

__all__ = ["evaluate_cases", "evaluate_frames", "markdown_table", "real_hole_cases", "score_fill"]

METRICS = ("psnr", "ssim", "l1", "edge_p", "edge_r", "edge_f1")


def _edges(image: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    grey = to_grey(image)
    return safe_canny(grey, np.zeros(grey.shape, bool), sigma=sigma)[0]


def score_fill(out: np.ndarray, target: np.ndarray, hidden: np.ndarray) -> dict[str, float]:
    """PSNR, SSIM, L1 and edge precision / recall / F1 of ``out`` against ``target`` inside ``hidden``.

    Edges: Canny σ = 2 (the model's own edge detector) of both images, compared pixel-exactly
    inside the hole as EdgeConnect's ``EdgeAccuracy``; F1 = 2PR / (P + R)."""
    ep, er = (float(v) for v in edge_precision_recall(_edges(out), _edges(target), hidden))
    return {"psnr": float(psnr(out, target, hidden)), "ssim": float(ssim(out, target, hidden)),
            "l1": float(l1(out, target, hidden)), "edge_p": ep, "edge_r": er,
            "edge_f1": 2 * ep * er / (ep + er) if ep + er > 0 else 0.0}


def evaluate_cases(
    cases: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
    methods: Sequence[str],
    *,
    inpainter: Inpainter | None = None,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, dict[str, np.ndarray]]:
    """Per-case :func:`score_fill` metrics for each method.

    ``cases`` yield ``(image, target, masks (K, H, W) bool)``; each method fills ``image`` under
    ``masks`` with :func:`~privslam_jax.inpaint.filter.filter_frame` and is scored against
    ``target`` inside the union of the masks. Cases with empty masks are skipped."""
    res: dict[str, dict[str, list[float]]] = {m: {k: [] for k in METRICS} for m in methods}
    for i, (image, target, masks) in enumerate(tqdm(cases, desc="evaluate", disable=not progress)):
        hidden = masks.any(axis=0)
        if not hidden.any():
            continue
        for m in methods:
            out = filter_frame(image, masks, m, inpainter=inpainter, seed=seed + i)
            for k, v in score_fill(out, target, hidden).items():
                res[m][k].append(v)
    return {m: {k: np.asarray(v) for k, v in d.items()} for m, d in res.items()}


def evaluate_frames(
    frames: Iterable,
    methods: Sequence[str],
    *,
    inpainter: Inpainter | None = None,
    dilation: int = 4,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, dict[str, np.ndarray]]:
    """:func:`evaluate_cases` on synthetic frames: their instance masks (dilated by ``dilation``)
    filled and scored against the object-free render.

    ``frames`` yield objects with ``image``, ``background`` and ``instance_ids``.
    """
    def cases():
        for f in frames:
            if f.background is None or f.instance_ids is None:
                raise ValueError("frames need background and instance_ids (synthetic ground truth)")
            yield f.image, f.background, instance_masks(f.instance_ids, dilation=dilation)

    return evaluate_cases(cases(), methods, inpainter=inpainter, seed=seed, progress=progress)


def real_hole_cases(
    paths: Sequence[Path], shapes: Sequence[ObjectShape], *, objects: int = 3, repeats: int = 1,
    dilation: int = 4, seed: int = 0,
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Real frames with holes whose answer is known: ``objects`` shapes moved onto each frame by
    :func:`~privslam_jax.inpaint.data.place_shape` (dilated by ``dilation``), ``repeats`` times
    with different placements; the target is the frame itself. Deterministic in ``seed``."""
    for r in range(repeats):
        for i, p in enumerate(paths):
            image = read_rgb8(p).astype(np.float32) / np.float32(255)
            rng = np.random.default_rng((seed, r, i))
            h, w = image.shape[:2]
            masks = np.stack([dilate(place_shape(rng, shapes[int(rng.integers(len(shapes)))], h, w), dilation)
                              for _ in range(objects)])
            yield image, image, masks


def markdown_table(results: dict[str, dict[str, np.ndarray]]) -> str:
    """Mean, median and IQR of each metric per method (+ paired mean PSNR difference to telea)."""
    ref = results.get("telea", {}).get("psnr")
    lines = ["| method | frames | PSNR mean (dB) | PSNR median [IQR] | SSIM mean | SSIM median [IQR] | L1 mean "
             "| ΔPSNR vs telea, paired mean [IQR] |",
             "|---|---|---|---|---|---|---|---|"]
    for m, d in results.items():
        p, s = d["psnr"], d["ssim"]
        if len(p) == 0:
            lines.append(f"| {m} | 0 | – | – | – | – | – | – |")
            continue
        q = lambda x: f"{np.median(x):.3f} [{np.percentile(x, 25):.3f}, {np.percentile(x, 75):.3f}]"  # noqa: E731
        dp = "–"
        if ref is not None and len(ref) == len(p):
            dd = p - ref
            dp = f"{dd.mean():+.2f} [{np.percentile(dd, 25):+.2f}, {np.percentile(dd, 75):+.2f}]"
        lines.append(f"| {m} | {len(p)} | {p.mean():.2f} | {q(p)} | {s.mean():.4f} | {q(s)} | {d['l1'].mean():.4f} "
                     f"| {dp} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from privslam_jax.data.kitti import KittiSequence

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, nargs="+")
    p.add_argument("--model", type=Path, help="Inpainter .npz for 'edgeconnect' (default: the embedded one)")
    p.add_argument("--methods", default="edgeconnect,black,gray,gaussian,noise50,telea,ns")
    p.add_argument("--ablate-edges", action="store_true", help="add edgeconnect without its edge generator")
    p.add_argument("--dilation", type=int, default=4)
    p.add_argument("--out", type=Path)
    a = p.parse_args(argv)
    seqs = [KittiSequence(s) for s in a.sequence]
    methods = [m for m in a.methods.split(",") if m]
    inpainter = None
    if "edgeconnect" in methods or a.ablate_edges:
        inpainter = Inpainter.load(a.model) if a.model is not None else Inpainter.embedded()

    def frames():
        return (s[i] for s in seqs for i in range(len(s)))

    res = evaluate_frames(frames(), methods, inpainter=inpainter, dilation=a.dilation)
    if a.ablate_edges:
        abl = evaluate_frames(frames(), ["edgeconnect"], inpainter=inpainter.without_edge_model(),
                              dilation=a.dilation)
        res["edgeconnect, no edge model"] = abl["edgeconnect"]
    table = markdown_table(res)
    print(table)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        names = ", ".join(f"`{s}`" for s in a.sequence)
        write_atomic(a.out, f"Sequences {names}, dilation {a.dilation}, model `{a.model or 'embedded'}`\n\n{table}\n")
    return 0


if __name__ == "__main__":
    from privslam_jax._xla import configure_xla

    configure_xla()
    raise SystemExit(main())
