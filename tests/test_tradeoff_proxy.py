"""``privslam_jax.tradeoff.proxy``: the pieces of ``experiments/proxy_vs_slam.py``.

References, independent of the module:

* the frames SLAM sees: the files ``privslam synth`` (``write_kitti_sequence``) and ``privslam filter
  --masks gt`` (``filter_sequence``) write, read back as ``privslam slam`` reads them
  (``load_sequence_frames``) — bit for bit;
* the proxy: ``accuracy_loss`` called pair by pair on frames downsampled by OpenCV's ``INTER_AREA``,
  with the intrinsics of the world rendered directly at the smaller size and ``T_gt`` from the frames'
  poses;
* the stereo world's right frames and the object-free frames: the ``image_3/`` and ``background/`` files
  ``privslam synth --stereo`` writes; the right frames filtered by ``filter_frame`` frame by frame on
  masks built directly from the renderer's right-view ids;
* the depth reduction: a per-block Python loop;
* the paired changes and medians: plain numpy on hand-made records; the rank correlation:
  ``scipy.stats.spearmanr`` called directly.
"""

from __future__ import annotations

import math

import cv2
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from privslam_jax.data.images import grey_as_read
from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.tradeoff import PhotometricConfig, accuracy_loss
from privslam_jax.tradeoff.proxy import (
    ProxySettings,
    box_downsample,
    downsample_depth,
    filter_world,
    frame_pairs,
    paired_changes,
    relative_pose,
    render_world,
    scale_intrinsics,
    sequence_proxy,
    spearman,
    summarize_changes,
)

pytestmark = pytest.mark.xla_optimized  # the proxy runs the alignment over whole sequences (tests/conftest.py)

TINY = SynthConfig(width=320, height=96, num_frames=4, seed=300001)
"""One small world for every test (the renderer compiles once per size)."""
TINY_STEREO = SynthConfig(width=320, height=96, num_frames=3, seed=400001, stereo=True)
"""A small stereo world (the same as ``tests/test_pareto_tradeoff.py``'s: one compile per session)."""


@pytest.fixture(scope="module")
def tiny_world():
    return render_world(TINY)


def test_in_memory_frames_equal_what_the_commands_write_and_slam_reads(tmp_path, tiny_world):
    """``privslam synth`` → ``privslam filter --masks gt`` → ``privslam slam``'s reader, against the
    in-memory path, for no filter, a deterministic baseline, a seeded one and EdgeConnect (a tiny
    random inpainter passed as a checkpoint file)."""
    from privslam_jax.data.kitti_write import write_kitti_sequence
    from privslam_jax.inpaint.filter import Inpainter, InpainterConfig
    from privslam_jax.inpaint.sequence import filter_sequence
    from privslam_jax.slam.outputs import load_sequence_frames

    world = tiny_world
    assert (world.instance_ids > 0).any(), "the tiny world must show objects"
    seq_dir = write_kitti_sequence(make_sequence(TINY), tmp_path / "original", progress=False)
    model = tmp_path / "tiny_inpainter.npz"
    inpainter = Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1), seed=0)
    inpainter.save(model)
    for method in ("none", "telea", "noise25", "edgeconnect"):
        if method == "none":
            path = seq_dir
        else:
            path = filter_sequence(seq_dir, tmp_path / method, method, masks_source="gt",
                                   model_path=model if method == "edgeconnect" else None, progress=False)
        seq, frames, n = load_sequence_frames(path, "mono")
        mine = filter_world(world, method, Inpainter.load(model) if method == "edgeconnect" else None)
        assert n == len(world)
        for i, grey in enumerate(frames):
            np.testing.assert_array_equal(grey_as_read(mine[i]), grey, err_msg=f"{method} frame {i}")
        if method != "none":
            assert (mine != world.rgb8).any()  # the filter did something
        np.testing.assert_array_equal(world.timestamps, seq.timestamps)
        np.testing.assert_array_equal(world.poses, seq.poses)
        cam = seq.camera
        assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
            world.camera.fx, world.camera.fy, world.camera.cx, world.camera.cy, world.camera.width, world.camera.height)
        assert cam.baseline == pytest.approx(world.camera.baseline, rel=1e-9)


