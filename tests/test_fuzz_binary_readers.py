"""Fuzz suite over the binary file readers (issue 15 item 5): images, PLY, torch ``.pt``, ``.npz``.

Each test starts from a small *valid* file written by the project's own writers (or by OpenCV /
``zipfile`` for formats the project only reads) and damages it: truncation at any byte, bytes
replaced or inserted, random content after the magic, inflated header counts and dimensions.
The property: the reader either returns a well-formed result (shapes, dtypes, finite values) or
raises :class:`~privslam_jax.errors.InputError` whose one-line message contains the file's path.
Any other exception (``BadZipFile``, ``zlib.error``, ``cv2.error``, ``UnpicklingError``,
``KeyError``, a warning turned error, …) fails the test.

Allocation bound (``tracemalloc``: Python and numpy allocations are traced, OpenCV's internal
buffers are not), for a damaged file of ``n`` bytes, peak traced memory during the read is at most

* PLY (``read_ply``): ``64 n + 1 MiB`` (binary takes about ``3 n``, ASCII its lines as strings);
* ``.npz`` (``read_npz``, which every ``.npz`` loader uses): ``1100 n + 1 MiB`` (no member may expand
  more than 1100:1, deflate's own limit being 1032:1; headers are checked before allocating);
* torch ``.pt`` (``read_torch_checkpoint``): ``4 × 1100 n + 2 MiB`` (members ≤ 1100:1, tensors ≤ 3 ×
  their storages);
* images (``read_raw``/``read_image``): ``12 × 8 × 1100 n + 1 MiB`` (at most 8·1100 pixels per file
  byte — a 1-bit PNG —, 12 bytes per float RGB pixel). As OpenCV's own buffers are invisible to
  tracemalloc, crafted bombs (a valid tiny PNG whose IHDR claims 100000×100000 or 16384×16384
  pixels, CRC fixed up) must also be refused from the header, quickly.

Plain regression tests below each failed on the code before this suite (wrong exception type, a
traceback, or an allocation far beyond the file).
"""

from __future__ import annotations

import atexit
import functools
import io
import json
import pickle
import re
import shutil
import struct
import tempfile
import time
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from privslam_jax.data.images import read_image, read_raw, read_rgb8
from privslam_jax.data.npz import read_npz
from privslam_jax.data.ply import (
    load_line_cloud,
    load_point_cloud,
    read_ply,
    save_line_cloud,
    save_point_cloud,
)
from privslam_jax.detect.weights import (
    UnsafeCheckpointError,
    checkpoint_meta,
    load_detector,
    read_torch_checkpoint,
)
from privslam_jax.errors import InputError
from privslam_jax.inpaint.data import CropBank
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig
from privslam_jax.types import LineCloud, PointCloud

