"""BAL reader, BAL-convention residual, conversion to the OpenCV convention, and BA on real BAL data."""

from __future__ import annotations

import bz2

import cv2
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from privslam_jax.data.bal import BALProblem, bal_cost, bal_residuals, bal_to_opencv, opencv_to_bal_cameras, read_bal
from privslam_jax.slam.ba import BAConfig, bundle_adjust


def _write(path, cams, pts, obs, compress=False):
    lines = [f"{len(cams)} {len(pts)} {len(obs)}"]
    lines += [f"{int(c)} {int(p)} {x:.10f} {y:.10f}" for c, p, x, y in obs]
    lines += [f"{v:.12e}" for v in np.concatenate([cams.ravel(), pts.ravel()])]
    text = "\n".join(lines) + "\n"
    if compress:
        path.write_bytes(bz2.compress(text.encode()))
    else:
        path.write_text(text)
    return path


def _tiny(seed=0, k=(0.0, 0.0)):
    rng = np.random.default_rng(seed)
    cams = np.concatenate([rng.normal(0, 0.1, (3, 3)), rng.normal(0, 0.5, (3, 3)) + [0, 0, -10],
                           np.full((3, 1), 500.0), np.tile(k, (3, 1))], axis=1)
    pts = rng.normal(0, 1, (4, 3))
    obs = [(c, p, *rng.normal(0, 50, 2)) for c in range(3) for p in range(4) if (c + p) % 3]
    return cams, pts, np.array(obs)


def test_read_plain_and_bz2_and_residual_against_opencv(tmp_path):
    cams, pts, obs = _tiny(k=(0.01, -0.002))
    for name, comp in (("p.txt", False), ("p.txt.bz2", True)):
        prob = read_bal(_write(tmp_path / name, cams, pts, obs, comp))
        assert (prob.n_cameras, prob.n_points, prob.n_observations) == (3, 4, len(obs))
        np.testing.assert_allclose(prob.cameras, cams, rtol=1e-10)
        np.testing.assert_array_equal(prob.obs_cam, obs[:, 0].astype(int))
    # independent residual: cv2.Rodrigues and the BAL formula written out
    r = bal_residuals(prob)
    for i, (c, p, x, y) in enumerate(obs):
        R, _ = cv2.Rodrigues(cams[int(c), :3])
        P = R @ pts[int(p)] + cams[int(c), 3:6]
        q = -P[:2] / P[2]
        n2 = q @ q
        pred = cams[int(c), 6] * (1 + cams[int(c), 7] * n2 + cams[int(c), 8] * n2 * n2) * q
        np.testing.assert_allclose(r[i], pred - [x, y], rtol=1e-9, atol=1e-9)
    assert bal_cost(prob) == pytest.approx(0.5 * np.sum(r * r))


def test_opencv_conversion_preserves_residuals(tmp_path):
    cams, pts, obs = _tiny(seed=1)
    prob = read_bal(_write(tmp_path / "p.txt", cams, pts, obs))
    T, intr, uv = bal_to_opencv(prob)
    p_c = np.einsum("nij,nj->ni", T[prob.obs_cam, :3, :3], prob.points[prob.obs_pt]) + T[prob.obs_cam, :3, 3]
    r = p_c[:, :2] / p_c[:, 2:] * intr[prob.obs_cam, :1] - uv
    np.testing.assert_allclose(r, bal_residuals(prob) * [1, -1], atol=1e-9)
    np.testing.assert_allclose(opencv_to_bal_cameras(T, intr), cams, atol=1e-12)
    with pytest.raises(ValueError, match="distortion"):
        bal_to_opencv(BALProblem(cams + np.r_[np.zeros(7), 0.1, 0.0], pts, prob.obs_cam, prob.obs_pt, prob.obs_xy))


