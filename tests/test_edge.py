"""The edge split (issue 20): a device client and an edge SLAM server over gRPC, on loopback.

References: the single-process SLAM (``run_slam`` on the same filtered grey frames, same seed:
poses equal bit for bit), the protocol file (``grpc_tools.protoc``), the filter itself (every
image that crossed decodes to the client's filtered frame), and the geometry of the canonical
line-cloud export (each line written as its closest point to the origin and one unit along it).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import grpc
import numpy as np
import pytest

from privslam_jax.data.images import grey_as_read
from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.edge import edge_pb2 as pb
from privslam_jax.edge.client import EdgeError, calibration_message, frame_message, run_session
from privslam_jax.edge.server import start_server
from privslam_jax.slam.system import SlamConfig, run_slam

pytestmark = pytest.mark.xla_optimized  # the edge server and client run SLAM on whole sequences (tests/conftest.py)

N = 16


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x * 255.0), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def world():
    seq = make_sequence(SynthConfig(num_frames=N, seed=0, stereo=True))
    frames = [seq[i] for i in range(N)]
    return seq, [_u8(f.image) for f in frames], [_u8(f.image_right) for f in frames], frames


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = start_server(tmp_path_factory.mktemp("store"))
    yield f"127.0.0.1:{srv.port}"
    srv.stop()


class _Capture(grpc.StreamStreamClientInterceptor):
    """Every message of the call, as serialized bytes, in both directions."""

    def __init__(self):
        self.up: list[bytes] = []
        self.down: list[pb.Down] = []

    def intercept_stream_stream(self, continuation, details, request_iterator):
        def watched():
            for msg in request_iterator:
                self.up.append(msg.SerializeToString())
                yield msg

        capture = self

        class _Responses:
            def __init__(self, call):
                self.call = call

            def __iter__(self):
                for msg in self.call:
                    capture.down.append(msg)
                    yield msg

            def cancel(self):
                return self.call.cancel()

        return _Responses(continuation(details, watched()))


def _messages(left, right=None, n=N, depth=None):
    return [frame_message(i, 0.1 * i, left[i], right=None if right is None else right[i],
                          depth=None if depth is None else depth[i]) for i in range(n)]


def _millimetres(depth: np.ndarray) -> np.ndarray:
    """A depth map as it crosses (whole millimetres in 16 bits, 0 = none: so none beyond 65.535 m)
    and the server reads it back, in metres."""
    mm = np.rint(np.asarray(depth, np.float64) * 1000.0)
    return np.where((mm > 0) & (mm < 65536), mm, 0.0).astype(np.float32) / np.float32(1000.0)


def _reference(seq, left, right, mode, n=N, depth=None):
    items = [grey_as_read(x) for x in left[:n]]
    if mode == "stereo":
        items = list(zip(items, [grey_as_read(x) for x in right[:n]]))
    if mode == "rgbd":
        items = list(zip(items, [_millimetres(d) for d in depth[:n]]))
    return run_slam(items, seq.camera, SlamConfig(mode=mode, seed=0))


def test_generated_modules_match_the_proto_file(tmp_path):
    """``edge_pb2`` is what ``protoc`` makes of ``edge.proto`` today (the descriptor, whatever the
    generator's version)."""
    from google.protobuf import descriptor_pb2
    from grpc_tools import protoc

    root = Path(pb.__file__).resolve().parents[2]
    out = tmp_path / "set.pb"
    assert protoc.main(["protoc", f"-I{root}", f"--descriptor_set_out={out}", "privslam_jax/edge/edge.proto"]) == 0
    fresh = descriptor_pb2.FileDescriptorSet.FromString(out.read_bytes()).file[0]
    for message in fresh.message_type:  # the descriptor set spells out JSON names, the module does not
        for field in message.field:
            field.ClearField("json_name")
    committed = descriptor_pb2.FileDescriptorProto()
    pb.DESCRIPTOR.CopyToProto(committed)
    assert fresh == committed


@pytest.mark.parametrize("mode", ["mono", "stereo", "rgbd"])
def test_session_poses_equal_the_single_process_run_and_only_lines_come_back(world, server, mode, tmp_path):
    """Poses equal ``run_slam``'s on the same frames and seed, bit for bit; the server sends only
    ``started``/``pose``/``trajectory``/``line_cloud`` messages, and the line cloud has one line per
    map point, through it, written as the canonical segment (closest point to the origin, one unit
    along): nothing in the file depends on where on its line the point is."""
    from privslam_jax.data.ply import load_line_cloud, read_ply

    seq, left, right, frames = world
    depth = [f.depth for f in frames] if mode == "rgbd" else None
    capture = _Capture()
    res = run_session(server, calibration_message(f"eq-{mode}", seq.camera, mode),
                      _messages(left, right if mode == "stereo" else None, depth=depth), interceptors=[capture])
    ref = _reference(seq, left, right, mode, depth=depth)
    np.testing.assert_array_equal(res.T_w_c, np.asarray(ref.trajectory.as_matrices(), np.float64))
    np.testing.assert_array_equal(res.tracked, ref.tracked)
    assert res.tracked.sum() >= N - 4 and res.reconnects == 0 and np.isfinite(res.latency_s).all()
    kinds = [d.WhichOneof("kind") for d in capture.down]
    assert set(kinds) == {"started", "pose", "trajectory", "line_cloud"} and kinds.count("pose") == N
    (tmp_path / "lines.ply").write_bytes(res.line_cloud_ply)
    lines = load_line_cloud(tmp_path / "lines.ply")
    pts = np.asarray(ref.map.xyz, np.float64)
    assert len(pts) > 100 and len(lines) == len(pts)
    assert read_ply(tmp_path / "lines.ply")["descriptor"].shape[0] == len(pts)
    d, m = np.asarray(lines.directions, np.float64), np.asarray(lines.moments, np.float64)
    dist = np.linalg.norm(np.cross(pts[:, None], d[None]) - m[None], axis=2)  # |p × d − m|: distance to each line
    assert np.all(dist.min(axis=1) < 1e-3)  # every point is on a line (float32 map)
    # the vertices are a function of the line alone: its closest point to the origin and one unit on
    verts = np.stack([read_ply(tmp_path / "lines.ply")["vertex"][c] for c in "xyz"], axis=1).astype(np.float64)
    start, end = verts[0::2], verts[1::2]
    np.testing.assert_allclose(np.einsum("ij,ij->i", start, d), 0.0, atol=1e-4)
    np.testing.assert_allclose(end - start, d, atol=1e-5)


def test_a_growing_map_keeps_every_old_points_line():
    """The server's lift (``random_lift`` with ids): a point keeps its direction when the map grows;
    a lift by row would redraw it (two lines through a point meet at the point)."""
    from privslam_jax.privacy.lift import fixed_key, random_lift

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)) * 10
    ids = rng.permutation(1000)[:50]
    small, big = random_lift(pts[:20], fixed_key(1), ids=ids[:20]), random_lift(pts, fixed_key(1), ids=ids)
    np.testing.assert_allclose(np.asarray(big.directions)[:20], np.asarray(small.directions), atol=1e-6)
    by_row = random_lift(pts[5:25], fixed_key(1))
    assert np.abs(np.asarray(by_row.directions)[:15] - np.asarray(big.directions)[5:20]).max() > 0.1
    with pytest.raises(ValueError, match="distinct"):
        random_lift(pts[:2], fixed_key(1), ids=np.array([3, 3]))