MiB = 2**20
FUZZ = settings(max_examples=300, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@functools.cache
def _dir() -> Path:
    """One scratch folder per session (hypothesis tests cannot take function-scoped fixtures)."""
    path = Path(tempfile.mkdtemp(prefix="privslam_fuzz_binary_"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def _check(read, path: Path, validate=None, bound: int | None = None):
    """``read(path)``: a result passed to ``validate``, or InputError naming ``path``; anything else fails.

    With ``bound``, the peak traced allocation must stay below it.
    """
    if bound is not None:
        tracemalloc.start()
    try:
        out = read(path)
    except InputError as err:
        assert str(path) in str(err), f"InputError does not name the file: {err}"
        assert "\n" not in str(err), f"InputError is not one line: {err!r}"
        out = None
    finally:
        if bound is not None:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    if bound is not None:
        assert peak <= bound, f"{read.__name__} allocated {peak} bytes for a {path.stat().st_size}-byte file"
    if out is not None and validate is not None:
        validate(out)
    event(f"{read.__qualname__}: {'loaded' if out is not None else 'InputError'}")
    return out


@st.composite
def _damaged(draw, raw: bytes, head: int = 64) -> bytes:
    """``raw`` truncated, with bytes replaced, inserted or flipped (often in its first ``head`` bytes), or random."""
    kind = draw(st.sampled_from(["truncate", "replace", "replace_head", "insert", "flip", "random"]))
    if kind == "truncate":
        return raw[:draw(st.integers(0, len(raw) - 1))]
    if kind == "random":
        return raw[:draw(st.integers(0, 8))] + draw(st.binary(max_size=2 * len(raw)))
    b = bytearray(raw)
    for _ in range(draw(st.integers(1, 6))):
        top = min(head, len(b)) if kind == "replace_head" else len(b)
        i = draw(st.integers(0, top - 1))
        if kind == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "flip":
            b[i] ^= 1 << draw(st.integers(0, 7))
        else:
            b[i] = draw(st.integers(0, 255))
    return bytes(b)


def _write(name: str, data: bytes) -> Path:
    path = _dir() / name
    path.write_bytes(data)
    return path


# ---------------------------------------------------------------------------------------------- images


def _png_with_ihdr(raw: bytes, width: int, height: int, depth: int | None = None, colour: int | None = None) -> bytes:
    """``raw`` (a PNG) whose IHDR claims other dimensions (and bit depth / colour type), CRC fixed up."""
    ihdr = bytearray(raw[12:29])
    ihdr[4:12] = struct.pack(">II", width, height)
    if depth is not None:
        ihdr[12] = depth
    if colour is not None:
        ihdr[13] = colour
    return raw[:12] + bytes(ihdr) + struct.pack(">I", zlib.crc32(bytes(ihdr))) + raw[33:]


@functools.cache
def _images() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    rgb = (rng.random((12, 16, 3)) * 255).astype(np.uint8)
    out = {}
    for name, img in [("rgb.png", rgb), ("grey16.png", (rng.random((9, 7)) * 65535).astype(np.uint16)),
                      ("rgb.jpg", rgb), ("rgb.bmp", rgb), ("rgb.tif", rgb), ("rgb.webp", rgb), ("grey.pgm", rgb[..., 0])]:
        ok, buf = cv2.imencode(Path(name).suffix, img)
        assert ok
        out[name] = buf.tobytes()
    return out


def _image_bound(n: int) -> int:
    return 12 * 8 * 1100 * n + MiB


def _valid_image(img: np.ndarray) -> None:
    assert img.dtype == np.float32 and img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) > 0
    assert np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1


def _valid_rgb8(img: np.ndarray) -> None:
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3


def _valid_raw(img: np.ndarray) -> None:
    assert isinstance(img, np.ndarray) and img.ndim in (2, 3) and img.size > 0


@FUZZ
@given(data=st.data())
def test_fuzz_images(data):
    name = data.draw(st.sampled_from(sorted(_images())))
    raw = _images()[name]
    if name.endswith(".png") and data.draw(st.booleans()):  # inflate / change the header, CRC fixed
        w = data.draw(st.sampled_from([0, 1, 16, 17, 1000, 16384, 100000, 2**31 - 1]))
        h = data.draw(st.sampled_from([0, 1, 12, 13, 1000, 16384, 100000, 2**31 - 1]))
        bad = _png_with_ihdr(raw, w, h, data.draw(st.sampled_from([None, 1, 2, 4, 8, 16, 3])),
                             data.draw(st.sampled_from([None, 0, 2, 3, 4, 6, 5])))
    else:
        bad = data.draw(_damaged(raw))
    path = _write("fuzz_" + name, bad)
    bound = _image_bound(len(bad))
    _check(read_raw, path, _valid_raw, bound)
    _check(read_image, path, _valid_image, bound)
    _check(read_rgb8, path, _valid_rgb8)


def test_valid_images_still_load_identically(tmp_path):
    for name, raw in _images().items():
        path = tmp_path / name
        path.write_bytes(raw)
        flag = cv2.IMREAD_UNCHANGED
        np.testing.assert_array_equal(read_raw(path), cv2.imread(str(path), flag))
        np.testing.assert_array_equal(read_rgb8(path), cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB))


@pytest.mark.parametrize("width,height", [(100000, 100000), (16384, 16384), (2**31 - 1, 1)])
def test_png_decompression_bomb_is_refused_from_its_header(tmp_path, width, height):
    """A valid tiny PNG whose IHDR (CRC fixed up) claims a huge image: refused before decoding."""
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(_png_with_ihdr(_images()["rgb.png"], width, height))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"bomb\.png.*(decompression bomb)"):
        read_image(bomb)
    with pytest.raises(InputError, match=r"bomb\.png"):
        read_rgb8(bomb)
    assert time.perf_counter() - t0 < 1.0


