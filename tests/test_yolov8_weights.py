"""Ultralytics checkpoint import without torch: restricted unpickler, fp16 → fp32, layouts."""

from __future__ import annotations

import os
import pickle
import zipfile
from collections import OrderedDict

import numpy as np
import pytest

from privslam_jax.detect import (
    UnsafeCheckpointError,
    YOLOv8Config,
    count_parameters,
    load_detector,
    model_state_dict,
    read_torch_checkpoint,
    save_checkpoint,
)
from privslam_jax.detect.weights import ultralytics_state_dict
from privslam_jax.detect.yolov8 import init_yolov8


def _zip_with_pickle(path, payload: bytes) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("evil/data.pkl", payload)
        zf.writestr("evil/byteorder", "little")


class _SystemCall:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _Eval:
    def __reduce__(self):
        return (eval, ("__import__('os').getcwd()",))


@pytest.mark.parametrize("protocol", [2, 4])
def test_malicious_checkpoint_is_rejected_before_running(tmp_path, protocol):
    marker = tmp_path / "pwned"
    # Nested inside an otherwise valid-looking checkpoint dict, as an attacker would hide it.
    payload = pickle.dumps({"model": OrderedDict(x=_SystemCall(marker)), "epoch": -1}, protocol=protocol)
    ckpt = tmp_path / "evil.pt"
    _zip_with_pickle(ckpt, payload)
    with pytest.raises(UnsafeCheckpointError, match="system.*not on the allow-list"):
        read_torch_checkpoint(ckpt)
    assert not marker.exists()
    # the same archive unzipped into a folder
    folder = tmp_path / "unzipped"
    zipfile.ZipFile(ckpt).extractall(folder)
    with pytest.raises(UnsafeCheckpointError):
        load_detector(folder)
    assert not marker.exists()