def test_traffic_is_the_filtered_frames_and_does_not_depend_on_the_hidden_pixels(world, server):
    """What crosses: each image decodes to the grey 8-bit filtered frame, and noise written into the
    original frames inside the masks leaves every byte of the traffic unchanged (embedded EdgeConnect,
    ground-truth masks dilated by 4 px)."""
    from privslam_jax.inpaint.sequence import iter_filtered

    seq, left, _, frames = world
    n = 3
    kernel = np.ones((9, 9), np.uint8)

    def masks_of(i, k):
        ids = [int(v) for v in np.unique(frames[i].instance_ids) if v > 0]
        masks = np.stack([cv2.dilate((frames[i].instance_ids == v).astype(np.uint8), kernel) > 0 for v in ids])
        return masks, ids

    rng = np.random.default_rng(0)
    noisy = []
    for i in range(n):
        hidden = masks_of(i, 0)[0].any(axis=0)
        assert hidden.sum() > 500
        x = left[i].copy()
        x[hidden] = rng.integers(0, 256, (int(hidden.sum()), 3), dtype=np.uint8)
        noisy.append(x)
    traffic = []
    for images in (left[:n], noisy):
        filtered = list(iter_filtered(images, "edgeconnect", masks_of))
        msgs = [frame_message(i, 0.1 * i, f.left, mask=f.label_map > 0) for i, f in enumerate(filtered)]
        capture = _Capture()
        run_session(server, calibration_message(f"leak-{len(traffic)}", seq.camera, "mono"), msgs,
                    interceptors=[capture], want_map=False)
        frames_up = [pb.Up.FromString(b).frame for b in capture.up if pb.Up.FromString(b).WhichOneof("kind") == "frame"]
        assert len(frames_up) == n
        for f, sent in zip(filtered, frames_up):
            got = cv2.imdecode(np.frombuffer(sent.image, np.uint8), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(got, _u8(grey_as_read(f.left)))
            assert sent.right == b"" and sent.depth == b""
        traffic.append([b for b in capture.up if pb.Up.FromString(b).WhichOneof("kind") == "frame"])
    assert traffic[0] == traffic[1]


def _certificates(tmp: Path) -> tuple[bytes, bytes, bytes]:
    """A test CA and a server certificate for ``localhost`` signed by it: ``(ca, cert, key)`` PEM."""
    if subprocess.run(["openssl", "version"], capture_output=True).returncode != 0:
        pytest.skip("openssl is not installed")

    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=tmp)

    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=privslam test CA")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "srv.key", "-out", "srv.csr", "-subj", "/CN=localhost")
    (tmp / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "srv.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out", "srv.pem",
        "-days", "2", "-extfile", "ext.cnf")
    return (tmp / "ca.pem").read_bytes(), (tmp / "srv.pem").read_bytes(), (tmp / "srv.key").read_bytes()


