"""Safe defaults: checkpoints carry their training domain; a synthetic-only detector is refused on real frames."""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest

from privslam_jax.cli import main
from privslam_jax.inpaint.sequence import check_detector_domain
from privslam_jax.detect import Detector, DetectorConfig
from privslam_jax.detect.predict import EMBEDDED_REAL_WEIGHTS, EMBEDDED_WEIGHTS
from privslam_jax.detect.weights import checkpoint_meta, save_checkpoint
from privslam_jax.detect.yolov8 import YOLOv8Config, init_yolov8

H, W, N = 64, 96, 3


def _tiny_checkpoint(path, **kw):
    save_checkpoint(init_yolov8(YOLOv8Config(num_classes=8, scale="tiny")), path, **kw)
    return path


def test_checkpoint_meta_round_trip_and_old_files(tmp_path):
    p = _tiny_checkpoint(tmp_path / "a.npz", domain="synthetic", card={"real_recall": {"recall": 0.5, "fp_per_image": 1.0}})
    meta = checkpoint_meta(p)
    assert meta["domain"] == "synthetic" and meta["card"]["real_recall"]["recall"] == 0.5
    det = Detector.from_weights(p)
    assert det.domain == "synthetic" and det.meta["path"] == str(p)
    # a file written before the field existed reads as "unknown"
    with np.load(p) as data:
        old = {k: data[k] for k in data.files}
    m = json.loads(str(old["__meta__"]))
    del m["domain"], m["card"]
    old["__meta__"] = np.array(json.dumps(m))
    np.savez(tmp_path / "old.npz", **old)
    assert checkpoint_meta(tmp_path / "old.npz")["domain"] == "unknown"
    assert checkpoint_meta(tmp_path / "model.pt") == {"domain": "real", "card": {"source": "ultralytics"}}
    with pytest.raises(ValueError, match="domain must be one of"):
        _tiny_checkpoint(tmp_path / "b.npz", domain="synthetc")
    with pytest.raises(FileNotFoundError):
        checkpoint_meta(tmp_path / "missing.npz")


@pytest.mark.parametrize("path,domain", [(EMBEDDED_WEIGHTS, "synthetic"), (EMBEDDED_REAL_WEIGHTS, "real")])
def test_embedded_detectors_state_their_domain_and_real_recall(path, domain):
    meta = checkpoint_meta(path)
    assert meta["domain"] == domain
    rr = meta["card"]["real_recall"]
    assert 0 <= rr["recall"] <= 1 and rr["fp_per_image"] >= 0 and "table1b_real_recall.py" in rr["command"]


def test_filter_picks_the_embedded_detector_for_the_frames(tmp_path):
    """Without --detector: the real-frame detector on real frames (with its recall warning), the
    synthetic-world one on a privslam synth output (no warning)."""
    seq = _real_like_sequence(tmp_path / "real", synthetic=False)
    with pytest.warns(UserWarning, match="PRIVACY WARNING.*misses people"):
        assert main(["filter", str(seq), "--masks", "detect", "--method", "black", "--out", str(tmp_path / "o")]) == 0
    report = json.loads((tmp_path / "o" / "sequences" / "s" / "filter_report.json").read_text())
    assert report["detector"]["weights"] == str(EMBEDDED_REAL_WEIGHTS) and report["detector"]["domain"] == "real"
    # recall first on real frames: propagation over ±3 frames unless asked otherwise; the manifest says so too
    manifest = json.loads((tmp_path / "o" / "sequences" / "s" / "manifest.json").read_text())
    assert report["detector"]["propagate"] == 3 and "--propagate" not in report["detector"]["privacy_warning"]
    assert manifest["arguments"]["propagate"] == 3
    with pytest.warns(UserWarning, match="PRIVACY WARNING.*--propagate 3"):
        assert main(["filter", str(seq), "--masks", "detect", "--method", "black", "--propagate", "0",
                     "--out", str(tmp_path / "o0")]) == 0
    assert json.loads((tmp_path / "o0" / "sequences" / "s" / "filter_report.json").read_text())["detector"]["propagate"] == 0
    seq_syn = _real_like_sequence(tmp_path / "syn", synthetic=True)
    assert main(["filter", str(seq_syn), "--masks", "detect", "--method", "black", "--out", str(tmp_path / "o2")]) == 0
    report = json.loads((tmp_path / "o2" / "sequences" / "s" / "filter_report.json").read_text())
    assert report["detector"]["weights"] == str(EMBEDDED_WEIGHTS) and report["detector"]["privacy_warning"] is None
    assert report["detector"]["propagate"] == 0  # the paper's per-frame detection on the synthetic world


