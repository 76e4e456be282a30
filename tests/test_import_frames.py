"""``privslam import``: a folder of images or a video as a KITTI sequence (privslam_jax.data.import_frames).

Read back by :class:`~privslam_jax.data.kitti.KittiSequence`, as every SLAM command reads it, and
compared with the frames written (PNG: exactly; a Motion-JPEG video: within its compression).
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from privslam_jax.cli import main
from privslam_jax.data.import_frames import hfov_intrinsics, import_frames
from privslam_jax.data.kitti import KittiSequence
from privslam_jax.errors import InputError


def _frames(n: int, h: int = 24, w: int = 40, grey: bool = False, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        img = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3)).astype(np.uint8), (3, 3), 1.0)
        out.append(np.repeat(img[..., :1], 3, axis=2) if grey else img)
    return out


def _write_folder(folder, frames, names) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for img, name in zip(frames, names, strict=True):
        assert cv2.imwrite(str(folder / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def _manifest(seq_dir) -> dict:
    return json.loads((seq_dir / "manifest.json").read_text())


def test_an_image_folder_is_read_in_natural_order_and_comes_back_exactly(tmp_path):
    frames = _frames(12)
    # frame2 before frame10, whatever the suffix case; a text file is not a frame
    _write_folder(tmp_path / "in", frames, [f"frame{i}.{'PNG' if i % 3 else 'png'}" for i in range(12)])
    (tmp_path / "in" / "notes.txt").write_text("not a frame")
    r = import_frames(tmp_path / "in", tmp_path / "out", "mine", camera=(50.0, 51.0, 19.5, 11.5), fps=5.0, every=2,
                      max_frames=5, progress=False)
    assert (r["frames"], r["width"], r["height"], r["grey"]) == (5, 40, 24, False)
    seq = KittiSequence(r["sequence"])
    assert len(seq) == 5 and seq.left_dir.name == "image_2"
    for k in range(5):
        np.testing.assert_array_equal(np.rint(seq.image(k) * 255).astype(np.uint8), frames[2 * k])
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == (50.0, 51.0, 19.5, 11.5)
    assert seq.camera.baseline is None  # monocular: no right camera row
    np.testing.assert_allclose(seq.timestamps, np.arange(5) * 2 / 5.0)
    assert _manifest(r["sequence"])["complete"] is True


def test_grey_frames_go_to_image_0_and_the_field_of_view_gives_the_focal_length(tmp_path):
    frames = _frames(3, grey=True)
    _write_folder(tmp_path / "in", frames, ["a.png", "b.png", "c.png"])
    r = main(["import", str(tmp_path / "in"), "--out", str(tmp_path / "out"), "--hfov", "90", "--quiet"])
    assert r == 0
    seq = KittiSequence(tmp_path / "out" / "sequences" / "imported", grey=True)
    assert seq.left_dir.name == "image_0" and len(seq) == 3
    np.testing.assert_array_equal(np.rint(seq.image(1) * 255).astype(np.uint8), frames[1][..., 0])
    # hfov 90°: the image's half width is one focal length
    assert seq.camera.fx == pytest.approx(20.0) and seq.camera.fy == pytest.approx(20.0)
    assert (seq.camera.cx, seq.camera.cy) == (19.5, 11.5)
    fx, _, _, _ = hfov_intrinsics(60.0, 1242, 375)
    assert fx == pytest.approx(621.0 / np.tan(np.radians(30.0)))
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.1, 0.2])  # 10 fps by default


def test_a_video_is_read_frame_by_frame_with_its_rate(tmp_path):
    frames = _frames(6, h=64, w=96, seed=1)
    frames = [cv2.GaussianBlur(f, (0, 0), 3.0) for f in frames]  # smooth: Motion-JPEG keeps it well
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 4.0, (96, 64))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    r = import_frames(path, tmp_path / "out", camera=(80.0, 80.0, 47.5, 31.5), progress=False)
    assert r["frames"] == 6 and r["fps"] == pytest.approx(4.0)
    seq = KittiSequence(r["sequence"])
    for k in range(6):
        got = seq.image(k).astype(np.float64)
        mse = np.mean((got - frames[k] / 255.0) ** 2)
        assert 10 * np.log10(1 / mse) > 30, k  # the same frame, through JPEG
    np.testing.assert_allclose(seq.timestamps, np.arange(6) / 4.0)


def test_bad_sources_are_refused_and_never_look_finished(tmp_path):
    cam = (50.0, 50.0, 19.5, 11.5)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no image files"):
        import_frames(tmp_path / "empty", tmp_path / "o1", camera=cam, progress=False)
    assert not (tmp_path / "o1").exists()
    with pytest.raises(FileNotFoundError, match="no such image folder or video"):
        import_frames(tmp_path / "missing", tmp_path / "o1", camera=cam, progress=False)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError, match="cannot open it as a video"):
        import_frames(tmp_path / "notes.txt", tmp_path / "o1", camera=cam, progress=False)
    with pytest.raises(ValueError, match="intrinsics"):
        import_frames(tmp_path / "empty", tmp_path / "o1", progress=False)
    with pytest.raises(ValueError, match="intrinsics"):
        import_frames(tmp_path / "empty", tmp_path / "o1", camera=cam, hfov=60.0, progress=False)
    # a corrupt frame in the middle: named, and the sequence folder is not marked complete
    _write_folder(tmp_path / "bad", _frames(3), ["0.png", "1.png", "2.png"])
    (tmp_path / "bad" / "1.png").write_bytes((tmp_path / "bad" / "1.png").read_bytes()[:40])
    with pytest.raises(InputError, match=r"1\.png"):
        import_frames(tmp_path / "bad", tmp_path / "o2", camera=cam, progress=False)
    assert _manifest(tmp_path / "o2" / "sequences" / "imported")["complete"] is False
    # a frame of another size
    _write_folder(tmp_path / "sizes", [*_frames(2), _frames(1, h=30)[0]], ["0.png", "1.png", "2.png"])
    with pytest.raises(InputError, match=r"2\.png: 40x30 frame in a 40x24 sequence"):
        import_frames(tmp_path / "sizes", tmp_path / "o3", camera=cam, progress=False)
    assert _manifest(tmp_path / "o3" / "sequences" / "imported")["complete"] is False
    # an earlier import is kept unless asked
    _write_folder(tmp_path / "ok", _frames(2), ["0.png", "1.png"])
    import_frames(tmp_path / "ok", tmp_path / "o4", camera=cam, progress=False)
    with pytest.raises(ValueError, match="--overwrite"):
        import_frames(tmp_path / "ok", tmp_path / "o4", camera=cam, progress=False)
    assert import_frames(tmp_path / "ok", tmp_path / "o4", camera=cam, overwrite=True, progress=False)["frames"] == 2
