"""Load ultralytics YOLOv8 / YOLO11 checkpoints without torch and without running code from the file.

A torch ``.pt`` file is a zip archive ``<name>/data.pkl`` + ``<name>/data/<key>`` (raw little-endian
tensor storages) + ``<name>/byteorder``. ``data.pkl`` is a pickle whose globals name torch and
ultralytics classes. We read it with :class:`RestrictedUnpickler`, whose ``find_class`` resolves
only an explicit allow-list:

* tensor rebuilding (``torch._utils._rebuild_tensor_v2`` / ``_rebuild_parameter``) → numpy
  arrays (fp16 storages become float32), storage types ``torch.{Half,Float,Double,…}Storage``
  (resolved to inert dtype tags), ``torch.Size`` → ``tuple``, ``collections.OrderedDict``,
  ``builtins.set``, ``_codecs.encode`` (only ``latin1``, as protocol-2 pickles store bytes);
* module classes under :data:`STUB_MODULE_PREFIXES` (``ultralytics.nn.*``, ``torch.nn.modules.*``)
  → inert :class:`ModuleStub` subclasses that only record their pickled state. ultralytics and
  torch are never imported.

Any other global (``os.system``, ``builtins.eval``, ``subprocess.*``…) raises
:class:`UnsafeCheckpointError` *before* it could be called: pickle resolves a global when the
``GLOBAL``/``STACK_GLOBAL`` opcode is read, ahead of the ``REDUCE`` that would call it.
Persistent ids ``("storage", type, key, location, numel)`` are mapped to the raw storages.

The architecture and scale are read off the ``state_dict`` (:func:`detect_architecture`):
YOLO11 has a ``C2PSA`` attention block at index 10 and its ``Detect`` at 23, YOLOv8 its ``Detect``
at 22; the stem width and the number of blocks in layer 2 give the scale. Segmentation, pose, OBB,
classification and end-to-end heads are refused with the reason.

The same format is used for our own inference checkpoints (:func:`save_checkpoint`): an ``.npz``
holding the ultralytics-style ``state_dict`` plus a JSON config (with ``"arch"``, ``"yolov8"``
when absent), so one key mapping serves both.
"""

from __future__ import annotations

import collections
import io
import json
import math
import pickle
import pickletools
import zipfile
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from flax import nnx

from privslam_jax.data.npz import check_finite, check_zip_directory, read_npz
from privslam_jax.detect.yolo11 import YOLO11Config, abstract_yolo11
from privslam_jax.detect.yolov8 import YOLOv8, YOLOv8Config, abstract_yolov8
from privslam_jax.errors import InputError, input_error

__all__ = [
    "UnsafeCheckpointError",
    "RestrictedUnpickler",
    "ModuleStub",
    "read_torch_checkpoint",
    "ultralytics_state_dict",
    "load_state_dict",
    "model_state_dict",
    "load_ultralytics",
    "load_detector",
    "detect_architecture",
    "save_checkpoint",
    "checkpoint_meta",
    "DOMAINS",
]

STUB_MODULE_PREFIXES: tuple[str, ...] = ("ultralytics.nn.", "torch.nn.modules.")
"""Modules whose classes are replaced by inert :class:`ModuleStub` subclasses."""

_STORAGE_DTYPES: dict[str, np.dtype] = {
    "HalfStorage": np.dtype("<f2"), "FloatStorage": np.dtype("<f4"), "DoubleStorage": np.dtype("<f8"),
    "LongStorage": np.dtype("<i8"), "IntStorage": np.dtype("<i4"), "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"), "ByteStorage": np.dtype("u1"), "BoolStorage": np.dtype("?"),
}


class UnsafeCheckpointError(pickle.UnpicklingError, InputError):
    """The checkpoint pickle references something outside the allow-list (or would allocate more than the file holds)."""


class _StorageType:
    """Inert stand-in for ``torch.<X>Storage``: only carries the numpy dtype."""

    def __init__(self, name: str):
        self.name, self.dtype = name, _STORAGE_DTYPES[name]

    def __repr__(self) -> str:
        return f"torch.{self.name}"