def test_corrupt_and_foreign_files_are_input_errors(tmp_path):
    png = _images()["rgb.png"]
    for name, raw in [("trunc.png", png[:len(png) // 2]), ("text.png", b"hello, not an image\n"),
                      ("gif.png", b"GIF89a" + bytes(40)), ("empty.png", b"")]:
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(InputError, match=name.replace(".", r"\.")):
            read_image(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="missing.png"):
        read_image(tmp_path / "missing.png")


def test_a_corrupt_frame_of_a_sequence_names_that_file(tmp_path):
    from privslam_jax.data.kitti import KittiSequence

    seq = tmp_path / "sequences" / "00"
    (seq / "image_2").mkdir(parents=True)
    for i in range(3):
        (seq / "image_2" / f"{i:06d}.png").write_bytes(_images()["rgb.png"])
    row = "1 0 8 0 0 1 6 0 0 0 1 0"
    (seq / "calib.txt").write_text("".join(f"P{k}: {row}\n" for k in range(4)))
    bad = seq / "image_2" / "000001.png"
    bad.write_bytes(_images()["rgb.png"][:100])
    kitti = KittiSequence(seq)
    assert kitti[0].image.shape == (12, 16, 3)
    with pytest.raises(InputError, match=r"000001\.png"):
        kitti[1]
    bad.write_bytes(_png_with_ihdr(_images()["rgb.png"], 100000, 100000))
    with pytest.raises(InputError, match=r"000001\.png.*decompression bomb"):
        kitti.image(1)


# ---------------------------------------------------------------------------------------------- PLY


@functools.cache
def _plys() -> dict[str, bytes]:
    rng = np.random.default_rng(1)
    n = 12
    cloud = PointCloud(xyz=jnp.asarray(rng.normal(size=(n, 3)).astype(np.float32)),
                       colors=jnp.asarray(rng.integers(0, 256, (n, 3)) / 255.0, jnp.float32),
                       observations=jnp.asarray(rng.integers(1, 9, n).astype(np.int32)))
    d = rng.normal(size=(6, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lines = LineCloud(directions=jnp.asarray(d, jnp.float32),
                      moments=jnp.asarray(np.cross(rng.normal(size=(6, 3)), d), jnp.float32))
    out = {}
    for binary in (True, False):
        kind = "bin" if binary else "ascii"
        save_point_cloud(_dir() / f"points_{kind}.ply", cloud, binary=binary)
        save_line_cloud(_dir() / f"lines_{kind}.ply", lines, binary=binary)
        out[f"points_{kind}.ply"] = (_dir() / f"points_{kind}.ply").read_bytes()
        out[f"lines_{kind}.ply"] = (_dir() / f"lines_{kind}.ply").read_bytes()
    return out


def _valid_points(p: PointCloud) -> None:
    xyz = np.asarray(p.xyz)
    assert xyz.ndim == 2 and xyz.shape[1] == 3 and np.isfinite(xyz).all()
    if p.colors is not None:
        assert np.asarray(p.colors).shape == xyz.shape and np.isfinite(np.asarray(p.colors)).all()
    if p.observations is not None:
        assert np.asarray(p.observations).shape == (xyz.shape[0],)


def _valid_lines(lines: LineCloud) -> None:
    d, m = np.asarray(lines.directions), np.asarray(lines.moments)
    assert d.ndim == 2 and d.shape[1] == 3 and m.shape == d.shape
    assert np.isfinite(d).all() and np.isfinite(m).all()


def _valid_elements(el: dict) -> None:
    assert all(isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.names is not None for v in el.values())


_PLY_WORDS = ["element", "property", "vertex", "edge", "float", "double", "uchar", "int", "list", "format",
              "ascii", "binary_big_endian", "end_header", "comment", "nan", "inf", "-1", "1e39", "0", "x"]


@FUZZ
@given(data=st.data())
def test_fuzz_ply(data):
    name = data.draw(st.sampled_from(sorted(_plys())))
    raw = _plys()[name]
    header_len = raw.index(b"end_header")
    how = data.draw(st.sampled_from(["bytes", "count", "word"]))
    if how == "count":  # inflate (or shrink) an element count
        count = data.draw(st.sampled_from([0, 1, 7, 13, 10**6, 10**9, 10**18, 10**30]))
        element = data.draw(st.sampled_from([b"vertex", b"edge"]))
        bad = re.sub(rb"element " + element + rb" \d+", b"element %s %d" % (element, count), raw, count=1)
    elif how == "word":  # swap a header or body token for another PLY word or number
        tokens = raw.split(b" ")
        i = data.draw(st.integers(0, len(tokens) - 1))
        tokens[i] = data.draw(st.sampled_from(_PLY_WORDS)).encode()
        bad = b" ".join(tokens)
    else:
        bad = data.draw(_damaged(raw, head=header_len + 11))
    path = _write("fuzz_" + name, bad)
    _check(read_ply, path, _valid_elements, 64 * len(bad) + MiB)
    _check(load_point_cloud, path, _valid_points)
    _check(load_line_cloud, path, _valid_lines)


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_ply_header_counts_larger_than_the_file_are_refused_before_allocating(tmp_path, fmt):
    path = tmp_path / "huge.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex 1000000000\nproperty double x\nproperty double y\n"
                     "property double z\nend_header\n".encode() + b"0 0 0\n" * 4)
    assert path.stat().st_size < 200
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"huge\.ply.*truncated"):
            load_point_cloud(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MiB


def test_ascii_ply_with_many_properties_and_short_rows_allocates_nothing_large(tmp_path):
    """2000 double properties and 20000 one-value rows: the old reader allocated 20000 × 16000 bytes
    (320 MB) for a 80 kB file before finding that row 0 is short."""
    path = tmp_path / "wide.ply"
    props = "".join(f"property double p{i}\n" for i in range(2000))
    path.write_bytes(f"ply\nformat ascii 1.0\nelement vertex 20000\n{props}end_header\n".encode() + b"1\n" * 20000)
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"wide\.ply"):
            read_ply(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * path.stat().st_size + MiB


def test_ply_junk_nan_and_unknown_types_are_input_errors(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    for name, text, match in [
        ("nan.ply", head + "0 0 0\nnan 1 1\n", "NaN or inf"),
        ("junk.ply", head + "0 0 0\n1 2 zzz\n", "cannot parse"),
        ("big.ply", head + "0 0 0\n1e39 1 1\n", "cannot parse"),
        ("type.ply", head.replace("float z", "float128 z") + "0 0 0\n1 1 1\n", "bad property"),
        ("digits.ply", head.replace("vertex 2", "vertex " + "9" * 5000) + "0 0 0\n", "bad element line"),
        ("twice.ply", head.replace("float y", "float x") + "0 0 0\n1 1 1\n", "repeats property"),
    ]:
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match=name.replace(".", r"\.") + ".*" + match):
            load_point_cloud(tmp_path / name)


def test_binary_ply_with_a_signalling_nan_is_an_input_error(tmp_path):
    """Found by the fuzz campaign: float32 0x7FA00000 warned 'invalid value encountered in cast' (an error under pytest)."""
    path = tmp_path / "snan.ply"
    body = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "<f4")
    body.view("<u4")[3] = 0x7FA00000
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                     b"property float z\nend_header\n" + body.tobytes())
    with pytest.raises(InputError, match=r"snan\.ply.*NaN"):
        load_point_cloud(path)
    with pytest.raises(InputError, match=r"snan\.ply.*NaN"):
        load_line_cloud(path)


def test_cli_reports_a_damaged_ply_as_one_line_and_exit_code_2(tmp_path, capsys):
    from privslam_jax.cli import main

    bad = tmp_path / "damaged lines.ply"
    bad.write_bytes(_plys()["lines_bin.ply"][:-5])
    rc = main(["attack", str(bad), "--out", str(tmp_path / "out.ply")])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and str(bad) in err and "truncated" in err
    assert not (tmp_path / "out.ply").exists()


# ---------------------------------------------------------------------------------------------- .npz


@functools.cache
def _npzs() -> dict[str, bytes]:
    path = _dir() / "inpainter.npz"
    Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1, size=32)).save(path)
    out = {"inpainter.npz": path.read_bytes()}
    with np.load(path) as z:  # the same arrays stored uncompressed: mutations reach the .npy headers
        arrays = {k: z[k] for k in z.files}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    out["inpainter_stored.npz"] = buf.getvalue()
    rng = np.random.default_rng(2)
    buf = io.BytesIO()
    np.savez(buf, images=rng.integers(0, 256, (3, 8, 8, 3)).astype(np.uint8), holes=rng.random((3, 8, 8)) < 0.3)
    out["crops.npz"] = buf.getvalue()
    meta = {"num_classes": 2, "scale": "n", "reg_max": 16, "names": {"0": "person"}, "domain": "synthetic", "card": {}}
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(json.dumps(meta)), **{"model.0.conv.weight": rng.normal(size=(16, 3, 3, 3)).astype(np.float32),
                                                            "model.22.cv3.0.2.weight": np.zeros((2, 4, 1, 1), np.float32)})
    out["detector.npz"] = buf.getvalue()
    return out


