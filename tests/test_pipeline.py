"""The main job (``privslam run``) end to end on a short synthetic sequence, checked from its files;
the typed report and the pipeline's stages called one by one in memory."""

import contextlib
import io
import json

import numpy as np
import pytest

from privslam_jax import pipeline
from privslam_jax.cli import main
from privslam_jax.data.images import read_image
from privslam_jax.data.ply import load_line_cloud, load_point_cloud
from privslam_jax.data.trajectory_io import read_tum_matrices

pytestmark = pytest.mark.xla_optimized  # the pipeline runs SLAM on whole sequences (tests/conftest.py)


@pytest.fixture(scope="module")
def gt_run(tmp_path_factory):
    """One ``privslam run`` (14 synthetic frames, ground-truth masks, lift seed 3), shared by the tests
    of this module: ``(out folder, printed text, the PipelineReport run_pipeline returned)``."""
    out = tmp_path_factory.mktemp("gt_run") / "run"
    typed = []

    def keep(*args, **kwargs):
        typed.append(run_pipeline(*args, **kwargs))
        return typed[-1]

    run_pipeline = pipeline.run_pipeline
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(io.StringIO()) as printed:
        mp.setattr(pipeline, "run_pipeline", keep)  # the command imports it from the module at call time
        assert main(["run", "--out", str(out), "--frames", "14", "--masks", "gt", "--lift-seed", "3", "--quiet"]) == 0
    assert len(typed) == 1
    return out, printed.getvalue(), typed[0]


def test_run_writes_every_stage_and_consistent_report(gt_run):
    out, printed, _ = gt_run
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


def test_typed_report_is_what_the_command_printed_and_wrote(gt_run):
    """``run_pipeline`` returns a frozen PipelineReport; its ``to_json_dict()`` is ``report.json``, its summary the printed text."""
    import dataclasses

    from privslam_jax.types import LineCloud

    out, printed, report = gt_run
    assert isinstance(report, pipeline.PipelineReport)
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.summary = ""  # type: ignore[misc]
    d = report.to_json_dict()
    assert json.loads(json.dumps(d)) == json.loads((out / "report.json").read_text())
    assert list(d) == ["sequence", "synthetic", "data", "filter", "slam", "privacy", "timings_s"]
    assert report.summary in printed and printed.startswith(report.summary)
    # the typed fields agree with the files, and the in-memory values are there but not in the JSON
    assert report.filter.sequence == out / "filtered" / "sequences" / "synth"
    for label in ("original", "filtered"):
        stage = report.slam[label]
        assert stage.metrics == json.loads((out / f"slam_{label}" / "metrics.json").read_text())
        assert len(stage.result.tracked) == stage.metrics["frames"] == 14
    priv = report.privacy
    assert priv.skipped is None and priv.units == "m" and isinstance(priv.lines, LineCloud)
    assert priv.map_points == len(priv.map_xyz) == len(priv.recovered) == len(priv.lines)
    np.testing.assert_allclose(np.asarray(load_point_cloud(out / "recovered.ply").xyz), priv.recovered, rtol=1e-5, atol=1e-4)
    assert set(d["privacy"]) == {"map_points", "lift", "line2point", "no_attack_closest_point", "units"}
    assert d["slam"]["filtered"] is report.slam["filtered"].metrics  # the metrics only, not the SlamResult


def test_filter_stage_in_memory_is_what_the_files_hold_and_slam_reads(gt_run):
    """The pipeline filters in memory and runs SLAM on those frames; the filtered folder it writes as a
    sink holds the same frames and masks, and ``privslam slam``'s reading of that folder gives the same run."""
    from privslam_jax.data.kitti import KittiSequence
    from privslam_jax.data.images import read_raw
    from privslam_jax.slam.outputs import load_sequence_frames

    out, _, report = gt_run
    frames = report.filter.frames
    folder = out / "filtered" / "sequences" / "synth"
    files = KittiSequence(folder, grey=True)
    assert len(frames) == len(files) == 14
    for i in range(14):
        np.testing.assert_array_equal(frames.grey(i), files.image(i))
        np.testing.assert_array_equal(frames.left[i], read_raw(folder / "image_2" / f"{i:06d}.png")[..., ::-1])
        np.testing.assert_array_equal(frames.label_maps[i], read_raw(folder / "masks" / f"{i:06d}.png"))
    assert frames.instance_classes == {int(k): v for k, v in json.loads((folder / "instance_classes.json").read_text()).items()}
    seq, it, n = load_sequence_frames(folder, "mono")
    again = pipeline.slam_stage(it, seq.camera, "mono", timestamps=seq.timestamps[:n], gt_poses=seq.poses, total=n)
    mine = report.slam["filtered"]
    np.testing.assert_array_equal(again.result.trajectory.as_matrices(), mine.result.trajectory.as_matrices())
    assert again.metrics["ate_rmse_sim3"] == mine.metrics["ate_rmse_sim3"]


