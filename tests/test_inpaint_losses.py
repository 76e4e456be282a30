"""EdgeConnect losses against plain numpy formulas."""

from __future__ import annotations

import numpy as np

from privslam_jax.inpaint import losses as L


def _sig(x):
    return 1 / (1 + np.exp(-x))


def test_gan_losses_equal_sigmoid_bce():
    rng = np.random.default_rng(0)
    real, fake = rng.normal(size=(2, 6, 6, 1)), rng.normal(size=(2, 6, 6, 1))
    bce = lambda p, t: -np.mean(t * np.log(p) + (1 - t) * np.log(1 - p))  # noqa: E731
    d = 0.5 * (bce(_sig(real), 1) + bce(_sig(fake), 0))
    np.testing.assert_allclose(float(L.discriminator_loss(real, fake)), d, rtol=1e-5)
    np.testing.assert_allclose(float(L.generator_adversarial_loss(fake)), bce(_sig(fake), 1), rtol=1e-5)


def test_feature_matching_l1_gram():
    rng = np.random.default_rng(1)
    fa = [rng.normal(size=(2, 8, 8, 3)), rng.normal(size=(2, 4, 4, 5))]
    fb = [rng.normal(size=(2, 8, 8, 3)), rng.normal(size=(2, 4, 4, 5))]
    want = sum(np.mean(np.abs(a - b)) for a, b in zip(fa, fb))
    np.testing.assert_allclose(float(L.feature_matching_loss(fa, fb)), want, rtol=1e-5)
    np.testing.assert_allclose(float(L.perceptual_loss(fa, fb, [2.0, 0.5])),
                               2 * np.mean(np.abs(fa[0] - fb[0])) + 0.5 * np.mean(np.abs(fa[1] - fb[1])), rtol=1e-5)
    f = fa[0]
    g = np.stack([f[i].reshape(-1, 3).T @ f[i].reshape(-1, 3) / (8 * 8 * 3) for i in range(2)])
    np.testing.assert_allclose(np.asarray(L.gram(f)), g, rtol=1e-5)
    gs = [np.asarray(L.gram(x)) for x in fa], [np.asarray(L.gram(x)) for x in fb]
    np.testing.assert_allclose(float(L.style_loss(fa, fb)),
                               sum(np.mean(np.abs(a - b)) for a, b in zip(*gs)), rtol=1e-5)
    out, tgt = rng.random((2, 8, 8, 3)), rng.random((2, 8, 8, 3))
    hole = np.zeros((2, 8, 8, 1))
    hole[:, :4] = 1
    np.testing.assert_allclose(float(L.l1_hole_loss(out, tgt, hole)), np.mean(np.abs(out - tgt)) / 0.5, rtol=1e-5)


def test_masked_hole_loss_is_the_error_inside_the_hole_only():
    from privslam_jax.inpaint.losses import masked_hole_loss

    rng = np.random.default_rng(4)
    out, tgt = rng.random((2, 8, 8, 3)), rng.random((2, 8, 8, 3))
    hole = (rng.random((2, 8, 8, 1)) < 0.3).astype(np.float64)
    inside = np.broadcast_to(hole, out.shape).astype(bool)
    np.testing.assert_allclose(masked_hole_loss(out, tgt, hole), np.mean((out - tgt)[inside] ** 2), rtol=1e-5)
    np.testing.assert_allclose(masked_hole_loss(out, tgt, hole, power=1), np.mean(np.abs(out - tgt)[inside]),
                               rtol=1e-5)
    changed = np.where(inside, out, 5.0)  # pixels outside the hole do not count
    np.testing.assert_allclose(masked_hole_loss(changed, tgt, hole), masked_hole_loss(out, tgt, hole), rtol=1e-6)
