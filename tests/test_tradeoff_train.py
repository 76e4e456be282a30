"""Training the filter on the trade-off objectives (issue 18 item 2): ``privslam_jax.tradeoff.train``.

References, independent of the training step's ``vjp``/cotangent plumbing:

* each term's gradient in the inpainter's parameters against central finite differences of the loss
  composed directly from the public functions (``apply_filter`` then ``fidelity_loss``,
  ``privacy_loss``, ``accuracy_loss``), float64, tiny random inpainter and detector;
* a killed run resumed from its checkpoint ends where the uninterrupted run ends.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optax
import pytest
from flax import nnx

from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.inpaint.differentiable import FilterModel, apply_filter
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig
from privslam_jax.tradeoff import DetectorModel, PhotometricConfig, accuracy_loss, fidelity_loss, privacy_loss
from privslam_jax.tradeoff.train import (
    TradeoffConfig,
    _compiled_step,
    sample_of,
    synthetic_batches,
    synthetic_pairs,
    tradeoff_step,
    train_tradeoff,
)

pytestmark = pytest.mark.xla_optimized  # training loops (tests/conftest.py)

TINY = InpainterConfig(width=4, num_residual_blocks=1)
TIGHT = PhotometricConfig(max_iterations=300, function_tolerance=0.0, step_tolerance=1e-12, min_gradient=0.0, levels=1)
"""Solved to float64 rounding, every pixel with valid depth selected (as tests/test_tradeoff_objectives.py);
one pyramid level instead of three: a smaller program to compile (the finite-difference tests' file
alone: 82 → 62 s from three levels to two; 68.9 → 57.7 s from two to one, measured on 2026-12-06), its
finite differences still within the test's bound (below)."""
BASE = TradeoffConfig(width=192, height=64, frames_per_world=4, world_seeds=(7,), rows=6, dilation=1,
                      detector_input_hw=(64, 192), privacy_temperature=2e-4, alignment=TIGHT)


def _f64(tree):
    return jax.tree.map(lambda a: jnp.asarray(np.asarray(a, np.float64)) if np.issubdtype(np.asarray(a).dtype, np.floating)
                        else jnp.asarray(a), tree)


def _tiny_detector():
    from privslam_jax.detect.yolov8 import YOLOv8Config, init_yolov8

    model = init_yolov8(YOLOv8Config(num_classes=8, scale="tiny"), seed=0)
    for _, node in nnx.iter_graph(model):
        if isinstance(node, nnx.Conv):  # a random net's probabilities are tiny: give them some spread
            node.kernel.set_value(jnp.asarray(np.asarray(node.kernel.get_value()) * np.sqrt(6.0)))
    return DetectorModel.split(model)


@pytest.fixture(scope="module")
def case():
    seq = make_sequence(SynthConfig(width=BASE.width, height=BASE.height, num_frames=2, seed=7))
    model, state = FilterModel.split(Inpainter.init(TINY, seed=1))
    sample = sample_of(seq[0], seq[1], seq.camera, model, BASE.rows, BASE.dilation)
    det, det_params = _tiny_detector()
    return model, state, sample, det, det_params


def _direct_loss(params, rest, sample, model, det, det_params, weights, cfg: TradeoffConfig):
    """``L`` composed directly from the public functions (no vjp, no cotangents)."""
    state = nnx.merge_state(params, rest)
    y_t = apply_filter(state, sample.target, sample.geometry_t, model, sample.constants_t)
    y_r = apply_filter(state, sample.reference, sample.geometry_r, model, sample.constants_r)
    return (fidelity_loss(y_t, sample.background, sample.masks_t)
            + weights[0] * privacy_loss(det_params, y_t, sample.masks_t, det, temperature=cfg.privacy_temperature,
                                        input_hw=cfg.detector_input_hw)
            + weights[1] * accuracy_loss(y_t, y_r, sample.reference_depth, sample.intrinsics, jaxlie.SE3(sample.T_t_r),
                                         config=cfg.alignment))


