"""The privacy-preserving edge-assisted SLAM pipeline, composed from the stages (DESIGN §1).

Each stage is a public function that returns a frozen dataclass (or plain arrays), so a notebook
can call the stages one by one and get typed values back; :func:`run_pipeline` chains them and
returns a :class:`PipelineReport`.  Files are a sink: :func:`run_pipeline` writes every stage's
files under its output folder, so each intermediate result can be inspected or fed to the
matching ``privslam`` command, while the in-memory stages (:func:`filter_stage` and
:func:`slam_stage` without ``out``, :func:`privacy_stage`) write nothing.

1. **data** (:func:`data_stage` → :class:`DataStage`) – render the synthetic street world into a
   KITTI-layout sequence (:func:`privslam_jax.data.kitti_write.write_kitti_sequence`) →
   ``OUT/original``, or read the KITTI-layout folder ``config.sequence`` as it is (never written).
2. **privacy filter** (client side; :func:`filter_stage` → :class:`FilterStage`) – detect the
   privacy objects in the left images and remove them
   (:func:`privslam_jax.inpaint.sequence.filter_sequence_in_memory`, a leak-free fill): the filtered
   8-bit frames and their masks in memory (:class:`~privslam_jax.inpaint.sequence.FilteredFrames`),
   written to ``OUT/filtered`` by :func:`run_pipeline` in the same pass.  ``masks="detect"`` uses the embedded detector made for the frames (or ``detector``),
   ``masks="gt"`` the renderer's instance masks. Where ground-truth instance masks exist (synthetic
   frames) the report also says how much of each object the filter missed (:func:`mask_leak`): a
   detector miss is a privacy leak that no fill can repair.
3. **SLAM** (edge-server side; :func:`slam_stage` → :class:`SlamStage`) – monocular (or stereo)
   SLAM on frames in memory (:func:`privslam_jax.slam.system.run_slam`), with its metrics (ATE/RPE
   with ground-truth poses) and the in-memory ``SlamResult``; :func:`run_pipeline` runs it on the
   original frames (read from the sequence folder) and on the filtered frames in memory (the grey
   values ``privslam slam`` would read from their files) and writes ``OUT/slam_original``, ``OUT/slam_filtered``
   (trajectories, maps, ``metrics.json``, plots).  With ``config.edge`` the filtered run goes through
   the edge split instead (:func:`edge_slam_stage`: the device client sends the filtered frames to a
   gRPC server on loopback, as ``privslam client`` and ``privslam serve`` do; the same poses), its
   store in ``OUT/edge_store`` and the line cloud the client received in ``OUT/edge_lines_received.ply``.
4. **map privacy** (:func:`map_to_ground_truth`, :func:`privacy_stage` → :class:`PrivacyStage`) –
   the monocular map is first brought to metres by the Sim(3) alignment of its trajectory to the
   ground truth (SE(3) for stereo; without ground truth it stays in SLAM units); the filtered run's
   map is lifted to a random line cloud (OS-entropy key unless ``lift_seed`` is given) and attacked
   with Line2Point (:func:`privslam_jax.attacks.line2point`); point-recovery metrics next to the
   no-attack baseline (:mod:`privslam_jax.metrics.privacy`).  :func:`run_pipeline` then writes
   (:func:`write_privacy_outputs`) ``OUT/lines.ply`` (what the server would publish),
   ``OUT/recovered.ply`` (the attack) and ``OUT/map_metric.ply`` (the map in metres, for
   evaluation only).

``privslam run`` prints :attr:`PipelineReport.summary`, writes ``report.md`` / ``report.html``
(:func:`privslam_jax.report.write_report`) and ``report.json`` (:meth:`PipelineReport.to_json_dict`);
the folder's ``manifest.json`` says ``"complete": true`` only after all of it
(:mod:`privslam_jax.runs`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jaxtyping import ArrayLike

from privslam_jax.types import Camera, LineCloud

__all__ = [
    "PipelineConfig", "PipelineReport", "DataStage", "FilterStage", "SlamStage", "PrivacyStage",
    "data_stage", "filter_stage", "slam_stage", "edge_slam_stage", "map_to_ground_truth", "privacy_stage", "write_privacy_outputs",
    "run_pipeline", "mask_leak",
]


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Settings of :func:`run_pipeline` (the embedded default is the default instance)."""

    sequence: str | None = None
    """A KITTI-layout sequence folder (``…/sequences/<id>``) to run on; ``None``: render the synthetic default."""
    frames: int = 60
    """Number of synthetic frames (the synthetic default only)."""
    seed: int = 0
    """Synthetic world seed."""
    width: int = 640
    """Image width, px."""
    height: int = 192
    """Image height, px."""
    name: str = "synth"
    """Sequence name in the KITTI layout."""
    filter_method: str = "edgeconnect"
    """Privacy filter (any ``privslam filter --method``)."""
    inpainter: str | None = None
    """EdgeConnect checkpoint for ``filter_method="edgeconnect"`` or ``"tradeoff"`` (``None``: the embedded one)."""
    masks: str = "detect"
    """Where the filter's masks come from: ``"detect"`` (a detector) or ``"gt"`` (the renderer's)."""
    detector: str | None = None
    """Detector weights for ``masks="detect"`` (``None``: the embedded detector made for the frames' domain)."""
    conf: float | None = None
    """Detection threshold (``None``: the privacy preset's 0.4)."""
    tta: bool = False
    """Test-time augmentation of the detector (:func:`privslam_jax.detect.temporal.detect_tta`)."""
    propagate: int | None = None
    """Carry detections to this many frames before and after by optical flow (0: off; ``None``: 3 on real
    frames, 0 on the synthetic world, :data:`privslam_jax.inpaint.sequence.REAL_FRAME_PROPAGATION`)."""
    mode: str = "mono"
    """SLAM input: ``"mono"`` or ``"stereo"`` (the right images are filtered with their own detections, or with
    the right camera's ground-truth masks for ``masks="gt"``)."""
    slam: bool = True
    """Run SLAM on the original and the filtered frames."""
    attack: bool = True
    """Lift the filtered map to lines and attack it (needs ``slam``)."""
    lift_seed: int | None = None
    """Fixed lift seed (experiments only); ``None`` draws the key from OS entropy."""
    edge: bool = False
    """Run the filtered frames' SLAM through the edge split (:func:`edge_slam_stage`): a gRPC server on
    loopback and the device client, as ``privslam serve`` and ``privslam client``."""
    ignore_masked: bool | None = None
    """SLAM on the filtered frames extracts no feature where the filter filled in (``privslam slam
    --ignore-masked``); ``None``: on for stereo, off for mono, the better choice of each in Table 4 and
    docs/slam.md ("Stereo disparities of coarse keypoints")."""

    @property
    def masked_features(self) -> bool:
        """Whether the filtered frames' SLAM ignores the filled-in regions (``ignore_masked`` resolved)."""
        return masked_features_by_default(self.mode) if self.ignore_masked is None else self.ignore_masked


