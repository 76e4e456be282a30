"""KITTI odometry reader on the shared sequences and on broken copies."""

import shutil

import cv2
import numpy as np
import pytest

from privslam_jax.data.kitti import KittiSequence, read_calib


def _copy_seq(shared, tmp_path, name="seq1", frames=3):
    """A small copy of a shared sequence: ``frames`` images, calib and the first poses."""
    src = shared / "data/kitti_odometry"
    dst = tmp_path / "kitti"
    (dst / "sequences" / name / "image_0").mkdir(parents=True)
    for i in range(frames):
        shutil.copy(src / f"sequences/{name}/image_0/{i:06d}.png", dst / f"sequences/{name}/image_0/{i:06d}.png")
    shutil.copy(src / f"sequences/{name}/calib.txt", dst / f"sequences/{name}/calib.txt")
    (dst / "poses").mkdir()
    lines = (src / f"poses/{name}.txt").read_text().splitlines()[:frames]
    (dst / f"poses/{name}.txt").write_text("\n".join(lines) + "\n")
    return dst / "sequences" / name


def test_shared_seq1(shared):
    seq = KittiSequence(shared / "data/kitti_odometry/sequences/seq1")
    assert len(seq) == 51
    cam = seq.camera
    P = np.loadtxt(shared / "data/kitti_odometry/sequences/seq1/calib.txt", usecols=range(1, 13)).reshape(-1, 3, 4)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (P[0, 0, 0], P[0, 1, 1], P[0, 0, 2], P[0, 1, 2])
    assert cam.baseline == pytest.approx(-P[1, 0, 3] / P[1, 0, 0], rel=1e-12)
    assert cam.baseline == pytest.approx(0.537, abs=0.01)
    assert (cam.width, cam.height) == (1226, 370)
    gt = np.loadtxt(shared / "data/kitti_odometry/poses/seq1.txt").reshape(-1, 3, 4)
    np.testing.assert_array_equal(seq.poses[:, :3, :], gt)
    np.testing.assert_allclose(seq.timestamps, np.arange(51) / 10.0)
    f = seq[7]
    ref = cv2.imread(str(shared / "data/kitti_odometry/sequences/seq1/image_0/000007.png"), cv2.IMREAD_GRAYSCALE)
    assert f.image.shape == (370, 1226, 3) and f.image.dtype == np.float32
    for c in range(3):
        np.testing.assert_array_equal(f.image[:, :, c], ref.astype(np.float32) / 255.0)
    np.testing.assert_array_equal(f.T_w_c[:3, :], gt[7])
    assert f.timestamp == pytest.approx(0.7) and f.frame_id == 7 and f.image_right is None
    assert f.depth is None and f.boxes is None
    traj = seq.trajectory
    np.testing.assert_allclose(np.asarray(traj.positions), gt[:, :, 3], atol=1e-4)


def test_shared_00_subset_indexes_full_ground_truth(shared):
    seq = KittiSequence.from_root(shared / "data/kitti_odometry", "00", grey=True)
    assert len(seq) == 5 and seq.camera.fx == pytest.approx(718.856)
    gt = np.loadtxt(shared / "data/kitti_odometry/poses/00.txt", max_rows=5).reshape(-1, 3, 4)
    np.testing.assert_array_equal(seq.poses[:, :3, :], gt)
    assert seq[0].image.shape == (seq.camera.height, seq.camera.width)


def test_times_txt_and_missing_poses(shared, tmp_path):
    path = _copy_seq(shared, tmp_path)
    (path / "times.txt").write_text("0.0\n0.103\n0.207\n")
    shutil.rmtree(path.parent.parent / "poses")
    seq = KittiSequence(path)
    np.testing.assert_array_equal(seq.timestamps, [0.0, 0.103, 0.207])
    assert seq.poses is None and seq.trajectory is None and seq[1].T_w_c is None


@pytest.mark.parametrize("times,match", [("0.0\n0.2\n0.1\n", "line 3 is not after line 2"),
                                         ("0.0\n0.1\n0.1\n", "line 3 is not after line 2"),
                                         ("0.0\nnan\n0.2\n", r"times\.txt:2: NaN or inf")])