def test_tls_and_bearer_tokens_refuse_and_log(world, tmp_path, caplog):
    """TLS with a CA made here; a token is needed, a wrong one is refused, a revoked one (line deleted
    from the token file) is refused from the next call on; refusals are logged with the peer; a client
    that does not trust the server's certificate gets no session."""
    seq, left, _, _ = world
    ca, cert, key = _certificates(tmp_path)
    tokens = tmp_path / "tokens.txt"
    tokens.write_text("alice secret-a\nbob secret-b\n")
    srv = start_server(tmp_path / "store", "127.0.0.1:0", tls=(cert, key), tokens=tokens)
    addr = f"localhost:{srv.port}"
    msgs = _messages(left, n=2)
    try:
        with caplog.at_level(logging.WARNING, logger="privslam_jax.edge"):
            for token, why in ((None, "no bearer token"), ("secret-x", "unknown or revoked")):
                with pytest.raises(EdgeError, match=f"UNAUTHENTICATED: {why}"):
                    run_session(addr, calibration_message("t", seq.camera, "mono"), msgs, token=token,
                                root_certificates=ca)
            res = run_session(addr, calibration_message("t", seq.camera, "mono"), msgs, token="secret-b",
                              root_certificates=ca, want_map=False)
            assert len(res.T_w_c) == 2
            time.sleep(0.01)
            tokens.write_text("alice secret-a\n")  # bob revoked
            with pytest.raises(EdgeError, match="UNAUTHENTICATED"):
                run_session(addr, calibration_message("t", seq.camera, "mono"), msgs, token="secret-b",
                            root_certificates=ca)
            (tmp_path / "other").mkdir()
            other_ca = _certificates(tmp_path / "other")[0]
            with pytest.raises(EdgeError, match="no connection"):  # a CA that did not sign the server's certificate
                run_session(addr, calibration_message("t", seq.camera, "mono"), msgs, token="secret-a",
                            root_certificates=other_ca, reconnect_for_s=0.5)
        refusals = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
        assert len(refusals) == 3 and all("ipv" in r for r in refusals), refusals
    finally:
        srv.stop()