def _valid_npz(arrays: dict) -> None:
    assert all(isinstance(v, np.ndarray) and not v.dtype.hasobject for v in arrays.values())


def _valid_inpainter(model: Inpainter) -> None:
    import jax

    assert all(np.isfinite(np.asarray(v)).all() for v in jax.tree.leaves(model.state))


def _valid_bank(bank: CropBank) -> None:
    assert bank.images.dtype == np.uint8 and bank.images.ndim == 4 and bank.holes.shape == bank.images.shape[:3]


def _npy(array: np.ndarray, shape: tuple[int, ...] | None = None) -> bytes:
    """``np.save`` bytes of ``array``; with ``shape``, its header claims that shape instead (data unchanged)."""
    buf = io.BytesIO()
    if shape is None:
        np.save(buf, array)
    else:
        header = np.lib.format.header_data_from_array_1_0(array)
        np.lib.format.write_array_header_1_0(buf, {**header, "shape": shape})
        buf.write(np.ascontiguousarray(array).tobytes())
    return buf.getvalue()


def _zip(path: Path | io.BytesIO, members: dict[str, bytes], method: int = zipfile.ZIP_STORED) -> None:
    with zipfile.ZipFile(path, "w", compression=method) as zf:
        for k, v in members.items():
            zf.writestr(k, v)


