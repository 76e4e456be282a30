"""Filter a whole sequence: detect (or read) the privacy objects of every frame, hide and fill them.

:func:`filter_sequence` is the library side of ``privslam filter`` (its command-line help, in
:mod:`privslam_jax.commands.filter`, describes the folders it reads and writes); it writes frame by
frame, never holding the sequence in memory.  :func:`filter_sequence_in_memory` returns the same
frames, masks and report as :class:`FilteredFrames` (the pipeline's filter stage; the folder is an
optional sink), and :func:`filter_frames` / :func:`iter_filtered` filter frames already in memory
with any per-frame mask source.
:func:`check_detector_domain` refuses a synthetic-only detector on real frames and warns about one
whose measured real-frame recall is low.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from privslam_jax.data.files import write_atomic
from privslam_jax.data.images import write_image_file
from privslam_jax.runs import check_run_folder, claim_run_folder, complete_run_folder

__all__ = ["RECALL_WARNING_BELOW", "REAL_FRAME_PROPAGATION", "FilteredFrame", "FilteredFrames", "check_detector_domain", "filter_frames",
           "filter_sequence", "filter_sequence_in_memory", "iter_filtered", "write_filtered"]


def _label_map(masks: np.ndarray, ids: list[int], shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, np.uint16)
    for m, i in zip(masks, ids, strict=True):
        out[m & (out == 0)] = i
    return out


class _FrameFolder:
    """A plain folder of frames (any image format, name order = time order) seen as a sequence."""

    def __init__(self, path: Path):
        from privslam_jax.data.images import read_raw
        from privslam_jax.data.yolo import IMAGE_SUFFIXES

        if not path.is_dir():
            raise FileNotFoundError(f"sequence folder not found: {path}")
        self.path, self.name, self.poses_path, self.instance_classes = path, path.name, None, {}
        self.image_paths = sorted(q for q in path.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)
        if not self.image_paths:
            raise ValueError(f"{path} holds no image_2/ or image_0/ folder (KITTI layout) and no image files")
        first = read_raw(self.image_paths[0])
        self.grey = first.ndim == 2 or first.shape[-1] == 1
        self.camera = SimpleNamespace(height=first.shape[0], width=first.shape[1])

    def __len__(self) -> int:
        return len(self.image_paths)

    def has_extra(self, name: str) -> bool:
        return False


def _consecutive_runs(stems: list[str]) -> list[tuple[int, int]]:
    """Runs of evenly numbered frames (:func:`~privslam_jax.detect.temporal.consecutive_runs`; one
    run if the names are not numbers)."""
    from privslam_jax.detect.temporal import consecutive_runs

    return consecutive_runs([int(t) for t in stems]) if all(t.isdigit() for t in stems) else [(0, len(stems))]


RECALL_WARNING_BELOW = 0.9
"""A detector whose measured real-frame recall is below this gets a PRIVACY WARNING on real frames."""

REAL_FRAME_PROPAGATION = 3
"""Default ``propagate`` on frames that are not a ``privslam synth`` output: each detection carried
to the 3 frames before and after it (recall first; its effect on held-out real frames in
``results/table1b_real_recall.md``, ``kitti_raw_b``). On ``privslam synth`` output the default stays
0, the source paper's per-frame detection."""