class ModuleStub:
    """Inert stand-in for a pickled torch/ultralytics module: records state, runs nothing."""

    qualname: str = "?"

    def __init__(self, *args: object, **kwargs: object):
        self.args, self.kwargs = args, kwargs

    def __setstate__(self, state: object) -> None:
        self.state = state

    def __repr__(self) -> str:
        return f"<stub {self.qualname}>"


class _Budget:
    """Bytes the tensors of one checkpoint may still take (views of a storage are copied)."""

    def __init__(self, limit: int):
        self.left = limit

    def take(self, nbytes: int) -> None:
        self.left -= nbytes
        if self.left < 0:
            raise UnsafeCheckpointError("the checkpoint's tensors would take more memory than its storages hold "
                                        "(many views of the same storage)")


def _rebuild_tensor_v2(storage: np.ndarray, offset: int, size: tuple, stride: tuple, *_: object,
                       _budget: _Budget | None = None) -> np.ndarray:
    if not isinstance(storage, np.ndarray):
        raise UnsafeCheckpointError(f"tensor storage is a {type(storage).__name__}, not a storage")
    if (not isinstance(size, tuple) or not isinstance(stride, tuple) or len(size) != len(stride)
            or not all(isinstance(v, int) and v >= 0 for v in (offset, *size, *stride))):
        raise UnsafeCheckpointError(f"tensor view size {size!r} / stride {stride!r} / offset {offset!r} is malformed")
    n = math.prod(size)
    if n > storage.size:  # a view larger than its storage (e.g. stride 0) would allocate more than the file holds
        raise UnsafeCheckpointError(f"tensor view {size}/{stride} has {n} elements, more than its storage ({storage.size})")
    if _budget is not None:
        _budget.take(n * storage.dtype.itemsize * (3 if storage.dtype == np.float16 else 1))  # fp16 copy + fp32
    if n == 0:
        out = np.zeros(size, storage.dtype)
    else:
        extent = offset + 1 + sum((s - 1) * st for s, st in zip(size, stride))
        if offset < 0 or extent > storage.size or any(st < 0 for st in stride):
            raise UnsafeCheckpointError(f"tensor view {size}/{stride}+{offset} exceeds its storage ({storage.size})")
        item = storage.dtype.itemsize
        out = np.lib.stride_tricks.as_strided(storage[offset:], size, tuple(st * item for st in stride)).copy()
    return out.astype(np.float32) if out.dtype == np.float16 else out


def _rebuild_parameter(data: np.ndarray, *_: object) -> np.ndarray:
    return data


def _codecs_encode(text: str, encoding: str = "utf-8") -> bytes:
    if encoding != "latin1" or not isinstance(text, str):
        raise UnsafeCheckpointError(f"_codecs.encode only allowed with latin1 text, got {encoding!r}")
    return text.encode("latin1")


