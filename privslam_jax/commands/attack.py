"""``privslam attack LINES.ply --out RECOVERED.ply``: recover one point per line.

``--method line2point`` (default): Line2Point (Chelani et al., CVPR 2021) as in the authors'
code; ``--method gradient``: the optimistix consistency-energy attack; ``--method ray``: the attack on
ray clouds (``privslam lift --method ray``): find the points where the lines meet, then vote across
them (docs/privacy.md); ``--method tpf``: two-peak finding for paired lifting (Lee et al., CVPR
2023), the two points of each pair handed out by a fair coin (seed 0; nothing in the cloud says which
is which); ``--method plane``: each line meets the ground plane ``--plane`` (default ``0,1,0,1.65``:
KITTI's road 1.65 m below a first camera with y down) where its point would be if it is on the road:
the attack on sphere clouds, and on every other lift (``privslam_jax.attacks.plane``); ``--method road``:
each line meets the road under the keyframes of ``--trajectory`` (the map's keyframe poses, camera to
map: ``keyframes.txt`` of ``privslam slam``, TUM, or a KITTI pose file), ``--camera-height`` above it
along the camera's y axis: the road's slope no longer matters; ``--method path``: each line's point
nearest a camera centre of ``--trajectory`` (the prior left against axial clouds).  Point ``i`` of
the output is recovered from line ``i``.  Runs in float32; ``--x64`` runs in float64.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, plane, positive_float

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("attack", help="recover points from a line cloud (PLY)", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("lines", type=Path, help="input line cloud, PLY (edges or vertex pairs)")
    p.add_argument("--out", type=Path, required=True, help="output recovered point cloud, PLY")
    p.add_argument("--method", choices=("line2point", "gradient", "ray", "tpf", "plane", "road", "path"), default="line2point",
                   help="attack (default line2point)")
    p.add_argument("--plane", type=plane, default=((0.0, 1.0, 0.0), 1.65),
                   help="ground plane NX,NY,NZ,H (n·x = H) in the map's frame for --method plane (default 0,1,0,1.65)")
    p.add_argument("--trajectory", type=Path, default=None,
                   help="the map's keyframe poses (camera to map), TUM (privslam slam's keyframes.txt) or KITTI, for --method road and path")
    p.add_argument("--camera-height", type=positive_float, default=1.65,
                   help="camera above the road in metres, along its y axis, for --method road (default 1.65: KITTI)")
    p.add_argument("--refine", type=nonnegative_int, default=2, help="Line2Point refinement rounds (default 2; authors: 2 or 3)")
    p.add_argument("--x64", action="store_true", help="compute in float64")
    p.add_argument("--ascii", action="store_true", help="write ASCII PLY")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import jax
    from tqdm import tqdm

    from privslam_jax.attacks.centred import ray_cloud_attack
    from privslam_jax.attacks.gradient import GradientAttackConfig, gradient_attack
    from privslam_jax.attacks.two_peaks import assign_pairs, two_peak_attack
    from privslam_jax.attacks.line2point import Line2PointConfig, line2point
    from privslam_jax.attacks.plane import ground_plane_attack, path_attack, road_surface_attack
    from privslam_jax.data.trajectory_io import read_pose_matrices
    from privslam_jax.data.ply import load_line_cloud, save_point_cloud
    from privslam_jax.types import PointCloud

    if args.method in ("road", "path") and args.trajectory is None:
        raise ValueError(f"--method {args.method} needs --trajectory (the map's keyframe poses: privslam slam's keyframes.txt)")
    t0 = time.perf_counter()
    with jax.enable_x64(args.x64):
        lines = load_line_cloud(args.lines)
        if args.method == "line2point":
            pts, _ = line2point(lines, Line2PointConfig(num_refine_iterations=args.refine), progress=True)
        elif args.method == "ray":
            pts, centres, _ = ray_cloud_attack(lines, progress=True)
            pts = jax.numpy.asarray(pts, "float64" if args.x64 else "float32")
            print(f"{len(centres)} centres where the lines meet")
        elif args.method == "plane":
            pts = jax.numpy.asarray(ground_plane_attack(lines, *args.plane), "float64" if args.x64 else "float32")
        elif args.method == "road":
            keyframes = read_pose_matrices(args.trajectory)
            pts = jax.numpy.asarray(road_surface_attack(lines, keyframes, args.camera_height),
                                    "float64" if args.x64 else "float32")
            print(f"the road under {len(keyframes)} keyframes, {args.camera_height} m below each camera")
        elif args.method == "path":
            keyframes = read_pose_matrices(args.trajectory)
            pts = jax.numpy.asarray(path_attack(lines, keyframes), "float64" if args.x64 else "float32")
            print(f"each line's point nearest one of {len(keyframes)} camera centres")
        elif args.method == "tpf":
            res = two_peak_attack(lines, progress=True)
            pts = jax.numpy.asarray(assign_pairs(res, "random"), "float64" if args.x64 else "float32")
            print(f"{int((res.partner >= 0).sum()) // 2} pairs of identical lines")
        else:
            with tqdm(total=1, desc="gradient attack", unit="solve") as bar:
                result = gradient_attack(lines, GradientAttackConfig(), throw=False)
                bar.update(1)
            pts = result.points
            if not result.successful:  # the attack's best effort is still an attack: keep it, say so
                print(f"note: the gradient attack's solve did not converge ({result.message()}); the points are "
                      "its last iterate")
        pts = jax.block_until_ready(pts)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        save_point_cloud(args.out, PointCloud(xyz=pts), binary=not args.ascii)
    print(f"recovered {pts.shape[0]} points ({args.method}) in {time.perf_counter() - t0:.1f} s -> {args.out}")
    return 0