@functools.cache
def _npz_arrays(name: str) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(_npzs()[name])) as z:
        return {k: z[k] for k in z.files}


@settings(FUZZ, max_examples=200)
@given(data=st.data())
def test_fuzz_npz(data):
    name = data.draw(st.sampled_from(sorted(_npzs())))
    raw = _npzs()[name]
    if data.draw(st.booleans()):  # a member whose header (CRC right) claims another shape
        arrays = _npz_arrays(name)
        key = data.draw(st.sampled_from(sorted(arrays)))
        dims = data.draw(st.sampled_from([(10**9,), (2**62, 4), (2**40, 2**40), (0,), (1,), (-1, 4), (10**5, 10**5),
                                          arrays[key].shape[::-1], (*arrays[key].shape, 1)]))
        buf = io.BytesIO()
        _zip(buf, {f"{k}.npy": _npy(v, dims if k == key else None) for k, v in arrays.items()})
        bad = buf.getvalue()
    else:
        bad = data.draw(_damaged(raw, head=200))
    path = _write("fuzz_" + name, bad)
    _check(read_npz, path, _valid_npz, 1100 * len(bad) + MiB)
    if name.startswith("inpainter"):
        _check(Inpainter.load, path, _valid_inpainter)
    elif name == "crops.npz":
        _check(CropBank.load, path, _valid_bank)
    else:
        _check(load_detector, path)
        _check(checkpoint_meta, path)