def test_privacy_stage_in_memory_equals_a_numpy_recomputation_and_writes_nothing(tmp_path, monkeypatch):
    from privslam_jax.privacy.lift import fixed_key

    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    p = np.concatenate([rng.uniform([-10, -2, 0], [10, 2, 40], (150, 3)),
                        rng.normal([0, 0, 20], 0.3, (50, 3))])  # a box and a dense cluster
    lines, r, metrics = pipeline.privacy_stage(p, fixed_key(7))
    assert list(tmp_path.iterdir()) == []  # no folder given: nothing written
    d = np.asarray(lines.directions, np.float64)
    m = np.asarray(lines.moments, np.float64)
    assert r.shape == p.shape and r.dtype == np.float64
    np.testing.assert_allclose(np.cross(p, d), m, atol=1e-9)  # line i goes through p_i
    assert np.abs(np.cross(r, d) - m).max() < 1e-3 * np.abs(r).max()  # r_i lies on line i
    closest = np.cross(d / np.linalg.norm(d, axis=1, keepdims=True), m)
    for key, q in (("line2point", r), ("no_attack_closest_point", closest)):
        e = np.linalg.norm(q - p, axis=1)
        dist = np.linalg.norm(p[:, None, :] - q[None, :, :], axis=2)  # all pairs, no kd-tree
        got = metrics[key]
        assert got["per_point_median"] == pytest.approx(np.median(e), rel=1e-9)
        assert got["per_point_mean"] == pytest.approx(e.mean(), rel=1e-9)
        for tau in (0.1, 0.5, 1.0):
            assert got[f"within_{tau}"] == pytest.approx(100 * np.mean(e < tau), abs=1e-9)
        assert got["nn_mean"] == pytest.approx(dist.min(1).mean(), rel=1e-9)
        assert got["chamfer"] == pytest.approx(0.5 * (dist.min(1).mean() + dist.min(0).mean()), rel=1e-9)
    assert metrics["line2point"]["within_0.5"] > metrics["no_attack_closest_point"]["within_0.5"]
    # the same key gives the same lines and attack: the stage is a function of its inputs
    lines2, _, metrics2 = pipeline.privacy_stage(p, fixed_key(7))
    np.testing.assert_array_equal(np.asarray(lines2.directions), np.asarray(lines.directions))
    assert metrics2 == metrics
    # the optional sink writes the three clouds
    pipeline.write_privacy_outputs(tmp_path / "o", p, lines, r)
    assert sorted(f.name for f in (tmp_path / "o").iterdir()) == ["lines.ply", "map_metric.ply", "recovered.ply"]


@pytest.mark.parametrize(
    "points, match",
    [
        (np.zeros((0, 3)), "at least 2 map points"),
        (np.zeros((1, 3)), "at least 2 map points"),
        (np.zeros((5, 2)), r"shape \(N, 3\)"),
        (np.zeros((2, 3, 1)), r"shape \(N, 3\)"),
        (np.array([[0.0, 0, 0], [1, np.nan, 0]]), "NaN or inf"),
    ],
)
def test_privacy_stage_refuses_bad_maps(points, match, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=match):
        pipeline.privacy_stage(points)
    assert list(tmp_path.iterdir()) == []


def test_stages_refuse_bad_input(gt_run):
    from privslam_jax.types import Camera

    _, _, report = gt_run
    cam = Camera(fx=100.0, fy=100.0, cx=32.0, cy=24.0, width=64, height=48)
    frames = [np.zeros((48, 64), np.uint8)] * 3
    with pytest.raises(ValueError, match="mode must be 'mono' or 'stereo'"):
        pipeline.slam_stage(frames, cam, "rgbd")
    with pytest.raises(ValueError, match=r"gt_poses must have shape \(N, 4, 4\)"):
        pipeline.slam_stage(frames, cam, gt_poses=np.zeros((3, 3, 4)))
    with pytest.raises(ValueError, match="gt_poses has 2 entries for 3 frames"):
        pipeline.slam_stage(frames, cam, gt_poses=np.tile(np.eye(4), (2, 1, 1)), total=3)
    with pytest.raises(ValueError, match=r"timestamps must have shape \(N,\)"):
        pipeline.slam_stage(frames, cam, timestamps=np.zeros((3, 1)))
    with pytest.raises(ValueError, match="no frames"):
        pipeline.slam_stage([], cam)
    result = report.slam["filtered"].result
    with pytest.raises(ValueError, match=r"gt_poses must have shape \(N, 4, 4\)"):
        pipeline.map_to_ground_truth(result, np.zeros((14, 3, 4)))
    xyz, units = pipeline.map_to_ground_truth(result, None)
    assert units == "SLAM units (no ground truth)" and np.array_equal(xyz, np.asarray(result.map.xyz, np.float64))
    xyz, units = pipeline.map_to_ground_truth(result, _synthetic_gt(14))  # the ground truth the run used
    assert units == "m" and np.array_equal(xyz, report.privacy.map_xyz)
    with pytest.raises(ValueError, match="masks must be 'detect' or 'gt'"):
        pipeline.filter_stage(report.sequence, pipeline.PipelineConfig(masks="bogus"))
    with pytest.raises(ValueError, match="attack needs slam"):
        pipeline.run_pipeline(pipeline.PipelineConfig(slam=False), "unused", progress=False)
    assert [pipeline.PipelineConfig(mode=m).masked_features for m in ("mono", "stereo")] == [False, True]
    assert pipeline.PipelineConfig(mode="stereo", ignore_masked=False).masked_features is False


