"""``privslam client SEQUENCE --server HOST:PORT --out DIR [--mode mono|stereo|rgbd]``: the device side.

Filters ``SEQUENCE`` (a KITTI-layout sequence) on this machine exactly as ``privslam filter``
does (``--method``, ``--masks``, ``--detector`` … mean the same), sends only the filtered frames
to an edge server (``privslam serve``), and writes what came back into ``DIR``:
``trajectory.txt`` (TUM, every frame, the server's final estimates), ``frames.txt`` (``timestamp
tracked map``), ``lines.ply`` (the map as a line cloud: the server never sends points) and
``edge_report.json`` (frames, bytes each way, pose latency, reconnections, the filter's report).
What crosses the wire is described in docs/edge.md: grey 8-bit PNGs of the filtered frames and the
masks of the filled-in pixels (RGB-D: the depth, zero inside the masks).

``--token-file`` holds the bearer token (the first token in it; a token on the command line would
show in the process list); ``--ca`` the PEM certificate of the CA that signed the server's (TLS).
``--session`` names the session (default: the sequence's name); running the same command again
resumes it on the server and sends only the frames it has not acknowledged.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from privslam_jax.argtypes import nonnegative_int, positive_float, positive_int, unit_interval

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from privslam_jax.inpaint.filter import FILTER_METHODS

    p = subparsers.add_parser("client", help="device side: filter a sequence, send it to an edge server, get poses and "
                                             "a line-cloud map back (docs/edge.md)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sequence", type=Path, help="KITTI-layout sequence folder (…/sequences/<name>)")
    p.add_argument("--server", required=True, help="HOST:PORT of `privslam serve`")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--mode", choices=("mono", "stereo", "rgbd"), default="mono", help="SLAM mode (default mono)")
    p.add_argument("--session", type=_session_id, default=None,
                   help="session id, 1-64 characters of A-Z a-z 0-9 _ - (default: the sequence's folder name)")
    p.add_argument("--token-file", type=_token_file, default=None, help="file whose first token is this client's bearer token")
    p.add_argument("--ca", type=Path, default=None, help="CA certificate (PEM) of the server's TLS certificate")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="RANSAC seed of the server's SLAM (default 0)")
    p.add_argument("--ignore-masked", action=argparse.BooleanOptionalAction, default=None,
                   help="the server extracts no feature where the filter filled in (default: on for stereo, off for "
                        "mono and rgbd, as privslam run)")
    p.add_argument("--max-frames", type=positive_int, default=None, help="send only the first N frames")
    p.add_argument("--no-map", action="store_true", help="do not ask for the map")
    p.add_argument("--deadline", type=positive_float, default=3600.0, help="deadline of each connection, s (default 3600)")
    p.add_argument("--reconnect-for", type=positive_float, default=60.0,
                   help="keep reconnecting this long after the connection fails, s (default 60)")
    p.add_argument("--method", default="edgeconnect", choices=FILTER_METHODS, metavar="METHOD",
                   help="filter, as `privslam filter --method` (default edgeconnect)")
    p.add_argument("--masks", choices=("gt", "detect"), default=None,
                   help="ground-truth synthetic masks or detections (default: gt when masks/ exists)")
    p.add_argument("--detector", type=Path, default=None, help="detector weights (.pt or .npz), as `privslam filter`")
    p.add_argument("--model", type=Path, default=None, help="EdgeConnect Inpainter .npz, as `privslam filter`")
    p.add_argument("--conf", type=unit_interval, default=None, help="detection threshold (default 0.4)")
    p.add_argument("--propagate", type=nonnegative_int, default=None, metavar="K",
                   help="carry detections to the K frames before and after by optical flow, as `privslam filter` "
                        "(default 3 on real frames, 0 on privslam synth output)")
    p.add_argument("--tta", action="store_true", help="detector test-time augmentation, as `privslam filter`")
    p.add_argument("--dilation", type=nonnegative_int, default=4, help="mask dilation in pixels (default 4)")
    p.add_argument("--allow-domain-mismatch", action="store_true",
                   help="run a detector trained on the synthetic world only on real frames anyway")
    p.add_argument("--overwrite", action="store_true", help="clear --out first if it holds an earlier privslam run")
    p.set_defaults(func=run, owns_out=True)


def _session_id(text: str) -> str:
    from privslam_jax.edge.codec import SESSION_ID

    if not SESSION_ID.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not 1-64 characters of A-Z a-z 0-9 _ -")
    return text


def _first_token(path: Path) -> str | None:
    for line in path.read_text().splitlines():
        parts = line.split("#", 1)[0].split()
        if parts:
            return parts[-1]
    return None


def _token_file(text: str) -> Path:
    """argparse type: a readable token file holding a token (the path is kept, never the token:
    the arguments go into the output's manifest.json)."""
    try:
        token = _first_token(Path(text))
    except OSError as err:
        raise argparse.ArgumentTypeError(f"{text}: {err.strerror or err}") from err
    if token is None:
        raise argparse.ArgumentTypeError(f"{text}: no token in the file")
    return Path(text)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from privslam_jax.data.files import write_atomic
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.trajectory_io import write_tum_matrices
    from privslam_jax.edge.client import calibration_message, device_frames, run_session
    from privslam_jax.inpaint.sequence import filter_sequence_in_memory
    from privslam_jax.pipeline import masked_features_by_default
    from privslam_jax.slam.outputs import write_frame_status

    token = None if args.token_file is None else _first_token(args.token_file)
    ca = args.ca.read_bytes() if args.ca is not None else None
    seq = KittiSequence(args.sequence, stereo=args.mode == "stereo", grey=True)
    filtered, report, _ = filter_sequence_in_memory(
        args.sequence, args.method, masks_source=args.masks, detector_path=args.detector, model_path=args.model,
        dilation=args.dilation, conf=args.conf, propagate=args.propagate, tta=args.tta,
        allow_domain_mismatch=args.allow_domain_mismatch, progress=True)
    n = len(filtered) if args.max_frames is None else min(len(filtered), args.max_frames)
    depths = [seq[i].depth for i in range(n)] if args.mode == "rgbd" else None
    frames = device_frames(filtered, seq.timestamps, args.mode, depths)[:n]
    session = args.session or seq.name
    ignore_masked = masked_features_by_default(args.mode) if args.ignore_masked is None else args.ignore_masked
    cal = calibration_message(session, seq.camera, args.mode, seed=args.seed, ignore_masked=ignore_masked)
    done = [0]

    def progress(pose) -> None:
        done[0] += 1
        if done[0] % 25 == 0 or done[0] == n:
            print(f"  {done[0]}/{n} frames acknowledged", file=sys.stderr, flush=True)

    res = run_session(args.server, cal, frames, token=token, root_certificates=ca, deadline_s=args.deadline,
                      reconnect_for_s=args.reconnect_for, want_map=not args.no_map, on_pose=progress)
    out = args.out
    write_tum_matrices(out / "trajectory.txt", res.timestamps, res.T_w_c)
    write_frame_status(out / "frames.txt", res.timestamps, res.tracked, res.maps)
    if res.line_cloud_ply:
        write_atomic(out / "lines.ply", res.line_cloud_ply)
    lat = res.latency_s[np.isfinite(res.latency_s)]
    summary = {"session": session, "server": args.server, "mode": args.mode, "frames": n,
               "tracked": int(res.tracked.sum()), "bytes_up": res.bytes_up, "bytes_down": res.bytes_down,
               "bytes_up_per_frame": res.bytes_up / max(n, 1), "reconnects": res.reconnects,
               "latency_ms_p50": float(np.percentile(lat, 50) * 1e3) if len(lat) else None,
               "latency_ms_p99": float(np.percentile(lat, 99) * 1e3) if len(lat) else None,
               "map_lines_bytes": len(res.line_cloud_ply)}
    write_atomic(out / "edge_report.json", json.dumps({**summary, "filter": report}, indent=2, default=str) + "\n")
    print(json.dumps(summary))
    print(f"wrote {out}/trajectory.txt, frames.txt" + (", lines.ply" if res.line_cloud_ply else "") + ", edge_report.json")
    return 0