_ALLOWED: dict[tuple[str, str], object] = {
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    ("torch._utils", "_rebuild_parameter"): _rebuild_parameter,
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch", "Size"): tuple,
    ("builtins", "set"): set,
    ("__builtin__", "set"): set,
    ("_codecs", "encode"): _codecs_encode,
    **{("torch", name): _StorageType(name) for name in _STORAGE_DTYPES},
}


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickler for torch zip checkpoints that resolves only allow-listed globals.

    ``storages(key, dtype, numel)`` returns the raw storage ``key`` as a 1-D numpy array.
    ``max_tensor_bytes`` bounds the memory all rebuilt tensors take together
    (:class:`UnsafeCheckpointError` beyond it).
    """

    def __init__(self, file: io.BufferedIOBase, storages, max_tensor_bytes: int | None = None):
        super().__init__(file)
        self._storages = storages
        self._stubs: dict[str, type] = {}
        self._budget = None if max_tensor_bytes is None else _Budget(max_tensor_bytes)

    def find_class(self, module: str, name: str) -> object:
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            budget = self._budget
            return lambda *args: _rebuild_tensor_v2(*args, _budget=budget)
        if (module, name) in _ALLOWED:
            target = _ALLOWED[(module, name)]
            # Fresh objects per lookup: a pickle BUILD opcode on a returned global (e.g. setting
            # attributes of a function) then cannot alter this module's state for later loads.
            if isinstance(target, _StorageType):
                return _StorageType(target.name)
            if callable(target) and not isinstance(target, type):
                return lambda *args, **kwargs: target(*args, **kwargs)
            return target
        if module.startswith(STUB_MODULE_PREFIXES) and name.isidentifier() and not name.startswith("_"):
            qual = f"{module}.{name}"
            if qual not in self._stubs:
                self._stubs[qual] = type(name, (ModuleStub,), {"qualname": qual})
            return self._stubs[qual]
        raise UnsafeCheckpointError(
            f"checkpoint references {module}.{name}, which is not on the allow-list of a YOLOv8 "
            "checkpoint; refusing to load it (it could run arbitrary code)"
        )

    def persistent_load(self, pid: object) -> np.ndarray:
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"
                and isinstance(pid[1], _StorageType)):
            raise UnsafeCheckpointError(f"unexpected persistent id {pid!r}")
        _, stype, key, _location, numel = pid
        return self._storages(str(key), stype.dtype, int(numel))


def _open_archive(path: Path):
    """``(read(relpath) -> bytes, storage_bytes)`` for a torch zip or its unzipped folder.

    ``storage_bytes`` is the total size of the ``data/*`` storages (it bounds the tensors).
    """
    if path.is_dir():
        candidates = [path] if (path / "data.pkl").is_file() else sorted(p.parent for p in path.glob("*/data.pkl"))
        if len(candidates) != 1:
            raise FileNotFoundError(f"{path}: expected one data.pkl (an unzipped torch checkpoint), found {len(candidates)}")
        root = candidates[0]

        def read(rel: str) -> bytes:
            f = root / rel
            if not f.is_file():
                raise FileNotFoundError(f"{path}: missing {rel} in the unzipped checkpoint")
            return f.read_bytes()

        data = root / "data"
        return read, sum(f.stat().st_size for f in data.iterdir() if f.is_file()) if data.is_dir() else 0
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    if not zipfile.is_zipfile(path):
        raise input_error(path, "not a torch zip checkpoint (legacy pickle .pt files are not supported)")
    zf = zipfile.ZipFile(path)
    infos = zf.infolist()
    check_zip_directory(path, infos, path.stat().st_size)  # no member may expand beyond 1100x its bytes
    pkls = [n for n in zf.namelist() if n.endswith("data.pkl") and n.count("/") == 1]
    if len(pkls) != 1:
        raise input_error(path, f"expected one <name>/data.pkl in the archive, found {pkls[:4]}")
    prefix = pkls[0][: -len("data.pkl")]

    def read_zip(rel: str) -> bytes:
        try:
            return zf.read(prefix + rel)
        except KeyError:
            raise input_error(path, f"archive lacks {prefix + rel}") from None

    return read_zip, sum(i.file_size for i in infos if i.filename.startswith(prefix + "data/"))


def _check_pickle(path: Path, data: bytes) -> None:
    """Walk the pickle's opcodes without building anything: refuse what would make the C
    unpickler allocate beyond the data (a byte count larger than what follows it — CPython 3.11's
    unpickler allocates the count before reading — or a memo index far beyond the pickle's length)."""
    try:
        for op, arg, _ in pickletools.genops(data):  # a counted argument that the data lacks raises here
            if op.name in ("PUT", "BINPUT", "LONG_BINPUT") and not (isinstance(arg, int) and 0 <= arg <= len(data)):
                raise input_error(path, f"pickle memo index {arg} is beyond the pickle's {len(data)} bytes")
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - pickletools reports malformed opcodes with any of several types
        raise input_error(path, "data.pkl is not a readable pickle", err) from err


