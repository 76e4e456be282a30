"""EdgeConnect training: deterministic, killed-and-resumed equals uninterrupted, files written."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from privslam_jax.inpaint.masks import random_box_mask
from privslam_jax.inpaint.train import TrainConfig, train

CFG = TrainConfig(width=4, num_residual_blocks=1, size=32, batch_size=2,
                  stages=(("edge", 1), ("inpaint", 1), ("joint", 2)), checkpoint_every=2, sample_every=2)


def _data(step: int, batch: int):
    rng = np.random.default_rng((7, step))
    x = np.linspace(0, 1, 32, dtype=np.float32)
    imgs = np.stack([np.clip(x[None, :, None] * rng.random(3) + (x[:, None, None] > rng.random()) * 0.5, 0, 1)
                     for _ in range(batch)]).astype(np.float32)
    return imgs, np.stack([random_box_mask(rng, 32, 32) for _ in range(batch)])


def _leaves(tr):
    return jax.tree.leaves(tr.state_dict())


def test_resume_after_kill_equals_uninterrupted(tmp_path):
    full = train(CFG, _data, tmp_path / "full", progress=False)
    train(CFG, _data, tmp_path / "killed", max_steps=2, progress=False)  # "killed" after step 2
    resumed = train(CFG, _data, tmp_path / "killed", progress=False)
    a, b = _leaves(full), _leaves(resumed)
    assert len(a) == len(b) and len(a) > 20
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # the run changed the weights (Adam moved them) and wrote its artefacts
    fresh = _leaves(train(CFG, _data, tmp_path / "zero", max_steps=0, progress=False))
    assert any(not np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, fresh, strict=True))
    assert sorted(p.name for p in (tmp_path / "full" / "samples").iterdir()) == ["step_0000002.png", "step_0000004.png"]
    log = (tmp_path / "full" / "log.csv").read_text().splitlines()
    killed_log = (tmp_path / "killed" / "log.csv").read_text().splitlines()
    assert [r.split(",")[:2] for r in killed_log] == [r.split(",")[:2] for r in log]  # no duplicate rows
    assert len(log) == 5 and log[4].startswith("4,joint,") and "i_l1=" in log[4] and "e_fm=" in log[4]
    # the trained generators plug into the crop-based filter
    inp = full.inpainter()
    out = inp.inpaint_crop(*[v[0] for v in (_data(9, 1)[0], _data(9, 1)[1])])
    assert out.shape == (32, 32, 3) and np.all(np.isfinite(out))


def test_config_validation():
    with pytest.raises(ValueError, match="bad stage"):
        TrainConfig(stages=(("warmup", 3),))
    with pytest.raises(ValueError, match="multiple of 4"):
        TrainConfig(size=30)
    assert CFG.stage_at(0) == "edge" and CFG.stage_at(1) == "inpaint" and CFG.stage_at(3) == "joint"
    with pytest.raises(ValueError, match="beyond"):
        CFG.stage_at(4)
    with pytest.raises(ValueError, match="hole_loss"):
        TrainConfig(hole_loss="l3")
    with pytest.raises(ValueError, match="prefill"):
        TrainConfig(prefill="blur")


def test_edge_inpaint_stage_trains_only_g2_and_l1_only_skips_d2():
    """Official MODEL 3 (G1 frozen) with λ_adv,2 = 0: only G2's weights move; its lr follows a cosine."""
    from privslam_jax.inpaint.train import InpaintTrainer, prepare_batch

    cfg = TrainConfig(width=4, num_residual_blocks=1, size=32, batch_size=2, stages=(("edge_inpaint", 4),),
                      inpaint_adv_weight=0.0, inpaint_lr=1e-3, inpaint_beta1=0.5, inpaint_lr_final=1e-5)
    tr = InpaintTrainer(cfg)
    before = tr.state_dict()
    logs, outs = tr.step("edge_inpaint", prepare_batch(*_data(0, 2)))
    after = tr.state_dict()
    assert set(logs) == {"i_g", "i_adv", "i_l1"} and logs["i_adv"] == 0.0 and "edges" in outs
    for name in ("edge_g", "edge_d", "inpaint_d"):  # spectral u/v of G1 included: eval mode, no update
        for x, y in zip(jax.tree.leaves(before[name]), jax.tree.leaves(after[name]), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    moved = [not np.array_equal(np.asarray(x), np.asarray(y))
             for x, y in zip(jax.tree.leaves(before["inpaint_g"]), jax.tree.leaves(after["inpaint_g"]), strict=True)]
    assert any(moved)
    assert cfg.g2_steps == 4 and TrainConfig(stages=(("edge", 3), ("inpaint", 2), ("joint", 1))).g2_steps == 3
    # cosine schedule: lr(t) = final + (init - final)·(1 + cos(π t / T)) / 2
    from privslam_jax.inpaint.train import _adam

    tx = _adam(1e-3, 0.5, 0.9, 1e-5, 4)
    state = tx.init({"w": np.zeros(1, np.float32)})
    lrs = []
    for _ in range(5):
        upd, state = tx.update({"w": np.ones(1, np.float32)}, state)
        lrs.append(-float(upd["w"][0]))  # Adam's first normalised step of a constant gradient is ±lr
    t = np.arange(5)
    ref = 1e-5 + (1e-3 - 1e-5) * (1 + np.cos(np.pi * np.minimum(t, 4) / 4)) / 2
    np.testing.assert_allclose(lrs, ref, rtol=1e-3)


def test_blend_loss_is_the_squared_error_of_the_blend_the_filter_makes():
    """``hole_loss="l2_blend"``: the logged G2 term equals, in numpy, the mean squared error inside the
    hole of ``w · out + (1 − w) · fill`` with ``w = 1 − exp(−d / τ)``, ``d`` each pixel's distance to
    the nearest visible pixel found by brute force; ``l2_hole`` logs the same without the blend."""
    from privslam_jax.inpaint.train import InpaintTrainer, prepare_batch

    cfg = TrainConfig(width=4, num_residual_blocks=1, size=32, batch_size=2, stages=(("edge_inpaint", 1),),
                      inpaint_adv_weight=0.0, prefill="telea", residual=True, hole_loss="l2_blend", blend_distance=2.5)
    images, holes = _data(0, 2)
    batch = prepare_batch(images, holes, cfg.sigma, cfg.prefill, cfg.blend_distance)
    share = np.zeros(holes.shape)
    for k, h in enumerate(holes):
        vis = np.argwhere(~h)
        for q in np.argwhere(h):
            share[k, q[0], q[1]] = 1 - np.exp(-np.sqrt(((vis - q) ** 2).sum(axis=1).min()) / 2.5)
    np.testing.assert_allclose(batch["share"][..., 0], share, rtol=1e-5, atol=1e-6)
    logs, outs = InpaintTrainer(cfg).step("edge_inpaint", batch)
    out, fill, y, m = (np.asarray(a, np.float64) for a in (outs["image"], batch["fill"], batch["rgb"], batch["hole"]))
    blend = share[..., None] * out + (1 - share[..., None]) * fill
    np.testing.assert_allclose(logs["i_l1"], ((blend - y) ** 2 * m).sum() / (m.sum() * 3), rtol=1e-5)
    plain, _ = InpaintTrainer(dataclasses.replace(cfg, hole_loss="l2_hole")).step("edge_inpaint", batch)
    np.testing.assert_allclose(plain["i_l1"], ((out - y) ** 2 * m).sum() / (m.sum() * 3), rtol=1e-5)
    assert plain["i_l1"] != logs["i_l1"]
    with pytest.raises(ValueError, match="blend_distance"):
        TrainConfig(hole_loss="l2_blend", blend_distance=0.0)


def test_init_starts_from_the_given_generators(tmp_path):
    from privslam_jax.inpaint.filter import Inpainter, InpainterConfig

    init = Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1, size=32), seed=11)
    tr = train(CFG, _data, tmp_path / "ft", max_steps=0, init=init, progress=False)
    img, hole = (v[0] for v in _data(3, 1))
    np.testing.assert_array_equal(tr.inpainter().inpaint_crop(img, hole), init.inpaint_crop(img, hole))
    cold = train(CFG, _data, tmp_path / "cold", max_steps=0, progress=False)  # seed 0 differs from 11
    assert not np.array_equal(cold.inpainter().inpaint_crop(img, hole), init.inpaint_crop(img, hole))
    with pytest.raises(ValueError, match="width"):
        train(CFG, _data, tmp_path / "bad", max_steps=0, progress=False,
              init=Inpainter.init(InpainterConfig(width=8, num_residual_blocks=1, size=32)))


