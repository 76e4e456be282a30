"""The main job (``privslam run``) end to end on a short synthetic sequence, checked from its files."""

import json

import numpy as np
import pytest

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


def _report_checks(out, report):
    """report.md / report.html: every figure written, the HTML self-contained and equal to the PNGs, numbers from metrics.json."""
    import base64
    import re

    md = (out / "report.md").read_text()
    page = (out / "report.html").read_text()
    pngs = sorted((out / "report_files").glob("*.png"))
    assert {p.name for p in pngs} == {"frames.png", "trajectories.png", "map_lines.png", "attack.png"}
    embedded = [base64.b64decode(s) for s in re.findall(r'src="data:image/png;base64,([^"]+)"', page)]
    assert sorted(embedded) == sorted(p.read_bytes() for p in pngs)  # inline copies of the PNGs
    assert all(b[:8] == b"\x89PNG\r\n\x1a\n" for b in embedded)
    assert not re.search(r"(src|href)=\"(?!data:)", page) and "<script" not in page  # nothing fetched, no code
    for p in pngs:
        assert f"report_files/{p.name}" in md
    for label in ("original", "filtered"):
        m = json.loads((out / f"slam_{label}" / "metrics.json").read_text())
        if "ate_rmse_sim3" in m:
            assert f"| {label} | {m['tracked']}/{m['frames']} | {m['map_points']} | {m['ate_rmse_sim3']:.3f} |" in md
    assert report["timings_s"] and all(v > 0 for v in report["timings_s"].values())


def test_run_writes_a_report_a_person_reads(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--frames", "10", "--masks", "gt", "--filter", "telea", "--lift-seed", "1",
                 "--quiet"]) == 0
    _report_checks(out, json.loads((out / "report.json").read_text()))


def test_report_html_renders_offline_in_a_headless_browser(tmp_path):
    """Chromium (no network: every host name unresolvable) loads every figure of report.html."""
    import shutil
    import subprocess

    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("no headless Chromium (.ci/run installs the Debian package)")
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), "--frames", "10", "--masks", "gt", "--filter", "gray", "--lift-seed", "1",
                 "--quiet"]) == 0
    page = (out / "report.html").read_text()
    probe = ('<script>addEventListener("load",()=>{const i=[...document.images];document.body.setAttribute('
             '"data-check",i.length+" "+i.filter(x=>x.complete&&x.naturalWidth>0).length+" "+'
             'document.querySelectorAll("table").length)})</script>')
    (tmp_path / "probe.html").write_text(page.replace("</body>", probe + "</body>"))
    dom = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--host-resolver-rules=MAP * ~NOTFOUND",
         "--virtual-time-budget=10000", "--dump-dom", (tmp_path / "probe.html").as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    ).stdout
    loaded = dom.split('data-check="')[1].split('"')[0].split()
    assert loaded == ["4", "4", "3"], loaded  # 4 figures, all decoded; SLAM, privacy and timing tables


def test_run_on_a_real_kitti_sequence(shared, tmp_path):
    """``privslam run SEQUENCE`` on the first 12 real frames of KITTI seq1: ground truth used, report written."""
    import shutil

    src = shared / "data" / "kitti_odometry" / "sequences" / "seq1"
    seq = tmp_path / "kitti" / "sequences" / "seq1"
    (seq / "image_0").mkdir(parents=True)
    for i in range(12):
        shutil.copy(src / "image_0" / f"{i:06d}.png", seq / "image_0")
    shutil.copy(src / "calib.txt", seq)
    (tmp_path / "kitti" / "poses").mkdir()
    poses = (shared / "data" / "kitti_odometry" / "poses" / "seq1.txt").read_text().splitlines()[:12]
    (tmp_path / "kitti" / "poses" / "seq1.txt").write_text("\n".join(poses) + "\n")
    out = tmp_path / "run"
    with pytest.warns(UserWarning, match="PRIVACY WARNING"):  # the embedded real-frame detector's recall is low
        assert main(["run", str(seq), "--out", str(out), "--filter", "telea", "--lift-seed", "2", "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["synthetic"] is False and "leak" not in report["filter"]  # no ground-truth masks on real frames
    assert report["filter"]["report"]["detector"]["domain"] == "real"  # the embedded real-frame detector was chosen
    for label in ("original", "filtered"):
        assert report["slam"][label]["frames"] == 12 and "ate_rmse_sim3" in report["slam"][label]
    assert report["privacy"]["units"] == "m"
    _report_checks(out, report)
    # the input sequence is read, never written
    assert sorted(p.name for p in seq.iterdir()) == ["calib.txt", "image_0"]


def test_run_without_ground_truth_skips_the_metrics_with_a_note(tmp_path, capsys):
    from privslam_jax.data.kitti_write import write_kitti_sequence
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    seq_dir = write_kitti_sequence(make_sequence(SynthConfig(width=320, height=96, num_frames=8, seed=3)), tmp_path / "k",
                                   progress=False)
    (tmp_path / "k" / "poses" / "synth.txt").unlink()
    out = tmp_path / "run"
    assert main(["run", str(seq_dir), "--out", str(out), "--masks", "gt", "--filter", "gray", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "no ground-truth poses" in printed and "no ground truth: no ATE/RPE" in printed
    report = json.loads((out / "report.json").read_text())
    assert all("ate_rmse_sim3" not in m for m in report["slam"].values())
    assert report["privacy"].get("units", "").startswith("SLAM units") or "skipped" in report["privacy"]
    assert (out / "report.html").is_file()
