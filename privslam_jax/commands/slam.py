"""``privslam slam SEQUENCE [--mode mono|stereo|rgbd] --out DIR``: run SLAM on a KITTI-layout sequence.

SEQUENCE is a ``…/sequences/<id>`` folder (KITTI odometry, or what ``privslam synth`` writes);
ground truth is read from ``…/poses/<id>.txt`` when present.  Writes into DIR:

* ``trajectory.txt`` — TUM ``t x y z qx qy qz qw``, one line per frame (``times.txt`` stamps,
  else frame/10 Hz); lost frames carry the motion-model prediction and are listed in metrics.json;
* ``keyframes.txt`` — TUM poses of the keyframes;
* ``map.ply`` — map points with their keyframe-observation counts;
* ``metrics.json`` — ``frames``, ``tracked``, ``lost_frames``, ``fps`` (all stages),
  ``tracking_fps`` (1 / median per-frame time of extraction + tracking, without local mapping),
  per-stage median times,
  events, and with ground truth ``ate_rmse_se3``, ``ate_rmse_sim3``, ``rpe_trans``, ``rpe_rot``
  (evo semantics, :mod:`privslam_jax.metrics.trajectory`) and ``path_length``;
* ``trajectory_xz.png`` (estimate aligned to the ground truth, top view) and
  ``ate_over_time.png`` (per-frame position error after alignment; Sim(3) for mono, SE(3) else).

Tracking loss is reported (metrics.json, stderr), never a crash.

``--ignore-masked`` extracts no ORB feature where the sequence's ``masks/`` map is nonzero: on the
output of ``privslam filter`` these are the regions it filled in, whose texture is made up.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["add_parser", "run", "load_sequence_frames", "masked_regions", "write_outputs"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "slam",
        help="run ORB-SLAM-style SLAM (mono / stereo / RGB-D) on a KITTI-layout sequence",
        description="Run SLAM on a KITTI-layout sequence folder (…/sequences/<id>); writes trajectory.txt (TUM, "
                    "every frame), keyframes.txt, map.ply, metrics.json and two plots into --out.",
    )
    p.add_argument("sequence", help="KITTI-layout sequence folder …/sequences/<id>")
    p.add_argument("--mode", choices=("mono", "stereo", "rgbd"), default="mono", help="input mode (default mono)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0, help="RANSAC shuffling seed (default 0)")
    p.add_argument("--max-frames", type=int, default=None, help="process only the first N frames")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--ignore-masked", action="store_true",
                   help="extract no features where the sequence's masks/ is nonzero (on a `privslam filter` "
                        "output: the filled-in objects)")
    p.set_defaults(func=run)


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


def _aligned(est: np.ndarray, gt: np.ndarray, sim3: bool) -> np.ndarray:
    from privslam_jax.geometry.align import apply_similarity, umeyama_np

    R, t, c = umeyama_np(est[:, :3, 3], gt[:, :3, 3], with_scale=sim3)
    return apply_similarity(R, t, c, est)


def write_outputs(out: Path, result, timestamps: np.ndarray, gt: np.ndarray | None, mode: str,
                  wall_time: float, plots: bool = True) -> dict:
    """Write the files described in the module docstring; returns the metrics dict."""
    from privslam_jax.data.ply import save_point_cloud
    from privslam_jax.data.trajectory_io import write_tum_matrices

    out.mkdir(parents=True, exist_ok=True)
    T = np.asarray(result.trajectory.as_matrices(), np.float64)
    n = T.shape[0]
    ts = np.asarray(timestamps, np.float64)[:n]
    write_tum_matrices(out / "trajectory.txt", ts, T)
    write_tum_matrices(out / "keyframes.txt", ts[result.keyframe_indices], result.keyframe_poses)
    save_point_cloud(out / "map.ply", result.map)
    total = result.timings.get("total", np.full(n, np.nan))
    mapping = np.nan_to_num(result.timings.get("mapping", np.zeros(n)))
    track = total - mapping  # per frame: extraction + stereo/depth + tracking, without local mapping
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
    }
    if gt is not None:
        from privslam_jax.metrics.trajectory import rpe, trajectory_metrics

        metrics["path_length"] = float(np.linalg.norm(np.diff(gt[:n, :3, 3], axis=0), axis=1).sum())
        try:
            m = trajectory_metrics((ts, T), (ts, gt[:n]))
            metrics.update({k: float(v) for k, v in m.items()})
            rt, _ = rpe((ts, T), (ts, gt[:n]), align="sim3")
            metrics["rpe_trans_sim3"] = float(rt.rmse)
        except ValueError as err:  # e.g. a straight ground-truth path: Umeyama is ill-posed; keep the outputs
            metrics["alignment_error"] = str(err)
            print(f"privslam slam: no ATE/RPE: {err}", file=sys.stderr)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    if plots:
        _plots(out, T, ts, gt[:n] if gt is not None else None, result.tracked, mode)
    return metrics


def _plots(out: Path, T: np.ndarray, ts: np.ndarray, gt: np.ndarray | None, tracked: np.ndarray, mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim3 = mode == "mono"
    try:
        est = _aligned(T, gt, sim3) if gt is not None and len(T) >= 3 else T
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
    fig.savefig(out / "trajectory_xz.png", dpi=120)
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
    fig.savefig(out / "ate_over_time.png", dpi=120)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.slam.system import SlamConfig, run_slam

    seq, frames, n = load_sequence_frames(args.sequence, args.mode, args.max_frames)
    ignore = masked_regions(seq, n) if args.ignore_masked else None
    cfg = SlamConfig(mode=args.mode, seed=args.seed)
    t0 = time.perf_counter()
    result = run_slam(frames, seq.camera, cfg, timestamps=seq.timestamps[:n], progress=True, total=n, ignore=ignore)
    wall = time.perf_counter() - t0
    out = Path(args.out)
    metrics = write_outputs(out, result, seq.timestamps[:n], seq.poses, args.mode, wall, plots=not args.no_plots)
    lost = metrics["lost_frames"]
    if lost:
        print(f"privslam slam: tracking lost on {len(lost)} of {n} frames: {lost} "
              "(motion-model poses written for them)", file=sys.stderr)
    summary = {k: metrics[k] for k in ("frames", "tracked", "keyframes", "map_points", "fps", "tracking_fps")}
    for k in ("ate_rmse_se3", "ate_rmse_sim3", "rpe_trans", "rpe_rot"):
        if k in metrics:
            summary[k] = round(metrics[k], 4)
    print(json.dumps(summary))
    print(f"wrote {out}/trajectory.txt, keyframes.txt, map.ply, metrics.json"
          + ("" if args.no_plots else ", trajectory_xz.png, ate_over_time.png"))
    return 0