def test_downsampling_matches_opencv_and_a_block_loop():
    rng = np.random.default_rng(0)
    img = rng.random((8, 12, 3)).astype(np.float32)
    np.testing.assert_allclose(box_downsample(img, 2), cv2.resize(img, (6, 4), interpolation=cv2.INTER_AREA), atol=1e-6)
    depth = rng.uniform(5, 5.2, (8, 12)).astype(np.float32)
    depth[0, 0] = 0.0  # sky in block (0, 0)
    depth[2, 4] = 9.0  # an occlusion boundary in block (1, 2)
    depth[5, 7] = 5.4  # within 10 %: kept (block (2, 3))
    got = downsample_depth(depth, 2, 0.1)
    for v in range(4):
        for u in range(6):
            blk = depth[2 * v:2 * v + 2, 2 * u:2 * u + 2].astype(np.float64).ravel()
            want = 0.0 if blk.min() <= 0 or blk.max() > 1.1 * blk.min() else 4.0 / np.sum(1.0 / blk)
            assert got[v, u] == pytest.approx(want, rel=1e-6), (v, u)
    assert got[0, 0] == 0 and got[1, 2] == 0 and got[2, 3] > 0


def test_frame_pairs():
    assert frame_pairs(10, 2, 3) == [(0, 2), (3, 5), (6, 8)]
    assert frame_pairs(3, 2, 10) == [(0, 2)]
    assert frame_pairs(2, 2, 1) == []


def test_sequence_proxy_is_the_mean_of_accuracy_loss_pair_by_pair(tiny_world):
    """A 320×96 world of 4 frames at half size (160×48, as the trade-off gradient test), pairs (0, 1)
    and (2, 3), one pyramid level (compiles in half the time of the default three; same values to
    1e-4 here), float64 (solved to rounding, so that the two independently prepared inputs give the
    same minimiser; in float32 they differed by 1e-3): every pair's value equals ``accuracy_loss`` on
    frames downsampled by OpenCV with the intrinsics of the world rendered at 160×48, and the proxy is
    their mean over the converged pairs."""
    world = tiny_world
    settings = ProxySettings(gap=1, stride=2, config=PhotometricConfig(levels=1))
    small = make_sequence(SynthConfig(width=160, height=48, num_frames=1, seed=TINY.seed)).camera
    K_small = np.array([small.fx, small.fy, small.cx, small.cy])
    np.testing.assert_allclose(scale_intrinsics(world.intrinsics, 2), K_small, rtol=1e-12)
    poses = make_sequence(TINY).poses  # ground truth without rendering
    with jax.enable_x64(True):
        res = sequence_proxy(world.rgb8, world.depth, world.poses, world.intrinsics, settings, np.float64)
        assert res.pairs == [(0, 1), (2, 3)]
        ref = jax.jit(lambda t, r, d, K, T: accuracy_loss(t, r, d, K, jaxlie.SE3.from_matrix(T),
                                                                config=settings.config))
        want = []
        for t, u in res.pairs:
            img = lambda i: cv2.resize(world.rgb8[i].astype(np.float64) / 255, (160, 48), interpolation=cv2.INTER_AREA)
            T_gt = np.linalg.inv(poses[u]) @ poses[t]
            np.testing.assert_allclose(relative_pose(world.poses[t], world.poses[u]), T_gt, atol=1e-12)
            d = downsample_depth(world.depth[t], 2).astype(np.float64)
            want.append(float(ref(jnp.asarray(img(u)), jnp.asarray(img(t)), jnp.asarray(d), jnp.asarray(K_small),
                                  jnp.asarray(T_gt))))
    print("proxy pairs", res.values, want, res.converged)
    np.testing.assert_allclose(res.values, want, rtol=1e-6)
    assert res.converged.all() and res.failed == 0
    assert res.mean == pytest.approx(float(np.mean(want)), rel=1e-6)
    assert 0 < res.mean < 0.1  # a sane alignment on unfiltered frames (metres + radians)


def _records():
    rng = np.random.default_rng(1)
    recs = []
    for w in (1, 2, 3):
        recs.append({"world": w, "filter": "none", "ate": 1.0 + w, "proxy": 0.01 * w})
        for j, f in enumerate(("a", "b", "c", "d")):
            recs.append({"world": w, "filter": f, "ate": 1.0 + w + rng.normal() + j, "proxy": 0.01 * w + 0.003 * j})
    recs.append({"world": 4, "filter": "a", "ate": 3.0, "proxy": 0.0})  # no 'none' for world 4: not paired
    recs[4]["ate"] = math.nan  # world 1, filter 'd': SLAM failed
    return recs


