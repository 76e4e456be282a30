"""Run folders (issue 15 item 7): a manifest written first with "complete": false and rewritten
last; a rerun into a folder holding another run refuses unless --overwrite; --overwrite never
clears a folder privslam did not write."""

import json

import pytest

from privslam_jax.cli import main
from privslam_jax.runs import MANIFEST, claim_run_folder, complete_run_folder, read_manifest


def test_manifest_is_incomplete_until_the_run_completes(tmp_path):
    out = tmp_path / "r"
    m = claim_run_folder(out, "slam", {"seed": 3})
    on_disk = read_manifest(out)
    assert on_disk["complete"] is False and on_disk["arguments"] == {"seed": 3}
    assert {"python", "numpy", "jax"} <= set(on_disk["versions"])
    complete_run_folder(out, m)
    assert read_manifest(out)["complete"] is True


def test_manifest_is_strict_json_with_an_infinite_argument(tmp_path):
    """``--stereo-max-depth-baselines inf`` in the arguments: both manifests parse with a parser that
    refuses JSON's missing Infinity/NaN, the values kept as strings."""
    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c} in the manifest"))

    out = tmp_path / "r"
    m = claim_run_folder(out, "slam", {"stereo_max_depth_baselines": float("inf"), "limits": [1.0, float("nan")]})
    assert strict((out / MANIFEST).read_text())["arguments"] == {"stereo_max_depth_baselines": "inf",
                                                                  "limits": [1.0, "nan"]}
    complete_run_folder(out, m)
    assert strict((out / MANIFEST).read_text())["complete"] is True


def test_a_folder_with_another_run_is_refused_then_cleared_with_overwrite(tmp_path):
    out = tmp_path / "r"
    claim_run_folder(out, "slam", {})
    (out / "trajectory.txt").write_text("old")
    with pytest.raises(ValueError, match="earlier unfinished `privslam slam` run"):
        claim_run_folder(out, "slam", {})
    assert (out / "trajectory.txt").read_text() == "old"  # nothing lost by the refusal
    claim_run_folder(out, "slam", {}, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST]


def test_overwrite_never_clears_a_folder_privslam_did_not_write(tmp_path):
    (tmp_path / "mine.txt").write_text("keep")
    with pytest.raises(ValueError, match="holds no privslam run"):
        claim_run_folder(tmp_path, "run", {}, overwrite=True)
    assert (tmp_path / "mine.txt").read_text() == "keep"
    with pytest.raises(ValueError, match="is a file"):
        claim_run_folder(tmp_path / "mine.txt", "run", {})


def test_cli_rerun_refuses_and_a_failed_run_stays_incomplete(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", "--out", str(out), "--frames", "4", "--masks", "gt", "--filter", "gray", "--no-slam", "--quiet"]
    assert main(argv) == 0
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["complete"] is True and manifest["command"] == "run" and manifest["arguments"]["frames"] == 4
    report = (out / "report.json").read_text()
    capsys.readouterr()
    assert main(argv) == 2  # a second run into the same folder
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "report.json").read_text() == report
    # a run that fails after claiming the folder leaves "complete": false
    bad = ["run", str(tmp_path / "missing"), "--out", str(out), "--overwrite", "--quiet"]
    assert main(bad) == 2
    assert json.loads((out / MANIFEST).read_text())["complete"] is False
    assert not (out / "report.json").exists()  # cleared by --overwrite, never rewritten


def _frames(folder):
    return sorted(p.name for p in folder.glob("*.png"))


# The synthetic frames below are 160x48: a size other files render in the same XLA mode, so the suite's
# shared compilation cache hands this file the renderer instead of compiling it (tests/conftest.py).


def test_synth_and_filter_own_their_sequence_folder(tmp_path, capsys):
    """A rerun with other arguments used to mix old and new frames (issue 15 item 7): now refused,
    and --overwrite clears the sequence folder and its poses file first."""
    root, filtered = tmp_path / "k", tmp_path / "f"
    synth = ["synth", "--out", str(root), "--frames", "4", "--width", "160", "--height", "48", "--quiet"]
    assert main(synth) == 0
    seq = root / "sequences" / "synth"
    assert read_manifest(seq)["complete"] is True and read_manifest(seq)["command"] == "synth"
    assert main(synth[:4] + ["3"] + synth[5:]) == 2  # 3 frames into the 4-frame run
    assert "--overwrite" in capsys.readouterr().err
    assert len(_frames(seq / "image_2")) == 4
    assert main(synth[:4] + ["3"] + synth[5:] + ["--overwrite"]) == 0
    assert len(_frames(seq / "image_2")) == 3  # no stale fourth frame
    assert len((root / "poses" / "synth.txt").read_text().splitlines()) == 3

    filt = ["filter", str(seq), "--out", str(filtered), "--method", "gray", "--masks", "gt"]
    assert main(filt) == 0
    out = filtered / "sequences" / "synth"
    assert read_manifest(out)["complete"] is True and read_manifest(out)["arguments"]["method"] == "gray"
    assert main(filt) == 2
    (out / "image_2" / "000099.png").write_bytes((out / "image_2" / "000000.png").read_bytes())
    assert main(filt[:-4] + ["--method", "white", "--masks", "gt", "--overwrite"]) == 0
    assert _frames(out / "image_2") == _frames(seq / "image_2")  # the stray frame was cleared
    assert read_manifest(out)["arguments"]["method"] == "white"


def test_a_poses_file_no_run_owns_is_refused_and_a_failed_filter_stays_incomplete(tmp_path, capsys):
    root = tmp_path / "k"
    (root / "poses").mkdir(parents=True)
    (root / "poses" / "synth.txt").write_text("mine\n")
    synth = ["synth", "--out", str(root), "--frames", "3", "--width", "160", "--height", "48", "--quiet"]
    assert main(synth) == 2 and main(synth + ["--overwrite"]) == 2
    assert "no privslam run" in capsys.readouterr().err
    assert (root / "poses" / "synth.txt").read_text() == "mine\n"  # never touched
    (root / "poses" / "synth.txt").unlink()
    assert main(synth) == 0
    seq = root / "sequences" / "synth"
    (seq / "image_2" / "000001.png").write_bytes(b"not a png")  # fails half-way through the filter
    assert main(["filter", str(seq), "--out", str(tmp_path / "f"), "--method", "gray", "--masks", "gt"]) == 2
    assert "000001.png" in capsys.readouterr().err
    assert read_manifest(tmp_path / "f" / "sequences" / "synth")["complete"] is False


def test_a_frame_of_another_size_is_refused_by_name(tmp_path, capsys):
    import cv2
    import numpy as np

    root = tmp_path / "k"
    assert main(["synth", "--out", str(root), "--frames", "3", "--width", "160", "--height", "48", "--quiet"]) == 0
    seq = root / "sequences" / "synth"
    cv2.imwrite(str(seq / "image_2" / "000002.png"), np.zeros((20, 160, 3), np.uint8))
    for masks in ("gt", "detect"):
        capsys.readouterr()
        assert main(["filter", str(seq), "--out", str(tmp_path / masks), "--method", "gray", "--masks", masks]) == 2
        err = capsys.readouterr().err
        assert "000002.png is 160x20, the sequence's frames are 160x48" in err, err