def test_npz_member_claiming_a_huge_shape_is_refused_before_allocating(tmp_path):
    """The .npy header (CRCs right) claims 10^9 float64 but holds 8 bytes: np.load allocated 8 GB first."""
    path = tmp_path / "bomb.npz"
    _zip(path, {"images.npy": _npy(np.zeros(1), (10**9,)), "holes.npy": _npy(np.zeros((1, 8, 8), bool))})
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"bomb\.npz.*images.*1000000000"):
            CropBank.load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MiB


def test_zip_bombs_and_damaged_directories_are_refused(tmp_path):
    big = _npy(np.zeros(2**22, np.uint8))  # 4 MB of zeros; bzip2 packs it into ~50 bytes
    path = tmp_path / "bz.npz"
    _zip(path, {"images.npy": big}, zipfile.ZIP_BZIP2)
    with pytest.raises(InputError, match=r"bz\.npz.*compression method"):
        read_npz(path)
    # a deflated member whose directory entry claims more than 1100x its compressed size
    path = tmp_path / "claims.npz"
    _zip(path, {"a.npy": _npy(np.zeros(10))}, zipfile.ZIP_DEFLATED)
    raw = bytearray(path.read_bytes())
    cd = raw.rindex(b"PK\x01\x02")
    raw[cd + 24:cd + 28] = struct.pack("<I", 2**31)  # central directory: uncompressed size
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"claims\.npz.*zip bomb"):
        read_npz(path)
    # the end record puts the directory 1000 bytes later: zipfile seeks to a negative offset (OSError EINVAL)
    path = tmp_path / "offset.npz"
    _zip(path, {"images.npy": _npy(np.zeros((1, 8, 8, 3), np.uint8)), "holes.npy": _npy(np.zeros((1, 8, 8), bool))})
    raw = bytearray(path.read_bytes())
    end = raw.rindex(b"PK\x05\x06")
    raw[end + 16:end + 20] = struct.pack("<I", struct.unpack("<I", raw[end + 16:end + 20])[0] + 1000)
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"offset\.npz.*not a readable"):
        CropBank.load(path)


def test_npy_headers_numpy_cannot_tokenize_are_input_errors(tmp_path):
    """Found by the fuzz campaign: an unbalanced header sends numpy to its Python-2 fallback, whose
    tokenizer raises tokenize.TokenError (not a ValueError)."""
    header = b"{'descr': '<f4', 'fortran_order': False, 'shape': (8,), ("
    header += b" " * (63 - (10 + len(header)) % 64) + b"\n"
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + bytes(32)
    path = tmp_path / "tokens.npz"
    _zip(path, {"images.npy": npy, "holes.npy": _npy(np.zeros((1, 8, 8), bool))})
    with pytest.raises(InputError, match=r"tokens\.npz"):
        CropBank.load(path)


