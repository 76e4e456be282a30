"""PLY input/output for point clouds and line clouds (no dependency beyond numpy).

Format (http://paulbourke.net/dataformats/ply/): a text header followed by the element data,
either ``ascii`` or ``binary_little_endian`` (``binary_big_endian`` is read, never written).
Only scalar properties are supported (list properties, as in mesh faces, raise a clear error).

* **Point cloud**: element ``vertex`` with ``x y z`` (``float`` for float32 input, ``double``
  otherwise), optional ``red green blue`` (``uchar``; colours in ``[0, 1]`` are stored as
  ``round(255·c)``), optional ``nx ny nz`` (the points' unit mean viewing directions, the type of
  ``x``) and optional ``observations`` (``int``).
* **Descriptors** (both kinds of cloud, optional): element ``descriptor`` with one row per point
  or line and ``uchar`` properties ``b0 … b{D-1}`` (a SLAM map's 32-byte ORB descriptors), row
  ``i`` for point or line ``i``.  Readers that do not know the element skip it.
* **Line cloud**: line ``i`` is the segment from vertex ``2i`` to vertex ``2i+1`` plus the
  element ``edge`` row ``i`` = ``(vertex1, vertex2) = (2i, 2i+1)``.  The exported segment is the
  *canonical* unit segment: it starts at the line's closest point to the origin ``c = d × m``
  and ends at ``c + d``.  It therefore carries nothing but the line (DESIGN §5.4): a segment
  centred on the original point would bound the recovery error by 0.5 m.
  Reading accepts any segments (edges if present, else consecutive vertex pairs) and turns
  them into Plücker coordinates ``d = (b − a)/‖b − a‖, m = a × d``.

Writing uses numpy structured arrays: ``tofile`` for binary, ``savetxt`` for ASCII.

Reading refuses, with an :class:`~privslam_jax.errors.InputError` (a ``ValueError``) naming the
file, anything it cannot use: no ``ply`` magic or ``end_header``, an unknown format, keyword or
property type, element counts larger than the file can hold (checked before anything is
allocated), a truncated body, ASCII rows with the wrong number of values or junk, values out of
their type's range, and NaN/inf coordinates (or float colours). A missing file raises
``FileNotFoundError``. Memory: a binary file is read with at most about 3 times its size, an ASCII
file with at most about 40 times (its lines as Python strings).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from privslam_jax.data.files import write_atomic
from privslam_jax.errors import input_error
from privslam_jax.types import LineCloud, PointCloud

__all__ = [
    "read_ply",
    "write_ply",
    "save_point_cloud",
    "load_point_cloud",
    "save_line_cloud",
    "load_line_cloud",
    "load_line_cloud_and_descriptors",
    "load_descriptors",
]

_PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NP_TO_PLY: dict[str, str] = {
    "i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort",
    "i4": "int", "u4": "uint", "f4": "float", "f8": "double",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def _float_dtype() -> np.dtype:
    """The default JAX float dtype (float32 unless x64 is enabled)."""
    return np.dtype(jax.dtypes.canonicalize_dtype(np.float64))


def write_ply(path: str | os.PathLike, elements: dict[str, np.ndarray], *, binary: bool = True,
              comments: tuple[str, ...] = ()) -> None:
    """Write named elements (1-D numpy structured arrays with scalar fields) to a PLY file."""
    path = Path(path)
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0"]
    header += [f"comment {c}" for c in comments]
    for name, arr in elements.items():
        if arr.dtype.names is None or arr.ndim != 1:
            raise ValueError(f"element {name!r} must be a 1-D structured array")
        header.append(f"element {name} {arr.shape[0]}")
        for field in arr.dtype.names:
            code = arr.dtype[field].str[1:]
            if code not in _NP_TO_PLY:
                raise ValueError(f"element {name!r} field {field!r}: unsupported dtype {arr.dtype[field]}")
            header.append(f"property {_NP_TO_PLY[code]} {field}")
    header.append("end_header")
    with io.BytesIO() as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        for name, arr in elements.items():
            if binary:
                le = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
                f.write(le.tobytes())
            elif arr.shape[0]:
                fmts = ["%.17g" if arr.dtype[n].kind == "f" else "%d" for n in arr.dtype.names]
                np.savetxt(f, arr, fmt=" ".join(fmts))
        write_atomic(path, f.getvalue())


def _parse_header(path: Path, raw: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int]:
    if not raw.startswith(b"ply"):
        raise input_error(path, "not a PLY file (missing 'ply' magic)")
    end = raw.find(b"end_header")
    if end < 0:
        raise input_error(path, "PLY header has no 'end_header'")
    nl = raw.find(b"\n", end)
    body_start = len(raw) if nl < 0 else nl + 1
    try:
        lines = raw[:end].decode("ascii").splitlines()
    except UnicodeDecodeError as err:
        raise input_error(path, "PLY header is not ASCII") from err
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for lineno, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in _FORMATS:
                raise input_error(path, f"unsupported PLY format line {line!r}")
            fmt = tok[1]
        elif tok[0] == "element":
            # at most 18 digits: a count beyond 10^18 cannot fit any file (and int() of 4300+ digits fails)
            if len(tok) != 3 or not tok[2].isdigit() or len(tok[2]) > 18:
                raise input_error(path, f"bad element line {lineno}: {line[:200]!r}")
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise input_error(path, f"property before any element (line {lineno})")
            if len(tok) >= 2 and tok[1] == "list":
                raise input_error(path, f"list properties are not supported (element {elements[-1][0]!r})")
            if len(tok) != 3 or tok[1] not in _PLY_TYPES:
                raise input_error(path, f"bad property line {lineno}: {line[:200]!r}")
            if tok[2] in (name for name, _ in elements[-1][2]):
                raise input_error(path, f"element {elements[-1][0]!r} repeats property {tok[2]!r} (line {lineno})")
            elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
        else:
            raise input_error(path, f"unknown PLY header keyword on line {lineno}: {line[:200]!r}")
    if fmt is None:
        raise input_error(path, "PLY header has no 'format' line")
    return fmt, elements, body_start


def read_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every element of a PLY file into numpy structured arrays, keyed by element name.

    Raises ``FileNotFoundError`` for a missing file and :class:`~privslam_jax.errors.InputError`
    (a ``ValueError`` naming the file) for a corrupt header, element counts the file cannot hold,
    a truncated body or unparsable ASCII values. Nothing larger than the file's content is
    allocated before it is checked (see the module docstring).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"PLY file not found: {path}")
    raw = path.read_bytes()
    fmt, elements, pos = _parse_header(path, raw)
    names = [name for name, _, _ in elements]
    if len(set(names)) != len(names):
        raise input_error(path, f"PLY header repeats an element name: {names}")
    out: dict[str, np.ndarray] = {}
    if fmt == "ascii":
        rows = raw[pos:].decode("ascii", errors="replace").splitlines()
        rows = [r for r in rows if r.strip()]
        r0 = 0
        for name, count, props in elements:
            dtype = np.dtype([(p, t) for p, t in props])
            chunk = rows[r0:r0 + count]
            if len(chunk) < count:
                raise input_error(path, f"truncated: element {name!r} has {len(chunk)} of {count} rows")
            # k values need at least 2k - 1 characters per row: check before allocating count rows
            if props and sum(map(len, chunk)) < count * (2 * len(props) - 1):
                raise input_error(path, f"element {name!r}: its rows are too short to hold {len(props)} values each")
            arr = np.zeros(count, dtype)
            for i, row in enumerate(chunk):
                tok = row.split()
                if len(tok) != len(props):
                    raise input_error(path, f"element {name!r} row {i}: expected {len(props)} values, got {len(tok)}")
                try:
                    with np.errstate(over="raise", invalid="raise"):  # 1e39 in a float field: an error, not inf
                        arr[i] = tuple(float(v) if t[0] == "f" else int(v) for v, (_, t) in zip(tok, props))
                except (ValueError, OverflowError, FloatingPointError) as err:
                    raise input_error(path, f"element {name!r} row {i}: cannot parse {row[:200]!r}") from err
            out[name] = arr
            r0 += count
    else:
        order = _FORMATS[fmt]
        for name, count, props in elements:
            dtype = np.dtype([(p, order + t) for p, t in props])
            nbytes = dtype.itemsize * count
            if pos + nbytes > len(raw):
                raise input_error(
                    path, f"truncated: element {name!r} needs {nbytes} bytes, {max(len(raw) - pos, 0)} left"
                )
            if dtype.itemsize == 0:  # an element without properties: rows of nothing
                if count > len(raw):
                    raise input_error(path, f"element {name!r} has no properties but claims {count} rows")
                out[name] = np.zeros(count, dtype)
                continue
            arr = np.frombuffer(raw, dtype=dtype, count=count, offset=pos)
            with np.errstate(all="ignore"):  # byte order only; NaN bit patterns are checked by the loaders
                out[name] = arr.astype(dtype.newbyteorder("="))
            pos += nbytes
    return out


def _vertex_xyz(path: Path, elements: dict[str, np.ndarray]) -> np.ndarray:
    if "vertex" not in elements:
        raise input_error(path, "PLY file has no 'vertex' element")
    v = elements["vertex"]
    missing = [c for c in "xyz" if c not in (v.dtype.names or ())]
    if missing:
        raise input_error(path, f"vertex element lacks properties {missing}")
    with np.errstate(invalid="ignore"):  # a signalling-NaN bit pattern warns when cast; refused just below
        xyz = np.stack([v["x"], v["y"], v["z"]], axis=-1).astype(np.float64)
    if not np.all(np.isfinite(xyz)):
        raise input_error(path, "vertex coordinates contain NaN or inf")
    return xyz


def _as_float(path: Path, x: np.ndarray, what: str, dtype: np.dtype) -> np.ndarray:
    """``x`` cast to ``dtype``; values beyond its range (1e39 in float32) are refused, not made inf."""
    with np.errstate(over="ignore", invalid="ignore"):
        y = x.astype(dtype)
    if not np.all(np.isfinite(y)):
        raise input_error(path, f"{what} exceed the {dtype} range")
    return y


def save_point_cloud(path: str | os.PathLike, cloud: PointCloud, *, binary: bool = True) -> None:
    """Save a :class:`PointCloud` as PLY vertices (``x y z [red green blue] [nx ny nz] [observations]``) and, if it
    has descriptors, the ``descriptor`` element."""
    xyz = np.asarray(cloud.xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"point cloud xyz must have shape (N, 3), got {xyz.shape}")
    ftype = "f4" if xyz.dtype == np.float32 else "f8"
    fields: list[tuple[str, str]] = [("x", ftype), ("y", ftype), ("z", ftype)]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if cloud.normals is not None:
        fields += [("nx", ftype), ("ny", ftype), ("nz", ftype)]
    if cloud.observations is not None:
        fields += [("observations", "i4")]
    arr = np.zeros(xyz.shape[0], np.dtype(fields))
    for k, c in enumerate("xyz"):
        arr[c] = xyz[:, k]
    if cloud.colors is not None:
        rgb = np.clip(np.rint(np.asarray(cloud.colors, np.float64) * 255.0), 0, 255).astype(np.uint8)
        for k, c in enumerate(("red", "green", "blue")):
            arr[c] = rgb[:, k]
    if cloud.normals is not None:
        nrm = np.asarray(cloud.normals)
        if nrm.shape != xyz.shape:
            raise ValueError(f"normals must have the points' shape {xyz.shape}, got {nrm.shape}")
        for k, c in enumerate(("nx", "ny", "nz")):
            arr[c] = nrm[:, k]
    if cloud.observations is not None:
        arr["observations"] = np.asarray(cloud.observations)
    elements = {"vertex": arr}
    if cloud.descriptors is not None:
        elements["descriptor"] = _descriptor_rows(cloud.descriptors, xyz.shape[0])
    write_ply(path, elements, binary=binary, comments=("privslam_jax point cloud",))


def _descriptor_rows(descriptors, n: int) -> np.ndarray:
    """The ``descriptor`` element: ``(n, D)`` uint8 descriptors as rows of ``uchar`` ``b0 … b{D-1}``."""
    desc = np.asarray(descriptors)
    if desc.ndim != 2 or desc.shape[0] != n or desc.dtype != np.uint8:
        raise ValueError(f"descriptors must be uint8 of shape ({n}, D), got {desc.dtype} {desc.shape}")
    rows = np.zeros(n, np.dtype([(f"b{k}", "u1") for k in range(desc.shape[1])]))
    for k in range(desc.shape[1]):
        rows[f"b{k}"] = desc[:, k]
    return rows


def load_descriptors(path: str | os.PathLike) -> np.ndarray | None:
    """The ``(N, D)`` uint8 descriptors of a point or line cloud, or ``None`` if it has none.

    ``N`` must be the number of edges (a line cloud) or else of vertices (a point cloud).
    """
    path = Path(path)
    return _descriptors(path, read_ply(path))


def _descriptors(path: Path, elements: dict[str, np.ndarray]) -> np.ndarray | None:
    if "descriptor" not in elements:
        return None
    e = elements["descriptor"]
    names = e.dtype.names or ()
    if not names or any(e.dtype[c].kind not in "iu" for c in names):
        raise input_error(path, "the descriptor element must hold integer properties b0 … b{D-1}")
    desc = np.stack([e[c] for c in names], axis=-1).reshape(len(e), len(names))
    if desc.size and (desc.min() < 0 or desc.max() > 255):
        raise input_error(path, "descriptor values outside 0..255")
    what = "edge" if "edge" in elements else "vertex"
    n = len(elements[what]) if what in elements else 0
    if len(desc) != n:
        raise input_error(path, f"{len(desc)} descriptors for {n} {what} rows")
    return desc.astype(np.uint8)


def load_point_cloud(path: str | os.PathLike) -> PointCloud:
    """Load a PLY point cloud (any extra vertex properties are ignored; edges are ignored)."""
    path = Path(path)
    elements = read_ply(path)
    xyz = _vertex_xyz(path, elements)
    v = elements["vertex"]
    names = v.dtype.names or ()
    colors = None
    if all(c in names for c in ("red", "green", "blue")):
        with np.errstate(invalid="ignore"):
            rgb = np.stack([v["red"], v["green"], v["blue"]], axis=-1).astype(np.float64)
        if not np.all(np.isfinite(rgb)):
            raise input_error(path, "vertex colours contain NaN or inf")
        # integer colours are 0..255; float colours are taken to be in [0, 1] already
        colors = rgb if v.dtype["red"].kind == "f" else rgb / 255.0
    obs = None
    if "observations" in names:
        o = v["observations"]
        info = np.iinfo(np.int32)
        with np.errstate(invalid="ignore"):
            ok = np.all(np.isfinite(o) & (o == np.round(o))) if o.dtype.kind == "f" else True
        if not ok or (o.size and (o.min() < info.min or o.max() > info.max)):
            raise input_error(path, "vertex observations are not int32 integers")
        obs = jnp.asarray(o.astype(np.int32))
    fdt = _float_dtype()
    normals = None
    if all(c in names for c in ("nx", "ny", "nz")):
        with np.errstate(invalid="ignore"):
            nrm = np.stack([v["nx"], v["ny"], v["nz"]], axis=-1).astype(np.float64)
        if not np.all(np.isfinite(nrm)):
            raise input_error(path, "vertex normals contain NaN or inf")
        normals = _as_float(path, nrm, "vertex normals", fdt)
    desc = _descriptors(path, elements)
    return PointCloud(
        xyz=jnp.asarray(_as_float(path, xyz, "vertex coordinates", fdt)),
        colors=None if colors is None else jnp.asarray(_as_float(path, colors, "vertex colours", fdt)),
        observations=obs,
        normals=None if normals is None else jnp.asarray(normals),
        descriptors=None if desc is None else jnp.asarray(desc),
    )


def save_line_cloud(path: str | os.PathLike, lines: LineCloud, *, descriptors=None, binary: bool = True) -> None:
    """Save a :class:`LineCloud` as canonical unit segments (vertices ``2i``, ``2i+1``) plus edges,
    and the ``(N, D)`` uint8 ``descriptors`` of its lines if given (what localisation matches)."""
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    if d.ndim != 2 or d.shape[1] != 3 or m.shape != d.shape:
        raise ValueError(f"line cloud directions/moments must both be (N, 3), got {d.shape} and {m.shape}")
    n = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(n == 0) or not np.all(np.isfinite(d)) or not np.all(np.isfinite(m)):
        raise ValueError("line cloud has zero, NaN or inf directions/moments")
    d = d / n
    start = np.cross(d, m / n)  # closest point to the origin (moment of the unit direction)
    seg = np.stack([start, start + d], axis=1).reshape(-1, 3)
    # float32 only for float32 lines near the origin: at 1e4 m a float32 coordinate is already
    # 1e-3 m coarse, and at 1e7 m the unit segment collapses to a point.
    small = float(np.abs(seg).max(initial=0.0)) < 1e3
    ftype = "f4" if np.asarray(lines.directions).dtype == np.float32 and small else "f8"
    vert = np.zeros(seg.shape[0], np.dtype([("x", ftype), ("y", ftype), ("z", ftype)]))
    for k, c in enumerate("xyz"):
        vert[c] = seg[:, k]
    edge = np.zeros(d.shape[0], np.dtype([("vertex1", "i4"), ("vertex2", "i4")]))
    edge["vertex1"] = 2 * np.arange(d.shape[0])
    edge["vertex2"] = 2 * np.arange(d.shape[0]) + 1
    elements = {"vertex": vert, "edge": edge}
    if descriptors is not None:
        elements["descriptor"] = _descriptor_rows(descriptors, d.shape[0])
    write_ply(path, elements, binary=binary,
              comments=("privslam_jax line cloud: line i = edge i = unit segment from its closest point to the origin",))


def load_line_cloud(path: str | os.PathLike) -> LineCloud:
    """Load segments (edges, or consecutive vertex pairs when there is no ``edge`` element) as lines."""
    path = Path(path)
    return _line_cloud(path, read_ply(path))


def load_line_cloud_and_descriptors(path: str | os.PathLike) -> tuple[LineCloud, np.ndarray | None]:
    """:func:`load_line_cloud` and :func:`load_descriptors` of one file, read once."""
    path = Path(path)
    elements = read_ply(path)
    return _line_cloud(path, elements), _descriptors(path, elements)


def _line_cloud(path: Path, elements: dict[str, np.ndarray]) -> LineCloud:
    xyz = _vertex_xyz(path, elements)
    if "edge" in elements:
        e = elements["edge"]
        if not all(c in (e.dtype.names or ()) for c in ("vertex1", "vertex2")):
            raise input_error(path, "edge element lacks vertex1/vertex2")
        f1, f2 = e["vertex1"], e["vertex2"]
        bad = np.zeros(len(e), bool)
        for f in (f1, f2):
            with np.errstate(invalid="ignore"):
                bad |= ~((f >= 0) & (f < len(xyz)))  # also NaN
                if f.dtype.kind == "f":
                    bad |= f != np.floor(f)
        if np.any(bad):
            raise input_error(path, f"edge {int(np.argmax(bad))} refers to a vertex outside 0..{len(xyz) - 1}")
        i1, i2 = f1.astype(np.int64), f2.astype(np.int64)
    else:
        if len(xyz) % 2:
            raise input_error(path, f"no edges and an odd number of vertices ({len(xyz)})")
        i1, i2 = np.arange(0, len(xyz), 2), np.arange(1, len(xyz), 2)
    a, b = xyz[i1], xyz[i2]
    with np.errstate(over="ignore", invalid="ignore"):
        length = np.linalg.norm(b - a, axis=1, keepdims=True)
        if np.any(length == 0):
            raise input_error(path, f"segment {int(np.argmin(length[:, 0]))} has zero length")
        d = (b - a) / length
        m = np.cross(a, d)
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(m))):
        raise input_error(path, "segment coordinates too large (their lines overflow float64)")
    if elements["vertex"]["x"].dtype == np.float64 and _float_dtype() != np.float64:  # keep a float64 file's precision
        return LineCloud(directions=d, moments=m)
    fdt = _float_dtype()
    return LineCloud(directions=jnp.asarray(_as_float(path, d, "line directions", fdt)),
                     moments=jnp.asarray(_as_float(path, m, "line moments", fdt)))