def check_detector_domain(detector, sequence_is_synthetic: bool, allow_mismatch: bool, propagate: int = 0) -> str | None:
    """Refuse, or warn about, a detector that will miss objects in these frames.

    On frames that are not a ``privslam synth`` output: a detector trained on the synthetic world
    only is refused (``ValueError``) unless ``allow_mismatch``, then warned about; any detector
    whose checkpoint states a real-frame recall below :data:`RECALL_WARNING_BELOW` is warned about
    with that number, and with the recall knobs not yet in use (``propagate``: the window the
    filter runs with). Returns the warning text (``None`` without one). A privacy filter that
    quietly finds nothing on frames it does not understand leaks every object in them.
    """
    import warnings

    from privslam_jax.errors import PrivacyWarning

    if sequence_is_synthetic:
        return None
    recall = detector.meta.get("card", {}).get("real_recall")
    measured = (f"measured recall on real KITTI frames: {recall['recall']:.2f} at conf {recall.get('conf', 0.4)} with "
                f"{recall['fp_per_image']:.2f} false positives per image ({recall.get('command', '')})"
                if isinstance(recall, dict) else "its recall on real frames has not been measured")
    name = detector.meta.get("path", "embedded")
    if detector.domain == "synthetic":
        text = (f"the detector {name} was trained on the synthetic world only ({measured}); on these frames, which "
                "are not a `privslam synth` output, it leaves most people and vehicles visible")
        if not allow_mismatch:
            raise ValueError(text + ". Give --detector a detector trained on real images (e.g. an ultralytics .pt you "
                             "own, see docs/detector.md), or pass --allow-domain-mismatch to run anyway.")
    elif isinstance(recall, dict) and recall["recall"] < RECALL_WARNING_BELOW:
        text = (f"the detector {name} misses people and vehicles in real frames ({measured}; on grey frames, on other "
                "drives and on frames of other cameras it misses more, results/table1b_real_recall.md); raise recall with "
                + ("--tta and --conf 0.1" if propagate else "--tta, --conf 0.1 and --propagate 3")
                + ", or use a stronger detector (docs/detector.md)")
    else:
        return None
    warnings.warn("PRIVACY WARNING: " + text, PrivacyWarning, stacklevel=2)
    return text


@dataclasses.dataclass(frozen=True)
class FilteredFrame:
    """One frame out of :func:`iter_filtered`: the filtered images as ``privslam filter`` writes them."""

    index: int
    left: np.ndarray
    """``(H, W, 3)`` uint8 RGB, or ``(H, W)`` uint8 for a grey sequence."""
    right: np.ndarray | None
    """The right image, filtered with its own masks (``None``: not filtered)."""
    label_map: np.ndarray
    """``(H, W)`` uint16: the id of the left image's mask covering each pixel (0: not hidden)."""


@dataclasses.dataclass(frozen=True)
class FilteredFrames:
    """A filtered sequence in memory (:func:`filter_frames`); :func:`write_filtered` is its file sink."""

    left: np.ndarray
    """``(N, H, W, 3)`` uint8 RGB, or ``(N, H, W)`` uint8 grey: the frames ``image_2/`` (``image_0/``) gets."""
    right: np.ndarray | None
    """The right frames, filtered with their own masks (``None``: not filtered)."""
    label_maps: np.ndarray
    """``(N, H, W)`` uint16 mask ids of the left frames (``masks/``; 0: not hidden)."""
    instance_classes: dict[int, int]
    """Class id of every mask id (``instance_classes.json``; -1: unknown)."""

    def __len__(self) -> int:
        return len(self.left)

    def grey(self, i: int, right: bool = False) -> np.ndarray:
        """Frame ``i`` as ``privslam slam`` reads its file (``KittiSequence(grey=True)``): float32 ``(H, W)``."""
        from privslam_jax.data.images import grey_as_read

        frames = self.right if right else self.left
        if frames is None:
            raise ValueError("the right frames were not filtered (they need detected masks or the right camera's "
                             "ground-truth masks, masks_3/)")
        return grey_as_read(frames[i])


def _to_u8(image: np.ndarray, grey: bool) -> np.ndarray:
    u8 = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    return u8[..., 0] if grey else u8


