"""Fuzz suite over the text-file readers (issue 15 item 5, text half).

Every reader is fed damaged copies of a small valid file — truncated at any byte, bytes replaced,
inserted or deleted, numbers replaced by NaN/inf/huge/negative/non-numbers, columns added, lines
dropped or repeated, whole random content, inflated header counts — and for every example:

* either it returns, and the result is well-formed (shapes, dtypes, finite values, indices in
  range, increasing timestamps),
* or it raises :class:`~privslam_jax.errors.InputError` whose message names the file, on one line
  (what the CLI prints); any other exception fails the test;
* **allocation bound**: the ``tracemalloc`` peak during the read is at most
  ``64 × S + 1 MiB``, where ``S`` is the number of bytes the reader parses — the file size (for a
  KITTI sequence the size of its files), and for a ``.bz2`` BAL file the size of the text it
  decompresses to, which the reader caps at ``MAX_BZ2_RATIO × (file size) + BZ2_SLACK``.

Each plain regression test below the fuzz tests failed on the readers before issue 15 (the CLI test
already passed: it pins the exit code 2 and the one line on stderr).
"""

import bz2
import re
import tempfile
import tracemalloc
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from privslam_jax.cli import main
from privslam_jax.data import bal as bal_module
from privslam_jax.data.bal import read_bal
from privslam_jax.data.kitti import KittiSequence, read_calib
from privslam_jax.data.kitti_object import KITTI_TYPES, read_kitti_object_labels
from privslam_jax.data.trajectory_io import (
    ROTATION_TOLERANCE,
    load_kitti,
    load_tum,
    read_kitti_matrices,
    read_pose_matrices,
    read_tum_matrices,
    write_kitti_matrices,
    write_tum_matrices,
)
from privslam_jax.data.yolo import read_yolo_labels
from privslam_jax.errors import InputError

try:  # hypothesis imports this (libcst -> a mypy_extensions DeprecationWarning) only when a test fails, where
    # warnings-as-errors turns the failure report into a pytest INTERNALERROR that hides the example
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import hypothesis.extra._patching  # noqa: F401
except ImportError:
    pass

