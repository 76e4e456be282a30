"""The report a person reads first: ``report.md`` and a self-contained ``report.html`` for a run.

:func:`write_report` turns the files of a :func:`privslam_jax.pipeline.run_pipeline` run folder
and its typed :class:`~privslam_jax.pipeline.PipelineReport` into figures (matplotlib, Agg) and two
documents:

* a strip of original / mask / filtered frames with the filter's masks outlined and labelled;
* the trajectories of SLAM on the original and on the filtered frames against the ground truth
  (top view x–z, and the position error over time, each aligned as its ATE is: Sim(3) for mono,
  SE(3) for stereo);
* the ATE/RPE table; the map and the published line cloud, top view; the attack's recovered
  points coloured by their error; per-stage timings.

``report.md`` links the PNGs in ``report_files/``; ``report.html`` carries them inline as
``data:`` URIs and has no script and no external reference, so it opens offline and can be mailed
as one file. The frame strip shows the **original** frames: the report belongs on the device side.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from privslam_jax.data.files import write_atomic, write_figure
from privslam_jax.data.kitti_write import COCO_NAMES
from privslam_jax.pipeline import PipelineReport

__all__ = ["markdown_table", "write_report"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    write_figure(fig, path)
    _plt().close(fig)
    return path


def _frame_strip(original: Path, filtered: Path, path: Path, count: int = 3) -> Path | None:
    """Original (with the filter's masks outlined), mask and filtered image for ``count`` frames."""
    from privslam_jax.data.images import read_raw, read_rgb8

    left = next((d for d in ("image_2", "image_0") if (filtered / d).is_dir()), None)
    if left is None or not (filtered / "masks").is_dir():
        return None
    names = sorted(p.name for p in (filtered / left).glob("*.png"))
    if not names:
        return None
    classes_path = filtered / "instance_classes.json"
    classes = {int(k): v for k, v in json.loads(classes_path.read_text()).items()} if classes_path.is_file() else {}
    picks = [names[i] for i in sorted({round(j * (len(names) - 1) / max(count - 1, 1)) for j in range(count)})]
    plt = _plt()
    h, w = read_raw(filtered / left / picks[0]).shape[:2]
    fig, axes = plt.subplots(len(picks), 3, figsize=(15, 15 / 3 * h / w * len(picks) + 0.6), squeeze=False)
    for row, name in zip(axes, picks, strict=True):
        ids = read_raw(filtered / "masks" / name)
        row[0].imshow(read_rgb8(original / left / name))
        for k in np.unique(ids[ids > 0]):
            ys, xs = np.nonzero(ids == k)
            x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
            row[0].add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="yellow", lw=1))
            row[0].text(x0, y0, COCO_NAMES.get(classes.get(int(k), -1), "?"), color="black", fontsize=7,
                        backgroundcolor="yellow", va="bottom")
        row[1].imshow(ids > 0, cmap="gray", vmin=0, vmax=1)
        row[2].imshow(read_rgb8(filtered / left / name))
        row[0].set_ylabel(name, fontsize=8)
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    for ax, title in zip(axes[0], ("original + masks", "mask", "filtered"), strict=True):
        ax.set_title(title)
    fig.tight_layout()
    return _save(fig, path)


def _trajectories(out: Path, gt: np.ndarray | None, mode: str, path: Path) -> Path | None:
    """Top view and error over time of both SLAM runs (aligned to the ground truth when there is one)."""
    from privslam_jax.data.trajectory_io import read_tum_matrices
    from privslam_jax.slam.outputs import align_to_ground_truth

    runs = {}
    for label in ("original", "filtered"):
        f = out / f"slam_{label}" / "trajectory.txt"
        if f.is_file():
            runs[label] = read_tum_matrices(f)
    if not runs:
        return None
    plt = _plt()
    fig, (top, err) = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw={"width_ratios": [1, 1.4]})
    if gt is not None:
        top.plot(gt[:, 0, 3], gt[:, 2, 3], "k-", lw=2.5, label="ground truth")
    colours = {"original": "tab:blue", "filtered": "tab:orange"}
    for label, (ts, T) in runs.items():
        aligned = T
        if gt is not None and len(T) >= 3:
            try:
                aligned = align_to_ground_truth(T, gt[: len(T)], mode == "mono")
            except ValueError:
                pass
        top.plot(aligned[:, 0, 3], aligned[:, 2, 3], "-", color=colours[label], lw=1.3, label=f"SLAM on {label} frames")
        if gt is not None:
            err.plot(ts, np.linalg.norm(aligned[:, :3, 3] - gt[: len(T), :3, 3], axis=1), color=colours[label], label=label)
    top.set_xlabel("x [m]")
    top.set_ylabel("z [m]")
    top.set_aspect("equal", adjustable="datalim")
    top.legend(fontsize=8)
    top.set_title(f"top view ({'Sim(3)' if mode == 'mono' else 'SE(3)'}-aligned)" if gt is not None else "top view (no ground truth)")
    if gt is not None:
        err.set_ylabel("position error after alignment [m]")
        err.legend(fontsize=8)
    else:
        err.text(0.5, 0.5, "no ground truth", ha="center", va="center", transform=err.transAxes)
    err.set_xlabel("time [s]")
    err.set_title("error over time")
    fig.tight_layout()
    return _save(fig, path)


