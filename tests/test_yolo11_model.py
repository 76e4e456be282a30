"""YOLO11 (and every YOLOv8 scale): parameter counts as ultralytics reports them, the importer's
architecture/scale detection, attention against a numpy transcription of torch's layout, BatchNorm
folding, checkpoints, bad input. Parity with ultralytics itself: tests/test_yolo_scales_parity.py."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from privslam_jax.detect import (
    YOLO11,
    YOLO11Config,
    YOLOv8Config,
    count_parameters,
    decode_head,
    detect_architecture,
    load_detector,
    model_state_dict,
    save_checkpoint,
)
from privslam_jax.detect.predict import Detector, DetectorConfig
from privslam_jax.detect.weights import load_state_dict
from privslam_jax.detect.yolo11 import Attention, abstract_yolo11, init_yolo11
from privslam_jax.detect.yolov8 import Conv, abstract_yolov8, fuse_batchnorm, init_yolov8

# ultralytics 8.4 model summaries (80 classes, unfused, DFL weight included), also printed by the
# yaml headers (cfg/models/{v8/yolov8,11/yolo11}.yaml) and checked against
# sum(p.numel() for p in YOLO("<name>.yaml").model.parameters()) in the test environment.
ULTRALYTICS_PARAMS = {
    ("yolov8", "n"): 3_157_200, ("yolov8", "s"): 11_166_560, ("yolov8", "m"): 25_902_640,
    ("yolov8", "l"): 43_691_520, ("yolov8", "x"): 68_229_648,
    ("yolo11", "n"): 2_624_080, ("yolo11", "s"): 9_458_752, ("yolo11", "m"): 20_114_688,
    ("yolo11", "l"): 25_372_160, ("yolo11", "x"): 56_966_176,
}


def _abstract(arch: str, scale: str, nc: int = 80):
    if arch == "yolo11":
        return abstract_yolo11(YOLO11Config(num_classes=nc, scale=scale))
    return abstract_yolov8(YOLOv8Config(num_classes=nc, scale=scale))


def _shape_only_state_dict(model) -> dict[str, np.ndarray]:
    """The ultralytics-layout state_dict of an abstract model, as zero-stride views (no memory)."""
    for _, var in nnx.iter_graph(model):
        if isinstance(var, (nnx.Param, nnx.BatchStat)):
            var.set_value(np.broadcast_to(np.float32(0), var.get_value().shape))
    return model_state_dict(model)


@pytest.mark.parametrize(("arch", "scale"), list(ULTRALYTICS_PARAMS), ids=[a + s for a, s in ULTRALYTICS_PARAMS])
def test_parameter_count_and_scale_detection(arch, scale):
    model = _abstract(arch, scale)  # shapes only: no x-size forward or init in the default suite
    assert count_parameters(model) == ULTRALYTICS_PARAMS[(arch, scale)]
    cfg = detect_architecture(_shape_only_state_dict(model))
    assert (cfg.arch, cfg.scale, cfg.num_classes, cfg.reg_max) == (arch, scale, 80, 16)


def _randomise_bn(model, seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _, node in nnx.iter_graph(model):
        if isinstance(node, Conv):
            c = node.bn.mean.shape[0]
            node.bn.mean.set_value(jnp.asarray(rng.normal(0, 0.5, c), jnp.float32))
            node.bn.var.set_value(jnp.asarray(rng.uniform(0.05, 3.0, c), jnp.float32))
            node.bn.scale.set_value(jnp.asarray(rng.uniform(0.5, 1.5, c), jnp.float32))
            node.bn.bias.set_value(jnp.asarray(rng.normal(0, 0.3, c), jnp.float32))


_forward = nnx.jit(lambda model, x: model(x))
"""A model's forward, one compiled program per model structure (eager NNX dispatches op by op)."""


@pytest.fixture(scope="module")
def tiny():
    model = init_yolo11(YOLO11Config(num_classes=3, scale="tiny"), seed=1)
    _randomise_bn(model, 2)
    model.eval()
    return model


