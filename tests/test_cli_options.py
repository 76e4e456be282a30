"""Bad option values are refused by every ``privslam`` subcommand and every ``train/`` script (issue 22 item 4).

Each case calls the real ``main(argv)`` and expects exit status 2 (argparse's ``SystemExit(2)``, or
the ``privslam`` error path that turns a ValueError/OSError into status 2 and one stderr line) with
an error message naming the option. Input files point to paths that do not exist: a value that
slipped through validation would fail on the missing input instead, with a message that does not
name the option. Commands that own their ``--out`` folder must refuse before claiming it.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

from privslam_jax.cli import main as privslam_main

REPO = Path(__file__).resolve().parents[1]
MISSING = "/nonexistent/privslam-test-input"
"""An input path that does not exist."""


def _exit_code(main, argv: list[str]) -> int | str | None:
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


def _check(main, argv: list[str], option: str, capsys) -> None:
    code = _exit_code(main, argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, f"exit {code!r} for {argv}; stderr: {err[-500:]}"
    last = err.splitlines()[-1] if err else ""
    assert re.search(r"error: .*" + re.escape(option) + r"(?![\w-])", last), f"{option} not named in: {last!r}"



OWN_OUT = {"run", "detect", "slam", "localize", "client"}
"""Subcommands that claim ``--out`` (manifest.json) before they run."""

PRIVSLAM_CASES = [
    # run: the main job
    (["run", "--mode", "bogus"], "--mode"),
    (["run", "--masks", "bogus"], "--masks"),
    (["run", "--filter", "bogus"], "--filter"),
    (["run", "--frames", "0"], "--frames"),
    (["run", "--frames", "-5"], "--frames"),
    (["run", "--frames", "2.5"], "--frames"),
    (["run", "--seed", "-1"], "--seed"),
    (["run", "--conf", "nan"], "--conf"),
    (["run", "--conf", "1.5"], "--conf"),
    (["run", "--conf", "-0.1"], "--conf"),
    (["run", "--propagate", "-1"], "--propagate"),
    (["run", MISSING, "--mode", "rgbd"], "--mode"),
    # synth
    (["synth", "--frames", "0"], "--frames"),
    (["synth", "--frames", "x"], "--frames"),
    (["synth", "--width", "8"], "--width"),
    (["synth", "--height", "-1"], "--height"),
    (["synth", "--name", "a/b"], "--name"),
    (["synth", "--seed", "-1", "--frames", "1"], "--seed"),
    # import
    (["import", MISSING], "--hfov"),
    (["import", MISSING, "--hfov", "0"], "--hfov"),
    (["import", MISSING, "--hfov", "180"], "--hfov"),
    (["import", MISSING, "--camera", "700,700,320"], "--camera"),
    (["import", MISSING, "--camera", "0,700,320,96"], "--camera"),
    (["import", MISSING, "--camera", "nan,700,320,96"], "--camera"),
    (["import", MISSING, "--camera", "700,700,320,96", "--hfov", "60"], "--hfov"),
    (["import", MISSING, "--hfov", "60", "--every", "0"], "--every"),
    (["import", MISSING, "--hfov", "60", "--max-frames", "-1"], "--max-frames"),
    (["import", MISSING, "--hfov", "60", "--fps", "nan"], "--fps"),
    (["import", MISSING, "--hfov", "60", "--name", "a/b"], "--name"),
    (["import", MISSING, "--hfov", "60", "--grey", "--colour"], "--colour"),
    # detect
    (["detect", MISSING, "--embedded", "bogus"], "--embedded"),
    (["detect", MISSING, "--classes", "bogus"], "--classes"),
    (["detect", MISSING, "--conf", "1.5"], "--conf"),
    (["detect", MISSING, "--conf", "nan"], "--conf"),
    (["detect", MISSING, "--iou", "-0.1"], "--iou"),
    (["detect", MISSING, "--imgsz", "0"], "--imgsz"),
    (["detect", MISSING, "--imgsz", "-32"], "--imgsz"),
    (["detect", MISSING, "--imgsz", "100"], "--imgsz"),
    # lift, attack, eval-points
    (["lift", MISSING, "--method", "bogus"], "--method"),
    (["lift", MISSING, "--seed", "1.5"], "--seed"),
    (["lift", MISSING, "--passes", "0"], "--passes"),
    (["lift", MISSING, "--road-within", "0"], "--road-within"),
    (["lift", MISSING, "--camera-height", "nan"], "--camera-height"),
    (["localize", MISSING, MISSING, "--every", "0"], "--every"),
    (["localize", MISSING, MISSING, "--threshold", "nan"], "--threshold"),
    (["localize", MISSING, MISSING, "--min-inliers", "0"], "--min-inliers"),
    (["attack", MISSING, "--method", "bogus"], "--method"),
    (["attack", MISSING, "--refine", "-1"], "--refine"),
    (["attack", MISSING, "--method", "plane", "--plane", "0,0,0,1"], "--plane"),
    (["attack", MISSING, "--method", "plane", "--plane", "0,1,0"], "--plane"),
    (["attack", MISSING, "--method", "plane", "--plane", "0,1,0,inf"], "--plane"),
    (["attack", MISSING, "--method", "road", "--camera-height", "0"], "--camera-height"),
    (["eval-points", MISSING, MISSING, "--method", "bogus"], "--method"),
    # filter
    (["filter", MISSING, "--method", "bogus"], "--method"),
    (["filter", MISSING, "--masks", "bogus"], "--masks"),
    (["filter", MISSING, "--conf", "1.5"], "--conf"),
    (["filter", MISSING, "--conf", "nan"], "--conf"),
    (["filter", MISSING, "--propagate", "-1"], "--propagate"),
    (["filter", MISSING, "--dilation", "-1"], "--dilation"),
    (["filter", MISSING, "--seed", "-1"], "--seed"),
    # slam
    (["slam", MISSING, "--mode", "bogus"], "--mode"),
    (["slam", MISSING, "--seed", "-1"], "--seed"),
    (["slam", MISSING, "--max-frames", "0"], "--max-frames"),
    (["slam", MISSING, "--max-frames", "-2"], "--max-frames"),
    (["slam", MISSING, "--new-map-after", "-1"], "--new-map-after"),
    (["slam", MISSING, "--stereo-max-depth-baselines", "0"], "--stereo-max-depth-baselines"),
    (["slam", MISSING, "--stereo-max-depth-baselines", "nan"], "--stereo-max-depth-baselines"),
    (["slam", MISSING, "--stereo-max-depth-baselines", "-inf"], "--stereo-max-depth-baselines"),
    (["slam", MISSING, "--vocabulary", MISSING], "--vocabulary"),
    (["slam", MISSING, "--loop-closing", "--vocabulary", str(REPO / "README.md")], "--vocabulary"),
    # the edge split (serve takes no --out)
    (["serve", "--store", MISSING, "--max-sessions", "0"], "--max-sessions"),
    (["serve", "--store", MISSING, "--max-message-mb", "-1"], "--max-message-mb"),
    (["serve", "--store", MISSING, "--tls-cert", MISSING], "--tls-key"),
    (["serve", "--store", MISSING, "--token-file", MISSING], "--token-file"),
    (["client", MISSING, "--server", "localhost:1", "--mode", "bogus"], "--mode"),
    (["client", MISSING, "--server", "localhost:1", "--session", "a/b"], "--session"),
    (["client", MISSING, "--server", "localhost:1", "--deadline", "0"], "--deadline"),
    (["client", MISSING, "--server", "localhost:1", "--reconnect-for", "nan"], "--reconnect-for"),
    (["client", MISSING, "--server", "localhost:1", "--max-frames", "0"], "--max-frames"),
    (["client", MISSING, "--server", "localhost:1", "--dilation", "-1"], "--dilation"),
    (["client", MISSING, "--server", "localhost:1", "--token-file", MISSING], "--token-file"),
]


def _id(case) -> str:
    argv = case.values[0] if hasattr(case, "values") else case[0]
    return " ".join(a if a != MISSING else "MISSING" for a in argv)


@pytest.mark.parametrize(("argv", "option"), PRIVSLAM_CASES, ids=[_id(c) for c in PRIVSLAM_CASES])
def test_privslam_refuses_bad_option_value(argv, option, tmp_path, capsys):
    out = tmp_path / "out"
    _check(privslam_main, argv if argv[0] in ("eval-points", "serve") else [*argv, "--out", str(out)], option, capsys)
    if argv[0] in OWN_OUT or argv[0] in ("synth", "import"):
        assert not out.exists(), "the output folder was claimed before the options were checked"


def test_every_subcommand_is_covered():
    import argparse

    from privslam_jax.cli import build_parser

    covered = {(c.values[0] if hasattr(c, "values") else c[0])[0] for c in PRIVSLAM_CASES}
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert covered == set(sub.choices)


def test_depth_limit_takes_a_positive_number_or_inf():
    """``--stereo-max-depth-baselines``' type: ``inf`` (ORB-SLAM's every depth) passes, as any number > 0."""
    import math

    from privslam_jax.argtypes import positive_or_inf

    assert positive_or_inf("inf") == positive_or_inf(" Infinity ") == math.inf
    assert positive_or_inf("80") == 80.0 and positive_or_inf("1e-3") == 1e-3


def test_eval_points_names_the_missing_lines_file(tmp_path, capsys):
    """eval-points has no numeric option: a --lines file that does not exist is named on the one error line."""
    import jax.numpy as jnp
    import numpy as np

    from privslam_jax.data.ply import save_point_cloud
    from privslam_jax.types import PointCloud

    pts = tmp_path / "points.ply"
    save_point_cloud(pts, PointCloud(xyz=jnp.asarray(np.random.default_rng(0).normal(size=(5, 3)))))
    lines = tmp_path / "no_lines.ply"
    assert _exit_code(privslam_main, ["eval-points", str(pts), str(pts), "--lines", str(lines)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("privslam eval-points: error:") and str(lines) in err[0]


# ---------------------------------------------------------------- train/ scripts

def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"_train_{name}", REPO / "train" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


DETECTOR = ["--data", MISSING, "--num-classes", "2"]
INPAINT = ["--folder", MISSING, "--workdir", MISSING]
LABELS = ["--synthetic", MISSING, "--out", MISSING]

TRAIN_CASES = [
    ("detector", [*DETECTOR, "--optimizer", "bogus"], "--optimizer"),
    ("detector", [*DETECTOR, "--scale", "bogus"], "--scale"),
    ("detector", [*DETECTOR, "--domain", "bogus"], "--domain"),
    ("detector", ["--data", MISSING, "--num-classes", "0"], "--num-classes"),
    ("detector", [*DETECTOR, "--imgsz", "0"], "--imgsz"),
    ("detector", [*DETECTOR, "--imgsz", "33"], "--imgsz"),
    ("detector", [*DETECTOR, "--imgh", "200"], "--imgh"),
    ("detector", [*DETECTOR, "--imgsz", "320", "--imgh", "352"], "--imgh"),
    ("detector", [*DETECTOR, "--batch", "0"], "--batch"),
    ("detector", [*DETECTOR, "--batch", "-4"], "--batch"),
    ("detector", [*DETECTOR, "--devices", "0"], "--devices"),
    ("detector", [*DETECTOR, "--batch", "3", "--devices", "2"], "--devices"),
    ("detector", [*DETECTOR, "--batch", "4096", "--devices", "4096"], "--devices"),
    ("detector", [*DETECTOR, "--process-id", "1"], "--distributed"),
    ("detector", [*DETECTOR, "--num-processes", "0"], "--num-processes"),
    ("detector", [*DETECTOR, "--distributed", "--num-processes", "2", "--process-id", "2"], "--distributed"),
    ("detector", [*DETECTOR, "--epochs", "0"], "--epochs"),
    ("detector", [*DETECTOR, "--lr0", "nan"], "--lr0"),
    ("detector", [*DETECTOR, "--lr0", "-0.01"], "--lr0"),
    ("detector", [*DETECTOR, "--lrf", "-1"], "--lrf"),
    ("detector", [*DETECTOR, "--momentum", "1.5"], "--momentum"),
    ("detector", [*DETECTOR, "--ckpt-every", "0"], "--ckpt-every"),
    ("detector", [*DETECTOR, "--warmup-epochs", "-1"], "--warmup-epochs"),
    ("detector", [*DETECTOR, "--warmup-bias-lr", "inf"], "--warmup-bias-lr"),
    ("detector", [*DETECTOR, "--max-steps", "-1"], "--max-steps"),
    ("detector", [*DETECTOR, "--domain-rand", "2"], "--domain-rand"),
    ("detector", [*DETECTOR, "--style", "1.5"], "--style"),
    ("detector", [*DETECTOR, "--style", "0.5"], "--style"),  # no --style-frames
    ("detector", [*DETECTOR, "--style", "0.5", "--style-frames", MISSING], "--style-frames"),
    ("detector", [*DETECTOR, "--style-beta", "0.5"], "--style-beta"),
    ("detector", [*DETECTOR, "--style-frames", MISSING], "--style-frames"),  # without --style
    ("detector", [*DETECTOR, "--seed", "-1"], "--seed"),
    ("detector", [*DETECTOR, "--synth-frames", "0"], "--synth-frames"),
    ("detector", [*DETECTOR, "--synth-stride", "0"], "--synth-stride"),
    ("detector", [*DETECTOR, "--synth-train-seeds", "5-2"], "--synth-train-seeds"),
    ("detector", [*DETECTOR, "--synth-val-seeds", "a-b"], "--synth-val-seeds"),
    ("detector", ["--data", MISSING, "--num-classes", "9", "--coco-names"], "--coco-names"),
    ("inpaint", [*INPAINT, "--hole-loss", "bogus"], "--hole-loss"),
    ("inpaint", [*INPAINT, "--prefill", "bogus"], "--prefill"),
    ("inpaint", [*INPAINT, "--width", "0"], "--width"),
    ("inpaint", [*INPAINT, "--inpaint-width", "-1"], "--inpaint-width"),
    ("inpaint", [*INPAINT, "--export-prefill-blend", "1.5"], "--export-prefill-blend"),
    ("inpaint", [*INPAINT, "--export-prefill-blend", "0.8"], "--export-prefill-blend"),  # the white prefill has no blend
    ("inpaint", [*INPAINT, "--export-prefill-blend-distance", "-1"], "--export-prefill-blend-distance"),
    ("inpaint", [*INPAINT, "--export-prefill-blend-distance", "5"], "--export-prefill-blend-distance"),  # nor with white
    ("inpaint", [*INPAINT, "--export-prefill-blend-unit", "metres"], "--export-prefill-blend-unit"),
    ("inpaint", [*INPAINT, "--blend-distance", "0"], "--blend-distance"),
    ("inpaint", [*INPAINT, "--init", MISSING], "--init"),
    ("inpaint", [*INPAINT, "--init", str(REPO / "privslam_jax/assets/inpainter_cpu16.npz"), "--inpaint-width", "40"], "--init"),
    ("inpaint", [*INPAINT, "--devices", "0"], "--devices"),
    ("inpaint", [*INPAINT, "--batch", "3", "--devices", "2"], "--devices"),
    ("inpaint", [*INPAINT, "--batch", "4096", "--devices", "4096"], "--devices"),
    ("inpaint", [*INPAINT, "--coordinator", "127.0.0.1:1"], "--distributed"),
    ("inpaint", [*INPAINT, "--blocks", "-1"], "--blocks"),
    ("inpaint", [*INPAINT, "--size", "30"], "--size"),
    ("inpaint", [*INPAINT, "--size", "0"], "--size"),
    ("inpaint", [*INPAINT, "--batch", "0"], "--batch"),
    ("inpaint", [*INPAINT, "--checkpoint-every", "0"], "--checkpoint-every"),
    ("inpaint", [*INPAINT, "--sample-every", "-1"], "--sample-every"),
    ("inpaint", [*INPAINT, "--max-steps", "-1"], "--max-steps"),
    ("inpaint", [*INPAINT, "--lr", "nan"], "--lr"),
    ("inpaint", [*INPAINT, "--lr", "0"], "--lr"),
    ("inpaint", [*INPAINT, "--inpaint-lr", "-1e-4"], "--inpaint-lr"),
    ("inpaint", [*INPAINT, "--inpaint-beta1", "1"], "--inpaint-beta1"),
    ("inpaint", [*INPAINT, "--inpaint-lr-final", "-1"], "--inpaint-lr-final"),
    ("inpaint", [*INPAINT, "--inpaint-adv-weight", "-0.1"], "--inpaint-adv-weight"),
    ("inpaint", [*INPAINT, "--real-weight", "1.5"], "--real-weight"),
    ("inpaint", [*INPAINT, "--seed", "-1"], "--seed"),
    ("inpaint", [*INPAINT, "--frame-stride", "0"], "--frame-stride"),
    ("inpaint", ["--synth-frames", "0", "--workdir", MISSING], "--synth-frames"),
    ("inpaint", ["--synth-frames", "2", "--synth-seeds", "5-2", "--workdir", MISSING], "--synth-seeds"),
    ("inpaint", [*INPAINT, "--steps", "1,2"], "--steps"),
    ("inpaint", [*INPAINT, "--steps", "1,-2,3"], "--steps"),
    ("inpaint", [*INPAINT, "--steps", "a,b,c"], "--steps"),
    ("inpaint", [*INPAINT, "--stages", "warmup:3"], "--stages"),
    ("inpaint", [*INPAINT, "--stages", "edge"], "--stages"),
    ("inpaint", [*INPAINT, "--stages", "edge:-1"], "--stages"),
    ("inpaint", ["--real", MISSING, "--shapes", MISSING, "--shape-files", "5", "--workdir", MISSING], "--shape-files"),
    ("pseudo_labels", ["--weights", "w.npz", *LABELS, "--repeat", "0"], "--repeat"),
    ("pseudo_labels", ["--weights", "w.npz", *LABELS, "--label-conf", "1.5"], "--label-conf"),
    ("real_labels", [*LABELS, "--window", "-1"], "--window"),
    ("real_labels", [*LABELS, "--repeat", "0"], "--repeat"),
    ("real_labels", [*LABELS, "--paste-copies", "-1"], "--paste-copies"),
    ("real_labels", [*LABELS, "--paste-retexture", "1.5"], "--paste-retexture"),
    ("real_labels", [*LABELS, "--paste-match-light", "-0.1"], "--paste-match-light"),
    ("real_labels", [*LABELS, "--paste-synthetic-seeds", "a-b"], "--paste-synthetic-seeds"),
    ("real_labels", [*LABELS, "--paste-copies", "2", "--paste-synthetic-seeds", "5-2"], "--paste-synthetic-seeds"),
    ("real_labels", [*LABELS, "--paste-synthetic-seeds", "5-6"], "--paste-synthetic-seeds"),
    ("real_labels", [*LABELS, "--paste-copies", "2", "--paste-retexture", "0.5"], "--paste-retexture"),
    ("real_labels", [*LABELS, "--paste-real-matte", "grabcut"], "--paste-real-matte"),
    ("tradeoff", ["--workdir", MISSING, "--steps", "0"], "--steps"),
    ("tradeoff", ["--workdir", MISSING, "--privacy-weight", "-1"], "--privacy-weight"),
    ("tradeoff", ["--workdir", MISSING, "--accuracy-weight", "nan"], "--accuracy-weight"),
    ("tradeoff", ["--workdir", MISSING, "--lr", "0"], "--lr"),
    ("tradeoff", ["--workdir", MISSING, "--worlds", "5-2"], "--worlds"),
    ("tradeoff", ["--workdir", MISSING, "--frames", "1"], "--frames"),
    ("tradeoff", ["--workdir", MISSING, "--batch", "0"], "--batch"),
    ("tradeoff", ["--workdir", MISSING, "--batch", "3", "--devices", "2"], "--devices"),
    ("tradeoff", ["--workdir", MISSING, "--detector-input", "64x0"], "--detector-input"),
    ("tradeoff", ["--workdir", MISSING, "--width", "-5"], "--width"),
    ("tradeoff", ["--workdir", MISSING, "--init", MISSING], "--init"),
    ("tradeoff", ["--workdir", MISSING, "--detector", MISSING], "--detector"),
    ("tradeoff", ["--workdir", MISSING, "--init", str(REPO / "README.md")], "--init"),
    ("tradeoff", ["--workdir", MISSING, "--detector", str(REPO / "privslam_jax/assets/inpainter_cpu16.npz")], "--detector"),
    ("vocabulary", ["--out", MISSING, "--words", "0"], "--words"),
    ("vocabulary", ["--out", MISSING, "--words", "1"], "--words"),
    ("vocabulary", ["--out", MISSING, "--synth-seeds", "5-2"], "--synth-seeds"),
    ("vocabulary", ["--out", MISSING, "--stride", "0"], "--stride"),
    ("synthetic_shapes", ["--out", MISSING, "--seeds", "5-2"], "--seeds"),
    ("synthetic_shapes", ["--out", MISSING, "--frames", "10,x"], "--frames"),
    ("synthetic_shapes", ["--out", MISSING, "--frames", "100"], "--frames"),
    ("synthetic_shapes", ["--out", MISSING, "--min-area", "0"], "--min-area"),
    ("synthetic_shapes", ["--out", __file__], "--out"),
]


@pytest.fixture(scope="module")
def train_scripts() -> dict[str, ModuleType]:
    return {name: _load(name) for name in ("detector", "inpaint", "pseudo_labels", "real_labels", "synthetic_shapes", "tradeoff",
                                            "vocabulary")}


@pytest.mark.parametrize(("script", "argv", "option"), TRAIN_CASES,
                         ids=[f"{s} " + " ".join(a for a in argv if a != MISSING) for s, argv, _ in TRAIN_CASES])
def test_train_script_refuses_bad_option_value(script, argv, option, train_scripts, capsys):
    _check(train_scripts[script].main, argv, option, capsys)


def test_every_train_script_is_covered():
    assert {s for s, _, _ in TRAIN_CASES} == {p.stem for p in (REPO / "train").glob("*.py")}


@pytest.mark.parametrize(("flag", "zero_mean"), [([], True), (["--stereo-zero-mean-sad"], True),
                                               (["--no-stereo-zero-mean-sad"], False)])
def test_slam_passes_its_stereo_options_to_the_config(flag, zero_mean, tmp_path, monkeypatch):
    """``privslam slam``'s flags reach ``SlamConfig`` (the run itself is stubbed out after that)."""
    import privslam_jax.commands.slam as slam_cmd
    import privslam_jax.slam.system as system
    from privslam_jax.types import Camera

    class Stop(Exception):
        pass

    seen = {}

    def fake_run_slam(frames, camera, cfg, **kw):
        seen["cfg"] = cfg
        raise Stop

    cam = Camera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=4, height=4, baseline=0.5)
    seq = type("S", (), {"camera": cam, "timestamps": [0.0]})()
    monkeypatch.setattr(slam_cmd, "load_sequence_frames", lambda path, mode, n: (seq, iter([]), 1))
    monkeypatch.setattr(system, "run_slam", fake_run_slam)
    with pytest.raises(Stop):
        privslam_main(["slam", str(tmp_path / "seq"), "--mode", "stereo", "--stereo-max-depth-baselines", "80",
                       *flag, "--out", str(tmp_path / "out")])
    assert seen["cfg"].stereo_zero_mean_sad is zero_mean
    assert seen["cfg"].stereo_max_depth_baselines == 80.0 and seen["cfg"].mode == "stereo"
