"""Open a KITTI-layout sequence for SLAM and write a SLAM run's outputs (``privslam slam``).

SEQUENCE is a ``…/sequences/<id>`` folder (KITTI odometry, or what ``privslam synth`` writes);
ground truth is read from ``…/poses/<id>.txt`` when present.  :func:`write_outputs` writes into DIR:

* ``trajectory.txt`` — TUM ``t x y z qx qy qz qw``, one line per frame (``times.txt`` stamps,
  else frame/10 Hz); lost frames carry the motion-model prediction and are listed in metrics.json;
* ``frames.txt`` — one line per frame, ``timestamp tracked map`` (``tracked`` 1/0, ``map`` the Atlas
  map of the pose, ``-1`` none; ``#`` header): which poses of ``trajectory.txt`` are tracked and which
  share a world frame (evo reads ``trajectory.txt`` as is);
* ``keyframes.txt`` — TUM poses of the keyframes;
* ``map.ply`` — map points with their keyframe-observation counts, viewing normals and ORB descriptors
  (what ``privslam lift`` and ``privslam localize`` need);
* ``metrics.json`` — ``frames``, ``tracked``, ``lost_frames``, ``fps`` (all stages),
  ``tracking_fps`` (1 / median per-frame time of extraction + tracking, without local mapping),
  per-stage median times,
  events, ``loops`` (each closed loop or Atlas merge: query and matched keyframe and map, inliers,
  matches, scale, correction, ``merged``), ``maps`` (Atlas maps at the end), and with ground truth
  ``ate_rmse_se3``, ``ate_rmse_sim3``, ``rpe_trans``, ``rpe_rot`` (evo semantics,
  :mod:`privslam_jax.metrics.trajectory`) and ``path_length``; when the run ends with more than one
  map, the errors are measured on the frames of the map holding the most frames (``metrics_map``,
  ``metrics_frames``), since the maps' world frames differ;
* ``trajectory_xz.png`` (estimate aligned to the ground truth, top view) and
  ``ate_over_time.png`` (per-frame position error after alignment; Sim(3) for mono, SE(3) else).

Tracking loss is reported (metrics.json), never a crash.

``--ignore-masked`` extracts no ORB feature where the sequence's ``masks/`` map is nonzero: on the
output of ``privslam filter`` these are the regions it filled in, whose texture is made up.
"""

from __future__ import annotations

import dataclasses

import json
from pathlib import Path

import numpy as np

from privslam_jax.data.files import write_atomic, write_figure

__all__ = ["align_to_ground_truth", "load_sequence_frames", "masked_regions", "write_frame_status", "write_outputs"]


def load_sequence_frames(path: str | Path, mode: str, max_frames: int | None = None):
    """Open a KITTI-layout sequence for ``mode``: ``(sequence, frame iterator, n_frames)``."""
    from privslam_jax.data.kitti import KittiSequence

    seq = KittiSequence(path, stereo=mode == "stereo", grey=True)
    if mode == "rgbd" and not seq.has_extra("depth"):
        raise FileNotFoundError(f"rgbd mode needs a depth/ folder in {seq.path} (write one with `privslam synth`)")
    n = len(seq) if max_frames is None else max(0, min(len(seq), int(max_frames)))
    if n == 0:
        raise ValueError("no frames to process (--max-frames must be positive)")

    def frames():
        for i in range(n):
            if mode == "mono":
                yield seq.image(i)
            elif mode == "stereo":
                yield seq.image(i), seq.image(i, right=True)
            else:
                yield seq.image(i), seq[i].depth

    return seq, frames(), n


def masked_regions(seq, n: int):
    """Per frame, the ``(H, W)`` bool map where ``seq``'s ``masks/`` is nonzero (``--ignore-masked``)."""
    if not seq.has_extra("masks"):
        raise FileNotFoundError(f"--ignore-masked needs {seq.path / 'masks'} (written by `privslam filter`)")
    return (seq.instance_ids(i) > 0 for i in range(n))


def align_to_ground_truth(est: np.ndarray, gt: np.ndarray, sim3: bool) -> np.ndarray:
    """``(N, 4, 4)`` poses ``est`` moved by the Umeyama alignment of their positions onto ``gt``'s (Sim(3) if ``sim3``)."""
    from privslam_jax.geometry.align import apply_similarity, umeyama_np

    R, t, c = umeyama_np(est[:, :3, 3], gt[:, :3, 3], with_scale=sim3)
    return apply_similarity(R, t, c, est)