MiB = 1 << 20
ALLOC_FACTOR = 64
FUZZ = {"deadline": None, "database": None, "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large]}


def _bound(size):
    return ALLOC_FACTOR * size + MiB


def _load(path, read, size=None, named=None):
    """``read()`` under tracemalloc: its result, or ``None`` after an ``InputError`` naming ``named``
    (default ``path``) on one line; asserts the allocation bound for ``size`` (default: the file size)."""
    size = Path(path).stat().st_size if size is None else size
    named = str(path if named is None else named)
    tracemalloc.start()
    try:
        try:
            out = read()
        except InputError as err:
            msg = str(err)
            assert named in msg, msg
            assert "\n" not in msg and "\r" not in msg, msg
            out = None
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= _bound(size), f"peak {peak} B > {ALLOC_FACTOR} x {size} B + 1 MiB"
    return out


# ------------------------------------------------------------------------------------------------
# Damage

SPECIAL = [
    "nan", "-nan", "NaN", "inf", "-inf", "Infinity", "1e308", "-1e308", "1.7976931348623157e308", "1e999", "-1e999",
    "1e-320", "0", "-0", "0.0", "-1", "-5", "1.5", "2147483648", "1000000000", "4611686018427387904",
    "99999999999999999999999999", "1" * 400, "x", "abc", "", "1 2", "0x1p3", "1_0", "\u0663", "\u00e9", "#", ",", ":",
    "P0:", "P2:", "\x00", "\ufffd", "{", "[[[[", '"1"', "1e", "--1", "+1", ".", "Car", "DontCare",
]
_TEXTISH = st.text(alphabet="0123456789 .-+eE\n\tnaifxP:#,", max_size=200)


@st.composite
def damaged(draw, base):
    """``base`` (bytes) with up to three random kinds of damage (some harmless: other numbers, whitespace)."""
    data = base
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["truncate", "replace", "insert", "delete", "token", "token", "token", "column",
                                     "drop_line", "repeat_line", "random_binary", "random_text", "number", "number",
                                     "space"]))
        n = len(data)
        if kind == "truncate":
            data = data[: draw(st.integers(0, n))]
        elif kind == "replace" and n:
            i = draw(st.integers(0, n - 1))
            data = data[:i] + bytes([draw(st.integers(0, 255))]) + data[i + 1 :]
        elif kind == "insert":
            i = draw(st.integers(0, n))
            data = data[:i] + draw(st.binary(min_size=1, max_size=8)) + data[i:]
        elif kind == "delete" and n:
            i = draw(st.integers(0, n - 1))
            data = data[:i] + data[i + draw(st.integers(1, 16)) :]
        elif kind == "token":
            parts = re.split(rb"(\s+)", data)
            if len(parts) > 1 or parts[0]:
                i = 2 * draw(st.integers(0, (len(parts) - 1) // 2))
                parts[i] = draw(st.sampled_from(SPECIAL) | _TEXTISH).encode("utf-8")
                data = b"".join(parts)
        elif kind == "number":  # another valid number in place of one
            parts = re.split(rb"(\s+)", data)
            if len(parts) > 1 or parts[0]:
                i = 2 * draw(st.integers(0, (len(parts) - 1) // 2))
                value = draw(st.integers(-2, 9) | st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=False))
                parts[i] = repr(value).encode()
                data = b"".join(parts)
        elif kind == "space":  # whitespace where there is whitespace
            gaps = [m.start() for m in re.finditer(rb"\s", data)]
            if gaps:
                i = draw(st.sampled_from(gaps))
                data = data[:i] + draw(st.sampled_from([b" ", b"\t", b"\n", b"\r\n", b"\n\n  "])) + data[i:]
        elif kind == "column":
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i] += b" " + draw(st.sampled_from(SPECIAL)).encode("utf-8")
            data = b"\n".join(lines)
        elif kind in ("drop_line", "repeat_line"):
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i : i + 1] = [] if kind == "drop_line" else [lines[i]] * draw(st.integers(2, 4))
            data = b"\n".join(lines)
        elif kind == "random_binary":
            data = draw(st.binary(max_size=512))
        elif kind == "random_text":
            data = draw(_TEXTISH).encode("utf-8")
    return data


# ------------------------------------------------------------------------------------------------
# Valid files

def _rotations(n, seed):
    from scipy.spatial.transform import Rotation

    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = np.random.default_rng(seed).normal(scale=20.0, size=(n, 3))
    return T


def _text_of(writer, *args):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "f.txt"
        writer(p, *args)
        return p.read_bytes()


TUM = _text_of(write_tum_matrices, 1305031102.175304 + np.arange(4) * 0.0333, _rotations(4, 0))
KITTI_POSES = _text_of(write_kitti_matrices, _rotations(3, 1))
_P = [[718.856, 0.0, 607.1928, 0.0], [0.0, 718.856, 185.2157, 0.0], [0.0, 0.0, 1.0, 0.0]]
CALIB = "".join(
    f"P{k}: " + " ".join(f"{v:.12e}" for v in np.asarray(_P).ravel() + np.r_[[0, 0, 0, -386.1448 * (k % 2)], [0] * 8])
    + "\n" for k in range(4)
).encode() + b"Tr: " + b" ".join(f"{v:.12e}".encode() for v in np.eye(4)[:3].ravel()) + b"\n"
TIMES = b"0.000000e+00\n1.036000e-01\n2.072000e-01\n"
CLASSES = b'{"1": 2, "2": 0}\n'
PNG = cv2.imencode(".png", np.arange(48, dtype=np.uint8).reshape(6, 8))[1].tobytes()
BAL = (
    b"2 3 4\n0 0 -1.5 2.25\n1 0 3.0 -0.5\n0 1 10.0 4.0\n1 2 -7.5 0.125\n"
    + b"".join(f"{v!r}\n".encode() for v in [0.01, -0.02, 0.03, 0.1, 0.2, 0.3, 500.0, 0.0, 0.0,
                                              -0.01, 0.02, 0.0, -0.1, 0.0, 0.2, 480.0, 1e-3, -1e-4])
    + b"".join(f"{v!r}\n".encode() for v in [1.0, 2.0, -10.0, 0.5, -1.5, -12.0, 3.0, 0.0, -9.0])
)
LABELS = (b"Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01\n"
          b"Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57\n"
          b"Cyclist 0.70 1 -1.56 0.00 170.00 30.00 220.00 1.7 0.6 1.8 -9.0 1.7 10.0 -1.6\n"
          b"DontCare -1 -1 -10 503.89 169.71 590.74 190.13 -1 -1 -1 -1000 -1000 -1000 -10\n")
YOLO = b"0 0.5 0.5 0.2 0.3\n2 0.25 0.75 0.1 0.05\n7 0.1 0.1 0.2 0.1 0.2 0.3 0.05 0.25\n"


def _write(data, name="f.txt"):
    d = Path(tempfile.mkdtemp(prefix="privslam_fuzz_"))
    p = d / name
    p.write_bytes(data)
    return p


def _cleanup(path):
    import shutil

    shutil.rmtree(Path(path).parent, ignore_errors=True)


# ------------------------------------------------------------------------------------------------
# Well-formed results

def _check_rotations(T, tol):
    R = T[:, :3, :3]
    assert np.all(np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)) <= tol)
    assert np.all(np.linalg.det(R) > 0)
    np.testing.assert_array_equal(T[:, 3, :], np.tile([0.0, 0.0, 0.0, 1.0], (T.shape[0], 1)))