@pytest.fixture(scope="module")
def f64_programs(case):
    """The float64 SGD step and the directly composed ``L``, each jitted once with the weights as an
    argument (the step's program includes the alignment: ``accuracy_weight`` ≠ 0)."""
    model, state, sample, det, det_params = case
    cfg = dataclasses.replace(BASE, accuracy_weight=1.0)
    with jax.enable_x64(True):
        params, rest = nnx.split_state(_f64(state), nnx.Param, ...)
        smp, dp = _f64(sample), _f64(det_params)
    sgd = optax.sgd(1.0)
    step = jax.jit(lambda p, o, w: tradeoff_step(p, rest, o, smp, dp, w, model=model, detector=det, optimizer=sgd,
                                                 config=cfg))
    loss = jax.jit(lambda p, w: _direct_loss(p, rest, smp, model, det, dp, w, cfg))
    return params, sgd, step, loss


@pytest.mark.parametrize("privacy_weight, accuracy_weight, h, rtol",
                         [(0.0, 0.0, 1e-8, 1e-3), (1.0, 0.0, 1e-8, 1e-3), (0.0, 1.0, 1e-7, 3e-3)])
def test_each_term_gradient_matches_finite_differences(f64_programs, privacy_weight, accuracy_weight, h, rtol):
    """One SGD step of rate 1 moves the parameters by −∂L/∂φ; that gradient against central
    differences of the directly composed ``L`` along a direction with the gradient's signs (relative
    error ≤ 1e-3; 3e-3 with the accuracy term), for the fidelity term alone, with the privacy term,
    with the accuracy term.

    Every term needs a small step: the losses are only piecewise smooth in the parameters (the
    filter's clipping; the alignment's Huber loss has thousands of residuals near its kink), and the
    finite differences converge to the gradient as the step shrinks until float64 rounding takes
    over.  Measured relative errors for steps 1e-5 / 1e-6 / 1e-7 / 1e-8 / 1e-9: fidelity
    4.3e-3 / 6.7e-4 / 8.6e-5 / 8.2e-6 / 1.2e-9 (privacy the same to two digits); accuracy 3.2e-3 /
    1.6e-3 / 4.1e-4 / 2.2e-3 / 4.7e-3 (with the alignment's two pyramid levels it was 1.3e-2 / 5.4e-3 /
    7.2e-5 / 2.5e-4 / 7.1e-3: the kinks, not the program, set the error).  On an AVX-512 machine
    (2026-12-07) the accuracy term gave 3.2e-3 / 1.7e-3 / 1.1e-3 / 2.7e-3 / 1.7e-2 for the same steps,
    and 4e-4 to 1.6e-3 for steps between 3e-6 and 3e-8: which residuals cross a kink depends on the
    last bits of the solve, so the error at one step wanders within that band.  A wrong gradient (a
    dropped term, a transposed Jacobian) is off by far more."""
    params, sgd, step_fn, f = f64_programs
    with jax.enable_x64(True):
        w = jnp.asarray([privacy_weight, accuracy_weight], jnp.float64)
        new, _, logs = step_fn(params, sgd.init(params), w)
        assert float(logs["acc_skipped"]) == 0.0
        grad = jax.tree.map(lambda a, b: a - b, params, new)
        flat = jax.tree.leaves(grad)
        assert sum(float(jnp.abs(g).max()) for g in flat) > 0
        rng = np.random.default_rng(0)
        direction = jax.tree.map(lambda g: jnp.asarray(np.abs(rng.standard_normal(g.shape)) * np.sign(np.asarray(g))), grad)
        # the same value (to the alignment's own tolerance: two compilations of the same solve)
        assert abs(float(f(params, w)) - float(logs["loss"])) <= 1e-7 * abs(float(logs["loss"]))
        step = lambda s: jax.tree.map(lambda a, d: a + s * d, params, direction)  # noqa: E731
        fd = (float(f(step(h), w)) - float(f(step(-h), w))) / (2 * h)
        analytic = sum(float(jnp.vdot(g, d)) for g, d in zip(flat, jax.tree.leaves(direction)))
        assert abs(fd - analytic) <= rtol * abs(analytic), (fd, analytic)
    assert step_fn._cache_size() == f._cache_size() == 1  # the weights are an argument: one program each


TRAIN = dataclasses.replace(BASE, steps=4, checkpoint_every=2, learning_rate=1e-3,
                            alignment=PhotometricConfig(max_iterations=1, levels=1))
"""Adam runs of ``train_tradeoff``; the alignment is cut off after one iteration of one pyramid level
(its gradient is then NaN by design; one level keeps the program small), and both tests below use
the one compiled step."""


