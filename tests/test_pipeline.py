"""The main job (``privslam run``) end to end on a short synthetic sequence, checked from its files."""

import json

import numpy as np

from privslam_jax.cli import main
from privslam_jax.data.images import read_image
from privslam_jax.data.ply import load_line_cloud, load_point_cloud
from privslam_jax.data.trajectory_io import read_tum_matrices


def test_run_writes_every_stage_and_consistent_report(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--frames", "14", "--masks", "gt", "--lift-seed", "3", "--quiet"]) == 0
    printed = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    orig = out / "original" / "sequences" / "synth"
    filt = out / "filtered" / "sequences" / "synth"
    # privacy filter: pixels outside the (dilated) masks it wrote untouched, inside changed
    masks = read_image(filt / "masks" / "000005.png")
    a = read_image(orig / "image_2" / "000005.png")
    b = read_image(filt / "image_2" / "000005.png")
    inside = np.asarray(masks) > 0
    assert inside.any()
    np.testing.assert_array_equal(np.asarray(a)[~inside], np.asarray(b)[~inside])
    assert np.abs(np.asarray(a, np.float64)[inside] - np.asarray(b, np.float64)[inside]).mean() > 0.01
    # SLAM: one TUM pose per frame for both runs
    for label in ("original", "filtered"):
        ts, T = read_tum_matrices(out / f"slam_{label}" / "trajectory.txt")
        assert len(ts) == 14 == report["slam"][label]["frames"]
    # privacy: recovered points lie on the published lines, metrics recomputed independently
    priv = report["privacy"]
    p = np.asarray(load_point_cloud(out / "map_metric.ply").xyz, np.float64)
    r = np.asarray(load_point_cloud(out / "recovered.ply").xyz, np.float64)
    lines = load_line_cloud(out / "lines.ply")
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    assert np.abs(np.cross(r, d) - m).max() < 1e-3 * max(1.0, np.abs(r).max())
    e = np.linalg.norm(p - r, axis=1)
    assert priv["map_points"] == len(p)
    assert abs(priv["line2point"]["within_0.5"] - 100 * np.mean(e < 0.5)) < 1e-6
    assert abs(priv["line2point"]["per_point_median"] - np.median(e)) < 1e-5
    assert "Line2Point recovers" in printed
    # ground-truth masks (dilated) hide every object entirely
    assert report["filter"]["leak"]["objects"] > 0
    assert report["filter"]["leak"]["objects_left_visible"] == 0.0


def test_mask_leak_counts_objects_and_pixels_left_unmasked(tmp_path):
    from privslam_jax.data.images import write_uint16
    from privslam_jax.pipeline import mask_leak

    (tmp_path / "o" / "masks").mkdir(parents=True)
    (tmp_path / "f" / "masks").mkdir(parents=True)
    ids = np.zeros((40, 60), np.uint16)
    ids[0:10, 0:10] = 1    # 100 px, fully hidden
    ids[20:30, 0:10] = 2   # 100 px, 70 hidden -> not "left visible"
    ids[0:10, 20:40] = 3   # 200 px, 40 hidden -> left visible
    ids[30:35, 50:55] = 4  # 25 px: below min_pixels, ignored
    hidden = np.zeros_like(ids)
    hidden[0:10, 0:10] = 7
    hidden[20:27, 0:10] = 8
    hidden[0:10, 20:24] = 9
    write_uint16(tmp_path / "o" / "masks" / "000000.png", ids)
    write_uint16(tmp_path / "f" / "masks" / "000000.png", hidden)
    leak = mask_leak(tmp_path / "o", tmp_path / "f", min_pixels=50)
    assert leak["objects"] == 3
    assert abs(leak["objects_left_visible"] - 100 / 3) < 1e-9
    assert abs(leak["pixels_left_visible"] - 100 * (30 + 160) / 400) < 1e-9