def _check_trajectory(traj, n):
    assert np.asarray(traj.timestamps).shape == (n,)
    pos = np.asarray(traj.positions)
    q = np.asarray(traj.poses.rotation().wxyz)
    assert pos.shape == (n, 3) and np.all(np.isfinite(pos)) and np.all(np.isfinite(np.asarray(traj.timestamps)))
    assert np.all(np.abs(np.linalg.norm(q, axis=1) - 1) < 0.05)


# ------------------------------------------------------------------------------------------------
# Fuzz tests

def _check_pose_file(path, expected):
    """``read_pose_matrices`` (TUM or KITTI by the first line) on the same file: the format's reader's
    matrices when that reader accepted it (``expected``), else finite rotations or an ``InputError``
    naming the file (a damaged first line may make it the other format)."""
    T = _load(path, lambda: read_pose_matrices(path))
    if expected is not None:
        np.testing.assert_array_equal(T, expected)
    elif T is not None:
        assert T.dtype == np.float64 and T.ndim == 3 and T.shape[1:] == (4, 4) and np.all(np.isfinite(T))


@settings(max_examples=150, **FUZZ)
@given(damaged(TUM))
def test_fuzz_tum(data):
    path = _write(data, "traj.txt")
    try:
        out = _load(path, lambda: read_tum_matrices(path))
        if out is not None:
            t, T = out
            assert t.dtype == T.dtype == np.float64 and T.shape == (t.shape[0], 4, 4) and t.shape[0] >= 1
            assert np.all(np.isfinite(t)) and np.all(np.isfinite(T)) and np.all(t[1:] > t[:-1])
            _check_rotations(T, 1e-9)
        _check_pose_file(path, out[1] if out is not None else None)
        try:
            traj = load_tum(path)
        except InputError as err:
            assert str(path) in str(err)
        else:
            assert out is not None
            _check_trajectory(traj, out[0].shape[0])
    finally:
        _cleanup(path)


@settings(max_examples=150, **FUZZ)
@given(damaged(KITTI_POSES))
def test_fuzz_kitti_poses(data):
    path = _write(data, "00.txt")
    try:
        T = _load(path, lambda: read_kitti_matrices(path))
        if T is not None:
            assert T.dtype == np.float64 and T.ndim == 3 and T.shape[1:] == (4, 4) and T.shape[0] >= 1
            assert np.all(np.isfinite(T))
            _check_rotations(T, ROTATION_TOLERANCE)
        _check_pose_file(path, T)
        try:
            traj = load_kitti(path)
        except InputError as err:
            assert str(path) in str(err)
        else:
            assert T is not None
            _check_trajectory(traj, T.shape[0])
    finally:
        _cleanup(path)


