"""Place recognition and loop closing: the vocabulary against numpy, Sim(3) RANSAC on a known transform,
point merging, and loops closed on the synthetic loop route judged by its ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from privslam_jax.errors import InputError
from privslam_jax.slam.frontend import OrbConfig, extract_orb, to_gray_u8
from privslam_jax.slam.vocabulary import Vocabulary, bow_scores, load_vocabulary, train_vocabulary

pytestmark = pytest.mark.xla_optimized  # SLAM on whole sequences (tests/conftest.py)


def _np_hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(N, M)`` Hamming distances by unpacking bits (numpy only)."""
    return (np.unpackbits(a, axis=1)[:, None, :] != np.unpackbits(b, axis=1)[None, :, :]).sum(-1)


@pytest.fixture(scope="module")
def image_descriptors() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    # three clusters of descriptors (centres plus a few flipped bits) spread over 6 "images"
    centres = rng.integers(0, 256, size=(3, 32), dtype=np.uint8)
    images = []
    for i in range(6):
        rows = []
        for c in (i % 3, (i + 1) % 3):
            bits = np.unpackbits(np.repeat(centres[c][None], 40, axis=0), axis=1)
            flip = rng.random(bits.shape) < 0.05
            rows.append(np.packbits(bits ^ flip, axis=1))
        images.append(np.concatenate(rows))
    return images


def test_vocabulary_training_quantise_and_idf_against_numpy(image_descriptors):
    vocab = train_vocabulary(image_descriptors, k=3, iterations=20, seed=1)
    data = np.concatenate(image_descriptors)
    # quantise = the nearest word by brute-force numpy Hamming distance
    d = _np_hamming(data, vocab.words)
    words = vocab.quantise(data)
    np.testing.assert_array_equal(d[np.arange(len(data)), words], d.min(axis=1))
    # converged k-majority: every word is the bitwise majority of its members
    bits = np.unpackbits(data, axis=1)
    for w in range(vocab.size):
        members = bits[words == w]
        assert len(members) == 160  # the three clusters are found (each in 4 images × 40)
        np.testing.assert_array_equal(np.unpackbits(vocab.words[w]), (2 * members.sum(0) > len(members)).astype(np.uint8))
    # idf = log(N / images containing the word); each word is in 4 of the 6 images
    np.testing.assert_allclose(vocab.idf, np.log(6 / 4), rtol=1e-12)
    # tf-idf vectors are L1-normalised; DBoW2's L1 score is 1 for equal, 0 for disjoint images
    v = np.stack([vocab.transform(x) for x in image_descriptors])
    np.testing.assert_allclose(v.sum(1), 1.0, rtol=1e-12)
    s = bow_scores(v[0], v)
    np.testing.assert_allclose(s, 1.0 - 0.5 * np.abs(v - v[0]).sum(1), rtol=1e-12)
    assert s[0] == pytest.approx(1.0) and s[3] == pytest.approx(1.0)  # images 0 and 3 hold the same clusters