def test_an_unconverged_alignment_drops_the_accuracy_term_instead_of_writing_nan(case, tmp_path):
    """A step with λ_a = 1 and one with λ_a = 2 end with the same finite weights, bit for bit, and log
    the term as dropped: the accuracy term added nothing (and no NaN)."""
    _, _, sample, det, det_params = case
    init = Inpainter.init(TINY, seed=1)
    runs = {a: train_tradeoff(dataclasses.replace(TRAIN, steps=1, accuracy_weight=a), init, det_params, det,
                              tmp_path / str(a), data=iter([sample]), progress=False) for a in (1.0, 2.0)}
    for a in runs:
        log = np.genfromtxt(tmp_path / str(a) / "log.csv", delimiter=",", names=True)
        assert float(log["acc_skipped"]) == 1.0
        assert float(log["loss"]) == pytest.approx(float(log["fidelity"]) + float(log["privacy"]), abs=2e-6)
    for a, b, p in zip(jax.tree.leaves(runs[1.0].state), jax.tree.leaves(runs[2.0].state), jax.tree.leaves(init.state)):
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(a, p) for a, p in zip(jax.tree.leaves(runs[1.0].state), jax.tree.leaves(init.state)))


def test_a_process_makes_its_own_pairs_of_every_batch(case):
    """``synthetic_batches`` with one process's rows (:func:`~privslam_jax.sharding.local_rows`) makes
    exactly those pairs of every batch: two processes' streams side by side are the one-process
    batches; a stream started at batch ``start`` (a resumed run) goes on as the uninterrupted one;
    the pairs do not depend on the batch size (``synthetic_pairs``)."""
    import itertools

    model = case[0]
    cfg = dataclasses.replace(BASE, batch_size=2)
    whole = list(itertools.islice(synthetic_batches(cfg, model), 3))
    halves = [list(itertools.islice(synthetic_batches(cfg, model, rows), 3)) for rows in (slice(0, 1), slice(1, 2))]
    resumed = next(synthetic_batches(cfg, model, slice(1, 2), start=2))
    pairs = list(itertools.islice(synthetic_pairs(cfg, model), 6))

    def same(a, b):
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(x, y)

    for b in range(3):
        assert len(whole[b]) == 2 and len(halves[0][b]) == len(halves[1][b]) == 1
        for i in (0, 1):
            same(halves[i][b][0], whole[b][i])
            same(pairs[2 * b + i], whole[b][i])
    same(resumed[0], whole[2][1])
    assert len({pair.target.tobytes() for batch in whole for pair in batch}) > 1  # not one pair over and over


def test_a_killed_run_resumes_to_the_same_weights(case, tmp_path):
    """4 steps in one go against 2 steps, a 'kill', and a rerun of the same call: the same weights, the
    same log rows (time column aside)."""
    model, _, _, det, det_params = case
    cfg = TRAIN
    init = Inpainter.init(TINY, seed=1)
    whole = train_tradeoff(cfg, init, det_params, det, tmp_path / "a", progress=False)
    train_tradeoff(cfg, init, det_params, det, tmp_path / "b", max_steps=2, progress=False)
    resumed = train_tradeoff(cfg, init, det_params, det, tmp_path / "b", progress=False)
    for a, b in zip(jax.tree.leaves(whole.state), jax.tree.leaves(resumed.state)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    rows = [[r.split(",")[:1] + r.split(",")[2:] for r in (p / "log.csv").read_text().splitlines()] for p in
            (tmp_path / "a", tmp_path / "b")]
    assert len(rows[0]) == 5 and rows[0] == rows[1]
    assert not np.allclose(jax.tree.leaves(whole.state)[0], jax.tree.leaves(init.state)[0])  # it trained
    # a sweep over the weights reuses the compiled step; dropping the accuracy term is another program
    assert _compiled_step(model, det, cfg) is _compiled_step(model, det, dataclasses.replace(
        cfg, privacy_weight=3.0, accuracy_weight=0.5, steps=9, seed=4))
    assert _compiled_step(model, det, cfg) is not _compiled_step(model, det, dataclasses.replace(cfg, accuracy_weight=0.0))
    # the data stream is reproducible: the same config gives the same first pair
    a, b = next(synthetic_pairs(cfg, model)), next(synthetic_pairs(cfg, model))
    np.testing.assert_array_equal(a.target, b.target)