@settings(max_examples=150, **FUZZ)
@given(damaged(CALIB))
def test_fuzz_calib(data):
    path = _write(data, "calib.txt")
    try:
        out = _load(path, lambda: read_calib(path))
        if out is not None:
            for key, P in out.items():
                assert isinstance(key, str) and key and P.shape == (3, 4) and P.dtype == np.float64
                assert np.all(np.isfinite(P))
    finally:
        _cleanup(path)


def _sequence(root, files):
    """A KITTI sequence folder ``root/sequences/07`` with three frames and the given text files."""
    seq = root / "sequences" / "07"
    (seq / "image_0").mkdir(parents=True)
    for i in range(3):
        (seq / "image_0" / f"{i:06d}.png").write_bytes(PNG)
    (root / "poses").mkdir()
    if "labels" in files:
        (seq / "labels").mkdir()
    where = {"poses": root / "poses" / "07.txt", "labels": seq / "labels" / "000000.txt"}
    for name, data in files.items():
        where.get(name, seq / name).write_bytes(data)
    return seq


_SEQ_FILES = {"calib.txt": CALIB, "times.txt": TIMES, "poses": KITTI_POSES, "instance_classes.json": CLASSES,
              "labels": YOLO}
_STRUCTURE = ["none", "no_image_folder", "empty_image_folder", "letters", "negative", "unpadded", "duplicate",
              "huge_number", "directory_png", "image_2_file"]


@settings(max_examples=100, **FUZZ)
@given(st.sampled_from(sorted(_SEQ_FILES)), st.data(), st.sampled_from(["none"] * 6 + _STRUCTURE))
def test_fuzz_kitti_sequence(victim, data, structure):
    files = dict(_SEQ_FILES)
    files[victim] = data.draw(damaged(files[victim]))
    root = Path(tempfile.mkdtemp(prefix="privslam_fuzz_"))
    try:
        seq_dir = _sequence(root, files)
        img = seq_dir / "image_0"
        if structure == "no_image_folder":
            for p in img.iterdir():
                p.unlink()
            img.rmdir()
        elif structure == "empty_image_folder":
            for p in img.iterdir():
                p.unlink()
        elif structure in ("letters", "negative", "unpadded", "duplicate", "huge_number", "directory_png"):
            name = {"letters": "frame.png", "negative": "-1.png", "unpadded": "10.png", "duplicate": "01.png",
                    "huge_number": "9" * 30 + ".png", "directory_png": "000005.png"}[structure]
            if structure == "directory_png":
                (img / name).mkdir()
            else:
                (img / name).write_bytes(PNG)
        elif structure == "image_2_file":
            (seq_dir / "image_2").write_bytes(b"not a folder")
        size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
        seq = _load(seq_dir, lambda: KittiSequence(seq_dir), size=size, named=root)  # poses live in root/poses
        if seq is not None:
            n = len(seq)
            assert n == len(seq.image_paths) >= 1 and seq.frame_ids.shape == (n,)
            assert np.all(seq.frame_ids[1:] > seq.frame_ids[:-1]) and seq.frame_ids.min() >= 0
            assert seq.timestamps.shape == (n,) and np.all(np.isfinite(seq.timestamps))
            assert np.all(seq.timestamps[1:] > seq.timestamps[:-1])
            cam = seq.camera
            assert cam.fx > 0 and cam.fy > 0 and np.isfinite([cam.fx, cam.fy, cam.cx, cam.cy]).all()
            assert (cam.width, cam.height) == (8, 6)
            assert cam.baseline is None or np.isfinite(cam.baseline)
            if seq.poses is not None:
                assert seq.poses.shape == (n, 4, 4) and np.all(np.isfinite(seq.poses))
            assert all(isinstance(k, int) and isinstance(v, int) for k, v in seq.instance_classes.items())
            try:  # outside tracemalloc: these build JAX arrays
                traj, frame = seq.trajectory, seq[0]
            except InputError as err:
                assert str(root) in str(err) and "\n" not in str(err), str(err)
            else:
                if traj is not None:
                    _check_trajectory(traj, n)
                assert frame.boxes.shape == (frame.class_ids.shape[0], 4) and np.all(np.isfinite(frame.boxes))
    finally:
        import shutil

        shutil.rmtree(root, ignore_errors=True)


