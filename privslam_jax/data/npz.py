"""Read ``.npz`` archives without trusting them: every array checked before it is allocated.

``np.load`` on an ``.npz`` is lazy and trusting: a member whose ``.npy`` header claims a huge
shape is allocated before its data is read, a zip member compressed with bzip2/LZMA (or
overlapping other members) can expand without bound, and a damaged archive raises
``BadZipFile``/``zlib.error``/``EOFError`` tracebacks that do not name the file.
:func:`read_npz` reads every array eagerly and raises :class:`~privslam_jax.errors.InputError`
(a ``ValueError``) naming the file instead, for

* a file that is not a zip archive, or a truncated or corrupt one (bad CRC, bad headers);
* members that are encrypted, compressed other than stored/deflate, not ``.npy`` arrays, repeated,
  or whose compressed sizes add up to more than the file;
* a member whose size is more than :data:`MAX_EXPANSION` (1100) times its compressed size (deflate
  cannot expand more than 1032:1), or whose header's ``shape × itemsize`` differs from the
  member's size — checked before the array is allocated;
* object arrays (which ``np.load`` could only read by unpickling): never unpickled.

So the arrays read, together, take at most ``1100 ×`` the file's size. A missing file raises
``FileNotFoundError``. :func:`check_finite` refuses NaN/inf in float arrays.
"""

from __future__ import annotations

import math
import os
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from privslam_jax.errors import InputError, input_error

__all__ = ["MAX_EXPANSION", "check_finite", "check_zip_directory", "read_npz"]

MAX_EXPANSION = 1100
"""Largest accepted ratio of a member's size to its compressed size (deflate's limit is 1032:1)."""

_METHODS = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


def check_zip_directory(path: str | os.PathLike, infos: list[zipfile.ZipInfo], size: int, suffix: str | None = None) -> None:
    """Refuse a zip directory whose members could expand beyond ``MAX_EXPANSION ×`` the file's ``size``.

    Members must be unique, stored or deflated, not encrypted, each at most ``MAX_EXPANSION``
    times its compressed size, their compressed sizes within the file (no overlapping members),
    and (with ``suffix``) named ``*<suffix>``. Raises :class:`~privslam_jax.errors.InputError`.
    """
    names = [i.filename for i in infos]
    if len(set(names)) != len(names):
        raise input_error(path, "the archive holds the same member twice")
    if sum(i.compress_size for i in infos) > size:
        raise input_error(path, "its members' compressed sizes add up to more than the file (overlapping members)")
    for i in infos:
        if suffix is not None and not i.filename.endswith(suffix):
            raise input_error(path, f"member {i.filename[:100]!r} is not a {suffix} file")
        if i.flag_bits & 0x1:
            raise input_error(path, f"member {i.filename[:100]!r} is encrypted")
        if i.compress_type not in _METHODS:
            raise input_error(path, f"member {i.filename[:100]!r} uses compression method {i.compress_type} "
                                    "(only stored and deflate are read)")
        if i.compress_type == zipfile.ZIP_STORED and i.file_size != i.compress_size:
            raise input_error(path, f"member {i.filename[:100]!r}: stored with {i.compress_size} bytes but claims "
                                    f"{i.file_size}")
        if i.file_size > MAX_EXPANSION * max(i.compress_size, 1):
            raise input_error(path, f"member {i.filename[:100]!r} claims {i.file_size} bytes from {i.compress_size} "
                                    f"compressed, more than {MAX_EXPANSION}:1 (corrupt or a zip bomb)")


def _check_header(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    """Read the member's ``.npy`` header (not its data) and check it against the member's size."""
    fmt = np.lib.format
    with zf.open(info) as f, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a Python-2 era header: numpy reads it, and so do we
        version = fmt.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = fmt.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = fmt.read_array_header_2_0(f)
        else:  # 3.0 only for utf-8 field names of structured arrays, never in a checkpoint
            raise input_error(path, f"member {info.filename[:100]!r}: .npy format version {version} is not read")
        header = f.tell()
    name = info.filename[:100]
    if dtype.hasobject:
        raise input_error(path, f"member {name!r} holds Python objects (dtype {dtype}); they would need unpickling "
                                "and are never loaded")
    if any(n < 0 for n in shape):
        raise input_error(path, f"member {name!r} has a negative dimension {shape}")
    count = math.prod(shape)
    if count > info.file_size or header + count * dtype.itemsize != info.file_size:
        raise input_error(path, f"member {name!r}: header claims {shape} {dtype} ({count * dtype.itemsize} bytes) "
                                f"but the member holds {info.file_size - header} bytes of data")


def read_npz(path: str | os.PathLike, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file (or only ``keys``, when present), keyed as ``np.load`` keys
    them (member name without ``.npy``).

    Values are exactly what ``np.load(path, allow_pickle=False)[key]`` returns for a valid file;
    anything else raises :class:`~privslam_jax.errors.InputError` naming the file (module
    docstring), a missing file ``FileNotFoundError``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"npz file not found: {path}")
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            check_zip_directory(path, infos, size, ".npy")
            out: dict[str, np.ndarray] = {}
            for info in infos:
                if keys is not None and info.filename[:-4] not in keys:
                    continue
                _check_header(path, zf, info)
                with zf.open(info) as f, warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)
                    out[info.filename[:-4]] = np.lib.format.read_array(f, allow_pickle=False)
            return out
    except InputError:
        raise
    except (FileNotFoundError, PermissionError, IsADirectoryError, MemoryError):
        raise
    except Exception as err:  # noqa: BLE001 - a file-reader boundary: zipfile and numpy's header parser raise
        # BadZipFile, zlib.error, EOFError, ValueError, struct.error, OSError (EINVAL on offsets a damaged
        # directory computes), tokenize.TokenError (numpy's Python-2 header fallback), ...
        raise input_error(path, f"not a readable .npz archive (truncated or corrupt): {type(err).__name__}: "
                                f"{_one_line(err)}") from err


def check_finite(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """Refuse (:class:`~privslam_jax.errors.InputError` naming ``path``) NaN or inf in any float array."""
    with np.errstate(invalid="ignore"):
        bad = [k for k, v in arrays.items() if np.issubdtype(np.asarray(v).dtype, np.inexact) and not np.isfinite(v).all()]
    if bad:
        raise input_error(path, f"{len(bad)} arrays hold NaN or infinite values, e.g. {bad[0]!r}")