def _bad(frame: pb.Frame, **fields) -> pb.Frame:
    out = pb.Frame()
    out.CopyFrom(frame)
    for k, v in fields.items():
        setattr(out, k, v)
    return out


def test_bad_input_ends_that_session_only_and_stores_nothing_of_it(world, tmp_path):
    """A corrupt PNG, a wrong size, a colour PNG, a gap, a NaN timestamp or calibration and a
    session without calibration each end their own call with INVALID_ARGUMENT and a message naming
    the frame and field, while another session streams on; the refused frame is not stored."""
    seq, left, _, _ = world
    srv = start_server(tmp_path / "store")
    addr = f"127.0.0.1:{srv.port}"
    good = _messages(left, n=N)
    result: dict = {}
    worker = threading.Thread(target=lambda: result.setdefault(
        "res", run_session(addr, calibration_message("good", seq.camera, "mono"), good, want_map=False)))
    worker.start()
    small = frame_message(1, 0.1, left[1][:100])
    _, colour = cv2.imencode(".png", left[1])
    cases = {
        "truncated": (_bad(good[1], image=good[1].image[:200]), "frame 1 image: the PNG could not be decoded"),
        "not a png": (_bad(good[1], image=b"GIF89a" + bytes(100)), "frame 1 image: not a PNG"),
        "size": (_bad(good[1], image=small.image), "frame 1 image: the PNG is 640x100"),
        "colour": (_bad(good[1], image=colour.tobytes()), "colour type 2"),
        "gap": (_bad(good[1], index=5), "the next frame of session bad-gap is 1"),
        "nan time": (_bad(good[1], timestamp=float("nan")), "frame 1: timestamp is not finite"),
    }
    def raw(cal: pb.Calibration | None, frames: list[pb.Frame]) -> grpc.RpcError:
        """The messages as they are (no client-side checks), to the end of the call."""
        from privslam_jax.edge.edge_pb2_grpc import EdgeSlamStub

        ups = ([] if cal is None else [pb.Up(calibration=cal)]) + [pb.Up(frame=f) for f in frames]
        with grpc.insecure_channel(addr) as channel:
            with pytest.raises(grpc.RpcError) as info:
                list(EdgeSlamStub(channel).Session(iter(ups), timeout=120))
        return info.value

    try:
        for name, (frame, message) in cases.items():
            sid = "bad-" + name.replace(" ", "-")
            err = raw(calibration_message(sid, seq.camera, "mono"), [good[0], frame])
            assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and message in err.details(), err.details()
            stored = sorted(p.name for p in (tmp_path / "store" / sid / "frames").iterdir())
            assert stored == ["000000.json", "000000.png"], stored
        nan_cal = calibration_message("bad-cal", seq.camera, "mono")
        nan_cal.fx = float("nan")
        with pytest.raises(EdgeError, match="INVALID_ARGUMENT: calibration: fx not finite"):
            run_session(addr, nan_cal, good[:1])
        assert not (tmp_path / "store" / "bad-cal").exists()
        err = raw(None, good[:1])
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "must be its calibration" in err.details()
        worker.join(timeout=600)
        assert len(result["res"].T_w_c) == N and result["res"].tracked.sum() >= N - 4
    finally:
        srv.stop()