def test_paired_changes_medians_and_spearman_against_numpy_and_scipy():
    from scipy.stats import spearmanr

    recs = _records()
    ch = paired_changes(recs)
    assert len(ch) == 12 and all(c["world"] != 4 for c in ch)
    base = {r["world"]: r for r in recs if r["filter"] == "none"}
    for c in ch:
        r = next(x for x in recs if x["world"] == c["world"] and x["filter"] == c["filter"])
        b = base[c["world"]]
        if math.isfinite(r["ate"]):
            assert c["d_ate"] == pytest.approx(r["ate"] - b["ate"])
            assert c["d_ate_pct"] == pytest.approx(100 * (r["ate"] - b["ate"]) / b["ate"])
        else:
            assert math.isnan(c["d_ate"]) and math.isnan(c["d_ate_pct"])
        assert c["d_proxy"] == pytest.approx(r["proxy"] - b["proxy"])
    s = summarize_changes(ch)
    assert list(s) == ["a", "b", "c", "d"]
    for f, row in s.items():
        v = np.asarray([c["d_ate_pct"] for c in ch if c["filter"] == f])
        v = v[np.isfinite(v)]
        assert row["d_ate_pct"] == pytest.approx(np.median(v))
        assert row["d_ate_pct_min"] == pytest.approx(v.min()) and row["d_ate_pct_max"] == pytest.approx(v.max())
        assert row["n"] == len(v) and row["worlds"] == 3
    x = [s[f]["d_proxy"] for f in s]
    y = [s[f]["d_ate_pct"] for f in s]
    rho, p, n = spearman(x, y)
    ref = spearmanr(x, y)
    assert n == 4 and rho == pytest.approx(ref.statistic) and p == pytest.approx(ref.pvalue)
    # non-finite pairs are dropped, then scipy on the rest
    xs = [c["d_proxy"] for c in ch]
    ys = [c["d_ate_pct"] for c in ch]
    keep = [i for i in range(len(xs)) if math.isfinite(ys[i])]
    rho, p, n = spearman(xs, ys)
    ref = spearmanr([xs[i] for i in keep], [ys[i] for i in keep])
    assert n == 11 and rho == pytest.approx(ref.statistic) and p == pytest.approx(ref.pvalue)
    # undefined cases give NaN (and no scipy warning: warnings are errors here)
    assert math.isnan(spearman([1, 2], [2, 1])[0])
    assert math.isnan(spearman([1, 1, 1, 1], [1, 2, 3, 4])[0])
    with pytest.raises(ValueError):
        spearman([1, 2, 3], [1, 2])


def test_stereo_world_right_frames_background_and_right_filtering(tmp_path, tiny_world):
    """``render_world`` of a stereo config: the right frames and the object-free left frames equal the
    ``image_3/`` and ``background/`` files of ``privslam synth --stereo``, the right ids are the renderer's
    right-view ids; ``filter_world(right=True)`` fills the right frames on masks of those ids (dilation 4,
    seed i) — against ``filter_frame`` on masks dilated by a 4-px disc here; a mono world has no right views."""
    from privslam_jax.data.images import read_raw
    from privslam_jax.data.kitti_write import write_kitti_sequence
    from privslam_jax.inpaint.filter import filter_frame

    assert tiny_world.right_rgb8 is None and tiny_world.right_instance_ids is None
    with pytest.raises(ValueError, match="stereo"):
        filter_world(tiny_world, "black", right=True)
    world = render_world(TINY_STEREO)
    seq = make_sequence(TINY_STEREO)
    seq_dir = write_kitti_sequence(seq, tmp_path / "stereo", progress=False)
    assert world.right_rgb8 is not None and world.right_instance_ids is not None
    for i in range(len(world)):
        def bgr(folder: str, i: int = i) -> np.ndarray:  # the file as RGB
            return read_raw(seq_dir / folder / f"{i:06d}.png")[..., ::-1]

        np.testing.assert_array_equal(world.right_rgb8[i], bgr("image_3"), err_msg=f"right frame {i}")
        np.testing.assert_array_equal(world.rgb8[i], bgr("image_2"), err_msg=f"left frame {i}")
        np.testing.assert_array_equal(world.background_rgb8[i], bgr("background"), err_msg=f"background {i}")
        np.testing.assert_array_equal(world.right_instance_ids[i], seq[i].instance_ids_right)
    assert (world.right_instance_ids > 0).any() and (world.right_instance_ids != world.instance_ids).any()
    hidden = world.instance_ids > 0
    assert (world.background_rgb8[hidden] != world.rgb8[hidden]).any()  # the objects are gone ...
    np.testing.assert_array_equal(world.background_rgb8[~hidden], world.rgb8[~hidden])  # ... and nothing else
    r = np.arange(-4, 5)
    kernel = (np.hypot(r[:, None], r[None, :]) <= 4).astype(np.uint8)  # every pixel within 4 px
    for method in ("none", "noise25"):
        got = filter_world(world, method, right=True)
        for i in range(len(world)):
            ids = world.right_instance_ids[i]
            masks = np.stack([cv2.dilate((ids == k).astype(np.uint8), kernel).astype(bool)
                              for k in np.unique(ids[ids > 0])])
            want = world.right_rgb8[i] if method == "none" else filter_frame(world.right_rgb8[i], masks, method, seed=i)
            np.testing.assert_array_equal(got[i], want, err_msg=f"{method} right frame {i}")
    assert (filter_world(world, "noise25", right=True) != world.right_rgb8).any()