def read_torch_checkpoint(path: str | Path) -> object:
    """Unpickle a torch zip checkpoint (file or unzipped folder) safely; tensors → numpy.

    A damaged file (truncated or corrupt archive, a pickle that does not build) raises
    :class:`~privslam_jax.errors.InputError` naming the file, never a traceback from ``zipfile``,
    ``zlib`` or ``pickle``; a pickle that names anything outside the allow-list
    :class:`UnsafeCheckpointError` (an ``InputError`` too), also naming the file. Memory stays
    within a multiple of the file: every zip member at most 1100 times its compressed bytes
    (:func:`~privslam_jax.data.npz.check_zip_directory`), each storage read once, the pickle
    checked for counts beyond its data before unpickling (:func:`_check_pickle`) and all tensors
    together at most ``3 ×`` the storages' bytes plus 1 MiB.
    """
    path = Path(path)
    try:
        return _read_torch_checkpoint(path)
    except InputError as err:
        if str(path) in str(err):
            raise
        raise type(err)(f"{path}: {err}") from err  # the unpickler does not know the file; keep the type
    except (FileNotFoundError, PermissionError):
        raise
    except Exception as err:  # noqa: BLE001 - a file-reader boundary: any library failure is a bad file
        raise input_error(path, "not a readable torch checkpoint", err) from err


def _read_torch_checkpoint(path: Path) -> object:
    read, storage_bytes = _open_archive(path)
    try:
        order = read("byteorder").decode().strip()
    except (FileNotFoundError, ValueError):
        order = "little"
    if order != "little":
        raise input_error(path, "big-endian checkpoints are not supported")
    cache: dict[str, bytes] = {}

    def storages(key: str, dtype: np.dtype, numel: int) -> np.ndarray:
        if key not in cache:  # a storage shared by many tensors is read once
            cache[key] = read(f"data/{key}")
        raw = cache[key]
        if len(raw) < numel * dtype.itemsize:
            raise input_error(path, f"storage {key} has {len(raw)} bytes, expected {numel * dtype.itemsize}")
        return np.frombuffer(raw, dtype=dtype, count=numel)

    pkl = read("data.pkl")
    _check_pickle(path, pkl)
    return RestrictedUnpickler(io.BytesIO(pkl), storages, max_tensor_bytes=3 * storage_bytes + 2**20).load()


def _module_state(stub: object, prefix: str, out: dict[str, np.ndarray]) -> None:
    state = getattr(stub, "state", None)
    if not isinstance(state, dict):
        return
    for group in ("_parameters", "_buffers"):
        for name, value in (state.get(group) or {}).items():
            if isinstance(value, np.ndarray):
                out[prefix + name] = value
    for name, child in (state.get("_modules") or {}).items():
        _module_state(child, f"{prefix}{name}.", out)


def ultralytics_state_dict(checkpoint: object) -> tuple[dict[str, np.ndarray], dict[int, str]]:
    """``(state_dict, class names)`` of the model in an unpickled ultralytics checkpoint.

    Uses ``ckpt["ema"]`` when present, else ``ckpt["model"]``, as ultralytics does.
    """
    if not isinstance(checkpoint, dict) or not ({"model", "ema"} & checkpoint.keys()):
        raise ValueError("not an ultralytics checkpoint: expected a dict with a 'model' entry")
    model = checkpoint.get("ema") or checkpoint.get("model")
    if not isinstance(model, ModuleStub):
        raise ValueError(f"checkpoint 'model' entry is a {type(model).__name__}, not a module")
    sd: dict[str, np.ndarray] = {}
    _module_state(model, "", sd)
    if not sd:
        raise ValueError("checkpoint model has no parameters")
    names = model.state.get("names") if isinstance(model.state, dict) else None
    names = {int(k): str(v) for k, v in (names or {}).items()} if isinstance(names, dict) else {}
    return sd, names


_ARCHS: dict[str, tuple[type[YOLOv8Config], int, int]] = {"yolov8": (YOLOv8Config, 22, 3), "yolo11": (YOLO11Config, 23, 2)}
"""``arch -> (config class, index of Detect, yaml repeats of layer 2)``."""

_OTHER_HEADS: dict[str, str] = {"proto": "a segmentation", "cv4": "a pose / OBB / segmentation", "cv5": "a segmentation",
                                "one2one_cv2": "an end-to-end (NMS-free)", "linear": "a classification"}
"""Sub-modules whose presence marks a head other than plain detection."""


