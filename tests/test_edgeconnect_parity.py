"""EdgeConnect networks against the official torch code (``../shared/reference``).

The reference npz holds the official networks (one residual block) run in torch eval mode on a
fixed 64×64 input: outputs, discriminator features and the spectral-norm σ of every layer.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from privslam_jax.inpaint import (
    Discriminator,
    EdgeGenerator,
    InpaintGenerator,
    count_params,
    load_npz,
    load_state_dict,
)

pytestmark = pytest.mark.shared

REF = "reference/edgeconnect_reference.npz"


def _nhwc(x: np.ndarray) -> jnp.ndarray:
    return jnp.asarray(np.transpose(x, (0, 2, 3, 1)))


def _nchw(x) -> np.ndarray:
    return np.transpose(np.asarray(x), (0, 3, 1, 2))


def _build(name: str):
    rngs = nnx.Rngs(0)
    if name == "edge_generator":
        return EdgeGenerator(num_residual_blocks=1, rngs=rngs)
    if name == "inpaint_generator":
        return InpaintGenerator(num_residual_blocks=1, rngs=rngs)
    if name == "edge_discriminator":
        return Discriminator(2, use_sigmoid=True, rngs=rngs)
    return Discriminator(3, use_sigmoid=False, rngs=rngs)


@pytest.mark.parametrize("name", ["edge_generator", "inpaint_generator"])
def test_generator_matches_official(shared, name):
    ref = np.load(shared / REF)
    net = _build(name)
    load_npz(net, shared / REF, prefix=f"{name}/")
    net.eval()
    out = _nchw(net(_nhwc(ref[f"{name}/input"])))
    np.testing.assert_allclose(out, ref[f"{name}/output"], atol=2e-4, rtol=0)
    # the untrained random module must not match: the test can fail
    fresh = _build(name)
    fresh.eval()
    assert np.abs(_nchw(fresh(_nhwc(ref[f"{name}/input"]))) - ref[f"{name}/output"]).max() > 1e-2


@pytest.mark.parametrize("name", ["edge_discriminator", "inpaint_discriminator"])
def test_discriminator_matches_official(shared, name):
    ref = np.load(shared / REF)
    net = _build(name)
    load_npz(net, shared / REF, prefix=f"{name}/")
    net.eval()
    out, feats = net(_nhwc(ref[f"{name}/input"]))
    np.testing.assert_allclose(_nchw(out), ref[f"{name}/output"], atol=1e-4, rtol=1e-4)
    for i, f in enumerate(feats, start=1):
        want = ref[f"{name}/features{i}"]
        np.testing.assert_allclose(_nchw(f), want, atol=1e-4 * max(1.0, np.abs(want).max()), rtol=0)


def test_spectral_sigma_matches_official(shared):
    ref = np.load(shared / REF)
    gen = _build("edge_generator")
    load_npz(gen, shared / REF, prefix="edge_generator/")
    layers = {"encoder.1": gen.enc1, "encoder.7": gen.enc3, "middle.0.conv_block.5": gen.middle[0].conv2,
              "decoder.0": gen.dec1, "decoder.3": gen.dec2}
    for key, conv in layers.items():
        np.testing.assert_allclose(float(conv.sigma()), ref[f"edge_generator/{key}.sigma"], rtol=1e-5)


def test_train_mode_does_one_torch_power_iteration(shared):
    ref = np.load(shared / REF)
    disc = _build("edge_discriminator")
    load_npz(disc, shared / REF, prefix="edge_discriminator/")
    conv = disc.convs[2]
    w = ref["edge_discriminator/conv3.0.weight_orig"].astype(np.float64).reshape(256, -1)
    u0 = ref["edge_discriminator/conv3.0.weight_u"].astype(np.float64)
    v = w.T @ u0
    v /= np.linalg.norm(v)
    u = w @ v
    u /= np.linalg.norm(u)
    disc(_nhwc(ref["edge_discriminator/input"]))  # train mode: one power iteration per call
    np.testing.assert_allclose(np.asarray(conv.v[...]), v, atol=1e-5)
    np.testing.assert_allclose(np.asarray(conv.u[...]), u, atol=1e-5)
    np.testing.assert_allclose(float(conv.sigma()), u @ w @ v, rtol=1e-5)


def test_full_size_param_counts(shared):
    counts = json.loads((shared / "reference/edgeconnect_param_counts.json").read_text())
    want = {k.split("(")[0] + ("[edge]" if "[edge]" in k else "[inpaint]" if "[inpaint]" in k else ""): v
            for k, v in counts.items()}
    rngs = nnx.Rngs(0)
    assert count_params(EdgeGenerator(rngs=rngs)) == want["EdgeGenerator"]
    assert count_params(InpaintGenerator(rngs=rngs)) == want["InpaintGenerator"]
    assert count_params(Discriminator(2, use_sigmoid=True, rngs=rngs)) == want["Discriminator[edge]"]
    assert count_params(Discriminator(3, use_sigmoid=False, rngs=rngs)) == want["Discriminator[inpaint]"]


def test_loader_rejects_bad_state(shared):
    ref = np.load(shared / REF)
    state = {k[len("inpaint_generator/"):]: ref[k] for k in ref.files
             if k.startswith("inpaint_generator/") and "." in k}
    net = _build("inpaint_generator")
    bad = dict(state)
    bad["encoder.1.weight"] = bad["encoder.1.weight"][:, :3]
    with pytest.raises(ValueError, match="encoder.1.weight: shape"):
        load_state_dict(net, bad)
    missing = dict(state)
    del missing["decoder.7.bias"]
    with pytest.raises(ValueError, match="lacks 1 parameters"):
        load_state_dict(net, missing)
    with pytest.raises(ValueError, match="residual block"):
        load_state_dict(InpaintGenerator(num_residual_blocks=0, rngs=nnx.Rngs(0)), state)
    with pytest.raises(FileNotFoundError):
        load_npz(net, shared / "reference/nope.npz")
