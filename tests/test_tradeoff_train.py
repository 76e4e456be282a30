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
from privslam_jax.tradeoff.train import TradeoffConfig, sample_of, synthetic_pairs, tradeoff_step, train_tradeoff

TINY = InpainterConfig(width=4, num_residual_blocks=1)
TIGHT = PhotometricConfig(max_iterations=300, function_tolerance=0.0, step_tolerance=1e-12, min_gradient=0.0)
"""Solved to float64 rounding (151 iterations on the tiny filter's output), every pixel with valid depth selected
(as tests/test_tradeoff_objectives.py)."""
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


def _direct_loss(params, rest, sample, model, det, det_params, cfg: TradeoffConfig):
    """``L`` composed directly from the public functions (no vjp, no cotangents)."""
    state = nnx.merge_state(params, rest)
    y_t = apply_filter(state, sample.target, sample.geometry_t, model, sample.constants_t)
    y_r = apply_filter(state, sample.reference, sample.geometry_r, model, sample.constants_r)
    loss = fidelity_loss(y_t, sample.background, sample.masks_t)
    if cfg.privacy_weight:
        loss += cfg.privacy_weight * privacy_loss(det_params, y_t, sample.masks_t, det,
                                                  temperature=cfg.privacy_temperature, input_hw=cfg.detector_input_hw)
    if cfg.accuracy_weight:
        loss += cfg.accuracy_weight * accuracy_loss(y_t, y_r, sample.reference_depth, sample.intrinsics,
                                                    jaxlie.SE3(sample.T_t_r), config=cfg.alignment)
    return loss


@pytest.mark.parametrize("privacy_weight, accuracy_weight, h", [(0.0, 0.0, 1e-6), (1.0, 0.0, 1e-6), (0.0, 1.0, 1e-8)])
def test_each_term_gradient_matches_finite_differences(case, privacy_weight, accuracy_weight, h):
    """One SGD step of rate 1 moves the parameters by −∂L/∂φ; that gradient against central
    differences of the directly composed ``L`` along a direction with the gradient's signs (relative
    error ≤ 1e-3), for the fidelity term alone, with the privacy term, with the accuracy term.

    The accuracy term needs the small step: the alignment's Huber loss has thousands of residuals
    near its kink, so its minimiser is only piecewise smooth in the pixels; measured relative errors
    for steps 1e-5 / 1e-6 / 1e-7 / 1e-8: 1.3e-2 / 5.4e-3 / 7.2e-5 / 1.3e-5 — finite differences converge to
    the implicit gradient."""
    model, state, sample, det, det_params = case
    cfg = dataclasses.replace(BASE, privacy_weight=privacy_weight, accuracy_weight=accuracy_weight)
    with jax.enable_x64(True):
        params, rest = nnx.split_state(_f64(state), nnx.Param, ...)
        smp, dp = _f64(sample), _f64(det_params)
        sgd = optax.sgd(1.0)
        new, _, logs = jax.jit(lambda p, o: tradeoff_step(p, rest, o, smp, dp, model=model, detector=det,
                                                          optimizer=sgd, config=cfg))(params, sgd.init(params))
        assert float(logs["acc_skipped"]) == 0.0
        grad = jax.tree.map(lambda a, b: a - b, params, new)
        flat = jax.tree.leaves(grad)
        assert sum(float(jnp.abs(g).max()) for g in flat) > 0
        rng = np.random.default_rng(0)
        direction = jax.tree.map(lambda g: jnp.asarray(np.abs(rng.standard_normal(g.shape)) * np.sign(np.asarray(g))), grad)
        f = jax.jit(lambda p: _direct_loss(p, rest, smp, model, det, dp, cfg))
        # the same value (to the alignment's own tolerance: two compilations of the same solve)
        assert abs(float(f(params)) - float(logs["loss"])) <= 1e-7 * abs(float(logs["loss"]))
        step = lambda s: jax.tree.map(lambda a, d: a + s * d, params, direction)  # noqa: E731
        fd = (float(f(step(h))) - float(f(step(-h)))) / (2 * h)
        analytic = sum(float(jnp.vdot(g, d)) for g, d in zip(flat, jax.tree.leaves(direction)))
        assert abs(fd - analytic) <= 1e-3 * abs(analytic), (fd, analytic)


def test_an_unconverged_alignment_drops_the_accuracy_term_instead_of_writing_nan(case):
    model, state, sample, det, det_params = case
    params, rest = nnx.split_state(state, nnx.Param, ...)
    sgd = optax.sgd(1.0)

    def run(cfg):
        return jax.jit(lambda p, o, smp: tradeoff_step(p, rest, o, smp, det_params, model=model, detector=det,
                                                       optimizer=sgd, config=cfg))(params, sgd.init(params), sample)

    short = dataclasses.replace(BASE, accuracy_weight=1.0, alignment=PhotometricConfig(max_iterations=1))
    new, _, logs = run(short)
    ref, _, ref_logs = run(dataclasses.replace(short, accuracy_weight=0.0))
    assert float(logs["acc_skipped"]) == 1.0 and float(ref_logs["acc_skipped"]) == 0.0
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(ref)):
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a, b)


def test_a_killed_run_resumes_to_the_same_weights(case, tmp_path):
    """4 steps in one go against 2 steps, a 'kill', and a rerun of the same call: the same weights, the
    same log rows (time column aside)."""
    model, _, _, det, det_params = case
    cfg = dataclasses.replace(BASE, steps=4, checkpoint_every=2, learning_rate=1e-3, alignment=PhotometricConfig(
        function_tolerance=1e-6, step_tolerance=1e-6))
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
    # the data stream is reproducible: the same config gives the same first pair
    a, b = next(synthetic_pairs(cfg, model)), next(synthetic_pairs(cfg, model))
    np.testing.assert_array_equal(a.target, b.target)