def masked_features_by_default(mode: str) -> bool:
    """Whether SLAM on filtered frames of ``mode`` keeps its features off the filled-in regions unless
    told otherwise: stereo yes, mono and RGB-D no (Table 4; docs/slam.md)."""
    return mode == "stereo"




def _check_config(config: PipelineConfig) -> None:
    if config.masks not in ("detect", "gt"):
        raise ValueError(f"masks must be 'detect' or 'gt', got {config.masks!r}")
    if config.mode not in ("mono", "stereo"):
        raise ValueError(f"mode must be 'mono' or 'stereo', got {config.mode!r} (rgbd is not offered: the depth maps "
                         "show the hidden objects' shapes, and the privacy filter does not remove them)")
    if config.attack and not config.slam:
        raise ValueError("attack needs slam (the attacked map is the SLAM map)")
    if config.edge and not config.slam:
        raise ValueError("edge needs slam (the edge server runs the SLAM)")
    if config.ignore_masked not in (None, True, False):
        raise ValueError(f"ignore_masked must be True, False or None, got {config.ignore_masked!r}")


def _fmt(m: dict[str, Any], key: str) -> str:
    v = m.get(key)
    return "n/a" if v is None else f"{v:.3f}"


# --------------------------------------------------------------------------------------------
# Stage values


@dataclasses.dataclass(frozen=True)
class DataStage:
    """The input sequence (stage 1): where it is, what it holds, its ground truth."""

    sequence: Path
    """The KITTI-layout sequence folder the later stages read."""
    synthetic: bool
    """Rendered by the synthetic world (``background/`` present: ground-truth instance masks)."""
    stats: dict[str, Any]
    """:func:`privslam_jax.data.kitti_write.sequence_stats` of the sequence (JSON-able)."""
    description: str
    """Printable description (several lines), the start of :attr:`PipelineReport.summary`."""
    gt_poses: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    """``(N, 4, 4)`` ground-truth ``T_w_c`` of every frame (``None``: no ground truth); in memory only."""