def test_corrupt_files_give_clear_errors(tmp_path):
    cams, pts, obs = _tiny()
    good = _write(tmp_path / "g.txt", cams, pts, obs).read_text()
    with pytest.raises(FileNotFoundError, match="missing.txt"):
        read_bal(tmp_path / "missing.txt")
    cases = {
        "truncated": (good[: len(good) // 2], "truncated"),
        "trailing": (good + "1.0\n", "trailing"),
        "header": ("3 x 5\n" + good.split("\n", 1)[1], "header"),
        "text": (good.replace(good.split()[7], "abc", 1), "non-numeric"),
        "index": (good.replace("\n0 1 ", "\n7 1 ", 1), "out of range"),
        "nan": (good.replace(good.split()[-1], "nan"), "NaN"),
    }
    for name, (text, msg) in cases.items():
        path = tmp_path / f"{name}.txt"
        path.write_text(text)
        with pytest.raises(ValueError, match=msg) as info:
            read_bal(path)
        assert str(path) in str(info.value)
    bad = tmp_path / "bad.txt.bz2"
    bad.write_bytes(b"BZh9 not really bzip2")
    with pytest.raises(ValueError, match="bad.txt.bz2"):
        read_bal(bad)


def test_real_problem_start_and_optimum_costs(shared):
    start = read_bal(shared / "reference/ba/kitti_seq1_perturbed.bal.txt.bz2")
    opt = read_bal(shared / "reference/ba/kitti_seq1_colmap_optimum.bal.txt.bz2")
    assert (start.n_cameras, start.n_points, start.n_observations) == (51, 15_698, 89_884)
    assert bal_cost(start) == pytest.approx(26.26e6, rel=1e-3)  # README: 26.26 M px²
    assert bal_cost(opt) == pytest.approx(13_289, rel=1e-4)  # README: 13,289 px²


def test_ba_on_real_subset_reaches_scipy_optimum(shared):
    full = read_bal(shared / "reference/ba/kitti_seq1_perturbed.bal.txt.bz2")
    cams = np.arange(4)
    sel = np.isin(full.obs_cam, cams)
    counts = np.bincount(full.obs_pt[sel], minlength=full.n_points)
    keep_pts = np.flatnonzero(counts >= 3)[:60]
    sel &= np.isin(full.obs_pt, keep_pts)
    remap = np.full(full.n_points, -1)
    remap[keep_pts] = np.arange(keep_pts.size)
    prob = BALProblem(full.cameras[cams], full.points[keep_pts], full.obs_cam[sel], remap[full.obs_pt[sel]].astype(np.int32),
                      full.obs_xy[sel])
    with jax.enable_x64(True):
        T, intr, uv = bal_to_opencv(prob)
        wxyz = np.c_[Rotation.from_matrix(T[:, :3, :3]).as_quat(scalar_first=True), T[:, :3, 3]]
        fixed = np.array([True, False, False, False])
        res = bundle_adjust(jaxlie.SE3(jnp.asarray(wxyz)), prob.points, prob.obs_cam, prob.obs_pt, uv, None, fixed,
                            intr, BAConfig(huber_delta=None, max_iterations=100))
        Tm = np.asarray(res.T_c_w.as_matrix())

        # scipy reference in the BAL parametrisation (Rodrigues = SO3.exp, BAL residual), camera 0 fixed
        f0 = prob.cameras[0, 6]
        oc, op, xy = jnp.asarray(prob.obs_cam), jnp.asarray(prob.obs_pt), jnp.asarray(prob.obs_xy)

        def fun(x):
            c = jnp.concatenate([jnp.asarray(prob.cameras[:1, :6]), x[:18].reshape(3, 6)])
            X = x[18:].reshape(-1, 3)
            P = jax.vmap(lambda r, t, p: jaxlie.SO3.exp(r) @ p + t)(c[oc, :3], c[oc, 3:], X[op])
            return (-f0 * P[:, :2] / P[:, 2:] - xy).reshape(-1)

        x0 = np.concatenate([prob.cameras[1:, :6].ravel(), prob.points.ravel()])
        jf, jj = jax.jit(fun), jax.jit(jax.jacfwd(fun))
        ref = least_squares(lambda x: np.asarray(jf(jnp.asarray(x))), x0, jac=lambda x: np.asarray(jj(jnp.asarray(x))),
                            method="lm", ftol=1e-12, xtol=1e-12, gtol=1e-12)
    ours = bal_cost(prob, opencv_to_bal_cameras(Tm, intr), np.asarray(res.points))
    assert ours == pytest.approx(float(res.cost), rel=1e-9)
    assert ours < 0.01 * bal_cost(prob)
    assert ours == pytest.approx(ref.cost, rel=1e-3)