def _synthetic_gt(frames):
    """The ground-truth poses the pipeline uses for the default synthetic sequence of ``frames`` frames."""
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    c = pipeline.PipelineConfig()
    seq = make_sequence(SynthConfig(width=c.width, height=c.height, num_frames=frames, seed=c.seed, stereo=True))
    return np.asarray(seq.trajectory.as_matrices(), np.float64)


def test_mask_leak_counts_objects_and_pixels_left_unmasked():
    from privslam_jax.pipeline import mask_leak

    ids = np.zeros((40, 60), np.uint16)
    ids[0:10, 0:10] = 1    # 100 px, fully hidden
    ids[20:30, 0:10] = 2   # 100 px, 70 hidden -> not "left visible"
    ids[0:10, 20:40] = 3   # 200 px, 40 hidden -> left visible
    ids[30:35, 50:55] = 4  # 25 px: below min_pixels, ignored
    hidden = np.zeros_like(ids)
    hidden[0:10, 0:10] = 7
    hidden[20:27, 0:10] = 8
    hidden[0:10, 20:24] = 9
    leak = mask_leak([ids], [hidden], min_pixels=50)
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


def test_run_writes_a_report_a_person_reads(gt_run):
    out, _, _ = gt_run
    _report_checks(out, json.loads((out / "report.json").read_text()))


def test_report_html_renders_offline_in_a_headless_browser(gt_run, tmp_path):
    """Chromium (no network: every host name unresolvable) loads every figure of the run's report.html."""
    import shutil
    import subprocess

    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        pytest.skip("no headless Chromium (.ci/run installs the Debian package)")
    page = (gt_run[0] / "report.html").read_text()
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


def test_stereo_ground_truth_masks_filter_the_right_frames_too(tmp_path):
    """``privslam synth --stereo`` writes the right camera's ids (``masks_3/``, equal to the renderer's);
    ``filter --masks gt`` then hides the objects in the right frames with them: pixels outside the
    dilated right masks untouched, inside changed; and the pipeline runs stereo SLAM on ground-truth masks.
    (320×96: a stereo size other files render, so the suite's compilation cache holds the renderer.)"""
    from privslam_jax.data.images import read_raw
    from privslam_jax.data.synthetic import SynthConfig, make_sequence
    from privslam_jax.inpaint.masks import instance_masks

    root = tmp_path / "s"
    assert main(["synth", "--out", str(root), "--frames", "3", "--width", "320", "--height", "96", "--stereo",
                 "--seed", "2", "--quiet"]) == 0
    seq_dir = root / "sequences" / "synth"
    rendered = make_sequence(SynthConfig(width=320, height=96, num_frames=3, seed=2, stereo=True))
    assert main(["filter", str(seq_dir), "--out", str(tmp_path / "f"), "--method", "black", "--masks", "gt"]) == 0
    out = tmp_path / "f" / "sequences" / "synth"
    changed = 0
    for i in range(3):
        ids = read_raw(seq_dir / "masks_3" / f"{i:06d}.png")
        np.testing.assert_array_equal(ids, rendered[i].instance_ids_right)
        hidden = instance_masks(ids.astype(np.int32), None, 4).any(axis=0)
        a = read_raw(seq_dir / "image_3" / f"{i:06d}.png")
        b = read_raw(out / "image_3" / f"{i:06d}.png")
        np.testing.assert_array_equal(a[~hidden], b[~hidden])
        assert (b[hidden] == 0).all()  # black fill
        changed += int(hidden.sum())
    assert changed > 0
    report = pipeline.run_pipeline(pipeline.PipelineConfig(frames=10, masks="gt", mode="stereo", filter_method="black",
                                                           attack=False), tmp_path / "run", progress=False)
    m = report.slam["filtered"].metrics
    assert m["mode"] == "stereo" and m["frames"] == 10 and report.filter.frames.right is not None
    # stereo on filtered frames ignores the filled-in regions by default: the run `privslam slam --mode
    # stereo --ignore-masked` makes of the filtered folder the pipeline wrote
    from privslam_jax.slam.outputs import load_sequence_frames, masked_regions

    assert "no features on the filled-in regions" in report.summary
    seq, it, n = load_sequence_frames(tmp_path / "run" / "filtered" / "sequences" / "synth", "stereo")
    again = pipeline.slam_stage(it, seq.camera, "stereo", timestamps=seq.timestamps[:n], total=n,
                                ignore=masked_regions(seq, n))
    np.testing.assert_array_equal(again.result.trajectory.as_matrices(),
                                  report.slam["filtered"].result.trajectory.as_matrices())
