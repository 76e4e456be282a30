"""PLY round trips (binary and ASCII), a hand-written ASCII file, and clear errors."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.data.ply import (
    load_descriptors,
    load_line_cloud,
    load_line_cloud_and_descriptors,
    load_point_cloud,
    read_ply,
    save_line_cloud,
    save_point_cloud,
    write_ply,
)
from privslam_jax.types import LineCloud, PointCloud


def _cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)).astype(np.float32) * 10
    colors = rng.integers(0, 256, size=(n, 3)) / 255.0
    obs = rng.integers(1, 20, size=n).astype(np.int32)
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    desc = rng.integers(0, 256, size=(n, 32), dtype=np.uint8)
    return PointCloud(xyz=jnp.asarray(xyz), colors=jnp.asarray(colors, jnp.float32), observations=jnp.asarray(obs),
                      normals=jnp.asarray(nrm / np.linalg.norm(nrm, axis=1, keepdims=True)), descriptors=jnp.asarray(desc))


@pytest.mark.parametrize("binary", [True, False])
def test_point_cloud_round_trip(tmp_path, binary):
    cloud = _cloud()
    path = tmp_path / "p.ply"
    save_point_cloud(path, cloud, binary=binary)
    back = load_point_cloud(path)
    np.testing.assert_array_equal(np.asarray(back.xyz), np.asarray(cloud.xyz))
    np.testing.assert_allclose(np.asarray(back.colors), np.asarray(cloud.colors), atol=1e-7)
    np.testing.assert_array_equal(np.asarray(back.observations), np.asarray(cloud.observations))
    np.testing.assert_allclose(np.asarray(back.normals), np.asarray(cloud.normals), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(back.descriptors), np.asarray(cloud.descriptors))
    np.testing.assert_array_equal(load_descriptors(path), np.asarray(cloud.descriptors))
    head = path.read_bytes()[:400]
    assert (b"binary_little_endian" in head) == binary


def test_point_cloud_without_optional_fields(tmp_path):
    xyz = jnp.asarray(np.arange(12, dtype=np.float32).reshape(4, 3))
    save_point_cloud(tmp_path / "p.ply", PointCloud(xyz=xyz))
    back = load_point_cloud(tmp_path / "p.ply")
    assert back.colors is None and back.observations is None and back.normals is None and back.descriptors is None
    assert load_descriptors(tmp_path / "p.ply") is None
    np.testing.assert_array_equal(np.asarray(back.xyz), np.asarray(xyz))
    assert len(read_ply(tmp_path / "p.ply")["vertex"].dtype.names) == 3


@pytest.mark.parametrize("binary", [True, False])
def test_line_cloud_round_trip_is_canonical(tmp_path, binary):
    rng = np.random.default_rng(1)
    p = rng.normal(size=(40, 3)) * 5
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    m = np.cross(p, d)
    lines = LineCloud(directions=jnp.asarray(d, jnp.float32), moments=jnp.asarray(m, jnp.float32))
    path = tmp_path / "l.ply"
    save_line_cloud(path, lines, binary=binary)
    el = read_ply(path)
    v = np.stack([el["vertex"][c] for c in "xyz"], -1).astype(np.float64)
    np.testing.assert_array_equal(el["edge"]["vertex1"], 2 * np.arange(40))
    np.testing.assert_array_equal(el["edge"]["vertex2"], 2 * np.arange(40) + 1)
    start, end = v[0::2], v[1::2]
    # start = closest point to the origin (independent formula: p - (p·d) d), unit length along d
    np.testing.assert_allclose(start, p - np.sum(p * d, 1, keepdims=True) * d, atol=1e-5)
    np.testing.assert_allclose(end - start, d, atol=1e-5)
    back = load_line_cloud(path)
    np.testing.assert_allclose(np.asarray(back.directions), d, atol=1e-5)
    np.testing.assert_allclose(np.asarray(back.moments), m, atol=1e-4)


def test_hand_written_ascii(tmp_path):
    text = """ply
