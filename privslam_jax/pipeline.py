"""The privacy-preserving edge-assisted SLAM pipeline, composed from the stages (DESIGN §1).

Each stage is a plain function of the previous stage's files, so every intermediate result is on
disk under the run folder and can be inspected or fed to the matching ``privslam`` command:

1. **data** – render the synthetic street world into a KITTI-layout sequence
   (:func:`privslam_jax.data.kitti_write.write_kitti_sequence`) → ``OUT/original``, or read the
   KITTI-layout folder ``config.sequence`` as it is (never written).
2. **privacy filter** (client side) – detect the privacy objects in the left images and remove
   them (:func:`privslam_jax.inpaint.sequence.filter_sequence`, a leak-free fill) → ``OUT/filtered``.
   ``masks="detect"`` uses the embedded detector made for the frames (or ``detector``),
   ``masks="gt"`` the renderer's instance masks. Where ground-truth instance masks exist (synthetic
   frames) the report also says how much of each object the filter missed (:func:`mask_leak`): a
   detector miss is a privacy leak that no fill can repair.
3. **SLAM** (edge-server side) – monocular (or stereo) SLAM on the original and on the filtered
   frames (:func:`privslam_jax.slam.run_slam`) → ``OUT/slam_original``, ``OUT/slam_filtered`` with
   trajectories, maps and, with ground-truth poses, ATE/RPE.
4. **map privacy** – lift the filtered run's map to a random line cloud (OS-entropy key unless
   ``lift_seed`` is given) and attack it with Line2Point
   (:func:`privslam_jax.attacks.line2point`); the monocular map is first brought to metres by the
   Sim(3) alignment of its trajectory to the ground truth (SE(3) for stereo; without ground truth
   it stays in SLAM units); point-recovery metrics next to the no-attack
   baseline (:mod:`privslam_jax.metrics.privacy`) → ``OUT/lines.ply`` (what the server would
   publish), ``OUT/recovered.ply`` (the attack), ``OUT/map_metric.ply`` (the map in metres, for
   evaluation only).

``privslam run`` then writes ``report.md`` / ``report.html`` (:func:`privslam_jax.report.write_report`)
and ``report.json``; the folder's ``manifest.json`` says ``"complete": true`` only after all of it
(:mod:`privslam_jax.runs`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PipelineConfig", "run_pipeline", "mask_leak"]


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
    """EdgeConnect checkpoint for ``filter_method="edgeconnect"`` (``None``: the embedded one)."""
    masks: str = "detect"
    """Where the filter's masks come from: ``"detect"`` (a detector) or ``"gt"`` (the renderer's)."""
    detector: str | None = None
    """Detector weights for ``masks="detect"`` (``None``: the embedded detector made for the frames' domain)."""
    conf: float | None = None
    """Detection threshold (``None``: the privacy preset's 0.4)."""
    tta: bool = False
    """Test-time augmentation of the detector (:func:`privslam_jax.detect.temporal.detect_tta`)."""
    propagate: int = 0
    """Carry detections to this many frames before and after by optical flow (0: off)."""
    mode: str = "mono"
    """SLAM input: ``"mono"`` or ``"stereo"`` (the right images are filtered with their own detections)."""
    slam: bool = True
    """Run SLAM on the original and the filtered frames."""
    attack: bool = True
    """Lift the filtered map to lines and attack it (needs ``slam``)."""
    lift_seed: int | None = None
    """Fixed lift seed (experiments only); ``None`` draws the key from OS entropy."""


def _slam(seq_dir: Path, out: Path, mode: str, progress: bool) -> tuple[dict[str, Any], Any]:
    from privslam_jax.slam.outputs import load_sequence_frames, write_outputs
    from privslam_jax.slam.system import SlamConfig, run_slam

    seq, frames, n = load_sequence_frames(seq_dir, mode)
    t0 = time.perf_counter()
    result = run_slam(frames, seq.camera, SlamConfig(mode=mode), timestamps=seq.timestamps[:n], progress=progress, total=n)
    metrics = write_outputs(out, result, seq.timestamps[:n], seq.poses, mode, time.perf_counter() - t0)
    return metrics, result


def _privacy(map_xyz: np.ndarray, out: Path, seed: int | None, progress: bool) -> dict[str, Any]:
    from privslam_jax.attacks.line2point import line2point
    from privslam_jax.data.ply import save_line_cloud, save_point_cloud
    from privslam_jax.metrics.privacy import baseline_points, point_recovery_metrics
    from privslam_jax.privacy.lift import fixed_key, random_lift
    from privslam_jax.types import PointCloud
    import jax.numpy as jnp

    if len(map_xyz) < 2:
        return {"skipped": f"the map has {len(map_xyz)} points"}
    save_point_cloud(out / "map_metric.ply", PointCloud(xyz=jnp.asarray(map_xyz)))  # evaluation only: the attacker's target
    lines = random_lift(map_xyz, None if seed is None else fixed_key(seed))
    save_line_cloud(out / "lines.ply", lines)
    recovered, _ = line2point(lines, progress=progress)
    recovered = np.asarray(recovered, np.float64)
    save_point_cloud(out / "recovered.ply", PointCloud(xyz=jnp.asarray(recovered)))
    return {
        "map_points": int(len(map_xyz)),
        "lift": "random" + ("" if seed is None else f" (fixed seed {seed}: not secret)"),
        "line2point": point_recovery_metrics(map_xyz, recovered),
        "no_attack_closest_point": point_recovery_metrics(map_xyz, baseline_points(lines, "closest")),
    }


def mask_leak(original: Path, filtered: Path, min_pixels: int = 50, visible: float = 0.5) -> dict[str, Any]:
    """How much of the ground-truth objects the privacy filter left unmasked.

    For every frame, each ground-truth instance of ``original/masks`` (uint16 instance ids) with at
    least ``min_pixels`` pixels is compared with the filter's mask ``filtered/masks`` (label map,
    > 0 = hidden). Returns the number of such objects (instance × frame), the percentage with more
    than ``visible`` of their pixels left unmasked (``objects_left_visible``), and the percentage of
    all their pixels left unmasked (``pixels_left_visible``).
    """
    from privslam_jax.data.images import read_raw

    n = left = px = px_left = 0
    for f in sorted((original / "masks").glob("*.png")):
        ids = read_raw(f)
        hidden = read_raw(filtered / "masks" / f.name) > 0
        for k in np.unique(ids[ids > 0]):
            inst = ids == k
            size = int(inst.sum())
            if size < min_pixels:
                continue
            missed = int((inst & ~hidden).sum())
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


def _fmt(m: dict[str, Any], key: str) -> str:
    v = m.get(key)
    return "n/a" if v is None else f"{v:.3f}"


def _trajectory_to_gt(result: Any, gt: np.ndarray, n: int, scale: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Umeyama alignment (``scale``: Sim(3)) of the SLAM trajectory to the ground truth: ``(R, t, c)``."""
    from privslam_jax.geometry.align import umeyama_np

    est = np.asarray(result.trajectory.positions, np.float64)[:n]
    return umeyama_np(est, np.asarray(gt, np.float64)[:n, :3, 3], with_scale=scale)


def run_pipeline(config: PipelineConfig, out: str | Path, progress: bool = True) -> dict[str, Any]:
    """Run every stage; returns a JSON-able report with a ``summary`` text and per-stage ``timings_s``.

    Without ``config.sequence`` the synthetic default is rendered first; with it, the stages run
    on that KITTI-layout sequence as it is (ground-truth poses used when present, the metrics that
    need them skipped with a note when not; object-leak figures only where ground-truth masks exist).
    """
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.kitti_write import sequence_stats, summarize_sequence, write_kitti_sequence
    from privslam_jax.inpaint.sequence import filter_sequence

    if config.masks not in ("detect", "gt"):
        raise ValueError(f"masks must be 'detect' or 'gt', got {config.masks!r}")
    if config.mode not in ("mono", "stereo"):
        raise ValueError(f"mode must be 'mono' or 'stereo', got {config.mode!r} (rgbd is not offered: the depth maps "
                         "show the hidden objects' shapes, and the privacy filter does not remove them)")
    if config.attack and not config.slam:
        raise ValueError("attack needs slam (the attacked map is the SLAM map)")
    out = Path(out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if config.sequence is None:
        if config.frames < 1:
            raise ValueError(f"frames must be at least 1, got {config.frames}")
        from privslam_jax.data.synthetic import SynthConfig, make_sequence

        seq = make_sequence(
            SynthConfig(width=config.width, height=config.height, num_frames=config.frames, seed=config.seed, stereo=True)
        )
        records: list[Any] = []
        seq_dir = write_kitti_sequence(seq, out / "original", config.name, progress=progress, collect=records)
        report: dict[str, Any] = {"sequence": str(seq_dir), "synthetic": True, "data": sequence_stats(seq, frames=records)}
        lines = [summarize_sequence(seq, frames=records, title=f"synthetic sequence {seq_dir}")]
        timings["render"] = time.perf_counter() - t0
    else:
        seq_dir = Path(config.sequence)
        if out.resolve() == seq_dir.resolve() or seq_dir.resolve().is_relative_to(out.resolve()):
            raise ValueError(f"--out {out} must not contain the input sequence {seq_dir}")
        seq = KittiSequence(seq_dir, stereo=config.mode == "stereo")
        report = {"sequence": str(seq_dir), "synthetic": seq.has_extra("background"), "data": sequence_stats(seq)}
        lines = [summarize_sequence(seq, title=f"sequence {seq_dir}")]
        if seq.poses is None:
            lines.append("  no ground-truth poses: ATE/RPE are skipped and the map stays in SLAM units")
    gt_poses = seq.poses if config.sequence is not None else np.asarray(seq.trajectory.as_matrices(), np.float64)

    t0 = time.perf_counter()
    detector = None if config.detector is None else Path(config.detector)
    filtered_dir = filter_sequence(
        seq_dir, out / "filtered", config.filter_method, masks_source=config.masks, detector_path=detector,
        model_path=None if config.inpainter is None else Path(config.inpainter), progress=progress,
        conf=config.conf, propagate=config.propagate, tta=config.tta,
    )
    timings["filter"] = time.perf_counter() - t0
    freport = json.loads((filtered_dir / "filter_report.json").read_text())
    source = "ground-truth masks" if config.masks == "gt" else f"detections of {'the embedded detector' if detector is None else detector.name}"
    report["filter"] = {"method": config.filter_method, "masks": config.masks, "detector": "embedded" if detector is None else str(detector),
                        "sequence": str(filtered_dir), "report": freport}
    line = f"privacy filter: {config.filter_method} on {source} -> {filtered_dir}"
    if (seq_dir / "masks").is_dir() and report["synthetic"]:  # ground-truth instance masks: measure the leak
        leak = mask_leak(seq_dir, filtered_dir)
        report["filter"]["leak"] = leak
        line += (f"; {leak['objects_left_visible']:.1f}% of {leak['objects']} objects left visible "
                 f"({leak['pixels_left_visible']:.1f}% of their pixels)")
    elif "masks_per_frame" in freport:
        per = freport["masks_per_frame"]
        line += (f"; {sum(per['detected']) + sum(per['promoted']) + sum(per['propagated'])} masks, "
                 f"{freport['frames_without_masks']} of {freport['frames']} frames without any (no ground truth "
                 "to say what was missed)")
    lines.append(line)
    warning = freport.get("detector", {}).get("privacy_warning")
    if warning:
        lines.append("PRIVACY WARNING: " + warning)

    if config.slam:
        slam: dict[str, Any] = {}
        for label, path in (("original", seq_dir), ("filtered", filtered_dir)):
            t0 = time.perf_counter()
            metrics, result = _slam(path, out / f"slam_{label}", config.mode, progress)
            timings[f"slam_{label}"] = time.perf_counter() - t0
            slam[label] = metrics
            ate = "ate_rmse_sim3" if config.mode == "mono" else "ate_rmse_se3"
            lines.append(
                f"SLAM ({config.mode}) on {label} frames: tracked {metrics['tracked']}/{metrics['frames']}, "
                f"{metrics['map_points']} map points, "
                + (f"{'Sim(3)' if config.mode == 'mono' else 'SE(3)'} ATE {_fmt(metrics, ate)} m, "
                   f"RPE (Sim(3)) {_fmt(metrics, 'rpe_trans_sim3')} m / {_fmt(metrics, 'rpe_rot')} deg per frame"
                   if gt_poses is not None else "no ground truth: no ATE/RPE")
                + (f" ({metrics['alignment_error']})" if "alignment_error" in metrics else "")
            )
        report["slam"] = slam
        if config.attack:
            t0 = time.perf_counter()
            map_xyz = np.asarray(result.map.xyz, np.float64)
            units = "SLAM units (no ground truth)"
            if gt_poses is not None:
                # Bring the map into metres (the ground-truth frame) with the alignment of its
                # trajectory (Sim(3) for mono, whose scale is arbitrary), so distances are metres.
                try:
                    R, t, c = _trajectory_to_gt(result, gt_poses, metrics["frames"], scale=config.mode == "mono")
                    map_xyz, units = c * map_xyz @ R.T + t, "m"
                except ValueError as err:
                    units = f"SLAM units (alignment failed: {err})"
            priv = _privacy(map_xyz, out, config.lift_seed, progress)
            priv["units"] = units
            timings["lift_and_attack"] = time.perf_counter() - t0
            report["privacy"] = priv
            u = "m" if units == "m" else "(SLAM units)"
            if "skipped" in priv:
                lines.append(f"map privacy: skipped ({priv['skipped']})")
            else:
                a, b = priv["line2point"], priv["no_attack_closest_point"]
                lines.append(
                    f"map privacy ({priv['map_points']} points, {priv['lift']} lift): Line2Point recovers "
                    f"{a['within_0.5']:.1f}% within 0.5 {u} (median error {a['per_point_median']:.2f} {u}); "
                    f"no attack: {b['within_0.5']:.1f}% (median {b['per_point_median']:.2f} {u})"
                )
    report["timings_s"] = timings
    report["summary"] = "\n".join(lines)
    return report