def iter_filtered(
    left: Sequence[Any] | np.ndarray,
    method: str,
    masks_of: Callable[[int, int], tuple[np.ndarray, list[int]]],
    *,
    right: Sequence[Any] | np.ndarray | None = None,
    inpainter: Any = None,
    seed: int = 0,
    grey: bool = False,
    shape: tuple[int, int] | None = None,
    progress: bool = False,
) -> Iterator[FilteredFrame]:
    """Filter ``left[i]`` (and ``right[i]``) frame by frame, yielding each as 8-bit images.

    ``left``/``right``: images as :func:`~privslam_jax.data.images.read_image` returns them (or
    uint8), read lazily by index. ``masks_of(i, k)``: the ``(K, H, W)`` bool masks and their ids of
    frame ``i`` of the left (``k = 0``) or right (``k = 1``) images.  Frame ``i`` is filled with
    seed ``seed + i``; ``grey``: the output keeps one channel.  ``shape``: the ``(H, W)`` every
    frame must have (refused otherwise).
    """
    from privslam_jax.data.images import as_unit_image
    from privslam_jax.inpaint.filter import filter_frame

    sides = [left] if right is None else [left, right]
    for i in tqdm(range(len(left)), desc=f"filter {method}", disable=not progress):
        out: list[np.ndarray] = []
        label_map = None
        for k, frames in enumerate(sides):
            where = frames.paths[i] if isinstance(frames, _Images) else f"frame {i}"
            image = as_unit_image(frames[i], str(where))
            if shape is not None and image.shape[:2] != shape:
                raise ValueError(f"{where} is {image.shape[1]}x{image.shape[0]}, the sequence's frames are "
                                 f"{shape[1]}x{shape[0]}")
            masks, ids = masks_of(i, k)
            out.append(_to_u8(filter_frame(image, masks, method, inpainter=inpainter, seed=seed + i), grey))
            if k == 0:
                label_map = _label_map(masks, ids, image.shape[:2])
        assert label_map is not None
        yield FilteredFrame(index=i, left=out[0], right=out[1] if len(out) > 1 else None, label_map=label_map)


def filter_frames(left: Sequence[Any] | np.ndarray, method: str, masks_of: Callable[[int, int], tuple[np.ndarray, list[int]]],
                  instance_classes: dict[int, int], **kwargs: Any) -> FilteredFrames:
    """:func:`iter_filtered` gathered in memory (same arguments; ``instance_classes``: class of every mask id)."""
    return _gather(list(iter_filtered(left, method, masks_of, **kwargs)), instance_classes)


def _gather(frames: list[FilteredFrame], instance_classes: dict[int, int]) -> FilteredFrames:
    right = [f.right for f in frames]
    return FilteredFrames(
        left=np.stack([f.left for f in frames]),
        right=None if right[0] is None else np.stack(right),  # type: ignore[arg-type]
        label_maps=np.stack([f.label_map for f in frames]),
        instance_classes=dict(sorted(instance_classes.items())),
    )


@dataclasses.dataclass(frozen=True)
class _Plan:
    """What :func:`plan_filter` decided for a sequence: the inputs, masks and report of a filter run."""

    seq: Any
    left_paths: list[Path]
    right_paths: list[Path] | None
    grey: bool
    masks_of: Callable[[int, int], tuple[np.ndarray, list[int]]]
    instance_classes: dict[int, int]
    inpainter: Any
    report: dict


class _Images(Sequence):
    """Images read by index from files (:func:`read_image`), so a long sequence is never all in memory."""

    def __init__(self, paths: list[Path]):
        self.paths = paths

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, i):  # type: ignore[override]  # an int index only
        from privslam_jax.data.images import read_image

        return read_image(self.paths[i])


