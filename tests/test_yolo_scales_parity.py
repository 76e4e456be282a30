"""Every YOLOv8 and YOLO11 scale against ultralytics itself (torch), through the torch-free importer.

For each of ``yolov8{n,s,m,l,x}`` and ``yolo11{n,s,m,l,x}``: ultralytics builds the network from
its yaml (random init), gets random BatchNorm affine parameters and running statistics measured on
other random images (so every BatchNorm really shifts and scales) and random class biases (so the class
probabilities spread over (0, 1) instead of sitting near 0), and saves it with ``YOLO.save`` (the
fp16 ``{"model": ...}`` zip ultralytics writes; the torch model is rounded to fp16 first so both
sides hold the same numbers). We load the file with :func:`privslam_jax.detect.load_detector` (no
torch) into a :class:`~privslam_jax.detect.predict.Detector` and compare the decoded raw head on a
fixed input with torch's ``(B, 4 + nc, A)`` output: boxes within 0.05 px, probabilities within 1e-3.
It also checks the importer picked the family and scale and that our parameter count is the one
ultralytics reports.

Skips unless torch and ultralytics import. The test environment (outside the repository; ultralytics
builds and saves models without importing torchvision, but needs its package metadata)::

    python3 -m venv /work/tvenv
    /work/tvenv/bin/pip install torch==2.13.0            # CPU wheel
    /work/tvenv/bin/pip install --no-deps ultralytics==8.4.190 torchvision==0.28.0 ultralytics-thop
    /work/tvenv/bin/pip install numpy pyyaml requests psutil pillow matplotlib opencv-python-headless
    /work/tvenv/bin/pip install -e "/work/main[test]"
    /work/tvenv/bin/python -m pytest tests/test_yolo_scales_parity.py -s   # -s prints the measured diffs

(``torchvision`` 0.28.0 from PyPI does not import beside the CPU torch; it is installed only for
ultralytics' version lookup.)
"""

from __future__ import annotations

import os
import tempfile
import zlib

import numpy as np
import pytest

os.environ.setdefault("YOLO_CONFIG_DIR", tempfile.mkdtemp(prefix="ultralytics-cfg-"))  # not ~/.config
os.environ.setdefault("YOLO_OFFLINE", "1")
torch = pytest.importorskip("torch", reason="parity with ultralytics needs torch (see the module docstring)")
ultralytics = pytest.importorskip("ultralytics", reason="parity needs ultralytics (see the module docstring)")

from privslam_jax.detect import count_parameters, load_detector  # noqa: E402
from privslam_jax.detect.predict import Detector, DetectorConfig  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::UserWarning",
                                        "ignore::FutureWarning")

MODELS = [(arch, scale) for arch in ("yolov8", "yolo11") for scale in "nsmlx"]


def _randomise(model: torch.nn.Module, seed: int) -> None:
    """Random BatchNorm γ/β and class biases; running statistics measured on random images; fp16-exact."""
    g = torch.Generator().manual_seed(seed)
    bns = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    with torch.no_grad():
        for bn in bns:
            c = bn.num_features
            bn.weight.copy_(0.5 + torch.rand(c, generator=g))
            bn.bias.copy_(0.2 * torch.randn(c, generator=g))
            bn.reset_running_stats()
            bn.momentum = None  # cumulative average over the calibration batches
        model.train()
        for _ in range(2):
            model(torch.rand(4, 3, 192, 320, generator=g))
        for bn in bns:  # (scaling the variances instead blows activations up to ~1e3 in 20 layers)
            bn.momentum = 0.03
        head = model.model[-1]
        for branch in head.cv3:
            branch[-1].bias.copy_(torch.randn(head.nc, generator=g))
        for tensor in model.state_dict().values():
            if tensor.is_floating_point():
                tensor.copy_(tensor.half().float())
    model.eval()


@pytest.mark.parametrize(("arch", "scale"), MODELS, ids=[f"{a}{s}" for a, s in MODELS])
def test_raw_head_matches_ultralytics(arch, scale, tmp_path):
    from ultralytics import YOLO

    torch.manual_seed(0)
    yolo = YOLO(f"{arch}{scale}.yaml", task="detect")
    model = yolo.model
    _randomise(model, seed=zlib.crc32(f"{arch}{scale}".encode()))
    path = tmp_path / f"{arch}{scale}.pt"
    yolo.save(path)
    n_torch = sum(p.numel() for p in model.parameters())

    ours, names = load_detector(path)  # torch-free
    assert ours.config.arch == arch and ours.config.scale == scale
    assert count_parameters(ours) == n_torch
    assert names == {int(k): v for k, v in model.names.items()}

    x = np.random.default_rng(7).random((1, 192, 320, 3), dtype=np.float32)
    with torch.no_grad():
        expected = model(torch.from_numpy(x.transpose(0, 3, 1, 2).copy()))[0][0].numpy()  # (4 + nc, A)
    out = Detector(ours, DetectorConfig()).forward(x)[0].T  # BatchNorm folded, as ultralytics predicts
    assert out.shape == expected.shape
    box = float(np.abs(out[:4] - expected[:4]).max())
    prob = float(np.abs(out[4:] - expected[4:]).max())
    spread = float(expected[4:].std())
    print(f"\n{arch}{scale}: {n_torch:,} params, max |box| diff {box:.2e} px, max |prob| diff {prob:.2e}, "
          f"prob std {spread:.3f}")
    assert spread > 0.05  # the probabilities are not all saturated: the comparison can fail
    assert box <= 0.05, f"{arch}{scale}: boxes differ by {box} px"
    assert prob <= 1e-3, f"{arch}{scale}: class probabilities differ by {prob}"