def test_residual_finetune_starts_exactly_at_the_prefill(tmp_path):
    """A residual G2 started from a non-residual inpainter reproduces its Telea prefill (zeroed last layer)."""
    import dataclasses

    from privslam_jax.inpaint.baselines import fill
    from privslam_jax.inpaint.filter import Inpainter, InpainterConfig

    init = Inpainter.init(InpainterConfig(width=4, num_residual_blocks=1, size=32), seed=11)
    cfg = dataclasses.replace(CFG, prefill="telea", residual=True)
    tr = train(cfg, _data, tmp_path / "res", max_steps=0, init=init, progress=False)
    inp = tr.inpainter()
    assert inp.config.prefill == "telea" and inp.config.residual
    img, hole = (v[0] for v in _data(3, 1))
    zeroed = np.where(hole[..., None], np.float32(0), img)
    np.testing.assert_allclose(inp.inpaint_crop(zeroed, hole), fill(zeroed, hole, "telea"), atol=1e-6)
    inp.save(tmp_path / "r.npz")
    again = Inpainter.load(tmp_path / "r.npz")
    assert again.config == inp.config
    trained = train(cfg, _data, tmp_path / "res2", max_steps=2, init=init, progress=False).inpainter()
    assert not np.allclose(trained.inpaint_crop(zeroed, hole), fill(zeroed, hole, "telea"), atol=1e-4)