def _check_bal(prob):
    C, P, O = prob.n_cameras, prob.n_points, prob.n_observations
    assert C >= 1 and P >= 1 and O >= 1
    assert prob.cameras.shape == (C, 9) and prob.points.shape == (P, 3) and prob.obs_xy.shape == (O, 2)
    assert prob.obs_cam.shape == prob.obs_pt.shape == (O,) and prob.obs_cam.dtype == prob.obs_pt.dtype == np.int32
    assert prob.obs_cam.min() >= 0 and prob.obs_cam.max() < C and prob.obs_pt.min() >= 0 and prob.obs_pt.max() < P
    for a in (prob.cameras, prob.points, prob.obs_xy):
        assert a.dtype == np.float64 and np.all(np.isfinite(a))


_HEADERS = st.tuples(*[st.sampled_from([b"0", b"-3", b"2", b"3", b"4", b"1000000000", b"10" * 40, b"9e9", b"x"])] * 3)


@st.composite
def damaged_bal(draw):
    data = draw(damaged(BAL))
    if draw(st.integers(0, 3)) == 0:  # inflate / break the header counts
        body = data.split(None, 3)[3:] or [b""]
        data = b" ".join(draw(_HEADERS)) + b"\n" + body[0]
    return data


@settings(max_examples=150, **FUZZ)
@given(damaged_bal())
def test_fuzz_bal(data):
    path = _write(data, "problem.txt")
    try:
        prob = _load(path, lambda: read_bal(path))
        if prob is not None:
            _check_bal(prob)
    finally:
        _cleanup(path)


@settings(max_examples=80, **FUZZ)
@given(st.booleans(), st.data())
def test_fuzz_bal_bz2(damage_stream, draw):
    """Damaged text compressed well, or a damaged (truncated, corrupted) bz2 stream of the valid text."""
    if damage_stream:
        data = draw.draw(damaged(bz2.compress(BAL)))
    else:
        data = bz2.compress(draw.draw(damaged_bal()))
    path = _write(data, "problem.bal.txt.bz2")
    try:
        cap = bal_module.MAX_BZ2_RATIO * len(data) + bal_module.BZ2_SLACK
        try:
            text_size = len(bz2.decompress(data))
        except (OSError, EOFError, ValueError):
            text_size = cap  # the reader stops at the cap or the first corrupt block
        prob = _load(path, lambda: read_bal(path), size=max(len(data), min(text_size, cap)))
        if prob is not None:
            _check_bal(prob)
    finally:
        _cleanup(path)


@settings(max_examples=120, **FUZZ)
@given(damaged(LABELS))
def test_fuzz_kitti_object_labels(data):
    path = _write(data, "000042.txt")
    try:
        lab = _load(path, lambda: read_kitti_object_labels(path))
        if lab is not None:
            m = lab.boxes.shape[0]
            assert lab.boxes.shape == (m, 4) and lab.ignored.ndim == 2 and lab.ignored.shape[1] == 4
            assert len(lab.accepted) == len(lab.types) == m and set(lab.types) <= set(KITTI_TYPES)
            for b in (lab.boxes, lab.ignored):
                assert b.dtype == np.float64 and np.all(np.isfinite(b))
                assert np.all(b[:, 2] >= b[:, 0]) and np.all(b[:, 3] >= b[:, 1])
    finally:
        _cleanup(path)


@settings(max_examples=120, **FUZZ)
@given(damaged(YOLO))
def test_fuzz_yolo_labels(data):
    path = _write(data, "000042.txt")
    try:
        out = _load(path, lambda: read_yolo_labels(path))
        if out is not None:
            cls, boxes = out
            k = cls.shape[0]
            assert cls.dtype == np.int32 and cls.shape == (k,) and np.all(cls >= 0)
            assert boxes.dtype == np.float64 and boxes.shape == (k, 4) and np.all(np.isfinite(boxes))
    finally:
        _cleanup(path)


# ------------------------------------------------------------------------------------------------
# Regression tests (each failed before issue 15)