def slam_metrics(result, timestamps: np.ndarray, gt: np.ndarray | None, mode: str, wall_time: float) -> dict:
    """The run's metrics (tracking, map, timings; ATE/RPE against ``gt`` when given), in memory."""
    T = np.asarray(result.trajectory.as_matrices(), np.float64)
    n = T.shape[0]
    ts = np.asarray(timestamps, np.float64)[:n]
    total = result.timings.get("total", np.full(n, np.nan))
    mapping = np.nan_to_num(result.timings.get("mapping", np.zeros(n)))
    track = total - mapping  # per frame: extraction + stereo/depth + tracking, without local mapping
    maps = result.frame_maps if result.frame_maps is not None else np.zeros(n, np.int64)
    metrics: dict = {
        "mode": mode,
        "frames": int(n),
        "tracked": int(result.tracked.sum()),
        "lost_frames": [int(i) for i in np.flatnonzero(~result.tracked)],
        "keyframes": int(len(result.keyframe_indices)),
        "map_points": int(len(result.map)),
        "fps": float(n / wall_time) if wall_time > 0 else None,
        "tracking_fps": float(1.0 / np.nanmedian(track)) if np.isfinite(track).any() else None,
        "median_ms": {k: float(np.nanmedian(v) * 1e3) for k, v in result.timings.items() if np.isfinite(v).any()},
        "events": result.events,
        "loops": [dataclasses.asdict(loop) for loop in result.loops],
        "maps": result.n_maps,
    }
    sel = np.ones(n, bool)
    if len(np.unique(maps[maps >= 0])) > 1:  # several world frames: measure the main map only
        ids, counts = np.unique(maps[maps >= 0], return_counts=True)
        sel = maps == ids[np.argmax(counts)]
        metrics["metrics_map"] = int(ids[np.argmax(counts)])
        metrics["metrics_frames"] = int(sel.sum())
    if gt is not None:
        from privslam_jax.metrics.trajectory import rpe, trajectory_metrics

        metrics["path_length"] = float(np.linalg.norm(np.diff(gt[:n, :3, 3], axis=0), axis=1).sum())
        try:
            est, ref = (ts[sel], T[sel]), (ts[sel], gt[:n][sel])
            m = trajectory_metrics(est, ref)
            metrics.update({k: float(v) for k, v in m.items()})
            rt, _ = rpe(est, ref, align="sim3")
            metrics["rpe_trans_sim3"] = float(rt.rmse)
        except ValueError as err:  # e.g. a straight ground-truth path: Umeyama is ill-posed; keep the outputs
            metrics["alignment_error"] = str(err)
    return metrics


def write_frame_status(path: Path, timestamps, tracked, maps=None) -> None:
    """Write ``frames.txt`` (module docstring) atomically: ``timestamp tracked map`` per frame, with a
    ``#`` header; ``maps`` ``None``: every pose in map 0."""
    ts = np.asarray(timestamps, np.float64).tolist()
    maps = np.zeros(len(ts), np.int64) if maps is None else maps
    write_atomic(path, "# timestamp tracked map\n" + "".join(
        f"{t!r} {int(k)} {int(m)}\n" for t, k, m in zip(ts, tracked, maps, strict=True)))


def write_outputs(out: Path, result, timestamps: np.ndarray, gt: np.ndarray | None, mode: str,
                  wall_time: float, plots: bool = True) -> dict:
    """Write the files described in the module docstring; returns :func:`slam_metrics`."""
    from privslam_jax.data.ply import save_point_cloud
    from privslam_jax.data.trajectory_io import write_tum_matrices

    out.mkdir(parents=True, exist_ok=True)
    T = np.asarray(result.trajectory.as_matrices(), np.float64)
    n = T.shape[0]
    ts = np.asarray(timestamps, np.float64)[:n]
    write_tum_matrices(out / "trajectory.txt", ts, T)
    write_frame_status(out / "frames.txt", ts, result.tracked, result.frame_maps)
    write_tum_matrices(out / "keyframes.txt", ts[result.keyframe_indices], result.keyframe_poses)
    save_point_cloud(out / "map.ply", result.map)
    metrics = slam_metrics(result, timestamps, gt, mode, wall_time)
    write_atomic(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    if plots:
        _plots(out, T, ts, gt[:n] if gt is not None else None, result.tracked, mode)
    return metrics


def _plots(out: Path, T: np.ndarray, ts: np.ndarray, gt: np.ndarray | None, tracked: np.ndarray, mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim3 = mode == "mono"
    try:
        est = align_to_ground_truth(T, gt, sim3) if gt is not None and len(T) >= 3 else T
    except ValueError:  # degenerate alignment (straight path): plot the estimate as it is
        est = T
    fig, ax = plt.subplots(figsize=(6, 6))
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 2, 3], "k-", lw=2, label="ground truth")
    ax.plot(est[:, 0, 3], est[:, 2, 3], "-", color="tab:blue", lw=1.2,
            label=f"SLAM ({mode}{', Sim(3)-aligned' if sim3 and gt is not None else ', SE(3)-aligned' if gt is not None else ''})")
    lost = ~tracked
    if lost.any():
        ax.plot(est[lost, 0, 3], est[lost, 2, 3], "rx", label="lost (motion-model pose)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title("trajectory, top view (x–z)")
    fig.tight_layout()
    write_figure(fig, out / "trajectory_xz.png", dpi=120)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    if gt is not None:
        err = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)
        ax.plot(ts, err, "-", color="tab:blue", label="position error")
        if lost.any():
            ax.plot(ts[lost], err[lost], "rx", label="lost")
        ax.set_ylabel(f"ATE after {'Sim(3)' if sim3 else 'SE(3)'} alignment [m]")
        ax.legend()
    else:
        ax.text(0.5, 0.5, "no ground truth", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("time [s]")
    fig.tight_layout()
    write_figure(fig, out / "ate_over_time.png", dpi=120)
    plt.close(fig)
