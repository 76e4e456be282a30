"""Umeyama alignment against closed-form ground truth and evo's implementation."""

import jax.numpy as jnp
import numpy as np
import pytest
from evo.core.geometry import umeyama_alignment
from scipy.spatial.transform import Rotation

from privslam_jax.geometry.align import apply_similarity, umeyama, umeyama_np


def _pair(seed: int, n: int = 30, scale: float = 2.5, noise: float = 0.0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3)) * [10.0, 2.0, 5.0]
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3) * 20
    y = scale * x @ R.T + t + noise * rng.normal(size=(n, 3))
    return x, y, R, t


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_known_similarity(seed):
    x, y, R, t = _pair(seed)
    R2, t2, c2 = umeyama_np(x, y, with_scale=True)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    assert c2 == pytest.approx(2.5, abs=1e-12)
    x, y, R, t = _pair(seed, scale=1.0)
    R2, t2, c2 = umeyama_np(x, y, with_scale=False)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    assert c2 == 1.0


@pytest.mark.parametrize("with_scale", [False, True])
def test_matches_evo_with_noise(with_scale):
    x, y, _, _ = _pair(5, noise=0.3, scale=0.7)
    R, t, c = umeyama_np(x, y, with_scale=with_scale)
    Re, te, ce = umeyama_alignment(x.T, y.T, with_scale=with_scale)
    np.testing.assert_allclose(R, Re, atol=1e-12)
    np.testing.assert_allclose(t, te, atol=1e-10)
    assert c == pytest.approx(ce, abs=1e-12)


def test_reflection_case_gives_rotation():
    # a mirrored target: the best proper rotation must have det +1 (eq. 43)
    x, _, _, _ = _pair(3, scale=1.0)
    y = x * [1.0, 1.0, -1.0]
    R, _, _ = umeyama_np(x, y)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    Re, _, _ = umeyama_alignment(x.T, y.T)
    np.testing.assert_allclose(R, Re, atol=1e-12)


def test_jax_version_matches_numpy():
    x, y, _, _ = _pair(7, noise=0.1)
    for with_scale in (False, True):
        R, t, c = umeyama(jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), with_scale=with_scale)
        R2, t2, c2 = umeyama_np(x, y, with_scale=with_scale)
        np.testing.assert_allclose(np.asarray(R), R2, atol=1e-5)
        np.testing.assert_allclose(np.asarray(t), t2, atol=1e-3)
        assert float(c) == pytest.approx(c2, rel=1e-5)


def test_apply_similarity_moves_poses():
    x, y, R, t = _pair(1, n=5)
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, 3] = x
    T[:, :3, :3] = Rotation.random(5, random_state=9).as_matrix()
    out = apply_similarity(R, t, 2.5, T)
    np.testing.assert_allclose(out[:, :3, 3], y, atol=1e-10)
    np.testing.assert_allclose(out[:, :3, :3], R @ T[:, :3, :3], atol=1e-12)


def test_bad_input():
    x, y, _, _ = _pair(0)
    with pytest.raises(ValueError, match="equal shape"):
        umeyama_np(x, y[:-1])
    with pytest.raises(ValueError, match="at least 3"):
        umeyama_np(x[:2], y[:2])
    with pytest.raises(ValueError, match="degenerate"):
        umeyama_np(np.ones((5, 3)), y[:5])


def test_collinear_residuals_do_not_depend_on_the_free_rotation():
    """A straight drive (rank-1 covariance): the residuals are those of the closed-form 1-D fit."""
    rng = np.random.default_rng(3)
    s = np.arange(12.0)
    line = np.outer(s, [0.0, 0.0, 1.0])  # ground truth along z
    est = np.outer(0.5 * s, [1.0, 0.0, 0.0]) + rng.normal(scale=0.05, size=(12, 3))  # half scale, along x, noisy
    R, t, c = umeyama_np(est, line, with_scale=True)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    res = np.linalg.norm(c * est @ R.T + t - line, axis=1)
    # Any rotation about the z axis after the alignment leaves every residual unchanged.
    a = 0.7
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    mu = line.mean(0)
    res_rot = np.linalg.norm((c * est @ R.T + t - mu) @ Rz.T + mu - line, axis=1)
    np.testing.assert_allclose(res_rot, res, atol=1e-12)
    # and the total is the optimum: no rotation of the family nor a scipy search finds lower.
    from scipy.optimize import minimize
    from scipy.spatial.transform import Rotation

    def cost(p):
        Rp = Rotation.from_rotvec(p[:3]).as_matrix()
        return np.sum((p[3] * est @ Rp.T + p[4:] - line) ** 2)

    x0 = np.concatenate([Rotation.from_matrix(R).as_rotvec(), [c], t])
    best = min(minimize(cost, x0 + rng.normal(scale=0.3, size=7), method="BFGS").fun for _ in range(5))
    assert np.sum(res**2) <= best + 1e-8


@pytest.mark.parametrize("seed", [3, 4])
def test_mirrored_target_with_scale_matches_evo(seed):
    """A reflected, scaled, noisy target (``det U det V < 0``): ``S = diag(1, 1, −1)`` enters both the
    rotation and the scale ``c = tr(DS)/σ_x²`` (eq. 42). Reference: evo's ``umeyama_alignment``
    (its own implementation), for the numpy and the JAX version separately; with ``tr(D)`` in place
    of ``tr(DS)`` the scale is off by ``2 d₃/σ_x²`` (here several per cent)."""
    x, _, R, t = _pair(seed, scale=1.0)
    rng = np.random.default_rng(seed + 100)
    y = 0.6 * (x * [1.0, 1.0, -1.0]) @ R.T + t + rng.normal(scale=1.5, size=x.shape)  # mirrored, shrunk
    Re, te, ce = umeyama_alignment(x.T, y.T, with_scale=True)
    assert np.linalg.det(Re) == pytest.approx(1.0, abs=1e-12)
    R2, t2, c2 = umeyama_np(x, y, with_scale=True)
    Rj, tj, cj = umeyama(jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), with_scale=True)
    assert (c2, float(cj)) == (pytest.approx(ce, rel=1e-12), pytest.approx(ce, rel=1e-5))
    np.testing.assert_allclose(R2, Re, atol=1e-12)
    np.testing.assert_allclose(t2, te, atol=1e-10)
    np.testing.assert_allclose(np.asarray(Rj), Re, atol=1e-5)
    np.testing.assert_allclose(np.asarray(tj), te, atol=1e-3)