def _refused(read, path):
    """``(InputError, tracemalloc peak)`` of ``read(path)``, which must raise ``InputError``."""
    tracemalloc.start()
    try:
        try:
            read(path)
        except InputError as e:
            err = e
        else:
            raise AssertionError(f"{path} was accepted")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(path) in str(err)
    return err, peak


def test_bal_header_bomb_is_refused_before_allocating(tmp_path):
    """A 10^9-point header in a ~50-byte file: an InputError naming the file, no header-sized array."""
    path = tmp_path / "bomb.bal"
    path.write_bytes(b"1000000000 1000000000 1000000000\n0 0 1.0 2.0\n")
    err, peak = _refused(read_bal, path)
    assert "header promises" in str(err) and peak < 64 * 1024


def test_bal_bz2_bomb_is_refused_without_decompressing_it(tmp_path):
    """94 bytes of bz2 that inflate to 48 MiB: refused after MAX_BZ2_RATIO x its size, within the stated bound
    (the old reader held the whole text, twice)."""
    path = tmp_path / "bomb.bal.bz2"
    path.write_bytes(bz2.compress(b"3 3 3 " + b" " * (48 * MiB), 9))
    err, peak = _refused(read_bal, path)
    assert "decompresses to more than" in str(err)
    assert peak <= _bound(bal_module.MAX_BZ2_RATIO * path.stat().st_size + bal_module.BZ2_SLACK) < 8 * MiB


def test_bal_extreme_indices_are_input_errors(tmp_path):
    """An observation index of 1e300 used to reach an int cast (a RuntimeWarning, garbage index)."""
    path = tmp_path / "p.txt"
    path.write_bytes(BAL.replace(b"\n1 2 -7.5", b"\n1 1e300 -7.5", 1))
    with pytest.raises(InputError, match="point index out of range") as info:
        read_bal(path)
    assert str(path) in str(info.value)