def test_builtins_eval_and_private_stub_names_rejected(tmp_path):
    ckpt = tmp_path / "eval.pt"
    _zip_with_pickle(ckpt, pickle.dumps([_Eval()], protocol=2))
    with pytest.raises(UnsafeCheckpointError, match="eval"):
        read_torch_checkpoint(ckpt)
    # a global under an allowed module prefix but not a plain class name
    payload = b"\x80\x02ctorch.nn.modules.conv\n__getattribute__\nq\x00."
    _zip_with_pickle(ckpt, payload)
    with pytest.raises(UnsafeCheckpointError):
        read_torch_checkpoint(ckpt)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_detector(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a torch zip"):
        read_torch_checkpoint(bad)
    ok = tmp_path / "plain.pt"
    _zip_with_pickle(ok, pickle.dumps({"epoch": 1}, protocol=2))
    with pytest.raises(ValueError, match="not an ultralytics checkpoint"):
        ultralytics_state_dict(read_torch_checkpoint(ok))


@pytest.fixture(scope="module")
def yolov8n(shared):
    path = shared / "weights" / "yolov8n.pt"
    return path, read_torch_checkpoint(path)


def test_real_checkpoint_fp16_to_fp32(yolov8n):
    path, ckpt = yolov8n
    sd, names = ultralytics_state_dict(ckpt)
    assert names[0] == "person" and names[7] == "truck" and len(names) == 80
    params = {k: v for k, v in sd.items() if "running" not in k and "num_batches" not in k}
    assert sum(v.size for v in params.values()) == 3_157_200
    for key, value in params.items():
        assert value.dtype == np.float32, key
        # stored as fp16: every value is exactly representable in half precision
        np.testing.assert_array_equal(value.astype(np.float16).astype(np.float32), value)
    # raw bytes of one storage, read independently of the unpickler (tensor 0 is the stem conv)
    w = sd["model.0.conv.weight"]
    assert w.shape == (16, 3, 3, 3)
    with zipfile.ZipFile(path) as zf:
        raws = [np.frombuffer(zf.read(n), "<f2") for n in zf.namelist() if "/data/" in n]
    assert any(r.size == w.size and np.array_equal(r.astype(np.float32), w.reshape(-1)) for r in raws)


def test_state_dict_round_trip_and_our_checkpoint(yolov8n, tmp_path):
    _, ckpt = yolov8n
    sd, names = ultralytics_state_dict(ckpt)
    out = tmp_path / "ours.npz"
    model = init_yolov8(YOLOv8Config(num_classes=80))
    from privslam_jax.detect import load_state_dict

    load_state_dict(model, sd)
    back = model_state_dict(model)
    assert set(back) == {k for k in sd if not k.endswith("num_batches_tracked")}
    for k, v in back.items():
        np.testing.assert_array_equal(v, sd[k])
    save_checkpoint(model, out, names)
    model2, names2 = load_detector(out)
    assert names2 == names and count_parameters(model2) == 3_157_200
    np.testing.assert_array_equal(np.asarray(model2.detect.cv3[1][2].kernel[...]),
                                  np.asarray(model.detect.cv3[1][2].kernel[...]))


def test_state_dict_shape_mismatch_is_clear(yolov8n):
    sd, _ = ultralytics_state_dict(yolov8n[1])
    model = init_yolov8(YOLOv8Config(num_classes=3))
    from privslam_jax.detect import load_state_dict

    with pytest.raises(ValueError, match=r"model\.22\.cv3\.0\..*: shape .* does not match"):
        load_state_dict(model, sd)


def test_build_opcode_cannot_mutate_allowed_globals(tmp_path):
    from privslam_jax.detect import weights

    # GLOBAL torch._utils._rebuild_parameter; BUILD (None, {"__defaults__": (1,)}) -> setattr on the global
    payload = (b"\x80\x02ctorch._utils\n_rebuild_parameter\n" + b"N}X\x0c\x00\x00\x00__defaults__K\x01\x85s\x86b.")
    ckpt = tmp_path / "build.pt"
    _zip_with_pickle(ckpt, payload)
    read_torch_checkpoint(ckpt)  # mutates only a throwaway wrapper
    assert weights._rebuild_parameter.__defaults__ is None
    payload = b"\x80\x02ctorch\nHalfStorage\nN}X\x05\x00\x00\x00dtypeX\x01\x00\x00\x00Os\x86b."
    _zip_with_pickle(ckpt, payload)
    read_torch_checkpoint(ckpt)
    assert weights._ALLOWED[("torch", "HalfStorage")].dtype == np.float16


def _tensor_pickle(size: int, stride: int) -> bytes:
    """``_rebuild_tensor_v2(storage of 1 float, 0, (size,), (stride,), False)`` as raw protocol-2 opcodes."""
    import struct

    def s(x):
        return b"X" + struct.pack("<I", len(x)) + x.encode()

    pid = b"(" + s("storage") + b"ctorch\nFloatStorage\n" + s("0") + s("cpu") + b"K\x01tQ"
    return (b"\x80\x02ctorch._utils\n_rebuild_tensor_v2\n(" + pid + b"K\x00J" + struct.pack("<i", size) + b"\x85"
            + b"J" + struct.pack("<i", stride) + b"\x85\x89tR.")


@pytest.mark.parametrize("size,stride", [(10**8, 0), (2, -1)])
def test_oversized_or_negative_tensor_views_are_refused_before_allocating(tmp_path, size, stride):
    import tracemalloc

    ckpt = tmp_path / "bomb.pt"
    with zipfile.ZipFile(ckpt, "w") as zf:
        zf.writestr("a/data.pkl", _tensor_pickle(size, stride))
        zf.writestr("a/byteorder", "little")
        zf.writestr("a/data/0", b"\0\0\x80\x3f")
    tracemalloc.start()
    try:
        with pytest.raises(UnsafeCheckpointError, match="tensor view"):
            read_torch_checkpoint(ckpt)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10 * 2**20  # a 400 MB view of a 4-byte storage was copied before
    with zipfile.ZipFile(ckpt, "w") as zf:  # the same opcodes with a sane view load
        zf.writestr("a/data.pkl", _tensor_pickle(1, 1))
        zf.writestr("a/data/0", b"\0\0\x80\x3f")
    assert read_torch_checkpoint(ckpt).tolist() == [1.0]


def test_damaged_checkpoints_are_a_clear_error_naming_the_file(tmp_path):
    """Issue 15 item 9: a truncated zip gave BadZipFile, a CRC-damaged one zlib/BadZipFile, a pickle
    whose BUILD does not apply a TypeError, all as tracebacks. Every damaged variant of a valid
    checkpoint now loads or raises ValueError naming the file."""
    good = tmp_path / "good.pt"
    with zipfile.ZipFile(good, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("a/data.pkl", _tensor_pickle(1, 1))
        zf.writestr("a/byteorder", "little")
        zf.writestr("a/data/0", b"\0\0\x80\x3f" * 64)
    raw = good.read_bytes()
    rng = np.random.default_rng(0)
    variants = [raw[:n] for n in (30, len(raw) // 2, len(raw) - 10)]  # truncated
    for _ in range(40):  # random byte flips
        b = bytearray(raw)
        for i in rng.integers(0, len(b), 3):
            b[i] ^= 0xFF
        variants.append(bytes(b))
    build = b"\x80\x02ctorch\nHalfStorage\nN(K\x01K\x02t\x86b."  # BUILD with a tuple state -> TypeError
    bad = tmp_path / "bad.pt"
    for payload in variants + [None]:
        if payload is None:
            _zip_with_pickle(bad, build)
        else:
            bad.write_bytes(payload)
        try:
            read_torch_checkpoint(bad)
        except ValueError as err:
            assert str(bad) in str(err)