def _plan_filter(sequence: Path, method: str, masks_source: str | None, detector_path: Path | None,
                 model_path: Path | None, dilation: int, conf: float | None, propagate: int | None, tta: bool,
                 allow_domain_mismatch: bool) -> _Plan:
    """Open ``sequence``, pick the detector and inpainter, run the detector over every frame (refusing bad
    frames before anything is written) and return the per-frame mask source and the report."""
    from privslam_jax.data.images import read_image
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.inpaint.filter import FILTER_METHODS, INPAINTER_METHODS, Inpainter
    from privslam_jax.inpaint.masks import boxes_to_masks, instance_masks

    if method not in FILTER_METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(FILTER_METHODS)}")
    sequence = Path(sequence)
    kitti = any((sequence / d).is_dir() for d in ("image_2", "image_0"))
    seq = KittiSequence(sequence) if kitti else _FrameFolder(sequence)
    if masks_source is None:
        masks_source = "gt" if seq.has_extra("masks") else "detect"
    if masks_source == "gt" and not seq.has_extra("masks"):
        raise FileNotFoundError(f"--masks gt needs {seq.path / 'masks'} (written by `privslam synth`)")
    if len(seq) == 0:
        raise ValueError(f"{sequence} has no frames")
    report: dict = {"method": method, "masks": masks_source, "frames": len(seq)}
    synthetic = seq.has_extra("background")  # privslam synth writes background/ (the object-free render)
    detector = None
    if masks_source == "detect":
        from privslam_jax.detect import PRIVACY_PRESET, Detector
        from privslam_jax.detect.temporal import PropagationConfig

        preset = PRIVACY_PRESET if conf is None else dataclasses.replace(PRIVACY_PRESET, conf=conf)
        if detector_path is not None:
            detector = Detector.from_weights(detector_path, preset)
        else:  # the embedded detector made for these frames
            detector = Detector.embedded(preset, domain="synthetic" if synthetic else "real")
        if propagate is None:
            propagate = 0 if synthetic else REAL_FRAME_PROPAGATION
        mismatch = check_detector_domain(detector, synthetic, allow_domain_mismatch, propagate)
        propagation = (PropagationConfig(window=propagate, high_conf=preset.conf, low_conf=min(0.1, preset.conf))
                       if propagate else None)
        report["detector"] = {"weights": detector.meta.get("path", "embedded"), "domain": detector.domain,
                              "card": detector.meta.get("card", {}), "conf": preset.conf, "propagate": propagate,
                              "tta": tta, "privacy_warning": mismatch}
    inpainter = None
    if method in INPAINTER_METHODS:
        # the embedded inpainter made for these frames; the trade-off point is trained on the synthetic world only
        domain = "tradeoff" if method == "tradeoff" else "synthetic" if synthetic else "real"
        inpainter = Inpainter.embedded(domain) if model_path is None else Inpainter.load(model_path)
        report["inpainter"] = {"weights": str(model_path) if model_path is not None else f"embedded ({domain})",
                               "config": dataclasses.asdict(inpainter.config)}

    stems = [p.stem for p in seq.image_paths]
    right_paths = None
    if kitti:
        grey = seq.left_dir.name in ("image_0", "image_1")
        left_paths = [seq.left_dir / f"{t}.png" for t in stems]
        right_dir = seq.path / {"image_2": "image_3", "image_0": "image_1"}[seq.left_dir.name]
        # right frames: with their own detections, or with the right camera's ground-truth masks
        if right_dir.is_dir() and (masks_source == "detect" or (seq.path / "masks_3").is_dir()):
            right_paths = [right_dir / f"{t}.png" for t in stems]
    else:
        grey, left_paths = seq.grey, list(seq.image_paths)
    h, w = seq.camera.height, seq.camera.width
    classes: dict[int, int] = {}

    if detector is None:
        def masks_of(i: int, k: int) -> tuple[np.ndarray, list[int]]:
            inst = seq.instance_ids(i, right=k == 1)
            ids = sorted(int(x) for x in np.unique(inst[inst > 0]))
            return instance_masks(inst, np.asarray(ids, np.int64), dilation), ids

        for i in range(len(seq)):  # the class of every instance id that occurs (in the left masks/ written)
            ids_i = seq.instance_ids(i)
            for j in np.unique(ids_i[ids_i > 0]).tolist():
                classes[int(j)] = int(seq.instance_classes.get(int(j), -1))
        return _Plan(seq, left_paths, right_paths, grey, masks_of, classes, inpainter, report)

    from privslam_jax.detect.temporal import detect_sequence

    runs = _consecutive_runs(stems)
    report["runs"] = [[stems[a], stems[b - 1]] for a, b in runs]
    detections: list[list[Any]] = []
    origins: list[Any] = []
    for k, paths in enumerate([left_paths] + ([right_paths] if right_paths is not None else [])):
        dets_k: list[Any] = []
        for a, b in runs:  # propagation never crosses a gap in the frame numbers
            images = [read_image(path) for path in paths[a:b]]
            for path, im in zip(paths[a:b], images):  # refuse before anything is written
                if im.shape[:2] != (h, w):
                    raise ValueError(f"{path} is {im.shape[1]}x{im.shape[0]}, the sequence's frames are {w}x{h}")
            d, o = detect_sequence(detector, images, propagation, (1.0, 1.5) if tta else None)
            dets_k += d
            if k == 0:
                origins += o
        detections.append(dets_k)
    counts = np.array([np.bincount(o, minlength=3) for o in origins]).reshape(-1, 3)
    report["masks_per_frame"] = {"detected": counts[:, 0].tolist(), "promoted": counts[:, 1].tolist(),
                                 "propagated": counts[:, 2].tolist()}
    report["frames_without_masks"] = int((counts.sum(1) == 0).sum())
    ids_of: dict[tuple[int, int], list[int]] = {}
    next_id = 1  # detections get sequence-unique ids, frame by frame, left before right
    for i in range(len(seq)):
        for k, dets_k in enumerate(detections):
            n = len(np.asarray(dets_k[i].boxes).reshape(-1, 4))
            ids_of[i, k] = list(range(next_id, next_id + n))
            next_id += n
            for j, c in zip(ids_of[i, k], np.asarray(dets_k[i].class_ids).tolist(), strict=True):
                classes[j] = int(c)

    def masks_of(i: int, k: int) -> tuple[np.ndarray, list[int]]:
        boxes = np.asarray(detections[k][i].boxes, np.float64).reshape(-1, 4)
        return boxes_to_masks(boxes, h, w, dilation), ids_of[i, k]

    return _Plan(seq, left_paths, right_paths, grey, masks_of, classes, inpainter, report)