def detect_architecture(sd: Mapping[str, np.ndarray]) -> YOLOv8Config:
    """The config (:class:`YOLOv8Config` or :class:`~privslam_jax.detect.yolo11.YOLO11Config`) of a ``state_dict``.

    YOLO11 is recognised by its C2PSA attention (``model.10.m.0.attn``) and a ``Detect`` at index 23,
    YOLOv8 by a ``Detect`` at 22; ``nc`` and ``reg_max`` come from the head's last 1×1 convs, the scale
    from the stem width and the number of blocks in layer 2. Anything else raises ``ValueError``.
    """
    layers = {int(k.split(".")[1]) for k in sd if k.startswith("model.") and k.split(".")[1].isdigit()}
    if not layers:
        raise ValueError("state_dict has no ultralytics 'model.<i>.' keys")
    last = max(layers)  # the head is the last module
    for part, kind in _OTHER_HEADS.items():
        if any(k.startswith(f"model.{last}.{part}.") for k in sd):
            raise ValueError(f"state_dict has {kind} head (model.{last}.{part}); only detection models "
                             "(YOLOv8 / YOLO11 Detect) are supported")
    if any(k.startswith("model.10.m.0.attn.") for k in sd):
        arch = "yolo11"
    elif any(k.startswith("model.22.cv3.") for k in sd) and not any(k.startswith("model.23.") for k in sd):
        arch = "yolov8"
    else:
        raise ValueError("state_dict is neither a YOLOv8 (Detect at model.22) nor a YOLO11 (C2PSA at model.10, "
                         f"Detect at model.23) detector; its layers: {sorted(layers)}")
    config_cls, head, repeats = _ARCHS[arch]
    try:
        width = sd["model.0.conv.weight"].shape[0]
        nc = sd[f"model.{head}.cv3.0.2.weight"].shape[0]
        reg_max = sd[f"model.{head}.cv2.0.2.weight"].shape[0] // 4
    except KeyError as err:
        raise ValueError(f"state_dict is not a {arch} detector (missing {err})") from None
    depth = len({k.split(".")[3] for k in sd if k.startswith("model.2.m.")})
    for scale in config_cls.scales:
        cfg = config_cls(num_classes=nc, scale=scale, reg_max=reg_max)
        if cfg.channels(64) == width and cfg.depth(repeats) == depth:
            return cfg
    raise ValueError(f"no {arch} scale has stem width {width} and {depth} blocks in layer 2")


def _variable(model: YOLOv8, key: str) -> nnx.Variable | None:
    """The NNX variable for an ultralytics ``state_dict`` key (``None`` for skipped buffers)."""
    parts = key.split(".")
    names = model.torch_layer_names
    if len(parts) < 3 or parts[0] != "model" or not parts[1].isdigit() or int(parts[1]) not in names:
        raise ValueError(f"unexpected state_dict key {key!r}")
    leaf = parts[-1]
    if leaf == "num_batches_tracked" or parts[2] == "dfl":
        return None
    node: object = getattr(model, names[int(parts[1])])
    for p in parts[2:-1]:
        if p.isdigit():
            node = node[int(p)] if isinstance(node, nnx.List) and int(p) < len(node) else None
        else:
            node = getattr(node, p, None)
        if node is None:
            raise ValueError(f"state_dict key {key!r} does not exist in the model")
    names = {"bn": {"weight": "scale", "bias": "bias", "running_mean": "mean", "running_var": "var"}}
    attr = names["bn"].get(leaf) if isinstance(node, nnx.BatchNorm) else {"weight": "kernel", "bias": "bias"}.get(leaf)
    var = getattr(node, attr, None) if attr else None
    if not isinstance(var, nnx.Variable):
        raise ValueError(f"state_dict key {key!r} does not exist in the model")
    return var


