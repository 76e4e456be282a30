"""``privslam filter`` on a tiny KITTI-layout sequence with ground-truth masks."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from privslam_jax.cli import main
from privslam_jax.data.kitti import KittiSequence
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig

H, W, N = 40, 64, 3


def _make_sequence(root):
    seq = root / "sequences" / "tiny"
    for d in ("image_2", "masks"):
        (seq / d).mkdir(parents=True)
    (root / "poses").mkdir()
    rng = np.random.default_rng(0)
    ids_all = []
    for i in range(N):
        img = (rng.random((H, W, 3)) * 255).astype(np.uint8)
        ids = np.zeros((H, W), np.uint16)
        if i != 1:  # frame 1 has no object
            ids[10:20, 5 + 10 * i:20 + 10 * i] = 7
        ids[25:35, 40:50] = 9 if i == 2 else 0
        cv2.imwrite(str(seq / "image_2" / f"{i:06d}.png"), img)
        cv2.imwrite(str(seq / "masks" / f"{i:06d}.png"), ids)
        ids_all.append(ids)
    P = "P{k}: 50 0 32 {t} 0 50 20 0 0 0 1 0"
    (seq / "calib.txt").write_text("\n".join(P.format(k=k, t=-27.0 if k % 2 else 0.0) for k in range(4)) + "\n")
    (seq / "times.txt").write_text("".join(f"{i / 10:.6f}\n" for i in range(N)))
    (seq / "instance_classes.json").write_text(json.dumps({"7": 2, "9": 0}))
    (root / "poses" / "tiny.txt").write_text("".join("1 0 0 0 0 1 0 0 0 0 1 %d\n" % i for i in range(N)))
    return seq, ids_all


def _dilated(ids, r=2):
    from privslam_jax.inpaint.masks import dilate

    return dilate(ids > 0, r)


@pytest.mark.parametrize("method", ["black", "telea"])
def test_filter_command_writes_kitti_layout(tmp_path, method):
    seq, ids_all = _make_sequence(tmp_path / "in")
    rc = main(["filter", str(seq), "--method", method, "--out", str(tmp_path / "out"), "--dilation", "2"])
    assert rc == 0
    out = tmp_path / "out" / "sequences" / "tiny"
    assert (out / "calib.txt").read_text() == (seq / "calib.txt").read_text()
    assert (out / "times.txt").read_text() == (seq / "times.txt").read_text()
    assert (tmp_path / "out" / "poses" / "tiny.txt").is_file()
    back = KittiSequence(out)
    assert len(back) == N and back.instance_classes == {7: 2, 9: 0}
    for i in range(N):
        src = cv2.imread(str(seq / "image_2" / f"{i:06d}.png"))
        dst = cv2.imread(str(out / "image_2" / f"{i:06d}.png"))
        hidden = _dilated(ids_all[i])
        np.testing.assert_array_equal(dst[~hidden], src[~hidden])  # outside untouched
        np.testing.assert_array_equal(back[i].instance_ids > 0, hidden)
        if method == "black":
            assert np.all(dst[hidden] == 0)
        if i == 1:
            np.testing.assert_array_equal(dst, src)  # no object: bit-identical frame


def test_filter_command_edgeconnect_and_errors(tmp_path, capsys):
    seq, ids_all = _make_sequence(tmp_path / "in")
    model = tmp_path / "m.npz"
    Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1, size=32, min_crop=16)).save(model)
    assert main(["filter", str(seq), "--method", "edgeconnect", "--model", str(model),
                 "--out", str(tmp_path / "o")]) == 0
    dst = cv2.imread(str(tmp_path / "o" / "sequences" / "tiny" / "image_2" / "000002.png"))
    src = cv2.imread(str(seq / "image_2" / "000002.png"))
    hidden = _dilated(ids_all[2], 4)
    np.testing.assert_array_equal(dst[~hidden], src[~hidden])
    assert not np.array_equal(dst[hidden], src[hidden])
    from privslam_jax.inpaint.filter import EMBEDDED_INPAINTER

    if not EMBEDDED_INPAINTER.is_file():  # no --model: the embedded checkpoint, or a clear error
        assert main(["filter", str(seq), "--method", "edgeconnect", "--out", str(tmp_path / "o2")]) == 2
        assert "embedded inpainter" in capsys.readouterr().err
    assert main(["filter", str(tmp_path / "nope"), "--method", "black", "--out", str(tmp_path / "o3")]) == 2
    from privslam_jax.cli import build_parser

    assert build_parser().parse_args(["filter", str(seq), "--out", "x"]).method == "edgeconnect"  # the default