def filter_sequence_in_memory(sequence: Path, method: str, *, out: Path | None = None, **settings: Any
                              ) -> tuple[FilteredFrames, dict, Path | None]:
    """:func:`filter_sequence` with the result in memory: ``(filtered frames, filter report, folder)``.

    ``settings``: the keyword arguments of :func:`filter_sequence` (``masks_source``, ``detector_path``,
    ``model_path``, ``dilation``, ``seed``, ``progress``, ``conf``, ``propagate``, ``tta``,
    ``allow_domain_mismatch``, ``overwrite``).  The same frames, masks and report as the files
    :func:`filter_sequence` writes (the input is read from ``sequence``).  ``out``: also write them
    there in the same pass (the written folder is returned; ``None``: nothing is written).
    """
    frames, report, folder = _run_filter(Path(sequence), None if out is None else Path(out), method, keep=True,
                                         **settings)
    assert frames is not None
    return frames, report, folder


def filter_sequence(
    sequence: Path,
    out: Path,
    method: str,
    masks_source: str | None = None,
    detector_path: Path | None = None,
    model_path: Path | None = None,
    dilation: int = 4,
    seed: int = 0,
    progress: bool = True,
    conf: float | None = None,
    propagate: int | None = None,
    tta: bool = False,
    allow_domain_mismatch: bool = False,
    overwrite: bool = False,
) -> Path:
    """Filter every frame of ``sequence`` into ``out``; returns the written sequence folder.

    The sequence folder is a run folder (:mod:`privslam_jax.runs`): its ``manifest.json`` says
    ``"complete": true`` only after every frame and report is written; a folder holding an earlier
    run is refused unless ``overwrite``, which clears it (and its ``poses/NAME.txt``) first.

    With ``masks_source="detect"`` the detector runs over the whole sequence first (threshold
    ``conf``, default the paper's 0.4; ``tta`` and ``propagate`` as in
    :func:`privslam_jax.detect.temporal.detect_sequence`; ``propagate=None``:
    :data:`REAL_FRAME_PROPAGATION` frames on real frames, 0 on ``privslam synth`` output), then each
    frame is filled.
    ``method="edgeconnect"`` without ``model_path`` uses the embedded inpainter made for the frames:
    the synthetic-world one on ``privslam synth`` output, the real-frame one on anything else;
    ``method="tradeoff"`` the embedded trade-off checkpoint (trained on the synthetic world).
    ``filter_report.json`` records the detector (and its training domain), the inpainter, the settings and the
    number of masks per frame by origin (detected, promoted low-score, propagated).
    Frames are filtered and written one at a time (:func:`iter_filtered`), never all held in memory;
    :func:`filter_sequence_in_memory` keeps them.
    """
    _, _, folder = _run_filter(Path(sequence), Path(out), method, masks_source=masks_source, detector_path=detector_path,
                               model_path=model_path, dilation=dilation, seed=seed, progress=progress, conf=conf,
                               propagate=propagate, tta=tta, allow_domain_mismatch=allow_domain_mismatch,
                               overwrite=overwrite, keep=False)
    assert folder is not None
    return folder


