"""Line2Point in JAX against the plain numpy re-implementation of the authors' code (tests/line2point_reference.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from privslam_jax.attacks.line2point import (
    Line2PointConfig,
    get_peak,
    line2point,
    num_coarse_neighbours,
    select_smallest,
    sort_values,
)
from privslam_jax.privacy.lift import fixed_key, random_lift
from privslam_jax.types import LineCloud

sys.path.insert(0, str(Path(__file__).parent))
import line2point_reference as ref  # noqa: E402


def street_points(n: int, seed: int) -> np.ndarray:
    """Two noisy façades and a road: a sparse SLAM-like map."""
    rng = np.random.default_rng(seed)
    k = n // 3
    fac1 = np.stack([rng.uniform(-40, 40, k), np.full(k, -6.0) + rng.normal(0, 0.1, k), rng.uniform(0, 10, k)], 1)
    fac2 = np.stack([rng.uniform(-40, 40, k), np.full(k, 6.0) + rng.normal(0, 0.1, k), rng.uniform(0, 10, k)], 1)
    m = n - 2 * k
    road = np.stack([rng.uniform(-40, 40, m), rng.uniform(-6, 6, m), rng.normal(0, 0.05, m)], 1)
    return np.concatenate([fac1, fac2, road])


def test_matches_numpy_reference_n2000():
    # rows run in blocks on one host thread per core (2 blocks on a 2-core machine): covered too
    pts = street_points(2000, 0)
    with jax.enable_x64(True):
        lines = random_lift(jnp.asarray(pts), fixed_key(1))
        rec, t = line2point(lines)
        rec, t = np.asarray(rec), np.asarray(t)
        d = np.asarray(lines.directions)
        a = np.cross(d, np.asarray(lines.moments))
    assert rec.dtype == np.float64
    ref_pts, ref_t = ref.line2point_reference(a, d, num_refine_iterations=2)
    np.testing.assert_allclose(rec, ref_pts, atol=1e-6, rtol=0)
    # the attack works at all: much better than the anchor (closest point to the origin)
    err = np.linalg.norm(rec - pts, axis=1)
    assert np.median(err) < 0.5 * np.median(np.linalg.norm(a - pts, axis=1))


def test_peak_finder_matches_reference_on_random_sets():
    rng = np.random.default_rng(3)
    gp = jax.jit(get_peak)
    with jax.enable_x64(True):
        for trial in range(60):
            m = int(rng.integers(3, 150))
            if trial % 3 == 0:
                e = rng.standard_cauchy(m)
            elif trial % 3 == 1:
                e = np.concatenate([rng.normal(2.0, 0.3, m), rng.uniform(-30, 30, 2 * m)])
            else:
                e = np.round(rng.normal(0, 3, m), 1)  # many exact ties
            valid = np.zeros(450, bool)
            valid[: len(e)] = True
            padded = np.concatenate([e, rng.normal(size=450 - len(e))])
            got = float(gp(jnp.asarray(padded), jnp.asarray(valid)))
            assert got == pytest.approx(ref.get_peak(e), abs=1e-9), (trial, len(e))


def test_peak_finder_at_the_loop_bound_matches_reference():
    """Sets of 15–17 offsets: 5–7 remain after trimming 5 at each end, right at the authors' loop
    bound ``while len > 5`` (a set of exactly 5 is not searched; 6 and 7 are). Reference:
    ``get_peak`` of tests/line2point_reference.py (the authors' numpy code)."""
    rng = np.random.default_rng(0)
    gp = jax.jit(get_peak)
    with jax.enable_x64(True):
        for m in (15, 16, 17):
            for trial in range(40):
                kind = trial % 4
                if kind == 0:
                    e = rng.standard_cauchy(m)
                elif kind == 1:  # a tight cluster among uniform clutter
                    e = np.concatenate([rng.normal(2.0, 0.05, m // 2), rng.uniform(-30, 30, m - m // 2)])
                elif kind == 2:
                    e = rng.uniform(-10, 10, m)
                else:
                    e = np.round(rng.normal(0, 3, m), 1)  # ties
                valid = np.zeros(32, bool)
                valid[:m] = True
                padded = np.concatenate([e, rng.normal(size=32 - m)])
                got = float(gp(jnp.asarray(padded), jnp.asarray(valid)))
                assert got == pytest.approx(ref.get_peak(e), abs=1e-9), (m, trial, e.tolist())


def test_select_smallest_is_stable_argsort():
    rng = np.random.default_rng(4)
    v = np.round(rng.uniform(0, 5, 3000), 1).astype(np.float32)  # heavy ties
    for k in (1, 37, 150):
        got = np.asarray(select_smallest(jnp.asarray(v), k))
        np.testing.assert_array_equal(np.sort(got), np.sort(np.argsort(v, kind="stable")[:k]))


def test_sort_values_is_numpy_sort():
    rng = np.random.default_rng(6)
    sort = jax.jit(sort_values)
    for k in (1, 7, 500):
        x = np.round(rng.normal(0, 3, (3, k)), 1)  # ties
        x[0, : k // 3] = np.inf
        got = np.asarray(sort(jnp.asarray(x, jnp.float32)))
        assert got.shape[-1] == 1 << (k - 1).bit_length()
        np.testing.assert_array_equal(got[:, :k], np.sort(x.astype(np.float32), axis=-1))
        assert np.all(np.isinf(got[:, k:]))


def test_neighbour_count_and_errors():
    assert num_coarse_neighbours(2000) == 100 and num_coarse_neighbours(20000) == 500
    assert num_coarse_neighbours(100000) == 500
    with pytest.raises(ValueError, match="NaN"):
        line2point(LineCloud(directions=jnp.zeros((5, 3)), moments=jnp.zeros((5, 3))), Line2PointConfig(num_refine_iterations=0))
    with pytest.raises(ValueError, match="at least 2"):
        line2point(LineCloud(directions=jnp.ones((1, 3)), moments=jnp.zeros((1, 3))))


def test_second_call_does_not_recompile():
    import importlib

    l2p = importlib.import_module("privslam_jax.attacks.line2point")  # the module, not the function

    pts = street_points(300, 5)
    cfg = Line2PointConfig(num_refine_iterations=1)
    first = np.asarray(line2point(random_lift(pts, fixed_key(0)), cfg)[0])
    sizes = (l2p._coarse_rows._cache_size(), l2p._refine_rows._cache_size())
    second = np.asarray(line2point(random_lift(pts, fixed_key(1)), cfg)[0])
    assert (l2p._coarse_rows._cache_size(), l2p._refine_rows._cache_size()) == sizes
    assert not np.allclose(first, second)


def test_equal_offsets_end_the_peak_search():
    """Issue 15 item 2: with all offsets equal the interval never shrank and the while_loop never ended.
    Run in a subprocess so that a regression fails on a timeout instead of hanging the suite."""
    import subprocess

    code = (
        "import numpy as np, jax.numpy as jnp\n"
        "from privslam_jax.attacks.line2point import get_peak, line2point\n"
        "from privslam_jax.privacy.lift import fixed_key, random_directions\n"
        "from privslam_jax.types import LineCloud\n"
        "v = np.zeros(64, bool); v[:40] = True\n"
        "print(float(get_peak(jnp.full(64, 2.5), jnp.asarray(v))))\n"
        "p = [10.0, -5.0, 30.0]  # hung before the fix (the origin did not)\n"
        "pts = jnp.tile(jnp.asarray([p]), (100, 1))  # 100 distinct lines through one point, built as the\n"
        "d = random_directions(fixed_key(0), pts)  # random lift did before it gave copies one line\n"
        "lines = LineCloud(directions=d, moments=jnp.cross(pts, d))\n"
        "rec = np.asarray(line2point(lines)[0])\n"
        "print(np.abs(rec - p).max())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    peak, err = (float(x) for x in out.stdout.split())
    assert peak == 2.5
    assert err < 1e-3  # every line passes through the one point: the attack recovers it