def load_state_dict(model: YOLOv8, sd: Mapping[str, np.ndarray]) -> None:
    """Copy an ultralytics-layout ``state_dict`` into ``model`` in place (strict: every variable set).

    Conv weights ``(O, I, kh, kw)`` become HWIO kernels; BatchNorm ``weight/bias/running_mean/
    running_var`` become ``scale/bias/mean/var``. The DFL conv must hold ``0..reg_max-1``.
    """
    filled: set[int] = set()
    for key, value in sd.items():
        arr = np.asarray(value, dtype=np.float32)
        if key.endswith("dfl.conv.weight"):
            if not np.array_equal(arr.reshape(-1), np.arange(model.config.reg_max, dtype=np.float32)):
                raise ValueError(f"{key} is not the fixed DFL projection 0..{model.config.reg_max - 1}")
            continue
        var = _variable(model, key)
        if var is None:
            continue
        if arr.ndim == 4:
            arr = arr.transpose(2, 3, 1, 0)
        if arr.shape != var.get_value().shape:
            raise ValueError(f"{key}: shape {arr.shape} does not match the model's {var.get_value().shape}")
        var.set_value(jnp.asarray(arr))
        filled.add(id(var))
    missing = [
        "/".join(map(str, path))
        for path, var in nnx.iter_graph(model) if isinstance(var, (nnx.Param, nnx.BatchStat)) and id(var) not in filled
    ]
    if missing:
        raise ValueError(f"state_dict lacks {len(missing)} model variables, e.g. {missing[:3]}")


def model_state_dict(model: YOLOv8) -> dict[str, np.ndarray]:
    """The ultralytics-layout ``state_dict`` of ``model`` (inverse of :func:`load_state_dict`)."""
    inverse = {v: k for k, v in model.torch_layer_names.items()}
    bn = {"scale": "weight", "bias": "bias", "mean": "running_mean", "var": "running_var"}
    out: dict[str, np.ndarray] = {}
    for path, var in nnx.iter_graph(model):
        if not isinstance(var, (nnx.Param, nnx.BatchStat)):
            continue
        parts = [str(p) for p in path]
        if parts[-2] == "bn":
            leaf = bn[parts[-1]]
        else:
            leaf = "weight" if parts[-1] == "kernel" else parts[-1]
        arr = np.asarray(var.get_value())
        if arr.ndim == 4:
            arr = arr.transpose(3, 2, 0, 1)
        out[".".join(["model", str(inverse[parts[0]]), *parts[1:-1], leaf])] = arr
    r = model.config.reg_max
    out[f"model.{inverse['detect']}.dfl.conv.weight"] = np.arange(r, dtype=np.float32).reshape(1, r, 1, 1)
    return out


def _build(sd: Mapping[str, np.ndarray], arch: str | None = None) -> YOLOv8:
    config = detect_architecture(sd)
    if arch is not None and arch != config.arch:
        raise ValueError(f"checkpoint says arch {arch!r} but its weights are a {config.arch} network")
    model = abstract_yolo11(config) if isinstance(config, YOLO11Config) else abstract_yolov8(config)
    load_state_dict(model, sd)
    model.eval()
    return model


def load_ultralytics(path: str | Path) -> tuple[YOLOv8, dict[int, str]]:
    """Build a YOLOv8 or :class:`~privslam_jax.detect.yolo11.YOLO11` (eval mode) from an ultralytics ``.pt``.

    Zip file or unzipped folder; architecture and scale from :func:`detect_architecture`.

    Returns the model and the class names stored in the checkpoint. A file that is not a usable
    detector checkpoint raises :class:`~privslam_jax.errors.InputError` naming it.
    """
    ckpt = read_torch_checkpoint(path)
    try:
        sd, names = ultralytics_state_dict(ckpt)
    except ValueError as err:
        raise input_error(path, "not a usable ultralytics checkpoint", err) from err
    return _build_from_file(path, sd), names


def _build_from_file(path: str | Path, sd: Mapping[str, np.ndarray], arch: str | None = None) -> YOLOv8:
    """:func:`_build`, with every way the arrays can be wrong an ``InputError`` naming ``path``."""
    bad = [k for k, v in sd.items() if not isinstance(v, np.ndarray) or v.dtype.kind not in "biuf"]
    if bad:
        raise input_error(path, f"state_dict entry {bad[0]!r} is not a number array")
    check_finite(path, sd)
    try:
        return _build(sd, arch)
    except (ValueError, IndexError, KeyError, TypeError) as err:
        raise input_error(path, "not a usable detector checkpoint", err) from err


