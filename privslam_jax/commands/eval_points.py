"""``privslam eval-points ORIGINAL.ply RECOVERED.ply``: point-recovery metrics as JSON.

Keys: ``nn_mean`` (the source paper's mean nearest-neighbour distance original → recovered),
``per_point_median``, ``per_point_mean`` (‖recovered_i − original_i‖, metres), ``within_0.1``,
``within_0.5``, ``within_1.0`` (percent of points recovered that close), ``chamfer`` (symmetric),
plus ``chamfer_orig_to_rec`` and ``chamfer_rec_to_orig``.  With ``--lines LINES.ply`` the same
metrics of the no-attack baselines (closest point to the origin; uniform on the line inside the
scene's box) are added under ``baseline_closest`` and ``baseline_uniform``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("eval-points", help="point-recovery metrics (JSON)", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("original", type=Path, help="original point cloud: PLY, or a BAL problem (its points)")
    p.add_argument("recovered", type=Path, help="recovered point cloud, PLY (point i from line i)")
    p.add_argument("--lines", type=Path, default=None, help="the line cloud, PLY: adds the no-attack baselines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from privslam_jax.commands.lift import load_points
    from privslam_jax.data.ply import load_line_cloud, load_point_cloud
    from privslam_jax.metrics.privacy import baseline_points, point_recovery_metrics

    orig = np.asarray(load_points(args.original).xyz)
    rec = np.asarray(load_point_cloud(args.recovered).xyz)
    if orig.shape != rec.shape:
        raise ValueError(f"{args.original} has {len(orig)} points but {args.recovered} has {len(rec)}")
    out: dict = point_recovery_metrics(orig, rec)
    if args.lines is not None:
        lines = load_line_cloud(args.lines)
        if len(lines) != len(orig):
            raise ValueError(f"{args.lines} has {len(lines)} lines, {args.original} {len(orig)} points")
        for rule in ("closest", "uniform"):
            out[f"baseline_{rule}"] = point_recovery_metrics(orig, baseline_points(lines, rule))
    print(json.dumps(out, indent=2))
    return 0