def test_truncated_npz_checkpoints_are_input_errors(tmp_path):
    raw = _npzs()["inpainter.npz"]
    for n in (0, 30, len(raw) // 2, len(raw) - 1):
        path = tmp_path / f"cut{n}.npz"
        path.write_bytes(raw[:n])
        with pytest.raises(InputError, match=rf"cut{n}\.npz"):
            Inpainter.load(path)
    from privslam_jax.detect.predict import EMBEDDED_WEIGHTS

    cut = tmp_path / "detector.npz"
    cut.write_bytes(EMBEDDED_WEIGHTS.read_bytes()[:100_000])
    with pytest.raises(InputError, match=r"detector\.npz"):
        load_detector(cut)
    with pytest.raises(InputError, match=r"detector\.npz"):
        checkpoint_meta(cut)


def test_npz_object_arrays_are_never_unpickled(tmp_path):
    marker = tmp_path / "pwned"

    class _Touch:
        def __reduce__(self):
            return (Path.touch, (marker,))

    buf = io.BytesIO()
    np.save(buf, np.array([_Touch()], dtype=object), allow_pickle=True)
    path = tmp_path / "objects.npz"
    _zip(path, {"images.npy": buf.getvalue(), "holes.npy": _npy(np.zeros((1, 8, 8), bool))})
    for load in (CropBank.load, Inpainter.load, load_detector, read_npz):
        with pytest.raises(InputError, match=r"objects\.npz.*never loaded"):
            load(path)
    assert not marker.exists()


def test_npz_checkpoint_contents_are_checked(tmp_path):
    model = Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1, size=32))
    path = tmp_path / "m.npz"
    model.save(path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    key = next(k for k in arrays if k.endswith("kernel"))
    cases = {
        "nan": {**arrays, key: np.full_like(arrays[key], np.nan)},
        "missing": {k: v for k, v in arrays.items() if k != key},
        "extra": {**arrays, "0.extra.kernel": np.zeros(3, np.float32)},
        "shape": {**arrays, key: arrays[key][..., :1]},
        "dtype": {**arrays, key: arrays[key].astype(np.float64)},
        "width": {**arrays, "config/width": np.asarray(10**9)},  # would build a 10^9-wide network
        "blocks": {**arrays, "config/num_residual_blocks": np.asarray(10**6)},
        "config": {**arrays, "config/sigma": np.asarray("two")},
    }
    for name, content in cases.items():
        bad = tmp_path / f"{name}.npz"
        np.savez(bad, **content)
        with pytest.raises(InputError, match=rf"{name}\.npz"):
            Inpainter.load(bad)
    np.savez(tmp_path / "ok.npz", **arrays)
    back = Inpainter.load(tmp_path / "ok.npz")
    import jax

    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(back.state), jax.tree.leaves(model.state)))


# ---------------------------------------------------------------------------------------------- torch .pt


def _s(text: str) -> bytes:
    return b"X" + struct.pack("<I", len(text)) + text.encode()


def _tensor(key: str, storage: str, numel: int, size: tuple[int, ...]) -> bytes:
    """``_rebuild_tensor_v2(<storage key>, 0, size, contiguous stride, False)`` as protocol-2 opcodes."""
    stride = tuple(int(np.prod(size[i + 1:])) for i in range(len(size)))
    tup = lambda xs: b"(" + b"".join(b"J" + struct.pack("<i", x) for x in xs) + b"t"
    pid = b"(" + _s("storage") + f"ctorch\n{storage}\n".encode() + _s(key) + _s("cpu") + b"J" + struct.pack("<i", numel) + b"tQ"
    return b"ctorch._utils\n_rebuild_tensor_v2\n(" + pid + b"K\x00" + tup(size) + tup(stride) + b"\x89tR"


@functools.cache
def _pt() -> bytes:
    pkl = (b"\x80\x02}(" + _s("w") + _tensor("0", "FloatStorage", 6, (2, 3)) + _s("h") + _tensor("1", "HalfStorage", 4, (4,))
           + _s("names") + b"}" + b"K\x00" + _s("person") + b"su.")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("ckpt/data.pkl", pkl, compress_type=zipfile.ZIP_DEFLATED)
        zf.writestr("ckpt/byteorder", "little")
        zf.writestr("ckpt/data/0", np.arange(6, dtype="<f4").tobytes())
        zf.writestr("ckpt/data/1", np.arange(4, dtype="<f2").tobytes())
    return buf.getvalue()


