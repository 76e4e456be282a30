"""YOLOv8 architecture: parameter counts as ultralytics reports them, shapes, bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from privslam_jax.detect import YOLOv8, YOLOv8Config, count_parameters, decode_head
from privslam_jax.detect.yolov8 import Conv, abstract_yolov8, fuse_batchnorm, init_yolov8


@pytest.mark.parametrize(
    ("scale", "nc", "expected"),
    [
        # ultralytics model summaries: "YOLOv8n summary: 225 layers, 3,157,200 parameters",
        # "YOLOv8s summary: 225 layers, 11,166,560 parameters" (80 classes, DFL weight included).
        ("n", 80, 3_157_200),
        ("s", 80, 11_166_560),
    ],
)
def test_parameter_count_matches_ultralytics(scale, nc, expected):
    model = abstract_yolov8(YOLOv8Config(num_classes=nc, scale=scale))
    assert count_parameters(model) == expected


def test_class_count_changes_only_the_class_branch():
    # Only the class branch depends on nc: c3 = max(64, min(nc, 100)) = 64 for nc <= 64, so the last
    # 1x1 convs change by (64 + 1)·Δnc per level, and c3 changes from 80 for nc = 80.
    n6 = count_parameters(abstract_yolov8(YOLOv8Config(num_classes=6)))
    n7 = count_parameters(abstract_yolov8(YOLOv8Config(num_classes=7)))
    assert n7 - n6 == 3 * (64 + 1)


def test_output_shapes_and_decode():
    model = init_yolov8(YOLOv8Config(num_classes=3, scale="tiny"), seed=1)
    model.eval()
    x = jnp.asarray(np.random.default_rng(0).random((2, 64, 96, 3), np.float32))
    graphdef, state = nnx.split(model)
    feats = jax.jit(lambda st, x: nnx.merge(graphdef, st)(x))(state, x)
    assert [f.shape for f in feats] == [(2, 8, 12, 67), (2, 4, 6, 67), (2, 2, 3, 67)]
    out = decode_head(feats)
    assert out.shape == (2, 8 * 12 + 4 * 6 + 2 * 3, 7)
    np.testing.assert_allclose(np.asarray(out), decode_numpy([np.asarray(f) for f in feats]), rtol=1e-5, atol=1e-4)


def decode_numpy(feats: list[np.ndarray], strides: tuple[int, ...] = (8, 16, 32), reg_max: int = 16) -> np.ndarray:
    """Plain numpy decoding of ultralytics' ``Detect`` inference, written per cell from its definition:
    anchor ``(x + 0.5, y + 0.5)`` of each cell (levels in order, cells row-major); per side
    ``(l, t, r, b)`` the expectation ``Σ_{k=0}^{15} k·softmax(z)_k`` over its 16 bins (channels
    side-major); box ``x1y1 = a − (l, t)``, ``x2y2 = a + (r, b)`` → ``cx, cy, w, h`` times the
    stride; then the sigmoid of the class logits."""
    rows = []
    for f, s in zip(feats, strides):
        f = f.astype(np.float64)
        for y in range(f.shape[1]):
            for x in range(f.shape[2]):
                z = f[:, y, x, : 4 * reg_max].reshape(-1, 4, reg_max)
                p = np.exp(z - z.max(-1, keepdims=True))
                p /= p.sum(-1, keepdims=True)
                l, t, r, b = np.moveaxis(p @ np.arange(reg_max, dtype=np.float64), -1, 0)
                ax, ay = x + 0.5, y + 0.5
                x1, y1, x2, y2 = ax - l, ay - t, ax + r, ay + b
                box = np.stack([(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1], -1) * s
                cls = 1.0 / (1.0 + np.exp(-f[:, y, x, 4 * reg_max:]))
                rows.append(np.concatenate([box, cls], -1))
    return np.stack(rows, 1)


def test_decode_head_matches_numpy_on_peaked_logits():
    """Random head maps with sharp DFL distributions (so the bin values matter, up to 15 grid cells per
    side), two classes. Reference: :func:`decode_numpy`."""
    rng = np.random.default_rng(4)
    shapes = [(2, 6, 10), (2, 3, 5), (2, 2, 3)]
    feats = [rng.normal(0, 4, s + (16 * 4 + 2,)).astype(np.float32) for s in shapes]
    out = np.asarray(decode_head([jnp.asarray(f) for f in feats]))
    ref = decode_numpy(feats)
    assert out.shape == ref.shape == (2, 60 + 15 + 6, 6)
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-3)


def test_fused_batchnorm_is_the_same_function():
    # Folding eval-mode BatchNorm into the conv (ultralytics fuse_conv_and_bn) must not change the
    # head output; non-trivial running statistics so a wrong fold (e.g. missing ε or μ) shows.
    model = init_yolov8(YOLOv8Config(num_classes=3, scale="tiny"), seed=2)
    rng = np.random.default_rng(3)
    for _, node in nnx.iter_graph(model):
        if isinstance(node, Conv):
            c = node.bn.mean.shape[0]
            node.bn.mean.set_value(jnp.asarray(rng.normal(0, 0.5, c), jnp.float32))
            node.bn.var.set_value(jnp.asarray(rng.uniform(0.05, 3.0, c), jnp.float32))
            node.bn.scale.set_value(jnp.asarray(rng.uniform(0.5, 1.5, c), jnp.float32))
            node.bn.bias.set_value(jnp.asarray(rng.normal(0, 0.3, c), jnp.float32))
    model.eval()
    fused = fuse_batchnorm(model)
    assert all(n.bn is None for _, n in nnx.iter_graph(fused) if isinstance(n, Conv))
    assert all(n.bn is not None for _, n in nnx.iter_graph(model) if isinstance(n, Conv))  # original untouched
    x = jnp.asarray(rng.random((1, 64, 96, 3), np.float32))
    ref = jnp.concatenate([f.reshape(-1) for f in model(x)])
    out = jnp.concatenate([f.reshape(-1) for f in fused(x)])
    np.testing.assert_allclose(np.asarray(out), np.asarray(ref), rtol=1e-4, atol=1e-4 * float(jnp.abs(ref).max()))


def test_init_matches_module_constructor_distributions():
    # host-side init vs the NNX constructor: same shapes, same bias constants, kernel bounds 1/sqrt(fan_in)
    cfg = YOLOv8Config(num_classes=2, scale="tiny")
    host = init_yolov8(cfg, seed=0)
    ref = abstract_yolov8(cfg)
    assert jax.tree.map(lambda a: a.shape, nnx.state(host)) == jax.tree.map(lambda a: a.shape, nnx.state(ref))
    k = np.asarray(host.neck3.cv2.conv.kernel[...])
    bound = 1 / np.sqrt(np.prod(k.shape[:3]))
    assert np.abs(k).max() <= bound and np.abs(k).max() > 0.9 * bound
    np.testing.assert_allclose(np.asarray(host.detect.cv3[2][2].bias[...]), np.log(5 / 2 / 20**2), rtol=1e-6)


def test_bad_input_and_config():
    model = abstract_yolov8(YOLOv8Config(num_classes=1, scale="tiny"))
    with pytest.raises(ValueError, match="multiples of 32"):
        model(jnp.zeros((1, 50, 64, 3)))
    with pytest.raises(ValueError, match="scale"):
        YOLOv8Config(scale="q")
    with pytest.raises(ValueError, match="num_classes"):
        YOLOv8Config(num_classes=0)