def test_times_must_be_finite_and_increasing(shared, tmp_path, times, match):
    """Issue 15 item 8: a non-monotonic times.txt made a trajectory the project's own reader rejected and an
    ATE over 7 of 8 frames; NaN times failed only after the whole SLAM run."""
    path = _copy_seq(shared, tmp_path)
    (path / "times.txt").write_text(times)
    with pytest.raises(ValueError, match=match):
        KittiSequence(path)


def test_missing_folder(tmp_path, shared):
    with pytest.raises(FileNotFoundError, match="nothere"):
        KittiSequence(tmp_path / "nothere")
    path = _copy_seq(shared, tmp_path)
    with pytest.raises(FileNotFoundError, match="image_1"):
        KittiSequence(path, stereo=True)
    with pytest.raises(FileNotFoundError, match="image_2"):
        KittiSequence(path, colour=True)


def test_missing_or_garbled_calibration(shared, tmp_path):
    path = _copy_seq(shared, tmp_path)
    calib = path / "calib.txt"
    good = calib.read_text()
    calib.unlink()
    with pytest.raises(FileNotFoundError, match="calib.txt"):
        KittiSequence(path)
    calib.write_text(good.replace("P0:", "P0 ", 1))
    with pytest.raises(ValueError, match=r"calib\.txt:1"):
        KittiSequence(path)
    calib.write_text(good.replace("7.070912000000e+02", "seven", 1))
    with pytest.raises(ValueError, match=r"calib\.txt:1: not a number"):
        KittiSequence(path)
    calib.write_text("\n".join(good.splitlines()[1:]) + "\n")  # P0 missing
    with pytest.raises(ValueError, match=r"calib\.txt: no P0"):
        KittiSequence(path)
    calib.write_text(good.splitlines()[0] + " 1.0\n")
    with pytest.raises(ValueError, match=r"calib\.txt:1: row 'P0' must have 12"):
        read_calib(calib)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_corrupt_png_names_the_file(shared, tmp_path, damage):
    path = _copy_seq(shared, tmp_path)
    png = path / "image_0/000002.png"
    data = png.read_bytes()
    png.write_bytes(data[: len(data) // 3] if damage == "truncate" else b"\x89PNG garbage" * 10)
    seq = KittiSequence(path)
    seq[1]
    with pytest.raises(ValueError, match="000002.png"):
        seq[2]


def test_pose_count_mismatch(shared, tmp_path):
    path = _copy_seq(shared, tmp_path)
    poses = path.parent.parent / "poses/seq1.txt"
    poses.write_text("\n".join(poses.read_text().splitlines()[:2]) + "\n")
    with pytest.raises(ValueError, match=r"seq1\.txt: 2 poses but 3 frames"):
        KittiSequence(path)
    (path / "times.txt").write_text("0.0\n0.1\n")
    poses.unlink()
    with pytest.raises(ValueError, match=r"times\.txt: 2 timestamps"):
        KittiSequence(path)


def test_stereo_and_colour_pose_shift(shared, tmp_path):
    """A colour pair whose P2 carries a translation: poses move to camera 2, baseline from P2 - P3."""
    path = _copy_seq(shared, tmp_path)
    img = cv2.imread(str(path / "image_0/000000.png"))
    for d in ("image_2", "image_3"):
        (path / d).mkdir()
        for i in range(3):
            cv2.imwrite(str(path / d / f"{i:06d}.png"), img)
    fx, cx, cy = 700.0, 600.0, 180.0
    t2 = np.array([fx * 0.06, 0.0, 0.0])
    P2 = np.array([[fx, 0, cx, t2[0]], [0, fx, cy, t2[1]], [0, 0, 1, t2[2]]])
    P3 = P2.copy()
    P3[0, 3] -= fx * 0.54
    rows = [f"P{k}: " + " ".join(repr(float(v)) for v in P.ravel()) for k, P in enumerate([P2, P2, P2, P3])]
    (path / "calib.txt").write_text("\n".join(rows) + "\n")
    seq = KittiSequence(path, stereo=True)
    assert seq.camera.baseline == pytest.approx(0.54)
    f = seq[0]
    assert f.image.shape == f.image_right.shape == (370, 1226, 3)
    gt = np.loadtxt(path.parent.parent / "poses/seq1.txt").reshape(-1, 3, 4)
    # camera 2 centre = camera 0 centre + R · (-0.06, 0, 0)
    np.testing.assert_allclose(seq.poses[:, :3, 3], gt[:, :, 3] + gt[:, :, :3] @ np.array([-0.06, 0.0, 0.0]), atol=1e-12)