def test_vocabulary_files_round_trip_and_refusals(tmp_path, image_descriptors):
    vocab = train_vocabulary(image_descriptors, k=3, iterations=5)
    path = tmp_path / "v.npz"
    vocab.save(path)
    back = load_vocabulary(path)
    np.testing.assert_array_equal(back.words, vocab.words)
    np.testing.assert_array_equal(back.idf, vocab.idf)
    with pytest.raises(FileNotFoundError):
        load_vocabulary(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(path.read_bytes()[:100])
    with pytest.raises(InputError, match="bad.npz"):
        load_vocabulary(bad)
    np.savez(tmp_path / "shape.npz", words=np.zeros((4, 16), np.uint8), idf=np.ones(4))
    with pytest.raises(InputError, match="words must be"):
        load_vocabulary(tmp_path / "shape.npz")
    with pytest.raises(ValueError, match="at least 2 images"):
        train_vocabulary(image_descriptors[:1], k=2)
    with pytest.raises(ValueError, match="descriptors must be"):
        vocab.quantise(np.zeros((3, 16), np.uint8))


def test_embedded_vocabulary_recognises_the_start_of_a_loop():
    """Frames of the loop route's second lap score highest against the first lap's frames at the same
    place (ground-truth distance ≤ 3 m), among all frames at least 150 earlier."""
    from privslam_jax.data.synthetic import SynthConfig, make_sequence
    from privslam_jax.slam.system import EMBEDDED_VOCABULARY

    vocab = load_vocabulary(EMBEDDED_VOCABULARY)
    seq = make_sequence(SynthConfig(num_frames=260, seed=11, route="loop", loop_blocks=(1, 1)))
    T = seq.poses
    lap = 100 + int(np.argmin(np.linalg.norm(T[100:, :3, 3] - T[0, :3, 3], axis=1)))
    db = list(range(0, lap - 60, 6))
    queries = [lap + 5, lap + 20, lap + 35]
    V = {i: vocab.transform(extract_orb(to_gray_u8(seq[i].image), OrbConfig()).desc) for i in db + queries}
    for q in queries:
        scores = bow_scores(V[q], np.stack([V[i] for i in db]))
        best = db[int(np.argmax(scores))]
        assert np.linalg.norm(T[best, :3, 3] - T[q, :3, 3]) <= 3.0, (q, best)


@pytest.mark.parametrize("with_scale", [True, False])
def test_sim3_ransac_recovers_a_known_transform(with_scale):
    from scipy.spatial.transform import Rotation

    from privslam_jax.slam.loop_closing import estimate_sim3_ransac
    from privslam_jax.types import Camera

    cam = Camera(fx=400.0, fy=400.0, cx=320.0, cy=96.0, width=640, height=192)
    rng = np.random.default_rng(3)
    n = 120
    X2 = np.c_[rng.uniform(-8, 8, n), rng.uniform(-2, 2, n), rng.uniform(5, 30, n)]
    R = Rotation.from_rotvec([0.02, 0.3, -0.01]).as_matrix()
    s = 1.7 if with_scale else 1.0
    t = np.array([0.5, -0.1, 0.8])
    X1 = s * X2 @ R.T + t
    outl = rng.random(n) < 0.4
    X1[outl] += rng.normal(0, 3.0, (outl.sum(), 3))
    pix = lambda X: np.c_[cam.fx * X[:, 0] / X[:, 2] + cam.cx, cam.fy * X[:, 1] / X[:, 2] + cam.cy]  # noqa: E731
    uv1, uv2 = pix(X1), pix(X2)
    X1_true = s * X2 @ R.T + t
    uv1[~outl] = pix(X1_true[~outl])
    ones = np.ones(n)
    S, inl = estimate_sim3_ransac(X1, X2, uv1, uv2, ones, ones, cam, with_scale, 200, np.random.default_rng(0))
    expected = np.eye(4)
    expected[:3, :3] = s * R
    expected[:3, 3] = t
    np.testing.assert_allclose(S, expected, atol=1e-9)
    in_front = X1[:, 2] > 0
    np.testing.assert_array_equal(inl[~outl], True)
    moved = np.linalg.norm(pix(X1) - uv1, axis=1) > 3.0  # outliers that still reproject are fine
    assert not np.any(inl & outl & moved & in_front)


def test_replace_points_moves_observations():
    """Merging a duplicate point: its observations move unless the keyframe sees the survivor already."""
    from privslam_jax.slam.frontend import Features
    from privslam_jax.slam.mapping import Map
    from privslam_jax.types import Camera

    cam = Camera(fx=400.0, fy=400.0, cx=320.0, cy=96.0, width=640, height=192)
    feats = Features(uv=np.zeros((4, 2)), octave=np.zeros(4, np.int64), angle=np.zeros(4), desc=np.zeros((4, 32), np.uint8))
    m = Map(cam)
    k0 = m.add_keyframe(0, np.eye(4), feats, np.full(4, -1))
    k1 = m.add_keyframe(1, np.eye(4), feats, np.full(4, -1))
    (old,) = m.add_points(np.array([[0, 0, 5.0]]), k0, np.array([0]))
    (new,) = m.add_points(np.array([[0, 0, 5.1]]), k1, np.array([1]))
    m.add_observations(k1, np.array([old]), np.array([2]))  # k1 sees both
    moved = m.replace_points(np.array([old]), np.array([new]))
    assert moved == 1  # k0's observation moved; k1's dropped (k1 sees `new` already)
    assert m.bad[old] and not m.bad[new]
    assert m.n_obs[new] == 2 and m.n_obs[old] == 0
    np.testing.assert_array_equal(k0.point_ids, [new, -1, -1, -1])
    np.testing.assert_array_equal(k1.point_ids, [-1, new, -1, -1])
    _, okf, opt = m.observations()
    assert sorted(zip(okf.tolist(), opt.tolist())) == [(0, new), (1, new)]