def test_the_tiny_checkpoint_is_valid(tmp_path):
    path = tmp_path / "tiny.pt"
    path.write_bytes(_pt())
    ck = read_torch_checkpoint(path)
    np.testing.assert_array_equal(ck["w"], np.arange(6, dtype=np.float32).reshape(2, 3))
    assert ck["h"].dtype == np.float32 and ck["h"].tolist() == [0, 1, 2, 3] and ck["names"] == {0: "person"}


@settings(FUZZ, max_examples=200)
@given(data=st.data())
def test_fuzz_torch_checkpoint(data):
    raw = _pt()
    bad = data.draw(_damaged(raw, head=len(raw)))
    path = _write("fuzz.pt", bad)
    _check(read_torch_checkpoint, path, None, 4 * 1100 * len(bad) + 2 * MiB)
    with pytest.raises(InputError, match=r"fuzz\.pt"):  # never an ultralytics model: always refused
        load_detector(path)


def _pt_with_pickle(path: Path, pkl: bytes, storage: bytes = b"\0\0\x80\x3f") -> None:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("a/data.pkl", pkl)
        zf.writestr("a/byteorder", "little")
        zf.writestr("a/data/0", storage)


@pytest.mark.parametrize("pkl", [b"\x80\x04\x8e" + struct.pack("<Q", 2**34) + b"abc.",  # BINBYTES8 of 16 GiB
                                 b"\x80\x02B" + struct.pack("<I", 2**31) + b"abc.",  # BINBYTES of 2 GiB
                                 b"\x80\x04\x96" + struct.pack("<Q", 2**34) + b"abc.",  # BYTEARRAY8
                                 b"\x80\x02Nr" + struct.pack("<I", 10**8) + b"."])  # memo index 10^8: 1.6 GB memo
def test_pickle_counts_beyond_the_data_are_refused_before_the_unpickler_allocates(tmp_path, pkl):
    path = tmp_path / "counts.pt"
    _pt_with_pickle(path, pkl)
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"counts\.pt"):
            read_torch_checkpoint(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * MiB


def test_many_views_of_one_storage_are_refused(tmp_path):
    """256 tensors viewing the same 1 MB storage: 256 MB of copies from a 10 kB file. Tensors may
    take at most 3 × their storages (plus 1 MiB)."""
    n = 2**18
    one = _tensor("0", "FloatStorage", n, (n,))
    # memoize the function (2) and the storage (1); every further tensor rebuilds a view of storage 1
    one = one.replace(b"_rebuild_tensor_v2\n", b"_rebuild_tensor_v2\nq\x02", 1).replace(b"tQ", b"tQq\x01", 1)
    again = b"h\x02(h\x01" + one[one.index(b"q\x01") + 2:]

    def pickle_of(views: int) -> bytes:
        return b"\x80\x02(" + one + again * (views - 1) + b"l."

    path = tmp_path / "views.pt"
    _pt_with_pickle(path, pickle_of(256), bytes(4 * n))
    assert path.stat().st_size < 20_000
    tracemalloc.start()
    try:
        with pytest.raises(UnsafeCheckpointError, match=r"views\.pt.*more memory than its storages"):
            read_torch_checkpoint(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * MiB
    _pt_with_pickle(path, pickle_of(2), bytes(4 * n))  # two views: fine
    assert [a.shape for a in read_torch_checkpoint(path)] == [(n,), (n,)]


def test_unsafe_checkpoint_error_is_an_input_error_naming_the_file(tmp_path):
    path = tmp_path / "evil.pt"
    _pt_with_pickle(path, b"\x80\x02cos\nsystem\n(X\x02\x00\x00\x00lstR.")
    with pytest.raises(UnsafeCheckpointError, match=r"evil\.pt.*os\.system.*allow-list") as info:
        read_torch_checkpoint(path)
    assert isinstance(info.value, InputError) and isinstance(info.value, pickle.UnpicklingError)
