"""The least-squares core (:mod:`privslam_jax.solvers`): the LM loop, its summary, implicit derivatives.

References: numpy's ``lstsq`` for a linear problem (closed form), central finite differences of the
whole solve for the implicit derivatives (float64, solved to the step tolerance), ``jacfwd`` against
``jacrev``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from privslam_jax.slam.ba import BAConfig, bundle_adjust_padded
from privslam_jax.solvers.implicit import implicit_argmin
from privslam_jax.solvers.linear import DenseSystem, dense_damped_solve
from privslam_jax.solvers.lm import STATUS_NAMES, LMParams, levenberg_marquardt
from privslam_jax.solvers.schur import analyze
from privslam_jax.slam.refine import RefineConfig, camera_params, refine_pose_padded
from privslam_jax.types import Camera

CAM = Camera(fx=500.0, fy=480.0, cx=320.0, cy=240.0, width=640, height=480, baseline=0.5)
# solved to the step tolerance, so that finite differences of the solution are meaningful
EXACT = RefineConfig(rounds=1, max_iterations=100, function_tolerance=0.0, step_tolerance=1e-13)
EXACT_BA = BAConfig(max_iterations=200, function_tolerance=0.0, parameter_tolerance=1e-14)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def _linear_problem(A: np.ndarray, b: np.ndarray):
    A, b = jnp.asarray(A), jnp.asarray(b)

    def cost(x):
        r = A @ x - b
        return 0.5 * jnp.dot(r, r)

    def linearise(x):
        return DenseSystem(H=A.T @ A, g=A.T @ (A @ x - b), cost=cost(x))

    return linearise, cost


def test_lm_solves_a_linear_problem_like_lstsq_and_says_why_it_stopped(x64):
    rng = np.random.default_rng(0)
    A, b = rng.normal(size=(30, 5)), rng.normal(size=30)
    linearise, cost = _linear_problem(A, b)
    params = LMParams.of(jnp.float64, 100, 1e-4, 0.0, step_tolerance=1e-12)
    x, system, summary = levenberg_marquardt(jnp.zeros(5), linearise, dense_damped_solve, cost, lambda x, d: x + d, params)
    ref = np.linalg.lstsq(A, b, rcond=None)[0]
    # steps are accepted on a lower cost, so x is exact to about √eps relative (the cost to eps)
    np.testing.assert_allclose(x, ref, rtol=1e-6, atol=1e-9)
    assert STATUS_NAMES[int(summary.status)] == "converged" and bool(summary.converged)
    np.testing.assert_allclose(summary.cost, 0.5 * np.sum((A @ ref - b) ** 2), rtol=1e-12)
    np.testing.assert_allclose(summary.initial_cost, 0.5 * np.sum(b * b), rtol=1e-12)
    assert 1 <= int(summary.iterations) < 100
    assert "converged" in summary.describe()

    one = LMParams.of(jnp.float64, 1, 1e-4, 1e-15, step_tolerance=1e-12)
    _, _, s1 = levenberg_marquardt(jnp.zeros(5), linearise, dense_damped_solve, cost, lambda x, d: x + d, one)
    assert STATUS_NAMES[int(s1.status)] == "max_steps" and int(s1.iterations) == 1 and not bool(s1.converged)

    nan_b = b.copy()
    nan_b[3] = np.nan
    lin_nan, cost_nan = _linear_problem(A, nan_b)
    _, _, s2 = levenberg_marquardt(jnp.zeros(5), lin_nan, dense_damped_solve, cost_nan, lambda x, d: x + d, params)
    assert STATUS_NAMES[int(s2.status)] == "non_finite"

    def uphill(system, lam):  # a solver that only proposes ascent steps: nothing is ever accepted
        return system.g, jnp.asarray(1.0)

    _, _, s3 = levenberg_marquardt(jnp.zeros(5), linearise, uphill, cost, lambda x, d: x + d, params)
    assert STATUS_NAMES[int(s3.status)] == "stalled" and int(s3.iterations) < 100


# ---- pose refinement ------------------------------------------------------------------------


def _pose_problem(seed: int, n: int, stereo: bool, outliers: int = 0):
    rng = np.random.default_rng(seed)
    X = rng.uniform([-5, -3, 4], [5, 3, 20], (n, 3))
    T = jaxlie.SE3.exp(jnp.asarray(rng.normal(0, [0.2, 0.2, 0.2, 0.03, 0.03, 0.03])))
    pc = X @ np.asarray(T.rotation().as_matrix()).T + np.asarray(T.translation())
    uv = np.c_[CAM.fx * pc[:, 0] / pc[:, 2] + CAM.cx, CAM.fy * pc[:, 1] / pc[:, 2] + CAM.cy] + rng.normal(0, 0.5, (n, 2))
    # inliers (σ = 0.5 px) stay well inside Huber's quadratic region and the outliers (+8 px) well
    # beyond it: the solution is smooth in θ there (crossing δ² makes dx*/dθ jump)
    uv[:outliers] += 8.0
    ur = None
    if stereo:
        ur = uv[:, 0] - CAM.fx * 0.5 / pc[:, 2] + rng.normal(0, 0.5, n)
        ur[::3] = -1.0
    isg = rng.uniform(0.5, 1.5, n)
    return jnp.asarray(X), jnp.asarray(uv), jnp.asarray(isg), None if ur is None else jnp.asarray(ur)


def _central_difference(f, theta, direction, h):
    plus = jax.tree.map(lambda a, d: a + h * d, theta, direction)
    minus = jax.tree.map(lambda a, d: a - h * d, theta, direction)
    return (f(plus) - f(minus)) / (2 * h)


@pytest.mark.parametrize("n, stereo, outliers", [(24, False, 0), (50, True, 6)])
def test_refine_gradient_matches_central_differences(x64, n, stereo, outliers):
    X, uv, isg, ur = _pose_problem(1, n, stereo, outliers)
    K = camera_params(CAM, jnp.float64)
    valid = jnp.ones(n, bool)
    w = jnp.asarray(np.random.default_rng(2).normal(size=7))

    def loss(theta):
        pts, obs, info, intr = theta
        r = refine_pose_padded(jaxlie.SE3.identity(), pts, obs, valid, info, ur, intr, EXACT)
        return jnp.dot(w, r.T_c_w.wxyz_xyz)

    theta = (X, uv, isg, K)
    grad = jax.jit(jax.grad(loss))(theta)
    rng = np.random.default_rng(3)
    for _ in range(3):
        direction = jax.tree.map(lambda a: jnp.asarray(rng.normal(size=a.shape)), theta)
        fd = _central_difference(loss, theta, direction, 1e-4)
        analytic = sum(jnp.vdot(g, d) for g, d in zip(jax.tree.leaves(grad), jax.tree.leaves(direction)))
        assert abs(float(analytic) - float(fd)) <= 1e-4 * max(abs(float(fd)), 1e-3), (float(analytic), float(fd))


@pytest.mark.xla_optimized  # a vmapped and a single compilation of the solve agree to 1e-8 as users compile them
def test_refine_jacfwd_equals_jacrev_and_batches(x64):
    X, uv, isg, ur = _pose_problem(4, 30, True)
    K = camera_params(CAM, jnp.float64)
    valid = jnp.ones(30, bool)

    def pose(pts, obs):
        return refine_pose_padded(jaxlie.SE3.identity(), pts, obs, valid, isg, ur, K, EXACT).T_c_w.wxyz_xyz

    Jf = jax.jit(jax.jacfwd(pose, argnums=(0, 1)))(X, uv)
    Jr = jax.jit(jax.jacrev(pose, argnums=(0, 1)))(X, uv)
    for a, b in zip(Jf, Jr):
        assert a.shape == b.shape and np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)

    # a batch of two problems under vmap gives each problem's own gradient
    X2, uv2, _, _ = _pose_problem(5, 30, True)
    loss = lambda pts, obs: jnp.sum(pose(pts, obs) ** 2)  # noqa: E731
    batched = jax.jit(jax.vmap(jax.grad(loss)))(jnp.stack([X, X2]), jnp.stack([uv, uv2]))
    single = jax.jit(jax.grad(loss))
    for k, (p, o) in enumerate(((X, uv), (X2, uv2))):
        np.testing.assert_allclose(batched[k], single(p, o), rtol=1e-8, atol=1e-12)


def test_refine_gradient_is_nan_when_the_solve_did_not_converge(x64):
    X, uv, isg, _ = _pose_problem(6, 24, False)
    K = camera_params(CAM, jnp.float64)
    valid = jnp.ones(24, bool)
    short = RefineConfig(rounds=1, max_iterations=1, function_tolerance=0.0, step_tolerance=1e-13)

    def run(pts):
        return refine_pose_padded(jaxlie.SE3.identity(), pts, uv, valid, isg, None, K, short)

    assert STATUS_NAMES[int(run(X).summary.status)] == "max_steps"
    g = jax.grad(lambda p: jnp.sum(run(p).T_c_w.wxyz_xyz))(X)
    assert np.all(np.isnan(g))


def test_grad_of_a_jitted_solve_equals_jit_of_grad_and_does_not_retrace(x64):
    """``grad(jit(f))`` (a user's jitted loss differentiated from outside) partially evaluates the
    jitted solve; the solver's constants (here the observations' information and intrinsics, traced
    arguments of the jitted function) must not become closed-over constants there.  ``jit(grad(f))``
    called again with the same shapes runs the compiled program (no trace)."""
    X, uv, isg, _ = _pose_problem(8, 24, False)
    valid = jnp.ones(24, bool)

    traces = []

    @jax.jit
    def loss(pts, info, intr):
        traces.append(1)
        r = refine_pose_padded(jaxlie.SE3.identity(), pts, uv, valid, info, None, intr, EXACT)
        return jnp.sum(r.T_c_w.wxyz_xyz)

    K = camera_params(CAM, jnp.float64)
    outside = jax.grad(loss)(X, isg, K)
    grad = jax.jit(jax.grad(loss))
    inside = grad(X, isg, K)
    assert np.all(np.isfinite(outside))
    np.testing.assert_allclose(outside, inside, rtol=1e-10, atol=1e-14)
    # a repeated shape reuses the compiled gradient: no new trace, new values
    n = len(traces)
    again = grad(X + 0.01, isg, K)
    assert len(traces) == n and not np.allclose(again, inside)


# ---- bundle adjustment ----------------------------------------------------------------------


def _ba_problem(seed: int, n_cams: int = 4, n_pts: int = 24):
    rng = np.random.default_rng(seed)
    X = rng.uniform([-3, -2, 6], [3, 2, 12], (n_pts, 3))
    cams = [jaxlie.SE3.exp(jnp.asarray([0.4 * k, 0.02 * k, 0.1 * k, 0.0, -0.02 * k, 0.01 * k])) for k in range(n_cams)]
    wxyz = np.stack([np.asarray(c.wxyz_xyz) for c in cams])
    oc, op, uv, ur = [], [], [], []
    for c, T in enumerate(cams):
        pc = X @ np.asarray(T.rotation().as_matrix()).T + np.asarray(T.translation())
        for p in range(n_pts):
            u = CAM.fx * pc[p, 0] / pc[p, 2] + CAM.cx + 0.3 * rng.normal()  # σ = 0.3 px: far from Huber's δ
            oc.append(c), op.append(p), uv.append([u, CAM.fy * pc[p, 1] / pc[p, 2] + CAM.cy + 0.3 * rng.normal()])
            ur.append(u - CAM.fx * 0.5 / pc[p, 2] + 0.3 * rng.normal() if p % 2 == 0 else -1.0)
    oc, op = np.asarray(oc, np.int32), np.asarray(op, np.int32)
    n_o = len(oc) + 1  # one padded row (the dummy of the pair list)
    pad = lambda a, fill: np.concatenate([np.asarray(a), np.full((1,) + np.shape(a)[1:], fill)])  # noqa: E731
    structure = analyze(oc, op, n_cams, n_o, BAConfig().chunk, pad=False)
    X0 = X + rng.normal(0, 0.05, X.shape)
    wxyz0 = wxyz.copy()
    wxyz0[1:, 4:] += rng.normal(0, 0.02, (n_cams - 1, 3))
    K = np.tile([CAM.fx, CAM.fy, CAM.cx, CAM.cy, 0.5], (n_cams, 1))
    fixed = np.zeros(n_cams, bool)
    fixed[0] = True
    return dict(
        T0=jaxlie.SE3(jnp.asarray(wxyz0)), X0=jnp.asarray(X0), cam=jnp.asarray(pad(oc, 0)), pt=jnp.asarray(pad(op, 0)),
        uv=jnp.asarray(pad(uv, 0.0)), valid=jnp.asarray(pad(np.ones(len(oc), bool), False)),
        isg=jnp.asarray(pad(np.ones(len(oc)), 1.0)), fixed=jnp.asarray(fixed), K=jnp.asarray(K), structure=structure,
        ur=jnp.asarray(pad(ur, -1.0)),
    )


def _ba(p, uv, K, ur, config=EXACT_BA, fixed=None):
    return bundle_adjust_padded(p["T0"], p["X0"], p["cam"], p["pt"], uv, p["valid"], p["isg"],
                                p["fixed"] if fixed is None else fixed, K, p["structure"], config, obs_u_right=ur)


def test_ba_gradient_matches_central_differences_and_jacfwd_equals_jacrev(x64):
    p = _ba_problem(0)
    w = jnp.asarray(np.random.default_rng(1).normal(size=(4, 7)))

    def loss(theta):
        uv, K, ur = theta
        r = _ba(p, uv, K, ur)
        return jnp.sum(w * r.T_c_w.wxyz_xyz) + jnp.sum(r.points[:, 2])

    theta = (p["uv"], p["K"], p["ur"])
    assert bool(_ba(p, *theta).summary.converged)
    grad = jax.jit(jax.grad(loss))(theta)
    rng = np.random.default_rng(2)
    for _ in range(2):
        direction = jax.tree.map(lambda a: jnp.asarray(rng.normal(size=a.shape)), theta)
        direction = (direction[0], direction[1], direction[2] * (p["ur"] >= 0))  # keep monocular rows monocular
        fd = _central_difference(loss, theta, direction, 1e-4)
        analytic = sum(jnp.vdot(g, d) for g, d in zip(jax.tree.leaves(grad), jax.tree.leaves(direction)))
        assert abs(float(analytic) - float(fd)) <= 1e-4 * max(abs(float(fd)), 1e-3), (float(analytic), float(fd))
    # the fixed camera does not move, whatever the observations do
    def solution(uv, K):
        r = _ba(p, uv, K, p["ur"])
        return r.T_c_w.wxyz_xyz, r.points

    (J_pose_uv, _), (_, Jr) = jax.jit(jax.jacrev(solution, argnums=(0, 1)))(p["uv"], p["K"])  # one reverse program
    assert np.all(J_pose_uv[0] == 0)
    Jf = jax.jit(jax.jacfwd(lambda K: solution(p["uv"], K)[1]))(p["K"])
    np.testing.assert_allclose(Jf, Jr, rtol=1e-8, atol=1e-10)


def test_monocular_ba_with_a_free_scale_flags_its_gradient(x64):
    p = _ba_problem(3)
    mono = jnp.full_like(p["ur"], -1.0)
    r = _ba(p, p["uv"], p["K"], mono)
    assert bool(r.summary.converged)
    g = jax.grad(lambda uv: jnp.sum(_ba(p, uv, p["K"], mono).points))(p["uv"])
    assert np.all(np.isnan(g))  # one fixed camera leaves the monocular scale free: H is singular
    two = p["fixed"].at[1].set(True)  # fixing a second camera removes it
    g2 = jax.grad(lambda uv: jnp.sum(_ba(p, uv, p["K"], mono, fixed=two).points))(p["uv"])
    assert np.all(np.isfinite(g2)) and np.any(g2 != 0)


def test_implicit_singularity_is_judged_in_the_variables_own_units():
    """float32 quadratic ``F = ½ Σ a_i (x_i − θ_i)²`` with curvatures 1e-4, 1, 1e4 (metres against
    radians against pixels): ``dx*/dθ = I`` exactly, though ``H``'s raw condition number (1e8) is
    beyond float32's; a truly free direction (``F = ½ (x_0 + x_1 − θ)²``) still gives NaN."""
    a = jnp.asarray([1e-4, 1.0, 1e4], jnp.float32)
    f = implicit_argmin(
        solve=lambda x0, th, const: (th, jnp.asarray(True)),
        objective=lambda x, th, const, aux: 0.5 * jnp.sum(const * (x - th) ** 2),
        retract=lambda x, xi, const: x + xi,
        zero_tangent=jnp.zeros_like,
        converged=lambda aux: aux,
    )
    J = jax.jacfwd(lambda th: f(jnp.zeros(3, jnp.float32), th, a)[0])(jnp.ones(3, jnp.float32))
    np.testing.assert_allclose(J, np.eye(3), atol=1e-6)
    free = implicit_argmin(
        solve=lambda x0, th, const: (jnp.stack([th, jnp.zeros_like(th)]), jnp.asarray(True)),
        objective=lambda x, th, const, aux: 0.5 * (x[0] + x[1] - th) ** 2,
        retract=lambda x, xi, const: x + xi,
        zero_tangent=jnp.zeros_like,
        converged=lambda aux: aux,
    )
    g = jax.grad(lambda th: jnp.sum(free(jnp.zeros(2, jnp.float32), th, None)[0]))(jnp.float32(1.0))
    assert np.isnan(g)
