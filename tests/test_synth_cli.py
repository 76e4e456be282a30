"""``privslam synth``: the KITTI-layout writer, read back with the KITTI reader."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from privslam_jax.data.kitti_write import sequence_stats, summarize_sequence, write_kitti_sequence
from privslam_jax.data.kitti import KittiSequence
from privslam_jax.types import Camera, Trajectory


class _FakeSequence:
    """A tiny stand-in with the SyntheticSequence interface (random content, known answers)."""

    def __init__(self, n=3, h=24, w=40, stereo=True):
        rng = np.random.default_rng(0)
        self.camera = Camera(fx=30.0, fy=31.0, cx=19.5, cy=11.5, width=w, height=h, baseline=0.54 if stereo else None)
        self.config = SimpleNamespace(baseline=0.54, stereo=stereo)
        self.instance_classes = {1: 0, 2: 2, 3: 7}
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, :3, :3] = Rotation.from_euler("y", np.linspace(0, 0.3, n)[:, None]).as_matrix()
        T[:, :3, 3] = np.stack([np.zeros(n), np.zeros(n), np.arange(n) * 1.5 + 0.123456789], 1)
        self._T = T
        self._frames = []
        for i in range(n):
            ids = np.zeros((h, w), np.int32)
            ids[2:10, 3:9] = 1
            ids[12:20, 20 + i : 35] = 2
            boxes = np.array([[3, 2, 9, 10], [20 + i, 12, 35, 20]], np.float32)
            self._frames.append(
                SimpleNamespace(
                    index=i,
                    timestamp=i / 10.0,
                    image=rng.random((h, w, 3)).astype(np.float32),
                    image_right=rng.random((h, w, 3)).astype(np.float32) if stereo else None,
                    depth=rng.uniform(1.0, 80.0, (h, w)).astype(np.float32),
                    depth_right=rng.uniform(1.0, 300.0, (h, w)).astype(np.float32) if stereo else None,
                    instance_ids=ids,
                    background=rng.random((h, w, 3)).astype(np.float32),
                    background_right=rng.random((h, w, 3)).astype(np.float32) if stereo else None,
                    boxes=boxes,
                    class_ids=np.array([0, 2], np.int32),
                    instance_of_box=np.array([1, 2], np.int32),
                    T_w_c=T[i],
                )
            )

    def __len__(self):
        return len(self._frames)

    def __getitem__(self, i):
        return self._frames[i]

    @property
    def trajectory(self):
        return Trajectory.from_matrices(np.arange(len(self)) / 10.0, self._T)


def _check_roundtrip(seq, seq_dir, stereo):
    back = KittiSequence(seq_dir, stereo=stereo)
    assert len(back) == len(seq)
    c, b = seq.camera, back.camera
    assert (b.fx, b.fy, b.cx, b.cy, b.width, b.height) == (c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    assert b.baseline == pytest.approx(0.54 if c.baseline is None else c.baseline, rel=1e-9)
    assert back.instance_classes == {int(k): int(v) for k, v in seq.instance_classes.items()}
    for i in range(len(seq)):
        f, g = seq[i], back[i]
        q = lambda x: np.rint(np.clip(np.asarray(x), 0, 1) * 255) / 255  # noqa: E731 (8-bit PNG)
        np.testing.assert_allclose(g.image, q(f.image), atol=1e-6)
        np.testing.assert_allclose(g.background, q(f.background), atol=1e-6)
        if stereo:
            np.testing.assert_allclose(g.image_right, q(f.image_right), atol=1e-6)
            np.testing.assert_allclose(g.background_right, q(f.background_right), atol=1e-6)
            dr = np.asarray(f.depth_right)
            far = dr >= 256.0
            np.testing.assert_allclose(g.depth_right[~far], dr[~far], atol=0.5 / 256 + 1e-6)
            assert np.all(g.depth_right[far] == 0)  # beyond the 16-bit range: "no depth"
        else:
            assert g.depth_right is None and g.background_right is None
        np.testing.assert_array_equal(g.instance_ids, np.asarray(f.instance_ids))
        d = np.asarray(f.depth)
        ok = d < 255.0
        np.testing.assert_allclose(g.depth[ok], d[ok], atol=0.5 / 256 + 1e-6)
        np.testing.assert_allclose(g.boxes, np.asarray(f.boxes), atol=2e-3 * max(c.width, c.height) / 1000 + 1e-3)
        np.testing.assert_array_equal(g.class_ids, np.asarray(f.class_ids))
        np.testing.assert_allclose(g.T_w_c, np.asarray(f.T_w_c, np.float64), rtol=0, atol=1e-12)
        assert g.timestamp == pytest.approx(float(f.timestamp), abs=1e-9)


@pytest.mark.parametrize("stereo", [True, False])
def test_fake_sequence_roundtrip(tmp_path, stereo):
    seq = _FakeSequence(stereo=stereo)
    seq_dir = write_kitti_sequence(seq, tmp_path / "out", "tiny", progress=False)
    assert seq_dir == tmp_path / "out/sequences/tiny"
    assert (tmp_path / "out/poses/tiny.txt").is_file()
    assert (seq_dir / "image_3").is_dir() == stereo
    _check_roundtrip(seq, seq_dir, stereo)
    P = np.loadtxt(seq_dir / "calib.txt", usecols=range(1, 13)).reshape(4, 3, 4)
    np.testing.assert_allclose(P[1, 0, 3], -30.0 * 0.54)
    np.testing.assert_array_equal(P[0], P[2])
    np.testing.assert_array_equal(P[1], P[3])


def test_summary_counts(tmp_path):
    seq = _FakeSequence(n=3)
    s = sequence_stats(seq)
    assert s["frames"] == 3 and (s["width"], s["height"]) == (40, 24)
    assert s["path_length_m"] == pytest.approx(3.0)
    assert s["objects_per_class"] == {0: 1, 2: 1, 7: 1}
    assert s["visible_objects_per_class"] == {0: 1, 2: 1}
    assert s["boxes_per_class"] == {0: 3, 2: 3}
    assert s["mean_boxes_per_frame"] == pytest.approx(2.0)
    text = summarize_sequence(seq, title="fake")
    assert "3 frames" in text and "40x24" in text and "person 3" in text and "3.0 m" in text
    # the written folder summarises to the same boxes
    seq_dir = write_kitti_sequence(seq, tmp_path, progress=False)
    s2 = sequence_stats(KittiSequence(seq_dir))
    assert s2["boxes_per_class"] == s["boxes_per_class"]
    assert s2["path_length_m"] == pytest.approx(3.0)


def _synth_main(argv):
    """Parse and run like ``privslam synth`` (the subparser of privslam_jax.commands.synth)."""
    import argparse

    from privslam_jax.commands import synth

    parser = argparse.ArgumentParser(prog="privslam")
    synth.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


# The frame sizes below are ones other files render in the same XLA mode (tests/test_synthetic.py):
# the suite's shared compilation cache then hands this file the renderer instead of compiling it.


def test_cli_writes_and_reads_back(tmp_path, capsys):
    from privslam_jax.data.synthetic import SynthConfig, make_sequence

    rc = _synth_main(["synth", "--out", str(tmp_path), "--frames", "3", "--width", "640", "--height", "192", "--stereo",
               "--name", "t", "--quiet"])
    assert rc == 0
    assert "3 frames" in capsys.readouterr().out
    seq = make_sequence(SynthConfig(width=640, height=192, num_frames=3, seed=0, stereo=True))
    _check_roundtrip(seq, tmp_path / "sequences/t", stereo=True)


def test_cli_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="--frames must be at least 1"):
        _synth_main(["synth", "--out", str(tmp_path), "--frames", "0"])
    with pytest.raises(ValueError, match="--name"):
        _synth_main(["synth", "--out", str(tmp_path), "--name", "a/b"])


def test_instance_ids_reader_and_slam_ignore_masked_needs_masks(tmp_path, capsys):
    import shutil

    from privslam_jax.cli import main
    from privslam_jax.data.kitti import KittiSequence

    _synth_main(["synth", "--out", str(tmp_path), "--frames", "2", "--width", "160", "--height", "48", "--name", "t",
                 "--quiet"])
    seq_dir = tmp_path / "sequences/t"
    seq = KittiSequence(seq_dir)
    np.testing.assert_array_equal(seq.instance_ids(1), seq[1].instance_ids)
    shutil.rmtree(seq_dir / "masks")
    with pytest.raises(FileNotFoundError, match="masks"):
        KittiSequence(seq_dir).instance_ids(0)
    assert main(["slam", str(seq_dir), "--ignore-masked", "--out", str(tmp_path / "out")]) == 2
    assert "--ignore-masked needs" in capsys.readouterr().err
