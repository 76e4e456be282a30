"""Point-recovery metrics against brute-force numpy."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.metrics.privacy import baseline_points, nn_distances, point_recovery_metrics
from privslam_jax.types import LineCloud


def test_metrics_brute_force():
    rng = np.random.default_rng(0)
    p = rng.uniform(-10, 10, (300, 3))
    r = p + rng.normal(0, 0.6, (300, 3))
    r[:20] = rng.uniform(-10, 10, (20, 3))
    m = point_recovery_metrics(p, r)
    D = np.linalg.norm(p[:, None, :] - r[None, :, :], axis=2)
    e = np.linalg.norm(p - r, axis=1)
    assert m["nn_mean"] == pytest.approx(D.min(1).mean(), rel=1e-12)
    assert m["chamfer"] == pytest.approx(0.5 * (D.min(1).mean() + D.min(0).mean()), rel=1e-12)
    assert m["chamfer_rec_to_orig"] == pytest.approx(D.min(0).mean(), rel=1e-12)
    assert m["per_point_median"] == pytest.approx(np.median(e))
    assert m["per_point_mean"] == pytest.approx(e.mean())
    for tau in (0.1, 0.5, 1.0):
        assert m[f"within_{tau}"] == pytest.approx(100 * np.sum(e < tau) / len(e))
    # a permutation keeps the paper's metric but ruins the per-point error: the point of reporting both
    perm = rng.permutation(300)
    m2 = point_recovery_metrics(p, r[perm])
    assert m2["nn_mean"] == pytest.approx(m["nn_mean"])
    assert m2["per_point_median"] > 5 * m["per_point_median"]
    np.testing.assert_allclose(nn_distances(p, r), D.min(1))


def test_baselines():
    rng = np.random.default_rng(1)
    p = rng.uniform(-10, 10, (200, 3))
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lines = LineCloud(directions=jnp.asarray(d, jnp.float32), moments=jnp.asarray(np.cross(p, d), jnp.float32))
    c = baseline_points(lines, "closest")
    np.testing.assert_allclose(c, p - np.sum(p * d, 1, keepdims=True) * d, atol=1e-4)
    u = baseline_points(lines, "uniform", seed=3)
    # on the line, inside the box of the closest points
    np.testing.assert_allclose(np.linalg.norm(np.cross(u - c, d), axis=1), 0, atol=1e-4)
    assert np.all(u >= c.min(0) - 1e-6) and np.all(u <= c.max(0) + 1e-6)
    np.testing.assert_array_equal(u, baseline_points(lines, "uniform", seed=3))
    with pytest.raises(ValueError, match="rule"):
        baseline_points(lines, "midpoint")


def test_bad_inputs():
    with pytest.raises(ValueError, match="one to one"):
        point_recovery_metrics(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        point_recovery_metrics(np.full((3, 3), np.nan), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="shape"):
        point_recovery_metrics(np.zeros((3, 2)), np.zeros((3, 2)))