format ascii 1.0
comment written by hand
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element edge 2
property int vertex1
property int vertex2
end_header
0 0 1 255 0 0
2 0 1 0 255 0
0 3 0 0 0 255
0 3 4 10 20 30
0 1
2 3
"""
    path = tmp_path / "hand.ply"
    path.write_text(text)
    pts = load_point_cloud(path)
    np.testing.assert_allclose(np.asarray(pts.xyz), [[0, 0, 1], [2, 0, 1], [0, 3, 0], [0, 3, 4]])
    np.testing.assert_allclose(np.asarray(pts.colors)[3], [10 / 255, 20 / 255, 30 / 255], atol=1e-7)
    lines = load_line_cloud(path)
    np.testing.assert_allclose(np.asarray(lines.directions), [[1, 0, 0], [0, 0, 1]], atol=1e-7)
    # moment p × d: (0,0,1)×(1,0,0) = (0,1,0); (0,3,0)×(0,0,1) = (3,0,0)
    np.testing.assert_allclose(np.asarray(lines.moments), [[0, 1, 0], [3, 0, 0]], atol=1e-6)


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        load_point_cloud(tmp_path / "nope.ply")
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"PK\x03\x04 not a ply")
    with pytest.raises(ValueError, match="bad.ply.*not a PLY"):
        load_point_cloud(bad)
    # truncated binary body
    good = tmp_path / "good.ply"
    save_point_cloud(good, _cloud(), binary=True)
    trunc = tmp_path / "trunc.ply"
    trunc.write_bytes(good.read_bytes()[:-7])
    with pytest.raises(ValueError, match="trunc.ply.*truncated"):
        load_point_cloud(trunc)
    # truncated ascii body and garbage values
    save_point_cloud(good, _cloud(), binary=False)
    lines = good.read_text().splitlines()
    (tmp_path / "t2.ply").write_text("\n".join(lines[:-3]) + "\n")
    with pytest.raises(ValueError, match="truncated"):
        load_point_cloud(tmp_path / "t2.ply")
    (tmp_path / "t3.ply").write_text("\n".join(lines[:-1] + ["1 2 abc 4 5 6 7"]) + "\n")
    with pytest.raises(ValueError, match="t3.ply"):
        load_point_cloud(tmp_path / "t3.ply")
    (tmp_path / "noend.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n")
    with pytest.raises(ValueError, match="end_header"):
        load_point_cloud(tmp_path / "noend.ply")
    (tmp_path / "face.ply").write_text(
        "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n"
    )
    with pytest.raises(ValueError, match="list properties"):
        load_point_cloud(tmp_path / "face.ply")
    (tmp_path / "noxyz.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(ValueError, match="lacks"):
        load_point_cloud(tmp_path / "noxyz.ply")
    (tmp_path / "zero.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n1 1 1\n1 1 1\n"
    )
    with pytest.raises(ValueError, match="zero length"):
        load_line_cloud(tmp_path / "zero.ply")
    (tmp_path / "nan_normal.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\nend_header\n1 2 3 nan 0 1\n"
    )
    with pytest.raises(ValueError, match="nan_normal.ply.*normals contain NaN or inf"):
        load_point_cloud(tmp_path / "nan_normal.ply")


def test_line_cloud_descriptors_round_trip_and_bad_descriptor_elements(tmp_path):
    """Row i of the descriptor element belongs to line i; a count or value that does not fit is refused."""
    rng = np.random.default_rng(3)
    d = rng.normal(size=(20, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lines = LineCloud(directions=d, moments=np.cross(rng.normal(size=(20, 3)), d))
    desc = rng.integers(0, 256, size=(20, 32), dtype=np.uint8)
    save_line_cloud(tmp_path / "l.ply", lines, descriptors=desc)
    np.testing.assert_array_equal(load_descriptors(tmp_path / "l.ply"), desc)
    assert len(load_line_cloud(tmp_path / "l.ply")) == 20  # readers that ignore the element are unaffected
    both, both_desc = load_line_cloud_and_descriptors(tmp_path / "l.ply")
    np.testing.assert_array_equal(both_desc, desc)
    np.testing.assert_array_equal(np.asarray(both.moments), np.asarray(load_line_cloud(tmp_path / "l.ply").moments))
    with pytest.raises(ValueError, match="uint8 of shape"):
        save_line_cloud(tmp_path / "x.ply", lines, descriptors=desc[:19])
    el = read_ply(tmp_path / "l.ply")
    write_ply(tmp_path / "short.ply", {"vertex": el["vertex"], "edge": el["edge"], "descriptor": el["descriptor"][:19]})
    with pytest.raises(ValueError, match="19 descriptors for 20 edge rows"):
        load_descriptors(tmp_path / "short.ply")
    wide = np.zeros(20, np.dtype([("b0", "i4"), ("b1", "i4")]))
    wide["b1"][3] = 300
    write_ply(tmp_path / "wide.ply", {"vertex": el["vertex"], "edge": el["edge"], "descriptor": wide})
    with pytest.raises(ValueError, match="outside 0..255"):
        load_descriptors(tmp_path / "wide.ply")
    flt = np.zeros(20, np.dtype([("b0", "f4")]))
    write_ply(tmp_path / "float.ply", {"vertex": el["vertex"], "edge": el["edge"], "descriptor": flt})
    with pytest.raises(ValueError, match="integer properties"):
        load_descriptors(tmp_path / "float.ply")