def test_output_shapes_and_decode(tiny):
    x = jnp.asarray(np.random.default_rng(0).random((2, 64, 96, 3), np.float32))
    graphdef, state = nnx.split(tiny)
    feats = jax.jit(lambda st, x: nnx.merge(graphdef, st)(x))(state, x)
    assert [f.shape for f in feats] == [(2, 8, 12, 67), (2, 4, 6, 67), (2, 2, 3, 67)]
    out = np.asarray(decode_head(feats))
    assert out.shape == (2, 8 * 12 + 4 * 6 + 2 * 3, 7) and np.all(out[..., 2:4] > 0)
    assert np.all((out[..., 4:] > 0) & (out[..., 4:] < 1))


def test_attention_matches_torch_layout_in_numpy():
    # ultralytics Attention.forward transcribed in numpy on NCHW: qkv viewed (B, heads, 2·kd + hd, N),
    # softmax((q·s)ᵀ k) over keys, v @ attnᵀ, + pe(v), proj. Two heads so the head layout matters.
    att = nnx.eval_shape(lambda: Attention(16, 2, rngs=nnx.Rngs(0)))
    rng = np.random.default_rng(0)
    for _, node in nnx.iter_graph(att):
        if isinstance(node, Conv):
            k = node.conv.kernel.get_value().shape
            node.conv.kernel.set_value(jnp.asarray(rng.normal(0, 0.3, k), jnp.float32))
            c = k[-1]
            for name, v in (("scale", rng.uniform(0.5, 1.5, c)), ("bias", rng.normal(0, 0.2, c)),
                            ("mean", rng.normal(0, 0.2, c)), ("var", rng.uniform(0.5, 2, c))):
                getattr(node.bn, name).set_value(jnp.asarray(v, jnp.float32))
    att.eval()
    x = rng.normal(size=(1, 4, 5, 16)).astype(np.float32)

    def conv_bn(node: Conv, z):  # z NCHW; eval BatchNorm; no activation
        y = jax.lax.conv_general_dilated(jnp.asarray(z), node.conv.kernel[...], (1, 1), "SAME",
                                         dimension_numbers=("NCHW", "HWIO", "NCHW"),
                                         feature_group_count=node.conv.feature_group_count)
        y = np.asarray(y, np.float64)
        s = np.asarray(node.bn.scale[...]) / np.sqrt(np.asarray(node.bn.var[...]) + 1e-3)
        return (y - np.asarray(node.bn.mean[...])[:, None, None]) * s[:, None, None] + np.asarray(node.bn.bias[...])[:, None, None]

    xc = x.transpose(0, 3, 1, 2)
    b, c, h, w = xc.shape
    nh, kd, hd = 2, att.key_dim, att.head_dim
    qkv = conv_bn(att.qkv, xc).reshape(b, nh, 2 * kd + hd, h * w)
    q, k, v = qkv[:, :, :kd], qkv[:, :, kd : 2 * kd], qkv[:, :, 2 * kd :]
    logits = np.swapaxes(q * kd**-0.5, -2, -1) @ k
    a = np.exp(logits - logits.max(-1, keepdims=True))
    a /= a.sum(-1, keepdims=True)
    o = (v @ np.swapaxes(a, -2, -1)).reshape(b, c, h, w) + conv_bn(att.pe, v.reshape(b, c, h, w).astype(np.float32))
    ref = conv_bn(att.proj, o.astype(np.float32)).transpose(0, 2, 3, 1)
    np.testing.assert_allclose(np.asarray(att(jnp.asarray(x))), ref, rtol=1e-4, atol=1e-4)


def test_fused_batchnorm_is_the_same_function(tiny):
    # covers the depthwise convs (groups) of the head and attention and the activation-free convs
    fused = fuse_batchnorm(tiny)
    convs = [n for _, n in nnx.iter_graph(fused) if isinstance(n, Conv)]
    assert all(n.bn is None for n in convs) and any(n.conv.feature_group_count > 1 for n in convs)
    assert any(not n.act for n in convs)
    x = jnp.asarray(np.random.default_rng(3).random((1, 64, 96, 3), np.float32))
    ref = jnp.concatenate([f.reshape(-1) for f in _forward(tiny, x)])
    out = jnp.concatenate([f.reshape(-1) for f in _forward(fused, x)])
    np.testing.assert_allclose(np.asarray(out), np.asarray(ref), rtol=1e-4, atol=1e-4 * float(jnp.abs(ref).max()))