class _Fake:
    def __init__(self, domain, card=None):
        self.domain, self.meta = domain, {"domain": domain, "card": card or {}, "path": "x.npz"}


def test_check_detector_domain():
    card = {"real_recall": {"recall": 0.07, "fp_per_image": 1.7, "command": "python experiments/table1b_real_recall.py"}}
    with pytest.raises(ValueError, match="0.07.*--allow-domain-mismatch"):
        check_detector_domain(_Fake("synthetic", card), sequence_is_synthetic=False, allow_mismatch=False)
    with pytest.warns(UserWarning, match="PRIVACY WARNING.*not been measured"):
        text = check_detector_domain(_Fake("synthetic"), sequence_is_synthetic=False, allow_mismatch=True)
    assert "synthetic world only" in text
    assert check_detector_domain(_Fake("synthetic"), sequence_is_synthetic=True, allow_mismatch=False) is None
    for domain in ("real", "unknown"):
        assert check_detector_domain(_Fake(domain), sequence_is_synthetic=False, allow_mismatch=False) is None
    # a real-domain detector whose measured recall is low runs, with the number in a warning
    with pytest.warns(UserWarning, match="PRIVACY WARNING.*0.07.*--tta"):
        assert "misses" in check_detector_domain(_Fake("real", card), sequence_is_synthetic=False, allow_mismatch=False)
    with pytest.warns(UserWarning, match="PRIVACY WARNING"):  # the knobs it suggests are those not in use
        text = check_detector_domain(_Fake("real", card), sequence_is_synthetic=False, allow_mismatch=False, propagate=3)
    assert "--tta and --conf 0.1" in text and "--propagate" not in text
    high = {"real_recall": {"recall": 0.95, "fp_per_image": 1.0}}
    assert check_detector_domain(_Fake("real", high), sequence_is_synthetic=False, allow_mismatch=False) is None