def _map_and_lines(out: Path, path: Path, max_lines: int = 400, seed: int = 0) -> Path | None:
    """The map (evaluation only) and the published line cloud, top view."""
    from privslam_jax.data.ply import load_line_cloud, load_point_cloud

    if not (out / "map_metric.ply").is_file() or not (out / "lines.ply").is_file():
        return None
    xyz = np.asarray(load_point_cloud(out / "map_metric.ply").xyz, np.float64)
    lines = load_line_cloud(out / "lines.ply")
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    plt = _plt()
    lo, hi = np.percentile(xyz, [1, 99], axis=0)
    panel = float(np.clip(6.0 * (hi[0] - lo[0] + 2) / (hi[2] - lo[2] + 2), 3.0, 7.0))  # equal-aspect panel width
    fig, (a, b) = plt.subplots(1, 2, figsize=(2 * panel + 1.5, 6.5))
    a.scatter(xyz[:, 0], xyz[:, 2], s=1, c=xyz[:, 1], cmap="viridis")
    a.set_title(f"SLAM map, filtered frames\n({len(xyz)} points; not published)", fontsize=10)
    # Each line drawn as a segment around its point closest to the map's centre (a public choice:
    # the drawing does not use the hidden points).
    centre = xyz.mean(0)
    pick = np.random.default_rng(seed).permutation(len(d))[:max_lines]
    dd = d[pick] / np.linalg.norm(d[pick], axis=1, keepdims=True)
    foot = np.cross(dd, m[pick])  # the line's point closest to the origin (unit direction)
    foot = foot + ((centre - foot) * dd).sum(1, keepdims=True) * dd
    half = 0.5 * np.ptp(xyz, axis=0).max()
    for p, u in zip(foot, dd, strict=True):
        b.plot([p[0] - half * u[0], p[0] + half * u[0]], [p[2] - half * u[2], p[2] + half * u[2]], "-", lw=0.3,
               color="tab:gray", alpha=0.6)
    b.set_title(f"published line cloud\n({len(d)} lines, {len(pick)} drawn)", fontsize=10)
    for ax in (a, b):
        ax.set_xlabel("x")
        ax.set_ylabel("z")
        ax.set_xlim(lo[0] - 1, hi[0] + 1)
        ax.set_ylim(lo[2] - 1, hi[2] + 1)
        ax.set_aspect("equal", adjustable="box")
    fig.tight_layout()
    return _save(fig, path)


