"""The trade-off objectives (issue 18 item 1) and their gradients (item 2).

References, all independent of ``privslam_jax/tradeoff``:

* photometric alignment: the ground-truth relative pose of two consecutive frames of the synthetic
  world (``T_t_r = T_w_t⁻¹ T_w_r``), and a closed-form warp — a textured fronto-parallel plane seen
  after a known motion, each target pixel's ray intersected with the plane in numpy;
* gradients: central finite differences in float64 along random directions (relative error ≤ 1e-3);
* privacy: the box coverage against a per-pixel numpy overlap; the soft maximum against the largest
  coverage-weighted probability recomputed in numpy; the embedded detector scores a frame with its
  objects higher than the same frame filtered by the embedded EdgeConnect;
* fidelity: a plain numpy mean.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError

from privslam_jax.data.synthetic import SynthConfig, make_sequence
from privslam_jax.inpaint.differentiable import (
    FilterModel,
    filter_constants,
    filter_image,
)
from privslam_jax.inpaint.filter import Inpainter, InpainterConfig, filter_frame
from privslam_jax.tradeoff import (
    DetectorModel,
    PhotometricConfig,
    accuracy_loss,
    align_photometric,
    anchor_mask_coverage,
    fidelity_loss,
    privacy_loss,
)

DATA = os.path.join(os.path.dirname(__file__), "data", "synth_frame_320x96.npz")
FD_RTOL = 1e-3
TIGHT = PhotometricConfig(max_iterations=100, function_tolerance=0.0, step_tolerance=1e-12, min_gradient=0.0, levels=2)
"""Solved to float64 rounding, so that finite differences of the solver's output measure its derivative;
every pixel with valid depth selected (the gradient threshold is a piecewise-constant function of the
reference image, which a finite-difference step may cross)."""


def _to64(tree):
    return jax.tree.map(lambda x: jnp.asarray(np.asarray(x, np.float64)), tree)


def _dot(a, b) -> float:
    return float(sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)))


def _check_fd(f, x, grad, direction, eps) -> float:
    """Central difference of ``f`` at ``x`` along ``direction`` against ``<grad, direction>``; returns the relative error."""
    step = lambda s: jax.tree.map(lambda a, d: a + s * d, x, direction)
    fd = (float(f(step(eps))) - float(f(step(-eps)))) / (2 * eps)
    an = _dot(grad, direction)
    rel = abs(fd - an) / abs(an)
    assert rel <= FD_RTOL, (fd, an)
    return rel


def _pose_errors(T: jaxlie.SE3, T_gt: jaxlie.SE3) -> tuple[float, float]:
    """``(‖Δt‖ m, ‖Δω‖ rad)`` of ``T⁻¹ T_gt`` (numpy on the matrices)."""
    E = np.linalg.inv(np.asarray(T.as_matrix(), np.float64)) @ np.asarray(T_gt.as_matrix(), np.float64)
    angle = np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


# --- photometric alignment / accuracy ------------------------------------------------------------


def _synthetic_pair(width: int, height: int):
    seq = make_sequence(SynthConfig(width=width, height=height, num_frames=2, seed=0))
    f0, f1 = seq[0], seq[1]
    cam = seq.camera
    K = np.array([cam.fx, cam.fy, cam.cx, cam.cy], np.float64)
    T_gt = np.linalg.inv(f1.T_w_c) @ f0.T_w_c
    return f0, f1, K, T_gt


def test_alignment_recovers_the_relative_pose_of_consecutive_synthetic_frames():
    """320×96, frames 0 → 1 (0.8 m forward), identity start, 3 levels, float64.  The object-free pair
    with its depth (a static scene): measured 9.7 mm / 0.037°; the frames with their objects (people
    walk, cars drive; the Huber loss absorbs them): 7.6 mm / 0.036°; both converged in 13–17
    finest-level iterations.  Bounds 3 cm and 0.2° (1 px on a 320×96 image is ~0.5 % of the depth).
    The same image as target and reference gives the identity (< 1e-9)."""
    f0, f1, K, T_gt = _synthetic_pair(320, 96)
    with jax.enable_x64(True):
        run = jax.jit(lambda t, r, d: align_photometric(t, r, d, jnp.asarray(K)))
        T_gt = jaxlie.SE3.from_matrix(jnp.asarray(T_gt))
        assert float(jnp.linalg.norm(T_gt.translation())) > 0.7
        for t, r, d in ((f1.background, f0.background, f0.background_depth), (f1.image, f0.image, f0.depth)):
            T, summary = run(jnp.asarray(t, jnp.float64), jnp.asarray(r, jnp.float64), jnp.asarray(d, jnp.float64))
            assert bool(summary.converged), summary.describe()
            dt, dr = _pose_errors(T, T_gt)
            print("synthetic pair error", dt, np.rad2deg(dr), summary.describe())
            assert dt < 0.03 and dr < np.deg2rad(0.2), (dt, np.rad2deg(dr))
            T_id, _ = run(jnp.asarray(r, jnp.float64), jnp.asarray(r, jnp.float64), jnp.asarray(d, jnp.float64))
            assert max(_pose_errors(T_id, jaxlie.SE3.exp(jnp.zeros(6)))) < 1e-9  # same image: identity


def _plane_pair(T_t_r: np.ndarray, width: int = 128, height: int = 64, Z: float = 4.0):
    """A textured plane ``z = Z`` (reference camera) and the image of it after ``T_t_r``, in closed form."""
    f, cx, cy = 100.0, (width - 1) / 2, (height - 1) / 2

    def tex(X, Y):
        return (0.5 + 0.2 * np.sin(2 * np.pi * X / 0.9) * np.cos(2 * np.pi * Y / 0.7)
                + 0.15 * np.sin(2 * np.pi * (X + 0.6 * Y) / 1.3))

    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    ref = tex((u - cx) / f * Z, (v - cy) / f * Z)
    T_r_t = np.linalg.inv(T_t_r)
    d = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], axis=-1)  # target rays
    dr = d @ T_r_t[:3, :3].T
    s = (Z - T_r_t[2, 3]) / dr[..., 2]
    p = s[..., None] * dr + T_r_t[:3, 3]
    tgt = tex(p[..., 0], p[..., 1])
    return ref, tgt, np.full((height, width), Z), np.array([f, f, cx, cy])


def test_alignment_recovers_a_closed_form_plane_warp():
    """A fronto-parallel textured plane at 4 m, motion t = (5, −3, 10) cm, ω = (0.6°, −1.1°, 0.3°):
    measured errors 0.14 mm and 0.0019° (interpolating the target is the only model error); bounds
    2 mm and 0.03°."""
    T = np.asarray(jaxlie.SE3.exp(jnp.asarray([0.05, -0.03, 0.10, 0.01, -0.02, 0.005], jnp.float32)).as_matrix(),
                   np.float64)
    ref, tgt, depth, K = _plane_pair(T)
    with jax.enable_x64(True):
        Tj = jaxlie.SE3.from_matrix(jnp.asarray(T))
        T_est, summary = jax.jit(align_photometric)(jnp.asarray(tgt), jnp.asarray(ref), jnp.asarray(depth),
                                                    jnp.asarray(K))
        assert bool(summary.converged), summary.describe()
        dt, dr = _pose_errors(T_est, Tj)
        print("plane error", dt, np.rad2deg(dr), summary.describe())
        assert dt < 2e-3 and dr < np.deg2rad(0.03), (dt, np.rad2deg(dr))


def test_accuracy_loss_gradient_matches_finite_differences():
    """d L_acc / d(target image) and d(reference image), 160×48 synthetic pair (frames with objects),
    float64, solved to rounding (``TIGHT``, two pyramid levels: the same errors as three, 3 s less to
    compile).  Central differences of the *solver's output*, step 1e-4,
    relative error ≤ 1e-3 (measured 1.3e-4 and 8.6e-5).  Why they must agree: the implicit-function theorem gives the derivative
    of the exact minimiser of the finest level's cost (C¹: bicubic sampling, Huber, smooth border
    ramp), and the solver reaches it to ~1e-12, so the finite difference of the solve measures the
    same derivative up to O(ε²) and solver noise/ε; a step this small moves the projected points by
    ~1e-5 px and crosses a pixel boundary (a jump of the interpolant's second derivative) rarely.
    Directions: random magnitudes with the signs of the gradient — along fully random directions the
    directional derivative is a sum of cancelling terms ~1 % of ‖g‖‖d‖ (measured 0.0049), and the
    relative error then measures solver noise (1.1e-3 at step 1e-4, 1e-2 at 1e-5)."""
    f0, f1, K, T_gt = _synthetic_pair(160, 48)
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        T_gt = jaxlie.SE3.from_matrix(jnp.asarray(T_gt))
        d = jnp.asarray(f0.depth, jnp.float64)
        vg = jax.jit(jax.value_and_grad(lambda t, r: accuracy_loss(t, r, d, jnp.asarray(K), T_gt, config=TIGHT),
                                        argnums=(0, 1)))
        t, r = jnp.asarray(f1.image, jnp.float64), jnp.asarray(f0.image, jnp.float64)
        value, (gt, gr) = vg(t, r)
        assert 0.0 < float(value) < 0.05 and np.isfinite(np.asarray(gt)).all()
        assert np.abs(np.asarray(gt)).max() > 0 and np.abs(np.asarray(gr)).max() > 0
        orthant = lambda g: jnp.asarray(np.abs(rng.standard_normal(g.shape)) * np.sign(np.asarray(g)))
        print("accuracy FD relative errors",
              _check_fd(lambda x: vg(x, r)[0], t, gt, orthant(gt), 1e-4),
              _check_fd(lambda x: vg(t, x)[0], r, gr, orthant(gr), 1e-4))


# --- privacy -------------------------------------------------------------------------------------


def test_box_coverage_equals_a_per_pixel_overlap():
    """``|B ∩ M| / |B|`` against the sum over mask pixels of their overlap with the real-valued box
    (numpy), boxes partly outside the image included."""
    rng = np.random.default_rng(2)
    masks = rng.random((3, 20, 30)) < 0.4
    boxes = np.concatenate([rng.uniform(-5, 35, (40, 1)), rng.uniform(-5, 25, (40, 1)),
                            rng.uniform(0.3, 15, (40, 2))], axis=1)
    got = np.asarray(anchor_mask_coverage(jnp.asarray(boxes, jnp.float32), masks))
    x1, x2 = boxes[:, 0] - boxes[:, 2] / 2, boxes[:, 0] + boxes[:, 2] / 2
    y1, y2 = boxes[:, 1] - boxes[:, 3] / 2, boxes[:, 1] + boxes[:, 3] / 2
    u, v = np.arange(30), np.arange(20)
    ox = np.clip(np.minimum(u[None] + 1, x2[:, None]) - np.maximum(u[None], x1[:, None]), 0, None)  # (A, W)
    oy = np.clip(np.minimum(v[None] + 1, y2[:, None]) - np.maximum(v[None], y1[:, None]), 0, None)  # (A, H)
    ref = np.einsum("khw,ah,aw->ka", masks.astype(np.float64), oy, ox) / (boxes[:, 2] * boxes[:, 3])[None]
    np.testing.assert_allclose(got, ref, atol=2e-5)


def _tiny_detector():
    """A random 8-class tiny YOLOv8 (kernels ×√6, as tests/test_filter_image.py), float64 state."""
    from privslam_jax.detect.yolov8 import YOLOv8Config, init_yolov8

    model = init_yolov8(YOLOv8Config(num_classes=8, scale="tiny"), seed=0)
    for _, node in nnx.iter_graph(model):
        if isinstance(node, nnx.Conv):
            node.kernel.set_value(jnp.asarray(np.asarray(node.kernel.get_value()) * np.sqrt(6.0)))
    det, state = DetectorModel.split(model)
    return det, _to64(state)


def _synth():
    d = np.load(DATA)
    return d["image"].astype(np.float32) / np.float32(255), d["masks"], d["background"].astype(np.float32) / 255


TAU = 2e-4


def _privacy_case():
    """The left 96×128 of the synthetic frame, its object masks plus one large mask, and the tiny
    random YOLOv8 (float64).  The random net's probabilities are ~1e-4–1e-3 and its boxes 120–480 px
    wide (coverage ≤ 0.08), so the temperature is scaled to them, τ = 2e-4 (with τ = 0.05 the loss is
    ≈ τ·log(A·C) plus a 1e-10 variation, below float64 finite differences)."""
    img, masks, _ = _synth()
    img, masks = img[:, :128], masks[:, :, :128]
    masks = masks[masks.any(axis=(1, 2))]
    big = np.zeros((1, 96, 128), bool)
    big[0, 8:88, 8:120] = True  # the tiny random net's boxes are large: most cover the objects' masks little
    return img, np.concatenate([masks, big]), *_tiny_detector()


def test_privacy_loss_is_a_soft_maximum_of_the_coverage_weighted_probabilities():
    """``L_priv`` lies within τ·log(A·C) above the mean over masks of the largest coverage-weighted
    privacy-class probability, recomputed in numpy from the raw decoded head (``_privacy_case``);
    no mask, no loss."""
    from privslam_jax.detect.decode import decode_head
    from privslam_jax.detect.predict import PRIVACY_CLASSES

    img, masks, det, params = _privacy_case()
    with jax.enable_x64(True):
        x = jnp.asarray(img, jnp.float64)
        loss = jax.jit(lambda x, m: privacy_loss(params, x, m, det, temperature=TAU))
        value = float(loss(x, jnp.asarray(masks)))
        out = np.asarray(jax.jit(lambda x: decode_head(nnx.merge(det.graphdef, params)(x[None]))[0])(x))
        cover = np.asarray(anchor_mask_coverage(jnp.asarray(out[:, :4]), masks))
        s = cover[:, :, None] * out[None, :, 4:][:, :, list(PRIVACY_CLASSES)]
        mx = s.reshape(len(masks), -1).max(axis=1)
        assert mx.mean() <= value <= mx.mean() + TAU * np.log(s[0].size), (mx.mean(), value)
        assert float(loss(x, jnp.zeros(masks.shape, bool))) == 0.0


@pytest.mark.slow
def test_privacy_loss_gradient_matches_finite_differences():
    """d L_priv / d(image) on ``_privacy_case``, float64: central differences along a random direction
    with the gradient's signs (a fully random one gives a cancelling sum, measured 1e-10, at the level
    of rounding), step 1e-6, relative error ≤ 1e-3 (measured 4e-7).  Left to ``-m slow`` (it took 20 s
    of the README's test command), which checks the privacy term's gradient through the filter, in the
    inpainter's parameters, against finite differences of the same loss
    (``tests/test_tradeoff_train.py::test_each_term_gradient_matches_finite_differences``)."""
    img, masks, det, params = _privacy_case()
    rng = np.random.default_rng(3)
    with jax.enable_x64(True):
        vg = jax.jit(jax.value_and_grad(lambda x: privacy_loss(params, x, masks, det, temperature=TAU)))
        x = jnp.asarray(img, jnp.float64)
        _, g = vg(x)
        assert np.abs(np.asarray(g)).max() > 0
        orthant = jnp.asarray(np.abs(rng.standard_normal(x.shape)) * np.sign(np.asarray(g)))
        print("privacy FD relative error", _check_fd(lambda y: vg(y)[0], x, g, orthant, 1e-6))


def test_privacy_loss_of_the_embedded_detector_drops_when_the_objects_are_filtered():
    """The synthetic-world YOLOv8n on the 320×96 frame (ten objects; detector input 640×192 as
    ``Detector`` letterboxes it): with its objects the loss is high (measured 0.67), after the embedded
    EdgeConnect filter low (0.096, the soft maximum's floor τ·log(A·C) = 0.01·log(2520·6)); the
    object-free render scores the same 0.096."""
    from privslam_jax.detect.predict import EMBEDDED_WEIGHTS
    from privslam_jax.detect.weights import load_detector

    if not EMBEDDED_WEIGHTS.is_file():
        pytest.skip("the embedded detector is not shipped in this checkout")
    img, masks, background = _synth()
    det, params = DetectorModel.split(load_detector(EMBEDDED_WEIGHTS)[0])
    f = jax.jit(lambda x: privacy_loss(params, x, masks, det, input_hw=(192, 640)))
    with_objects = float(f(jnp.asarray(img)))
    filtered = float(f(jnp.asarray(filter_frame(img, masks, "edgeconnect"))))
    empty = float(f(jnp.asarray(background)))
    print("embedded privacy loss", with_objects, filtered, empty)
    assert with_objects > 0.5 and filtered < with_objects - 0.3 and empty < with_objects - 0.3, (with_objects, filtered, empty)


# --- fidelity ------------------------------------------------------------------------------------


def test_fidelity_loss_equals_numpy():
    rng = np.random.default_rng(4)
    a, b = rng.random((24, 40, 3)), rng.random((24, 40, 3))
    masks = np.zeros((2, 24, 40), bool)
    masks[0, 2:10, 5:20] = True
    masks[1, 8:20, 15:30] = True
    union = masks.any(axis=0)
    ref = np.abs(a - b)[union].mean()
    assert abs(float(fidelity_loss(jnp.asarray(a), jnp.asarray(b), masks)) - ref) < 1e-6
    assert abs(float(fidelity_loss(jnp.asarray(a[..., 0]), jnp.asarray(b[..., 0]), masks))
               - np.abs(a - b)[..., 0][union].mean()) < 1e-6
    assert float(fidelity_loss(jnp.asarray(a), jnp.asarray(a), masks)) == 0.0
    assert float(fidelity_loss(jnp.asarray(a), jnp.asarray(b), np.zeros_like(masks))) == 0.0
    b2 = np.where(union[..., None], a, b)  # differences outside the masks do not count
    assert float(fidelity_loss(jnp.asarray(a), jnp.asarray(b2), masks)) == 0.0


def _param_direction(params, rng):
    """Random normal on every ``nnx.Param``; zero on the spectral-norm vectors (their gradient is stopped)."""
    flat = [(k, v.replace(jnp.asarray(rng.standard_normal(v[...].shape) if isinstance(v, nnx.Param)
                                      else np.zeros(v[...].shape))))
            for k, v in nnx.to_flat_state(params)]
    return nnx.from_flat_state(flat)


@pytest.mark.slow
def test_fidelity_loss_through_the_filter_matches_finite_differences_in_the_inpainter_params():
    """``L_fid(filter_image(φ, x, M), background, M)`` on a tiny random EdgeConnect (width 4, one
    residual block, as tests/test_filter_image.py), the left 96×128 of the synthetic frame with two
    objects, float64: d/dφ against central differences along 2 random directions, step 1e-8 (the
    generators are ReLU networks: a random direction crosses a kink within ~1e-6), relative
    error ≤ 1e-3 (measured 1.1e-8 and 5.5e-9).  Left to ``-m slow`` (it took 13 s of the README's
    test command), which checks the same composition in pieces: ``filter_image``'s gradient
    (``tests/test_filter_image.py::test_gradients_match_finite_differences``), ``fidelity_loss``
    against numpy (above), and the fidelity term's gradient in the inpainter's parameters through the
    training step (``tests/test_tradeoff_train.py::test_each_term_gradient_matches_finite_differences``)."""
    img, masks, background = _synth()
    img = (np.float32(0.05) + np.float32(0.9) * img[:, :128]).astype(np.float32)  # off the clip kinks
    masks = masks[:, :, :128]
    masks = masks[masks.any(axis=(1, 2))][:2]
    target = background[:, :128]
    config = InpainterConfig(width=4, num_residual_blocks=1)
    model, params = FilterModel.split(Inpainter.init(config, seed=5))
    consts = filter_constants(img, masks, config)
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        p64, x64, b64 = _to64(params), jnp.asarray(img, jnp.float64), jnp.asarray(target, jnp.float64)
        loss = lambda p: fidelity_loss(filter_image(p, x64, masks, model, consts), b64, masks)
        vg = jax.jit(jax.value_and_grad(loss))
        value, g = vg(p64)
        assert float(value) > 0
        print("fidelity FD relative errors", [_check_fd(lambda p: vg(p)[0], p64, g, _param_direction(params, rng), 1e-8)
                                              for _ in range(2)])


def test_bad_arguments():
    with pytest.raises((ValueError, TypeCheckError)):  # jaxtyping sees the shapes first
        fidelity_loss(jnp.zeros((4, 4, 3)), jnp.zeros((4, 5, 3)), np.zeros((1, 4, 4), bool))
    with pytest.raises(ValueError, match="divisible"):
        align_photometric(jnp.zeros((30, 40)), jnp.zeros((30, 40)), jnp.ones((30, 40)), jnp.asarray([50.0, 50, 20, 15]))
    det, params = _tiny_detector()
    with pytest.raises(ValueError, match="multiple of 32"):
        privacy_loss(params, jnp.zeros((40, 64, 3)), np.ones((1, 40, 64), bool), det)