def test_calib_with_letters_is_an_input_error_naming_the_file(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_bytes(CALIB.replace(b"7.188560000000e+02", b"seven", 1))
    with pytest.raises(InputError, match=r"calib\.txt:1: not a number") as info:
        read_calib(path)
    assert str(path) in str(info.value)
    path.write_bytes(CALIB + CALIB.splitlines(keepends=True)[0])
    with pytest.raises(InputError, match="appears twice"):
        read_calib(path)


@pytest.mark.parametrize("reader", ["tum", "kitti", "pose", "yolo", "label_2", "times"])
def test_binary_text_files_are_input_errors(tmp_path, reader):
    """Bytes that are not UTF-8 escaped as UnicodeDecodeError (or a numpy parse error) naming no file."""
    data = b"\xff\xfe\x00garbage\x80\n"
    if reader == "times":
        seq = _sequence(tmp_path, {"calib.txt": CALIB, "times.txt": data})
        with pytest.raises(InputError, match=r"times\.txt"):
            KittiSequence(seq)
        return
    path = tmp_path / "f.txt"
    path.write_bytes(data)
    read = {"tum": read_tum_matrices, "kitti": read_kitti_matrices, "pose": read_pose_matrices,
            "yolo": read_yolo_labels, "label_2": read_kitti_object_labels}[reader]
    with pytest.raises(InputError) as info:
        read(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("reader,text,match", [
    ("yolo", "inf 0.5 0.5 0.1 0.1\n", "class id"),  # was OverflowError from int(inf)
    ("yolo", "nan 0.5 0.5 0.1 0.1\n", "class id"),  # was a ValueError naming no file
    ("yolo", "5e9 0.5 0.5 0.1 0.1\n", "class id"),  # was OverflowError converting to int32
    ("yolo", "0 -1e308 0 1e308 0 1e308 1\n", "NaN or inf"),  # was a RuntimeWarning (overflow)
    ("label_2", "Car 0.00 inf 0 1 2 3 40\n", "occlusion"),  # was OverflowError from int(inf)
    ("kitti", "1 0 0 0 0 1 0 0 0 0 1 0\n0 0 0 0 0 0 0 0 0 0 0 0\n", r"f\.txt:2: the rotation block"),
    ("kitti", "1 0 0 0 0 1 0 0 0 0 -1 0\n", "not a rotation"),
])
def test_values_out_of_range_are_input_errors(tmp_path, reader, text, match):
    path = tmp_path / "f.txt"
    path.write_text(text)
    read = {"kitti": read_kitti_matrices, "yolo": read_yolo_labels, "label_2": read_kitti_object_labels}[reader]
    with pytest.raises(InputError, match=match) as info:
        read(path)
    assert str(path) in str(info.value)


def test_extreme_but_valid_tum_values_load(tmp_path):
    """Timestamps at +-1e308 and a quaternion of 1e200 are valid float64 (they used to overflow with a
    RuntimeWarning); a Trajectory (float32) refuses what it cannot hold, naming the file."""
    path = tmp_path / "t.txt"
    path.write_text("-1e308 0 0 0 0 0 0 1\n1e308 0 0 0 1e200 0 0 1e200\n")
    t, T = read_tum_matrices(path)
    np.testing.assert_array_equal(t, [-1e308, 1e308])
    np.testing.assert_allclose(T[1, :3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    with pytest.raises(InputError, match="range of a Trajectory") as info:
        load_tum(path)
    assert str(path) in str(info.value)


def test_kitti_sequence_folder_errors(tmp_path):
    seq = _sequence(tmp_path, {"calib.txt": CALIB})
    assert len(KittiSequence(seq)) == 3
    for p in (seq / "image_0").iterdir():
        p.unlink()
    with pytest.raises(InputError, match="no PNG frames"):
        KittiSequence(seq)
    (seq / "image_0").rmdir()
    with pytest.raises(InputError, match="not a KITTI sequence folder") as info:
        KittiSequence(seq)
    assert str(seq) in str(info.value)
    (seq / "image_0").mkdir()
    for name in ("000000.png", "9.png", "10.png"):
        (seq / "image_0" / name).write_bytes(PNG)
    s = KittiSequence(seq)  # frames in number order: timestamps increase
    np.testing.assert_array_equal(s.frame_ids, [0, 9, 10])
    (seq / "image_0" / "09.png").write_bytes(PNG)
    with pytest.raises(InputError, match="two files for frame 9"):
        KittiSequence(seq)
    (seq / "image_0" / "09.png").unlink()
    (seq / "image_0" / "-1.png").write_bytes(PNG)
    with pytest.raises(InputError, match="named by number"):
        KittiSequence(seq)


# ------------------------------------------------------------------------------------------------
# CLI

@pytest.mark.parametrize("command", ["lift", "slam"])
def test_cli_maps_input_errors_to_exit_2_and_one_line(tmp_path, capsys, command):
    if command == "lift":
        bad = tmp_path / "problem.bal"
        bad.write_bytes(b"1000000000 3 x\n0 0 1 2\n")
        argv = ["lift", str(bad), "--out", str(tmp_path / "lines.ply")]
    else:
        seq = _sequence(tmp_path, {"calib.txt": b"\x00garbage\xff P0: a b c\n"})
        bad = seq / "calib.txt"
        argv = ["slam", str(seq), "--out", str(tmp_path / "run"), "--no-plots"]
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    assert str(bad) in err and err.startswith(f"privslam {command}: error: ")


def test_pose_file_tells_the_format_apart_as_the_readers_parse_lines(tmp_path):
    """``read_pose_matrices`` counts a line's fields as the readers do (a ``#`` comment after the numbers,
    commas as separators): found by the TUM fuzz test above, where a trailing ``#`` made 9 fields."""
    tum = tmp_path / "t.txt"
    tum.write_text("# t x y z qx qy qz qw\n0.0 1 2 3 0 0 0 1 # first\n0.1,1,2,4,0,0,0,1\n")
    np.testing.assert_array_equal(read_pose_matrices(tum), read_tum_matrices(tum)[1])
    kitti = tmp_path / "k.txt"
    kitti.write_text("1 0 0 0 0 1 0 0 0 0 1 5 #\n")
    np.testing.assert_array_equal(read_pose_matrices(kitti), read_kitti_matrices(kitti))