def _npz_meta(path: Path, data: Mapping[str, np.ndarray]) -> dict:
    """The JSON ``__meta__`` of one of our detector ``.npz`` files, checked."""
    if "__meta__" not in data:
        raise input_error(path, "not a privslam detector checkpoint (no __meta__)")
    raw = data["__meta__"]
    if raw.dtype.kind != "U" or raw.size != 1:
        raise input_error(path, f"__meta__ is a {raw.dtype} {raw.shape} array, not a JSON string")
    try:
        meta = json.loads(str(raw))
    except ValueError as err:
        raise input_error(path, "__meta__ is not valid JSON", err) from err
    if not isinstance(meta, dict):
        raise input_error(path, f"__meta__ is a JSON {type(meta).__name__}, not an object")
    names = meta.get("names", {})
    if not isinstance(names, dict) or not all(k.lstrip("-").isdecimal() and len(k) < 10 and isinstance(v, str)
                                              for k, v in names.items()):
        raise input_error(path, "__meta__ 'names' must map class ids to names")
    if not isinstance(meta.get("arch", "yolov8"), str) or not isinstance(meta.get("card", {}), dict):
        raise input_error(path, "__meta__ 'arch' must be a string and 'card' an object")
    return meta


DOMAINS: tuple[str, ...] = ("synthetic", "real", "unknown")
"""What a detector was trained on: the synthetic world only, real photographs, or not recorded."""


def save_checkpoint(model: YOLOv8, path: str | Path, names: Mapping[int, str] | None = None,
                    domain: str = "unknown", card: Mapping[str, object] | None = None) -> None:
    """Write an inference checkpoint ``.npz``: ultralytics-layout arrays plus config and names.

    ``domain`` (one of :data:`DOMAINS`) records what the network was trained on; ``card`` holds
    measured facts worth carrying with the weights (e.g. ``{"real_recall": {...}}``, see
    :func:`checkpoint_meta`). Both are JSON in the ``__meta__`` entry.
    """
    if domain not in DOMAINS:
        raise ValueError(f"domain must be one of {DOMAINS}, got {domain!r}")
    meta = {"num_classes": model.config.num_classes, "scale": model.config.scale,
            "reg_max": model.config.reg_max, "names": {str(k): v for k, v in (names or {}).items()},
            "domain": domain, "card": dict(card or {})}
    meta["arch"] = model.config.arch
    from privslam_jax.data.files import write_npz

    path = Path(path)
    if path.suffix != ".npz":  # np.savez's naming, kept
        path = path.with_name(path.name + ".npz")
    write_npz(path, __meta__=np.array(json.dumps(meta)), **model_state_dict(model))


def checkpoint_meta(path: str | Path) -> dict:
    """``{"domain", "card", ...}`` of a detector checkpoint, without loading the weights.

    Our ``.npz`` files carry them (files written before the field existed read as
    ``"unknown"``); an ultralytics ``.pt`` is a network trained on real photographs (COCO or the
    user's own data): ``{"domain": "real", "card": {"source": "ultralytics"}}``.
    """
    path = Path(path)
    if path.suffix != ".npz":
        return {"domain": "real", "card": {"source": "ultralytics"}}
    if not path.is_file():
        raise FileNotFoundError(f"detector weights not found: {path}")
    meta = _npz_meta(path, read_npz(path, keys=("__meta__",)))
    meta.setdefault("domain", "unknown")
    meta.setdefault("card", {})
    if not isinstance(meta["domain"], str) or meta["domain"] not in DOMAINS:
        raise input_error(path, f"unknown detector domain {meta['domain']!r} (expected one of {DOMAINS})")
    return meta


def load_detector(path: str | Path) -> tuple[YOLOv8, dict[int, str]]:
    """Load weights from our ``.npz`` checkpoint or an ultralytics ``.pt`` (file or folder).

    A damaged or unusable file (corrupt archive, wrong or missing arrays, wrong shapes or dtypes,
    NaN weights, a bad ``__meta__``) raises :class:`~privslam_jax.errors.InputError` naming it;
    a missing one ``FileNotFoundError``.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"detector weights not found: {path}")
    if path.suffix == ".npz":
        data = read_npz(path)
        meta = _npz_meta(path, data)
        sd = {k: v for k, v in data.items() if k != "__meta__"}
        return _build_from_file(path, sd, meta.get("arch", "yolov8")), {int(k): v for k, v in meta.get("names", {}).items()}
    return load_ultralytics(path)