def _real_like_sequence(root, synthetic: bool):
    seq = root / "sequences" / "s"
    (seq / "image_2").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(N):
        cv2.imwrite(str(seq / "image_2" / f"{i:06d}.png"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
        if synthetic:
            (seq / "background").mkdir(exist_ok=True)
            cv2.imwrite(str(seq / "background" / f"{i:06d}.png"), np.zeros((H, W, 3), np.uint8))
    P = "P{k}: 50 0 48 0 0 50 32 0 0 0 1 0"
    (seq / "calib.txt").write_text("\n".join(P.format(k=k) for k in range(4)) + "\n")
    return seq


def test_filter_refuses_synthetic_detector_on_real_frames(tmp_path, capsys):
    weights = _tiny_checkpoint(tmp_path / "syn.npz", domain="synthetic")
    seq = _real_like_sequence(tmp_path / "real", synthetic=False)
    out = tmp_path / "out"
    assert main(["filter", str(seq), "--masks", "detect", "--detector", str(weights), "--method", "black",
                 "--out", str(out)]) == 2
    assert "--allow-domain-mismatch" in capsys.readouterr().err
    assert not out.exists()  # refused before anything was written
    with pytest.warns(UserWarning, match="PRIVACY WARNING"):
        assert main(["filter", str(seq), "--masks", "detect", "--detector", str(weights), "--method", "black",
                     "--allow-domain-mismatch", "--propagate", "1", "--conf", "0.3", "--out", str(out)]) == 0
    report = json.loads((out / "sequences" / "s" / "filter_report.json").read_text())
    det = report["detector"]
    assert (det["domain"], det["conf"], det["propagate"], det["tta"]) == ("synthetic", 0.3, 1, False)
    assert "synthetic world only" in det["privacy_warning"]
    assert len(report["masks_per_frame"]["detected"]) == N
    assert "PRIVACY WARNING" in capsys.readouterr().out
    # a privslam synth output (background/ present) is the synthetic detector's own domain: no warning
    seq_syn = _real_like_sequence(tmp_path / "syn", synthetic=True)
    assert main(["filter", str(seq_syn), "--masks", "detect", "--detector", str(weights), "--method", "black",
                 "--out", str(tmp_path / "out2")]) == 0


def test_the_command_shows_the_privacy_warning_as_one_line_of_its_own(tmp_path):
    """Run as users run it (a process of its own, Python's default warning display): the warning is
    one ``PRIVACY WARNING: …`` line on stderr, without the library's file, line and source text."""
    import subprocess
    import sys

    from privslam_jax.errors import PrivacyWarning

    assert issubclass(PrivacyWarning, UserWarning)
    weights = _tiny_checkpoint(tmp_path / "syn.npz", domain="synthetic")
    seq = _real_like_sequence(tmp_path / "real", synthetic=False)
    run = subprocess.run([sys.executable, "-m", "privslam_jax.cli", "filter", str(seq), "--masks", "detect",
                          "--detector", str(weights), "--method", "black", "--allow-domain-mismatch",
                          "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = [ln for ln in run.stderr.splitlines() if "PRIVACY WARNING" in ln]
    assert len(lines) == 1 and lines[0].startswith("PRIVACY WARNING: the detector "), run.stderr[-2000:]
    assert "Warning:" not in run.stderr and "sequence.py" not in run.stderr and "check_detector_domain" not in run.stderr
    assert "PRIVACY WARNING" in run.stdout  # and once more in the summary the command prints


def test_detector_default_meta_is_unknown():
    det = Detector(init_yolov8(YOLOv8Config(num_classes=8, scale="tiny")), DetectorConfig())
    assert det.domain == "unknown"


def test_filter_takes_a_plain_folder_of_frames(tmp_path):
    from privslam_jax.inpaint.sequence import _consecutive_runs

    assert _consecutive_runs(["0000", "0001", "0007", "0008", "0010"]) == [(0, 2), (2, 4), (4, 5)]
    assert _consecutive_runs(["a", "b"]) == [(0, 2)]
    weights = _tiny_checkpoint(tmp_path / "real.npz", domain="real")
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(1)
    for i in (0, 1, 5):
        cv2.imwrite(str(frames / f"{i:04d}.jpg"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
    assert main(["filter", str(frames), "--detector", str(weights), "--method", "black", "--propagate", "2",
                 "--out", str(tmp_path / "o")]) == 0
    out = tmp_path / "o" / "frames"
    assert sorted(p.name for p in out.glob("*.png")) == ["0000.png", "0001.png", "0005.png"]
    assert len(list((out / "masks").glob("*.png"))) == 3
    report = json.loads((out / "filter_report.json").read_text())
    assert report["runs"] == [["0000", "0001"], ["0005", "0005"]] and report["detector"]["domain"] == "real"
    cv2.imwrite(str(frames / "0006.png"), np.zeros((H + 1, W, 3), np.uint8))  # another size
    assert main(["filter", str(frames), "--detector", str(weights), "--method", "black",
                 "--out", str(tmp_path / "o2")]) == 2
    assert not (tmp_path / "o2").exists()  # refused before anything was written


def test_write_failure_is_an_error_not_a_shorter_sequence(tmp_path, capsys, monkeypatch):
    """Issue 15 item 3: cv2.imwrite's result was unchecked, so a frame that could not be written
    vanished and the run still said 'filtered sequence written'."""
    from privslam_jax.data.images import read_image, write_image_file

    img = (np.random.default_rng(0).random((H, W, 3)) * 255).astype(np.uint8)
    target = tmp_path / "a.png"
    write_image_file(target, img)
    np.testing.assert_array_equal(cv2.imread(str(target)), img)
    (tmp_path / "b.png").mkdir()  # a folder where the frame should go
    with pytest.raises(OSError, match="b.png"):
        write_image_file(tmp_path / "b.png", img)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]  # no temporary left behind
    assert read_image(target).shape == (H, W, 3)
    from privslam_jax.data.files import write_atomic

    write_atomic(tmp_path / "r.json", '{"a": 1}')
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": 1}
    with pytest.raises(OSError, match="b.png"):
        write_atomic(tmp_path / "b.png", b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png", "r.json"]

    weights = _tiny_checkpoint(tmp_path / "real.npz", domain="real")
    seq = _real_like_sequence(tmp_path / "real", synthetic=False)
    out = tmp_path / "out"
    import privslam_jax.inpaint.sequence as sequence_module

    claim = sequence_module.claim_run_folder

    def claim_then_block(folder, *args, **kwargs):  # a folder where frame 1 should go, once the run owns `out`
        manifest = claim(folder, *args, **kwargs)
        (folder / "image_2" / "000001.png").mkdir(parents=True)
        return manifest

    monkeypatch.setattr(sequence_module, "claim_run_folder", claim_then_block)
    assert main(["filter", str(seq), "--masks", "detect", "--detector", str(weights), "--method", "black",
                 "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "000001.png" in captured.err and "written" not in captured.out
    assert json.loads((out / "sequences" / "s" / "manifest.json").read_text())["complete"] is False


def test_filter_picks_the_embedded_inpainter_for_the_frames(tmp_path):
    """EdgeConnect without --model: the real-frame checkpoint (Telea prefill, residual) on real frames,
    the synthetic-world one on a privslam synth output; ``--method tradeoff``: the trade-off checkpoint.
    filter_report.json names it."""
    for synthetic, name in ((False, "real"), (True, "synthetic")):
        seq = _real_like_sequence(tmp_path / name, synthetic=synthetic)
        out = tmp_path / f"o_{name}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the real-frame detector's recall warning
            assert main(["filter", str(seq), "--masks", "detect", "--method", "edgeconnect", "--out", str(out)]) == 0
        inp = json.loads((out / "sequences" / "s" / "filter_report.json").read_text())["inpainter"]
        assert inp["weights"] == f"embedded ({name})"
        assert (inp["config"]["prefill"], inp["config"]["residual"]) == (("white", False) if synthetic else ("telea", True))
    # --method tradeoff: the trade-off checkpoint on either kind of frames
    seq = _real_like_sequence(tmp_path / "t", synthetic=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        assert main(["filter", str(seq), "--masks", "detect", "--method", "tradeoff", "--out", str(tmp_path / "o_t")]) == 0
    inp = json.loads((tmp_path / "o_t" / "sequences" / "s" / "filter_report.json").read_text())["inpainter"]
    assert inp["weights"] == "embedded (tradeoff)"


@pytest.mark.shared
def test_default_filter_hides_the_close_car_that_one_frame_misses(shared, tmp_path):
    """Seven real grey KITTI ``seq1`` frames (22-28) filtered with the defaults: the large parked car of
    frame 25, licence plate readable, that the embedded real-frame detector scores below 0.4 there
    but finds in the frames around it, is masked, as every object the imported YOLOv8n finds there
    at conf ≥ 0.6 (the reference, independent of the filter). With propagation off (the source
    paper's per-frame detection) it stays visible: the default is what hides it."""
    from privslam_jax.data.images import read_image
    from privslam_jax.detect import PRIVACY_CLASSES

    src = shared / "data" / "kitti_odometry" / "sequences" / "seq1"
    seq = tmp_path / "sequences" / "seq1"
    (seq / "image_0").mkdir(parents=True)
    (seq / "calib.txt").write_bytes((src / "calib.txt").read_bytes())
    for i in range(22, 29):
        (seq / "image_0" / f"{i:06d}.png").write_bytes((src / "image_0" / f"{i:06d}.png").read_bytes())
    ref = Detector.from_weights(shared / "weights" / "yolov8n.pt", DetectorConfig(conf=0.6, classes=PRIVACY_CLASSES))
    boxes = np.asarray(ref.detect([read_image(src / "image_0" / "000025.png")])[0].boxes).round().astype(int)
    assert len(boxes) >= 1 and max(y2 - y1 for _, y1, _, y2 in boxes) > 150  # the close car

    def coverage(out):
        mask = cv2.imread(str(out / "sequences" / "seq1" / "masks" / "000025.png"), cv2.IMREAD_UNCHANGED) > 0
        return [float(mask[y1:y2, x1:x2].mean()) for x1, y1, x2, y2 in boxes]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the real-frame detector's recall warning
        assert main(["filter", str(seq), "--masks", "detect", "--method", "black", "--out", str(tmp_path / "d")]) == 0
        assert main(["filter", str(seq), "--masks", "detect", "--method", "black", "--propagate", "0",
                     "--out", str(tmp_path / "p0")]) == 0
    assert min(coverage(tmp_path / "d")) >= 0.9, coverage(tmp_path / "d")
    assert min(coverage(tmp_path / "p0")) < 0.5, coverage(tmp_path / "p0")


def test_client_filters_with_the_recall_options_of_the_filter_command(tmp_path, monkeypatch):
    """``privslam client`` filters on the device as ``privslam filter`` does: ``--propagate`` and
    ``--tta`` reach the same library call (default ``None``: the frames' domain decides)."""
    import privslam_jax.inpaint.sequence as sequence_module

    seq = _real_like_sequence(tmp_path / "real", synthetic=False)
    calls = []

    def stop(*args, **kwargs):
        calls.append(kwargs)
        raise ValueError("stopped before any frame left the device")

    monkeypatch.setattr(sequence_module, "filter_sequence_in_memory", stop)
    base = ["client", str(seq), "--server", "127.0.0.1:9", "--masks", "detect"]
    assert main(base + ["--out", str(tmp_path / "o1"), "--propagate", "2", "--tta"]) == 2
    assert main(base + ["--out", str(tmp_path / "o2")]) == 2
    assert [(c["propagate"], c["tta"]) for c in calls] == [(2, True), (None, False)]