@dataclasses.dataclass(frozen=True)
class FilterStage:
    """What the privacy filter (stage 2) did; ``report.json``'s ``"filter"`` entry."""

    method: str
    """The filter method (any ``privslam filter --method``)."""
    masks: str
    """``"detect"`` (a detector's masks) or ``"gt"`` (the renderer's)."""
    detector: str
    """``"embedded"`` or the detector weights' path."""
    sequence: Path | None
    """The filtered KITTI-layout sequence folder written (``None``: in memory only)."""
    report: dict[str, Any]
    """The filter's ``filter_report.json`` (detector, inpainter, settings, masks per frame)."""
    leak: dict[str, Any] | None = None
    """:func:`mask_leak` against the ground-truth instance masks (``None``: no ground-truth masks)."""
    frames: Any = dataclasses.field(default=None, repr=False, compare=False)
    """The :class:`~privslam_jax.inpaint.sequence.FilteredFrames` (8-bit frames, mask ids); in memory only."""

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON-able dict of ``report.json``'s ``"filter"`` entry."""
        d: dict[str, Any] = {"method": self.method, "masks": self.masks, "detector": self.detector,
                             "sequence": str(self.sequence), "report": self.report}
        if self.leak is not None:
            d["leak"] = self.leak
        return d

    def summary(self) -> str:
        """Printable lines: what was filtered, what leaked, and the detector's privacy warning if any."""
        source = ("ground-truth masks" if self.masks == "gt" else
                  f"detections of {'the embedded detector' if self.detector == 'embedded' else Path(self.detector).name}")
        if self.report.get("detector", {}).get("propagate"):
            source += f" carried ±{self.report['detector']['propagate']} frames"
        line = f"privacy filter: {self.method} on {source} -> {self.sequence or 'memory'}"
        if self.leak is not None:
            leak = self.leak
            line += (f"; {leak['objects_left_visible']:.1f}% of {leak['objects']} objects left visible "
                     f"({leak['pixels_left_visible']:.1f}% of their pixels)")
        elif "masks_per_frame" in self.report:
            per = self.report["masks_per_frame"]
            line += (f"; {sum(per['detected']) + sum(per['promoted']) + sum(per['propagated'])} masks, "
                     f"{self.report['frames_without_masks']} of {self.report['frames']} frames without any (no ground truth "
                     "to say what was missed)")
        lines = [line]
        warning = self.report.get("detector", {}).get("privacy_warning")
        if warning:
            lines.append("PRIVACY WARNING: " + warning)
        return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class SlamStage:
    """One SLAM run (stage 3): its metrics and, in memory only, its result."""

    metrics: dict[str, Any]
    """The run's metrics as in its ``metrics.json`` (:func:`privslam_jax.slam.outputs.write_outputs`):
    ``mode``, ``frames``, ``tracked``, ``map_points``, timings and, with ground truth, ATE/RPE."""
    result: Any = dataclasses.field(default=None, repr=False, compare=False)
    """The :class:`privslam_jax.slam.system.SlamResult` (trajectory, keyframes, map); in memory only."""

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON-able metrics (``report.json``'s ``"slam"`` entry for this run)."""
        return self.metrics

    def summary(self, label: str, ground_truth: bool = True) -> str:
        """One printable line for the run on ``label`` frames (``ground_truth``: the ATE/RPE are meaningful)."""
        m = self.metrics
        mode = m["mode"]
        ate = "ate_rmse_sim3" if mode == "mono" else "ate_rmse_se3"
        return (
            f"SLAM ({mode}) on {label} frames: tracked {m['tracked']}/{m['frames']}, "
            f"{m['map_points']} map points, "
            + (f"{'Sim(3)' if mode == 'mono' else 'SE(3)'} ATE {_fmt(m, ate)} m, "
               f"RPE (Sim(3)) {_fmt(m, 'rpe_trans_sim3')} m / {_fmt(m, 'rpe_rot')} deg per frame"
               if ground_truth else "no ground truth: no ATE/RPE")
            + (f" ({m['alignment_error']})" if "alignment_error" in m else "")
        )


@dataclasses.dataclass(frozen=True)
class PrivacyStage:
    """The map-privacy stage (4): the lift, the attack's and the no-attack baseline's metrics, or why it was skipped."""

    units: str
    """``"m"`` (the map aligned to the ground truth) or ``"SLAM units (…)"`` with the reason."""
    map_points: int
    """Number of map points lifted and attacked."""
    lift: str | None = None
    """How the lines were lifted (``"random"``, or with the fixed seed that makes it not secret)."""
    line2point: dict[str, float] | None = None
    """:func:`privslam_jax.metrics.privacy.point_recovery_metrics` of the Line2Point attack."""
    no_attack_closest_point: dict[str, float] | None = None
    """The same metrics for the no-attack baseline (each line's point closest to the origin)."""
    skipped: str | None = None
    """Why the stage did not run (``None``: it ran)."""
    map_xyz: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    """``(N, 3)`` float64 map in :attr:`units` (evaluation only: the attacker's target); in memory only."""
    lines: LineCloud | None = dataclasses.field(default=None, repr=False, compare=False)
    """The published line cloud (line ``i`` lifted from ``map_xyz[i]``); in memory only."""
    recovered: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    """``(N, 3)`` float64 points Line2Point recovered; in memory only."""

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON-able dict of ``report.json``'s ``"privacy"`` entry."""
        if self.skipped is not None:
            return {"skipped": self.skipped, "units": self.units}
        return {"map_points": self.map_points, "lift": self.lift, "line2point": self.line2point,
                "no_attack_closest_point": self.no_attack_closest_point, "units": self.units}

    def summary(self) -> str:
        """One printable line."""
        if self.skipped is not None:
            return f"map privacy: skipped ({self.skipped})"
        u = "m" if self.units == "m" else "(SLAM units)"
        a, b = self.line2point, self.no_attack_closest_point
        assert a is not None and b is not None
        return (
            f"map privacy ({self.map_points} points, {self.lift} lift): Line2Point recovers "
            f"{a['within_0.5']:.1f}% within 0.5 {u} (median error {a['per_point_median']:.2f} {u}); "
            f"no attack: {b['within_0.5']:.1f}% (median {b['per_point_median']:.2f} {u})"
        )


@dataclasses.dataclass(frozen=True)
class PipelineReport:
    """What :func:`run_pipeline` returns: every stage's value, the timings and the printable summary."""

    sequence: Path
    """The input KITTI-layout sequence folder (rendered, or ``config.sequence``)."""
    synthetic: bool
    """The input was rendered by the synthetic world."""
    data: dict[str, Any]
    """Numbers describing the input (:attr:`DataStage.stats`)."""
    filter: FilterStage
    """The privacy filter's stage."""
    slam: dict[str, SlamStage] | None
    """The SLAM runs by frames, ``"original"`` and ``"filtered"`` (``None``: ``config.slam`` off)."""
    privacy: PrivacyStage | None
    """The map-privacy stage (``None``: ``config.attack`` off)."""
    timings_s: dict[str, float]
    """Wall time per stage, seconds (``render``, ``filter``, ``slam_original``, ``slam_filtered``, ``lift_and_attack``)."""
    summary: str
    """The printable summary (several lines)."""
    edge: dict[str, Any] | None = None
    """With ``config.edge``: what crossed the wire for the filtered run (:func:`edge_slam_stage`)."""

    def to_json_dict(self) -> dict[str, Any]:
        """The content of ``report.json``: every field but :attr:`summary` and the in-memory values, JSON-able."""
        d: dict[str, Any] = {"sequence": str(self.sequence), "synthetic": self.synthetic, "data": self.data,
                             "filter": self.filter.to_json_dict()}
        if self.slam is not None:
            d["slam"] = {label: stage.to_json_dict() for label, stage in self.slam.items()}
        if self.privacy is not None:
            d["privacy"] = self.privacy.to_json_dict()
        if self.edge is not None:
            d["edge"] = self.edge
        d["timings_s"] = self.timings_s
        return d


# --------------------------------------------------------------------------------------------
# Stages


def data_stage(config: PipelineConfig, out: str | Path, progress: bool = False) -> DataStage:
    """Stage 1: the input sequence as a KITTI-layout folder.

    Without ``config.sequence`` the synthetic world is rendered (in memory) and written to
    ``out/original`` (the filter stage reads folders); with it, ``config.sequence`` is opened as
    it is and never written (``out`` must not contain it).
    """
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.kitti_write import sequence_stats, summarize_sequence, write_kitti_sequence

    out = Path(out)
    if config.sequence is None:
        if config.frames < 1:
            raise ValueError(f"frames must be at least 1, got {config.frames}")
        from privslam_jax.data.synthetic import SynthConfig, make_sequence

        seq = make_sequence(
            SynthConfig(width=config.width, height=config.height, num_frames=config.frames, seed=config.seed, stereo=True)
        )
        records: list[Any] = []
        seq_dir = write_kitti_sequence(seq, out / "original", config.name, progress=progress, collect=records)
        return DataStage(
            sequence=seq_dir, synthetic=True, stats=sequence_stats(seq, frames=records),
            description=summarize_sequence(seq, frames=records, title=f"synthetic sequence {seq_dir}"),
            gt_poses=np.asarray(seq.trajectory.as_matrices(), np.float64),
        )
    seq_dir = Path(config.sequence)
    if out.resolve() == seq_dir.resolve() or seq_dir.resolve().is_relative_to(out.resolve()):
        raise ValueError(f"--out {out} must not contain the input sequence {seq_dir}")
    seq = KittiSequence(seq_dir, stereo=config.mode == "stereo")
    lines = [summarize_sequence(seq, title=f"sequence {seq_dir}")]
    if seq.poses is None:
        lines.append("  no ground-truth poses: ATE/RPE are skipped and the map stays in SLAM units")
    return DataStage(sequence=seq_dir, synthetic=seq.has_extra("background"), stats=sequence_stats(seq),
                     description="\n".join(lines), gt_poses=seq.poses)


def filter_stage(sequence: str | Path, config: PipelineConfig, *, out: str | Path | None = None,
                 synthetic: bool = False, progress: bool = False) -> FilterStage:
    """Stage 2: remove the privacy objects of the sequence folder ``sequence``, in memory.

    :func:`privslam_jax.inpaint.sequence.filter_sequence_in_memory` with ``config``'s filter
    settings (``filter_method``, ``masks``, ``detector``, ``inpainter``, ``conf``, ``propagate``,
    ``tta``): the filtered frames are :attr:`FilterStage.frames`.  ``out``: also write the filtered
    sequence there (as ``privslam filter --out`` does), in the same pass.  With ``synthetic`` and a
    ``masks/`` folder of ground-truth instance masks, the leak is measured (:func:`mask_leak`).
    """
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.inpaint.sequence import filter_sequence_in_memory

    if config.masks not in ("detect", "gt"):
        raise ValueError(f"masks must be 'detect' or 'gt', got {config.masks!r}")
    sequence = Path(sequence)
    detector = None if config.detector is None else Path(config.detector)
    frames, report, folder = filter_sequence_in_memory(
        sequence, config.filter_method, masks_source=config.masks, detector_path=detector,
        model_path=None if config.inpainter is None else Path(config.inpainter), progress=progress,
        conf=config.conf, propagate=config.propagate, tta=config.tta, out=None if out is None else Path(out),
    )
    leak = None
    if (sequence / "masks").is_dir() and synthetic:
        original = KittiSequence(sequence)
        leak = mask_leak((original.instance_ids(i) for i in range(len(original))), frames.label_maps)
    return FilterStage(method=config.filter_method, masks=config.masks,
                       detector="embedded" if detector is None else str(detector), sequence=folder,
                       report=report, leak=leak, frames=frames)


def slam_stage(
    frames: Iterable[Any],
    camera: Camera,
    mode: str = "mono",
    *,
    timestamps: ArrayLike | None = None,
    gt_poses: ArrayLike | None = None,
    out: str | Path | None = None,
    total: int | None = None,
    progress: bool = False,
    ignore: Iterable[np.ndarray] | None = None,
) -> SlamStage:
    """Stage 3: SLAM (:func:`privslam_jax.slam.system.run_slam`) on ``frames`` in memory.

    Args:
      frames: images (``mode="mono"``) or ``(left, right)`` pairs (``"stereo"``), as ``run_slam`` takes them.
      camera: the (left) camera; ``camera.baseline`` for stereo.
      mode: ``"mono"`` or ``"stereo"``.
      timestamps: ``(N,)`` seconds of the frames (``None``: the frame indices).
      gt_poses: ``(N, 4, 4)`` ground-truth ``T_w_c`` (``None``: no ATE/RPE).
      out: write the run's files there (trajectory, keyframes, ``map.ply``, ``metrics.json``, plots;
        :func:`privslam_jax.slam.outputs.write_outputs`); ``None``: nothing is written (the same
        metrics from :func:`privslam_jax.slam.outputs.slam_metrics`).
      total: number of frames, for the progress bar and an early check of ``gt_poses``.
      progress: a progress bar.
      ignore: per frame, an ``(H, W)`` bool map of the (left) image where no feature is extracted
        (``run_slam``'s ``ignore``; e.g. the filter's masks), or ``None``.
    """
    from privslam_jax.slam.outputs import slam_metrics, write_outputs
    from privslam_jax.slam.system import SlamConfig, run_slam

    if mode not in ("mono", "stereo"):
        raise ValueError(f"mode must be 'mono' or 'stereo', got {mode!r}")
    gt = None if gt_poses is None else np.asarray(gt_poses, np.float64)
    if gt is not None and (gt.ndim != 3 or gt.shape[1:] != (4, 4)):
        raise ValueError(f"gt_poses must have shape (N, 4, 4), got {gt.shape}")
    ts = None if timestamps is None else np.asarray(timestamps, np.float64)
    if ts is not None and ts.ndim != 1:
        raise ValueError(f"timestamps must have shape (N,), got {ts.shape}")
    for name, a in (("gt_poses", gt), ("timestamps", ts)):
        if a is not None and total is not None and len(a) < total:
            raise ValueError(f"{name} has {len(a)} entries for {total} frames")
    t0 = time.perf_counter()
    result = run_slam(frames, camera, SlamConfig(mode=mode), timestamps=ts, progress=progress, total=total,
                      ignore=ignore)
    wall = time.perf_counter() - t0
    n = len(result.tracked)  # run_slam refuses an empty frame iterator
    if ts is None:
        ts = np.arange(n, dtype=np.float64)
    for name, a in (("gt_poses", gt), ("timestamps", ts)):
        if a is not None and len(a) < n:
            raise ValueError(f"{name} has {len(a)} entries for {n} frames")
    if out is not None:
        metrics = write_outputs(Path(out), result, ts, gt, mode, wall)
    else:
        metrics = slam_metrics(result, ts, gt, mode, wall)
    return SlamStage(metrics=metrics, result=result)


def edge_slam_stage(filtered: Any, camera: Camera, mode: str = "mono", *, store: str | Path,
                    timestamps: ArrayLike | None = None, gt_poses: ArrayLike | None = None,
                    out: str | Path | None = None, ignore_masked: bool = False) -> tuple[SlamStage, dict[str, Any]]:
    """Stage 3 through the edge split: ``filtered`` (:class:`~privslam_jax.inpaint.sequence.FilteredFrames`)
    sent by the device client (:func:`privslam_jax.edge.client.run_session`) to an edge server
    started on loopback with its store in ``store``.  Returns the :class:`SlamStage` of the server's
    session (the same result :func:`slam_stage` gives on the same frames: SLAM is deterministic for a
    seed) and what crossed: bytes each way, pose latency, and the line cloud the client received
    (``"line_cloud_ply"``).  The poses the client received are checked against the session's.
    ``ignore_masked``: the server extracts no feature where the filter filled in (the frames' masks
    travel with them)."""
    from privslam_jax.edge.client import calibration_message, device_frames, run_session
    from privslam_jax.edge.server import start_server
    from privslam_jax.slam.outputs import slam_metrics, write_outputs

    n = len(filtered)
    ts = np.arange(n, dtype=np.float64) if timestamps is None else np.asarray(timestamps, np.float64)[:n]
    gt = None if gt_poses is None else np.asarray(gt_poses, np.float64)
    server = start_server(store)
    try:
        t0 = time.perf_counter()
        received = run_session(f"127.0.0.1:{server.port}",
                               calibration_message("pipeline", camera, mode, ignore_masked=ignore_masked),
                               device_frames(filtered, ts, mode))
        wall = time.perf_counter() - t0
        result = server.servicer.result("pipeline")
    finally:
        server.stop()
    if not np.array_equal(received.T_w_c, np.asarray(result.trajectory.as_matrices(), np.float64)):
        raise RuntimeError("the poses the client received differ from the server's session")
    metrics = write_outputs(Path(out), result, ts, gt, mode, wall) if out is not None else slam_metrics(
        result, ts, gt, mode, wall)
    lat = received.latency_s[np.isfinite(received.latency_s)] * 1e3
    crossed = {"server": "127.0.0.1 (loopback)", "store": str(store), "frames": n,
               "bytes_up_per_frame": received.bytes_up / n, "bytes_down_per_frame": received.bytes_down / n,
               "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p99": float(np.percentile(lat, 99)),
               "reconnects": received.reconnects, "line_cloud_bytes": len(received.line_cloud_ply),
               "line_cloud_ply": received.line_cloud_ply}
    return SlamStage(metrics=metrics, result=result), crossed


def map_to_ground_truth(result: Any, gt_poses: ArrayLike | None, mode: str = "mono") -> tuple[np.ndarray, str]:
    """The map of a SLAM result (``SlamResult``) in the ground-truth frame, and its units.

    The map is moved by the Umeyama alignment of the SLAM trajectory to ``gt_poses`` (Sim(3) for
    ``mode="mono"``, whose scale is arbitrary; SE(3) for stereo), so distances are metres:
    ``(map_xyz, "m")``.  Without ground truth, or when the alignment is ill-posed, the map is
    returned as it is with ``"SLAM units (…)"`` and the reason.
    """
    from privslam_jax.geometry.align import umeyama_np

    if mode not in ("mono", "stereo"):
        raise ValueError(f"mode must be 'mono' or 'stereo', got {mode!r}")
    map_xyz = np.asarray(result.map.xyz, np.float64)
    if gt_poses is None:
        return map_xyz, "SLAM units (no ground truth)"
    gt = np.asarray(gt_poses, np.float64)
    if gt.ndim != 3 or gt.shape[1:] != (4, 4):
        raise ValueError(f"gt_poses must have shape (N, 4, 4), got {gt.shape}")
    est = np.asarray(result.trajectory.positions, np.float64)
    n = est.shape[0]
    try:
        R, t, c = umeyama_np(est[:n], gt[:n, :3, 3], with_scale=mode == "mono")
    except ValueError as err:
        return map_xyz, f"SLAM units (alignment failed: {err})"
    return c * map_xyz @ R.T + t, "m"


def privacy_stage(
    map_xyz: ArrayLike, key: jax.Array | None = None, *, progress: bool = False
) -> tuple[LineCloud, np.ndarray, dict[str, dict[str, float]]]:
    """Stage 4 in memory: lift ``map_xyz`` to a random line cloud and attack it; writes nothing.

    Args:
      map_xyz: ``(N, 3)`` map points, ``N >= 2``, finite.
      key: the lift's ``jax.random`` key (:func:`privslam_jax.privacy.lift.fixed_key` for
        experiments); ``None`` draws one from OS entropy.
      progress: a progress bar for Line2Point.

    Returns:
      ``(lines, recovered, metrics)``: the published :class:`LineCloud` (line ``i`` through
      ``map_xyz[i]``), the ``(N, 3)`` float64 points Line2Point recovers from it, and
      ``{"line2point": …, "no_attack_closest_point": …}``, each
      :func:`privslam_jax.metrics.privacy.point_recovery_metrics` against ``map_xyz``.
      :func:`write_privacy_outputs` writes them as PLY files.
    """
    from privslam_jax.attacks.line2point import line2point
    from privslam_jax.metrics.privacy import baseline_points, point_recovery_metrics
    from privslam_jax.privacy.lift import random_lift

    p = np.asarray(map_xyz)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"privacy_stage needs map points of shape (N, 3), got {tuple(p.shape)}")
    if len(p) < 2:
        raise ValueError(f"privacy_stage needs at least 2 map points (Line2Point), got {len(p)}")
    if not np.issubdtype(p.dtype, np.floating) and not np.issubdtype(p.dtype, np.integer):
        raise ValueError(f"map points must be numbers, got dtype {p.dtype}")
    p = p.astype(np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError("map points contain NaN or inf")
    lines = random_lift(p, key)
    recovered, _ = line2point(lines, progress=progress)
    recovered = np.asarray(recovered, np.float64)
    metrics = {
        "line2point": point_recovery_metrics(p, recovered),
        "no_attack_closest_point": point_recovery_metrics(p, baseline_points(lines, "closest")),
    }
    return lines, recovered, metrics


def write_privacy_outputs(out: str | Path, map_xyz: ArrayLike, lines: LineCloud, recovered: ArrayLike) -> None:
    """Write ``out/map_metric.ply`` (evaluation only), ``out/lines.ply`` (published) and ``out/recovered.ply`` (the attack)."""
    import jax.numpy as jnp

    from privslam_jax.data.ply import save_line_cloud, save_point_cloud
    from privslam_jax.types import PointCloud

    out = Path(out)
    save_point_cloud(out / "map_metric.ply", PointCloud(xyz=jnp.asarray(np.asarray(map_xyz, np.float64))))
    save_line_cloud(out / "lines.ply", lines)
    save_point_cloud(out / "recovered.ply", PointCloud(xyz=jnp.asarray(np.asarray(recovered, np.float64))))


# --------------------------------------------------------------------------------------------
# The whole pipeline


def run_pipeline(config: PipelineConfig, out: str | Path, progress: bool = True) -> PipelineReport:
    """Run every stage, writing their files under ``out``; returns the typed :class:`PipelineReport`.

    Without ``config.sequence`` the synthetic default is rendered first; with it, the stages run
    on that KITTI-layout sequence as it is (ground-truth poses used when present, the metrics that
    need them skipped with a note when not; object-leak figures only where ground-truth masks exist).
    """
    from privslam_jax.data.files import write_atomic
    from privslam_jax.privacy.lift import fixed_key
    from privslam_jax.slam.outputs import load_sequence_frames

    _check_config(config)
    out = Path(out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    data = data_stage(config, out, progress)
    if config.sequence is None:
        timings["render"] = time.perf_counter() - t0
    gt_poses = data.gt_poses
    lines = [data.description]

    t0 = time.perf_counter()
    filt = filter_stage(data.sequence, config, out=out / "filtered", synthetic=data.synthetic, progress=progress)
    timings["filter"] = time.perf_counter() - t0
    lines.append(filt.summary())

    slam: dict[str, SlamStage] | None = None
    privacy: PrivacyStage | None = None
    edge: dict[str, Any] | None = None
    if config.slam:
        slam = {}
        seq, original, n = load_sequence_frames(data.sequence, config.mode)
        filtered = filt.frames
        if config.mode == "stereo" and filtered.right is None:
            raise ValueError("stereo SLAM on the filtered frames needs the right images filtered too: use masks='detect' "
                             "(the sequence has no right-camera ground-truth masks, masks_3/)")
        in_memory = (filtered.grey(i) if config.mode == "mono" else (filtered.grey(i), filtered.grey(i, right=True))
                     for i in range(n))
        for label, frames in (("original", original), ("filtered", in_memory)):
            t0 = time.perf_counter()
            if label == "filtered" and config.edge:
                slam[label], edge = edge_slam_stage(filtered, seq.camera, config.mode, store=out / "edge_store",
                                                    timestamps=seq.timestamps[:n], gt_poses=seq.poses,
                                                    out=out / f"slam_{label}", ignore_masked=config.masked_features)
                write_atomic(out / "edge_lines_received.ply", edge.pop("line_cloud_ply"))
            else:
                ignore = ((filtered.label_maps[i] > 0 for i in range(n))
                          if label == "filtered" and config.masked_features else None)
                slam[label] = slam_stage(frames, seq.camera, config.mode, timestamps=seq.timestamps[:n],
                                         gt_poses=seq.poses, out=out / f"slam_{label}", total=n, progress=progress,
                                         ignore=ignore)
            timings[f"slam_{label}"] = time.perf_counter() - t0
            lines.append(slam[label].summary(label, ground_truth=gt_poses is not None)
                         + ("; no features on the filled-in regions" if label == "filtered" and config.masked_features
                            else ""))
            if label == "filtered" and edge is not None:
                lines.append(f"edge: the filtered frames went through a gRPC server on loopback ({out / 'edge_store'}): "
                             f"{edge['bytes_up_per_frame'] / 1e3:.1f} kB up and {edge['bytes_down_per_frame'] / 1e3:.2f} kB "
                             f"down per frame, pose latency p50 {edge['latency_ms_p50']:.0f} ms, p99 "
                             f"{edge['latency_ms_p99']:.0f} ms; the map came back as {edge['line_cloud_bytes'] / 1e3:.0f} kB "
                             f"of lines ({out / 'edge_lines_received.ply'})")
        if config.attack:
            t0 = time.perf_counter()
            map_xyz, units = map_to_ground_truth(slam["filtered"].result, gt_poses, config.mode)
            if len(map_xyz) < 2:
                privacy = PrivacyStage(units=units, map_points=len(map_xyz), skipped=f"the map has {len(map_xyz)} points")
            else:
                seed = config.lift_seed
                cloud, recovered, metrics = privacy_stage(map_xyz, None if seed is None else fixed_key(seed),
                                                          progress=progress)
                write_privacy_outputs(out, map_xyz, cloud, recovered)
                privacy = PrivacyStage(
                    units=units, map_points=len(map_xyz),
                    lift="random" + ("" if seed is None else f" (fixed seed {seed}: not secret)"),
                    line2point=metrics["line2point"], no_attack_closest_point=metrics["no_attack_closest_point"],
                    map_xyz=map_xyz, lines=cloud, recovered=recovered,
                )
            timings["lift_and_attack"] = time.perf_counter() - t0
            lines.append(privacy.summary())
    return PipelineReport(sequence=data.sequence, synthetic=data.synthetic, data=data.stats, filter=filt, slam=slam,
                          privacy=privacy, timings_s=timings, summary="\n".join(lines), edge=edge)


def mask_leak(instance_ids: Iterable[ArrayLike], hidden: Iterable[ArrayLike], min_pixels: int = 50,
              visible: float = 0.5) -> dict[str, Any]:
    """How much of the ground-truth objects the privacy filter left unmasked.

    For every frame, each ground-truth instance of ``instance_ids`` (``(H, W)`` integer ids, 0 =
    none; a sequence's ``masks/``) with at least ``min_pixels`` pixels is compared with the filter's
    mask ``hidden`` of the same frame (``(H, W)`` label map, > 0 = hidden;
    :attr:`~privslam_jax.inpaint.sequence.FilteredFrames.label_maps`). Returns the number of such
    objects (instance × frame), the percentage with more than ``visible`` of their pixels left
    unmasked (``objects_left_visible``), and the percentage of all their pixels left unmasked
    (``pixels_left_visible``).
    """
    n = left = px = px_left = 0
    for k, (ids, hid) in enumerate(zip(instance_ids, hidden, strict=True)):
        ids, hid = np.asarray(ids), np.asarray(hid)
        if ids.shape != hid.shape:
            raise ValueError(f"frame {k}: instance ids {ids.shape} and hidden map {hid.shape} differ in shape")
        hid = hid > 0
        for j in np.unique(ids[ids > 0]):
            inst = ids == j
            size = int(inst.sum())
            if size < min_pixels:
                continue
            missed = int((inst & ~hid).sum())
            n += 1
            left += missed > visible * size
            px += size
            px_left += missed
    return {
        "objects": n,
        "objects_left_visible": 100.0 * left / max(n, 1),
        "pixels_left_visible": 100.0 * px_left / max(px, 1),
        "rule": f"instances of >= {min_pixels} px; 'left visible' = more than {visible:.0%} of its pixels unmasked",
    }
