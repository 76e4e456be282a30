"""``privslam lift POINTS.ply --out LINES.ply``: hide a point cloud in a line cloud.

Line ``i`` is written as vertices ``2i``, ``2i+1`` (its canonical unit segment, starting at the
line's closest point to the origin) and edge ``i``; it corresponds to point ``i``.
``--method random`` (default): a uniformly random direction through each point;
``--method paired``: paired-point lifting (Lee et al., CVPR 2023), one line through each random
pair of points; ``--method ray``: ray clouds (Moon et al., CVPR 2024), each line through its point
and a random one of ``--anchors`` k-means centres of the map; ``--method sphere``: sphere clouds
(Moon et al., BMVC 2024), every line through the map's centroid; ``--method axial``: axial clouds,
every line horizontal and meeting the vertical axis through the map's centroid, "vertical" being the
mean up axis of the map's keyframes (``--keyframes``); ``--method optimised``: directions
optimised against the gradient attack, kept away from the points' viewing directions when the PLY has
normals (``nx ny nz``, as ``privslam slam``'s ``map.ply``) so they still serve localisation.
``--road-parallel KEYFRAMES`` (random and optimised lifts) lays the lines of the points within
``--road-within`` metres of the road under the map's keyframes parallel to it, so the road-surface
attack (``privslam attack --method road``) has nothing to intersect.  See
docs/privacy.md for what each one hides and what it costs.  POINTS may also be a BAL problem (``*.bal``, ``*.bal.txt``, optionally ``.bz2``):
its 3D points are lifted.  The points' descriptors (``privslam slam``'s ``map.ply`` carries ORB
descriptors) go with their lines, so ``privslam localize`` can match query images against them.  Without ``--seed`` the key comes from OS entropy (the secure default); a seed
makes the lift reproducible and is for experiments only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from privslam_jax.argtypes import positive_float, positive_int

__all__ = ["add_parser", "run", "load_points"]


def load_points(path: Path):
    """Points of a PLY point cloud, or of a BAL problem (``.bal``/``.bal.txt``, optionally ``.bz2``)."""
    import jax.numpy as jnp
    import numpy as np

    from privslam_jax.data.ply import load_point_cloud
    from privslam_jax.types import PointCloud

    name = Path(path).name.lower()
    if not (name.endswith(".bal") or ".bal." in name):
        return load_point_cloud(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"BAL file not found: {path}")
    try:
        from privslam_jax.data.bal import read_bal

        xyz = np.asarray(read_bal(path).points)
    except ImportError:  # minimal reader: header, observations, cameras, points
        import bz2

        opener = bz2.open if name.endswith(".bz2") else open
        tok = opener(path, "rt").read().split()
        try:
            n_cams, n_pts, n_obs = (int(x) for x in tok[:3])
            start = 3 + 4 * n_obs + 9 * n_cams
            xyz = np.asarray(tok[start : start + 3 * n_pts], np.float64).reshape(n_pts, 3)
        except ValueError as err:
            raise ValueError(f"{path}: not a valid BAL file ({err})") from err
    return PointCloud(xyz=jnp.asarray(xyz.astype(np.float32)))


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("lift", help="lift a point cloud (PLY) to a line cloud (PLY)", description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("points", type=Path, help="input point cloud: PLY, or a BAL problem (its points)")
    p.add_argument("--out", type=Path, required=True, help="output line cloud, PLY")
    p.add_argument("--method", choices=("random", "paired", "ray", "sphere", "axial", "optimised"), default="random",
                   help="lift (default random)")
    p.add_argument("--anchors", type=positive_int, default=8, help="anchors of --method ray (default 8)")
    p.add_argument("--passes", type=positive_float, default=100.0,
                   help="--method optimised: optimisation steps per point, on average (default 100)")
    p.add_argument("--road-parallel", type=Path, default=None, metavar="KEYFRAMES",
                   help="lay the lines of points near the road parallel to it (random and optimised lifts): the "
                        "map's keyframe poses, TUM (privslam slam's keyframes.txt) or KITTI (privslam_jax.privacy.road)")
    p.add_argument("--keyframes", type=Path, default=None, metavar="KEYFRAMES",
                   help="--method axial: the map's keyframe poses, TUM (privslam slam's keyframes.txt) or KITTI; the "
                        "axis is along their mean up axis (camera -y)")
    p.add_argument("--camera-height", type=positive_float, default=1.65,
                   help="camera above the road in metres for --road-parallel (default 1.65: KITTI)")
    p.add_argument("--road-within", type=positive_float, default=1.0,
                   help="--road-parallel: the points within this many metres of the road (default 1.0)")
    p.add_argument("--seed", type=int, default=None, help="fixed seed (experiments only; default: OS entropy)")
    p.add_argument("--ascii", action="store_true", help="write ASCII PLY (default binary little-endian)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.data.ply import save_line_cloud
    from privslam_jax.privacy.lift import (
        axial_lift,
        entropy_key,
        fixed_key,
        paired_lift,
        random_lift,
        ray_lift,
        sphere_lift,
        unique_points,
    )
    from privslam_jax.privacy.optimised_lift import OptimisedLiftConfig, optimised_lift

    if args.road_parallel is not None and args.method not in ("random", "optimised"):
        raise ValueError(f"--road-parallel needs lines of free direction (--method random or optimised), not {args.method}")
    if (args.method == "axial") != (args.keyframes is not None):
        raise ValueError("--method axial needs --keyframes (the map's keyframe poses: privslam slam's keyframes.txt), "
                         "and --keyframes is only for --method axial")
    cloud = load_points(args.points)
    up = None
    if args.keyframes is not None:  # read (and checked) before the lift
        from privslam_jax.data.trajectory_io import read_pose_matrices
        from privslam_jax.privacy.road import keyframe_up

        up = keyframe_up(read_pose_matrices(args.keyframes))
    keyframes = None
    if args.road_parallel is not None:  # read (and checked) before the lift, which may take minutes
        from privslam_jax.attacks.plane import road_planes
        from privslam_jax.data.trajectory_io import read_pose_matrices

        keyframes = read_pose_matrices(args.road_parallel)
        road_planes(keyframes, args.camera_height)
    if args.seed is None:
        key = entropy_key()
    else:
        print(f"privslam lift: fixed seed {args.seed}: reproducible, NOT secret", file=sys.stderr)
        key = fixed_key(args.seed)
    lifts = {"random": random_lift, "paired": paired_lift, "sphere": sphere_lift,
             "ray": lambda p, k: ray_lift(p, k, num_anchors=args.anchors),
             "axial": lambda p, k: axial_lift(p, up, k),
             "optimised": lambda p, k: optimised_lift(p, k, viewing_directions=cloud.normals,
                                                      config=OptimisedLiftConfig(passes=args.passes), progress=True)}
    lines = lifts[args.method](cloud.xyz, key)
    if keyframes is not None:
        from privslam_jax.privacy.road import road_parallel

        lines = road_parallel(lines, cloud.xyz, keyframes, args.camera_height, within=args.road_within)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_line_cloud(args.out, lines, descriptors=cloud.descriptors, binary=not args.ascii)
    first, _ = unique_points(np.asarray(cloud.xyz))
    repeated = "" if len(first) == len(cloud) else f"; {len(cloud) - len(first)} repeated points share their point's line"
    desc = "" if cloud.descriptors is None else f"; line i keeps point i's descriptor ({cloud.descriptors.shape[1]} bytes)"
    print(f"lifted {len(cloud)} points to {len(lines)} lines ({args.method}{repeated}{desc}) -> {args.out}")
    return 0