def _run_filter(sequence: Path, out: Path | None, method: str, *, masks_source: str | None = None,
                detector_path: Path | None = None, model_path: Path | None = None, dilation: int = 4, seed: int = 0,
                progress: bool = True, conf: float | None = None, propagate: int | None = None, tta: bool = False,
                allow_domain_mismatch: bool = False, overwrite: bool = False, keep: bool = False
                ) -> tuple[FilteredFrames | None, dict, Path | None]:
    kitti = any((sequence / d).is_dir() for d in ("image_2", "image_0"))
    out_dir = manifest = None
    companions: tuple[Path, ...] = ()
    if out is not None:
        out_dir = out / "sequences" / sequence.name if kitti else out / sequence.name
        if sequence.is_dir() and out_dir.resolve() == sequence.resolve():
            raise ValueError("--out must differ from the input sequence's root (it would overwrite the originals)")
        companions = (out / "poses" / f"{sequence.name}.txt",) if kitti else ()
        check_run_folder(out_dir, overwrite, companions)  # refuse now; claim once the frames passed their checks
    plan = _plan_filter(sequence, method, masks_source, detector_path, model_path, dilation, conf, propagate, tta,
                        allow_domain_mismatch)
    seq = plan.seq
    frames: Iterable[FilteredFrame] = iter_filtered(
        _Images(plan.left_paths), method, plan.masks_of,
        right=None if plan.right_paths is None else _Images(plan.right_paths), inpainter=plan.inpainter, seed=seed,
        grey=plan.grey, shape=(seq.camera.height, seq.camera.width), progress=progress,
    )
    if keep:
        frames = list(frames)
    if out_dir is not None:
        manifest = claim_run_folder(out_dir, "filter", {
            "sequence": str(sequence), "method": method, "masks": plan.report["masks"], "detector": detector_path,
            "model": model_path, "dilation": dilation, "seed": seed, "conf": conf,
            "propagate": plan.report.get("detector", {}).get("propagate", propagate), "tta": tta,
            "allow_domain_mismatch": allow_domain_mismatch}, overwrite, companions)
        for name in ("calib.txt", "times.txt"):
            if (seq.path / name).is_file():
                write_atomic(out_dir / name, (seq.path / name).read_bytes())
        if seq.poses_path is not None and companions:
            write_atomic(companions[0], seq.poses_path.read_bytes())
        if kitti:
            left_dir = out_dir / seq.left_dir.name
            right_dir = out_dir / {"image_2": "image_3", "image_0": "image_1"}[seq.left_dir.name]
        else:
            left_dir = right_dir = out_dir
        write_filtered(out_dir, left_dir, right_dir, [p.stem for p in seq.image_paths], frames, plan.instance_classes,
                       plan.report)
        complete_run_folder(out_dir, manifest)  # last: the run finished
    if not keep:
        return None, plan.report, out_dir
    return _gather(list(frames), plan.instance_classes), plan.report, out_dir


def write_filtered(out_dir: Path, left_dir: Path, right_dir: Path, stems: Sequence[str],
                   frames: Iterable[FilteredFrame], instance_classes: dict[int, int], report: dict) -> None:
    """The file sink of a filter run: ``left_dir/STEM.png`` (and ``right_dir``), ``out_dir/masks/STEM.png``,
    ``instance_classes.json`` and ``filter_report.json``, every file written atomically."""
    (out_dir / "masks").mkdir(parents=True, exist_ok=True)
    left_dir.mkdir(parents=True, exist_ok=True)
    for f in frames:
        stem = stems[f.index]
        for image, d in ((f.left, left_dir), (f.right, right_dir)):
            if image is None:
                continue
            d.mkdir(parents=True, exist_ok=True)
            write_image_file(d / f"{stem}.png", image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        write_image_file(out_dir / "masks" / f"{stem}.png", f.label_map)
    write_atomic(out_dir / "instance_classes.json", json.dumps({str(k): v for k, v in sorted(instance_classes.items())}))
    write_atomic(out_dir / "filter_report.json", json.dumps(report, indent=1))