def test_a_client_that_disconnects_mid_stream_frees_what_it_held(world, tmp_path):
    """A client whose connection drops after five acknowledged frames (channel closed mid-stream,
    no end of stream) frees what it held on the server: the session's lock, its place among the
    sessions being served (OpenCV gets its threads back) and the one call slot of a server made for
    one session, which then serves another client; the five frames stay stored and the session
    resumes from frame 5, with the poses of an uninterrupted run."""
    import queue

    from privslam_jax.edge.edge_pb2_grpc import EdgeSlamStub

    seq, left, _, _ = world
    srv = start_server(tmp_path / "store", max_sessions=1)
    addr = f"127.0.0.1:{srv.port}"
    ups: queue.Queue = queue.Queue()
    ups.put(pb.Up(calibration=calibration_message("drop", seq.camera, "mono")))
    for msg in _messages(left, n=5):
        ups.put(pb.Up(frame=msg))

    def requests():  # the client never ends its stream: it is cut off
        while (msg := ups.get()) is not None:
            yield msg

    try:
        channel = grpc.insecure_channel(addr)
        for down in EdgeSlamStub(channel).Session(requests(), timeout=300):
            if down.WhichOneof("kind") == "pose" and down.pose.index == 4:
                break
        channel.close()
        ups.put(None)
        session = srv.servicer._sessions["drop"]
        deadline = time.monotonic() + 60
        while (session.lock.locked() or srv.servicer._active) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not session.lock.locked() and srv.servicer._active == 0
        assert cv2.getNumThreads() == srv.servicer._opencv_threads
        other = run_session(addr, calibration_message("next", seq.camera, "mono"), _messages(left, n=4),
                            want_map=False, reconnect_for_s=0.0)
        assert len(other.T_w_c) == 4 and other.reconnects == 0
        stored = sorted(p.name for p in (tmp_path / "store" / "drop" / "frames").glob("*.json"))
        assert stored == [f"{i:06d}.json" for i in range(5)]
        res = run_session(addr, calibration_message("drop", seq.camera, "mono"), _messages(left), want_map=False)
    finally:
        srv.stop()
    np.testing.assert_array_equal(res.T_w_c, np.asarray(_reference(seq, left, None, "mono").trajectory.as_matrices(),
                                                        np.float64))