def test_checkpoint_round_trip_records_arch(tiny, tmp_path):
    path = tmp_path / "y11.npz"
    save_checkpoint(tiny, path, {0: "a", 1: "b", 2: "c"})
    with np.load(path) as data:
        assert json.loads(str(data["__meta__"]))["arch"] == "yolo11"
    back, names = load_detector(path)
    assert isinstance(back, YOLO11) and back.config == tiny.config and names == {0: "a", 1: "b", 2: "c"}
    x = jnp.asarray(np.random.default_rng(4).random((1, 64, 64, 3), np.float32))
    for a, b in zip(_forward(back, x), _forward(tiny, x)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # the Detector (predict.py) runs a YOLO11 unchanged
    det = Detector(back, DetectorConfig(imgsz=64, conf=0.0))
    (found,) = det.detect([np.zeros((40, 64, 3), np.uint8)])
    assert len(found.boxes) > 0


def test_old_checkpoint_without_arch_and_wrong_arch(tmp_path):
    v8 = init_yolov8(YOLOv8Config(num_classes=2, scale="tiny"), seed=0)
    meta = {"num_classes": 2, "scale": "tiny", "reg_max": 16, "names": {}}  # written before "arch" existed
    np.savez(tmp_path / "old.npz", __meta__=np.array(json.dumps(meta)), **model_state_dict(v8))
    model, _ = load_detector(tmp_path / "old.npz")
    assert model.config.arch == "yolov8" and not isinstance(model, YOLO11)
    np.savez(tmp_path / "bad.npz", __meta__=np.array(json.dumps({**meta, "arch": "yolo11"})), **model_state_dict(v8))
    with pytest.raises(ValueError, match="says arch 'yolo11' but its weights are a yolov8"):
        load_detector(tmp_path / "bad.npz")


def test_unknown_layouts_are_refused(tiny):
    sd = model_state_dict(tiny)
    with pytest.raises(ValueError, match="segmentation head"):
        detect_architecture({**sd, "model.23.proto.cv1.conv.weight": np.zeros((8, 8, 3, 3))})
    with pytest.raises(ValueError, match="pose / OBB"):
        detect_architecture({**sd, "model.23.cv4.0.0.conv.weight": np.zeros((8, 8, 3, 3))})
    with pytest.raises(ValueError, match="end-to-end"):
        detect_architecture({**sd, "model.23.one2one_cv2.0.0.conv.weight": np.zeros((8, 8, 3, 3))})
    with pytest.raises(ValueError, match="classification"):
        detect_architecture({"model.0.conv.weight": np.zeros((8, 3, 3, 3)), "model.9.linear.weight": np.zeros((3, 8))})
    with pytest.raises(ValueError, match="neither a YOLOv8"):
        detect_architecture({k: v for k, v in sd.items() if not k.startswith("model.10.")})
    with pytest.raises(ValueError, match=r"missing 'model\.23\.cv3\.0\.2\.weight'"):
        detect_architecture({k: v for k, v in sd.items() if k != "model.23.cv3.0.2.weight"})
    with pytest.raises(ValueError, match="no ultralytics"):
        detect_architecture({"weight": np.zeros(3)})
    wide = {**sd, "model.0.conv.weight": np.zeros((24, 3, 3, 3), np.float32)}
    with pytest.raises(ValueError, match="no yolo11 scale has stem width 24"):
        detect_architecture(wide)
    # a missing variable deep inside the attention block
    model = abstract_yolo11(YOLO11Config(num_classes=3, scale="tiny"))
    with pytest.raises(ValueError, match="lacks 1 model variables"):
        load_state_dict(model, {k: v for k, v in sd.items() if k != "model.10.m.0.attn.pe.bn.running_var"})
    with pytest.raises(ValueError, match="does not exist in the model"):
        load_state_dict(model, {**sd, "model.10.m.5.attn.qkv.conv.weight": np.zeros((1, 1, 1, 1))})


def test_bad_config():
    with pytest.raises(ValueError, match="unknown yolo11 scale"):
        YOLO11Config(scale="q")
    with pytest.raises(TypeError, match="YOLO11Config"):
        YOLO11(YOLOv8Config(), rngs=nnx.Rngs(0))
    with pytest.raises(ValueError, match="multiples of 32"):
        abstract_yolo11(YOLO11Config(num_classes=1, scale="tiny"))(jnp.zeros((1, 50, 64, 3)))