def _attack(out: Path, path: Path, units: str) -> Path | None:
    """The attack's recovered points, top view, coloured by their distance to the true point."""
    from privslam_jax.data.ply import load_point_cloud

    if not (out / "recovered.ply").is_file() or not (out / "map_metric.ply").is_file():
        return None
    xyz = np.asarray(load_point_cloud(out / "map_metric.ply").xyz, np.float64)
    rec = np.asarray(load_point_cloud(out / "recovered.ply").xyz, np.float64)
    e = np.linalg.norm(rec - xyz, axis=1)
    plt = _plt()
    lo, hi = np.percentile(xyz, [1, 99], axis=0)
    panel = float(np.clip(6.0 * (hi[0] - lo[0] + 2) / (hi[2] - lo[2] + 2), 3.0, 8.0))
    fig, ax = plt.subplots(figsize=(panel + 2.5, 6.5))
    sc = ax.scatter(rec[:, 0], rec[:, 2], s=2, c=np.minimum(e, 2.0), cmap="RdYlGn_r", vmin=0, vmax=2.0)
    fig.colorbar(sc, ax=ax, label=f"error [{units}] (clipped at 2)")
    ax.set_xlim(lo[0] - 1, hi[0] + 1)
    ax.set_ylim(lo[2] - 1, hi[2] + 1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_title(f"Line2Point: {np.mean(e < 0.5) * 100:.1f}% of\nthe points within 0.5 {units}")
    fig.tight_layout()
    return _save(fig, path)


def markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    """The lines of a Markdown table."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def _f(v: Any, digits: int = 3) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{digits}f}"


def _tables(report: PipelineReport) -> list[tuple[str, list[str], list[list[str]]]]:
    """``(title, header, rows)`` of the report's tables."""
    tables = []
    slam = {label: stage.metrics for label, stage in (report.slam or {}).items()}
    if slam:
        rows = []
        for label, m in slam.items():
            rows.append([label, f"{m['tracked']}/{m['frames']}", str(m["map_points"]), _f(m.get("ate_rmse_sim3")),
                         _f(m.get("ate_rmse_se3")), _f(m.get("rpe_trans_sim3")), _f(m.get("rpe_rot"))])
        if "original" in slam and "filtered" in slam:
            a, b = slam["original"].get("ate_rmse_sim3"), slam["filtered"].get("ate_rmse_sim3")
            if a and b:
                rows.append(["filtered / original", "", "", f"{b / a:.2f}×", "", "", ""])
        tables.append(("SLAM accuracy (against the ground truth; evo semantics)",
                       ["SLAM on", "tracked frames", "map points", "ATE Sim(3) [m]", "ATE SE(3) [m]", "RPE Sim(3) [m/frame]",
                        "RPE [deg/frame]"], rows))
    priv = report.privacy
    if priv is not None and priv.line2point is not None and priv.no_attack_closest_point is not None:
        u = "m" if priv.units == "m" else "SLAM units"
        rows = [[name, _f(m["within_0.5"], 1), _f(m["per_point_median"], 2)]
                for name, m in (("Line2Point", priv.line2point), ("no attack (closest point)", priv.no_attack_closest_point))]
        tables.append((f"map privacy: {priv.map_points} points, {priv.lift} lift",
                       ["attack", f"% within 0.5 {u}", f"median error [{u}]"], rows))
    rows = [[k, f"{v:.1f} s"] for k, v in report.timings_s.items()]
    for label, m in slam.items():
        for k, v in m.get("median_ms", {}).items():
            rows.append([f"slam_{label}: {k} (median per frame)", f"{v:.1f} ms"])
    if rows:
        tables.append(("timings", ["stage", "time"], rows))
    return tables


def write_report(out: str | Path, report: PipelineReport) -> tuple[Path, Path]:
    """Write ``OUT/report.md``, ``OUT/report.html`` and ``OUT/report_files/*.png``; returns the two documents.

    The figures are drawn from the stage files of the run folder ``out``, the tables and the
    summary from ``report``.
    """
    from privslam_jax.data.kitti import KittiSequence

    out = Path(out)
    files = out / "report_files"
    original = Path(report.sequence)
    first = next(iter((report.slam or {}).values()), None)
    mode = "mono" if first is None else first.metrics.get("mode", "mono")
    try:
        gt = KittiSequence(original).poses
    except (OSError, ValueError):
        gt = None
    figures = []
    units = "m" if report.privacy is not None and report.privacy.units == "m" else "SLAM units"
    for title, make in (
        ("Frames: original with the filter's masks, the mask, the filtered frame",
         lambda: _frame_strip(original, report.filter.sequence, files / "frames.png")),
        ("Trajectories", lambda: _trajectories(out, gt, mode, files / "trajectories.png")),
        ("Map and published line cloud (top view)", lambda: _map_and_lines(out, files / "map_lines.png")),
        ("Attack", lambda: _attack(out, files / "attack.png", units)),
    ):
        p = make()
        if p is not None:
            figures.append((title, p))
    tables = _tables(report)
    summary = report.summary

    md = ["# privslam run report", "", "```", summary, "```", ""]
    for title, p in figures:
        md += [f"## {title}", "", f"![{title}]({p.relative_to(out).as_posix()})", ""]
    for title, header, rows in tables:
        md += [f"## {title}", "", *markdown_table(header, rows), ""]
    md_path = out / "report.md"
    write_atomic(md_path, "\n".join(md))

    body = ["<h1>privslam run report</h1>", f"<pre>{html.escape(summary)}</pre>"]
    for title, p in figures:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        body += [f"<h2>{html.escape(title)}</h2>", f'<img alt="{html.escape(title)}" src="data:image/png;base64,{data}">']
    for title, header, rows in tables:
        body += [f"<h2>{html.escape(title)}</h2>", "<table>",
                 "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
        body += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows] + ["</table>"]
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>privslam run report</title><style>"
            "body{font-family:sans-serif;max-width:1300px;margin:auto}img{max-width:100%}"
            "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}"
            "pre{background:#f4f4f4;padding:8px;white-space:pre-wrap}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")
    html_path = out / "report.html"
    write_atomic(html_path, page)
    return md_path, html_path