def _serve(store: Path, port: int) -> subprocess.Popen:
    env = dict(os.environ)
    return subprocess.Popen([sys.executable, "-m", "privslam_jax.cli", "serve", "--store", str(store), "--listen",
                             f"127.0.0.1:{port}"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def test_a_killed_server_resumes_the_session_and_loses_no_frame(world, tmp_path):
    """``privslam serve`` killed (SIGKILL) after frame 6 is acknowledged and started again on the
    same store: the client reconnects, resends only what was not acknowledged, and the final poses
    equal an uninterrupted single-process run's; every frame is stored once."""
    seq, left, _, _ = world
    with __import__("socket").socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    store = tmp_path / "store"
    procs = [_serve(store, port)]
    killed = threading.Event()

    def kill_at_six(pose: pb.Pose) -> None:
        if pose.index == 6 and not killed.is_set():
            killed.set()
            procs[0].send_signal(signal.SIGKILL)
            procs[0].wait()
            procs.append(_serve(store, port))

    try:
        res = run_session(f"127.0.0.1:{port}", calibration_message("resume", seq.camera, "mono"), _messages(left),
                          on_pose=kill_at_six, reconnect_for_s=300.0, want_map=False)
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
        logs = [p.communicate(timeout=60)[0] for p in procs]
    assert killed.is_set() and res.reconnects >= 1, logs
    ref = _reference(seq, left, None, "mono")
    np.testing.assert_array_equal(res.T_w_c, np.asarray(ref.trajectory.as_matrices(), np.float64))
    stored = sorted(p.name for p in (store / "resume" / "frames").glob("*.json"))
    assert stored == [f"{i:06d}.json" for i in range(N)]
    assert "frames stored" in logs[1] and " 0 frames stored" not in logs[1], logs[1]


def test_serve_and_client_commands(tmp_path, capsys):
    """``privslam client`` filters a ``privslam synth`` sequence (ground-truth masks, Telea), streams
    it to a server and writes the trajectory, the frames file, the line cloud and the report; with
    no server it fails with one line, exit code 2."""
    from privslam_jax.cli import main
    from privslam_jax.data.kitti_write import write_kitti_sequence
    from privslam_jax.data.ply import load_line_cloud
    from privslam_jax.data.trajectory_io import read_tum_matrices

    seq_dir = write_kitti_sequence(make_sequence(SynthConfig(num_frames=10, seed=0)), tmp_path / "k", progress=False)
    srv = start_server(tmp_path / "store")
    port = srv.port
    try:
        rc = main(["client", str(seq_dir), "--server", f"127.0.0.1:{port}", "--out", str(tmp_path / "out"),
                   "--method", "telea"])
    finally:
        srv.stop()
    assert rc == 0
    ts, T = read_tum_matrices(tmp_path / "out" / "trajectory.txt")
    assert T.shape == (10, 4, 4) and np.isfinite(T).all()
    assert len(load_line_cloud(tmp_path / "out" / "lines.ply")) > 0
    report = __import__("json").loads((tmp_path / "out" / "edge_report.json").read_text())
    assert report["frames"] == 10 and report["bytes_up"] > 10 * 10_000 and report["filter"]["frames"] == 10
    assert sorted(p.name for p in (tmp_path / "store" / "synth" / "frames").glob("*.png"))[-1] == "000009.png"
    capsys.readouterr()
    rc = main(["client", str(seq_dir), "--server", f"127.0.0.1:{port}", "--out", str(tmp_path / "out2"),
               "--method", "telea", "--reconnect-for", "0.5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("privslam client: error: session synth: no connection to"), err[-1]


def test_pipeline_edge_stage_equals_the_in_process_stage(world, tmp_path):
    """``privslam run --edge``'s SLAM stage (:func:`edge_slam_stage`) gives the in-process stage's
    trajectory and metrics on the same filtered frames, and reports what crossed."""
    from privslam_jax.inpaint.sequence import FilteredFrames
    from privslam_jax.pipeline import edge_slam_stage, slam_stage

    seq, left, _, _ = world
    labels = np.zeros((N, *left[0].shape[:2]), np.uint16)
    labels[:, 60:140, 200:400] = 1  # a filled-in region, where the server extracts no feature (``ignore_masked``)
    filtered = FilteredFrames(left=np.stack(left), right=None, label_maps=labels, instance_classes={1: 2})
    ts = np.arange(N) / 10.0
    gt = np.asarray(seq.trajectory.as_matrices(), np.float64)
    edge, crossed = edge_slam_stage(filtered, seq.camera, "mono", store=tmp_path / "store", timestamps=ts, gt_poses=gt,
                                    ignore_masked=True)
    local = slam_stage((filtered.grey(i) for i in range(N)), seq.camera, "mono", timestamps=ts, gt_poses=gt,
                       ignore=(labels[i] > 0 for i in range(N)))
    np.testing.assert_array_equal(np.asarray(edge.result.trajectory.as_matrices()),
                                  np.asarray(local.result.trajectory.as_matrices()))
    for key in ("tracked", "keyframes", "map_points", "ate_rmse_sim3", "rpe_trans"):
        assert edge.metrics[key] == local.metrics[key], key
    plain = slam_stage((filtered.grey(i) for i in range(N)), seq.camera, "mono", timestamps=ts, gt_poses=gt)
    assert not np.array_equal(np.asarray(plain.result.trajectory.as_matrices()),
                              np.asarray(local.result.trajectory.as_matrices()))  # the masks changed the run
    assert crossed["frames"] == N and crossed["bytes_up_per_frame"] > 10_000 and crossed["line_cloud_ply"]
