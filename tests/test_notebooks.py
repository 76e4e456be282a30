"""Execute every notebook (jupytext ``.py`` percent sources) on tiny settings and check what it shows.

Each ``notebooks/NN_*.py`` is run once per module by ``notebooks/render.py``'s ``execute`` (jupytext,
then nbclient in a ``python3`` kernel) with ``PRIVSLAM_NB_TINY=1``.  A first injected cell turns
warnings raised by privslam_jax code into errors inside the kernel; jupyter's own
DeprecationWarnings in this process are tolerated by a local filter.  Beyond "no cell raised",
every notebook has an entry in :data:`EXPECTED`: the lines it must print (regular expressions, with
the values the tiny settings imply) and the figures it must show; and its rendered copy
(``render.py``'s ``export``) holds them.
"""

import importlib.util
import os
import re
import warnings
from pathlib import Path

import pytest

from privslam_jax._shared import shared_dir

pytestmark = pytest.mark.xla_optimized  # the notebooks train and run SLAM (tests/conftest.py)

_spec = importlib.util.spec_from_file_location("render", Path(__file__).resolve().parents[1] / "notebooks" / "render.py")
RENDER = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(RENDER)
NOTEBOOKS = RENDER.NOTEBOOKS
STRICT_CELL = 'import warnings\nwarnings.filterwarnings("error", module=r"privslam_jax(\\..*)?$")'
PARETO_JSON = Path(__file__).resolve().parents[1] / "results" / "pareto_tradeoff.json"
HAS_KITTI = shared_dir() is not None and (shared_dir() / "data/kitti_odometry/sequences/seq1").is_dir()
HAS_KITTI_RAW = shared_dir() is not None and (shared_dir() / "data/real/kitti_raw_a/frames/0000000220.png").is_file()

EXPECTED = {
    # SynthConfig(width=160, height=48, num_frames=3, stereo=True): fx = 0.58 · 160 = 92.8 px; the
    # KITTI round trip stores 8-bit PNGs (error ≤ 1/510); seq1 of ../shared has 51 frames of 1226×370.
    "01_synthetic_world": {
        "stdout": [
            r"^tiny run SynthConfig\(width=160, height=48, num_frames=3, seed=0, stereo=True",
            r"^3 frames of 160x48, fx = 92\.8 px$",
            r"^KittiSequence\('.*/sequences/synth', frames=3, size=160x48, stereo=True, poses=yes\)$",
            r"^max \|image difference\| after the 8-bit PNG round trip: (\d\.\d{4}) \(≤ 1/510 expected\)$",
            r"^read back: 3 frames, 160x48 px, stereo baseline 0\.540 m$",
            r"^classes present: \[.*'(?:car|person)'.*\]$",
            r"^KittiSequence\('.*/sequences/seq1', frames=51, size=1226x370, stereo=False, poses=yes\)$"
            if HAS_KITTI else r"^\.\./shared is absent: skipping the real KITTI sequence$",
        ],
        # frames + boxes grid, stereo pair, camera path (+ the real KITTI frame and path)
        "figures": 4 if HAS_KITTI else 3,
    },
    # TrainConfig(width=4, num_residual_blocks=1, size=32, batch_size=4) trained edge:20 + edge_inpaint:40
    # on the crops of 3 frames of world 0 (640x192); the embedded checkpoints and Telea on frame 1 of
    # world 902 (PSNR inside the dilated instance masks against the object-free render); then
    # kitti_raw_a frame 220 (colour, 1242x375; KITTI seq1 frame 0 when only that is present) with the
    # embedded real-frame detector's boxes.
    "02_train_inpainter_cpu": {
        "stdout": [
            r"^tiny run: 32x32 crops, width 4, 1 residual block\(s\), batch 4, stages edge:20, edge_inpaint:40$",
            r"^\d+ object crops of 32x32 from 3 frames of world 0 \(640x192\)$",
            r"^hole share of the first batch: \d+\.\d% of the crop pixels$",
            r"^trained 60 steps in \d+ s: G1 e_g \d+\.\d{3} -> \d+\.\d{3}, G2 i_l1 \d\.\d{3} -> \d\.\d{3}$",
            r"^[1-4] held-out crops, mean \|error\| inside the hole: before 0\.\d{3}, after 0\.\d{3}$",
            r"^world 902, frame 1: \d+ objects, \d+\.\d% of the pixels hidden$",
            r"^method +PSNR in the hole \(dB\)$",
            r"^telea +\d+\.\d\d$",
            r"^edgeconnect \(just trained\) +\d+\.\d\d$",
            r"^edgeconnect \(synthetic\) +\d+\.\d\d$",
            r"^edgeconnect \(real\) +\d+\.\d\d$",
            r"^real frame (?:kitti_raw_a/frames/0000000220\.png: 1242x375|seq1/image_0/000000\.png: 1226x370), "
            r"(?:\d+ detections \(.+\)|no detection: a fixed box on the road)$"
            if HAS_KITTI_RAW or HAS_KITTI else r"^\.\./shared is absent: skipping the real KITTI frame$",
        ],
        # the crop batch, the loss curves, crops before/after, the synthetic frame's fills
        # (+ the real frame: original / mask / Telea / EdgeConnect-real)
        "figures": 5 if HAS_KITTI_RAW or HAS_KITTI else 4,
    },
    # TradeoffConfig at 320x96 with steps=2 of a width-4 net, 8-frame worlds, a one-level alignment and the detector at
    # 96x320; the privacy loss of a frame whose objects are all hidden sits at its floor tau*log(A*C) = 0.01*log(630*6)
    # = 0.0824 (docs/tradeoff.md; 0.0962 at the default 192x640 input).
    "03_privacy_accuracy_tradeoff": {
        "stdout": [
            r"^tiny run: 320x96 frames, 2 steps$",
            r"^pair \(5, 6\): \d+ objects in the target",
            r"^edgeconnect +0\.08\d\d +0\.\d{4} +\d+\.\d{4}$",
            r"^trained 2 steps: loss \d\.\d{4} -> \d\.\d{4} \(accuracy term dropped in [0-2]\)$",
            r"^front of \d+ filters from pareto_tradeoff\.json$" if PARETO_JSON.is_file()
            else r"^pareto_tradeoff\.json not found: run experiments/pareto_tradeoff\.py first$",
        ],
        # the filters on one frame, the loss curve (+ the front when the results file exists)
        "figures": 3 if PARETO_JSON.is_file() else 2,
    },
    # 400 points back-projected from 2 frames of 160x48 (depth < 40 m), random_lift with fixed_key(0):
    # Line2Point's k = int(0.05 * 400) = 20; the gradient attack (rtol = atol = 1e-4) converges, and
    # both attacks recover the median point to within 5 m (the no-attack baseline: ~8 m).
    "04_attacks_with_gradient_solvers": {
        "stdout": [
            r"^tiny run: 400 points from 2 frames of 160x48$",
            r"^\d+ valid depth pixels \(< 40 m\); map of 400 points, median distance to the first camera \d+\.\d m$",
            r"^random lift: 400 lines, ",
            r"^Line2Point: k = 20 coarse neighbours per line, 2 refinement rounds; gradient attack: 16 neighbours",
            (r"^used +GradientAttackResult\(points=\(400, 3\), offsets=\(400,\), result=successful, "
             r"num_steps=\d+\) successful=True$"),
            (r"^max_steps=20 GradientAttackResult\(points=\(400, 3\), offsets=\(400,\), "
             r"result=nonlinear_max_steps_reached, num_steps=20\) successful=False$"),
            r"^message of the cut-off solve: 'The maximum number of steps was reached",
            r"^with throw=True: RuntimeError\('gradient attack: the solve did not succeed after 20 ",
            r"^method +median \(m\) +within 0\.5 m \(%\)$",
            r"^no attack +\d+\.\d{3} +\d+\.\d$",
            r"^Line2Point +[0-4]\.\d{3} +\d+\.\d$",
            r"^gradient +[0-4]\.\d{3} +\d+\.\d$",
            r"^Line2Point \(paired\) +\d+\.\d{3} +\d+\.\d$",
            r"^gradient \(paired\) +\d+\.\d{3} +\d+\.\d$",
            (r"^d\(mean squared error\)/d\(moments\): shape \(400, 3\), finite True, solve successful True; "
             r"10% of the lines carry \d+% of the gradient norm$"),
        ],
        # the sampled pixels, the error histograms, the 3D view of original vs recovered points
        "figures": 3,
    },
}


@pytest.fixture(scope="module", params=NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def executed(request):
    """``(path, executed notebook)``, run once per notebook by ``notebooks/render.py``'s ``execute``
    (tiny settings, ``../shared`` visible when present); a cell that raises or writes to stderr fails it."""
    for module in ("jupytext", "nbclient", "nbformat"):
        pytest.importorskip(module)
    path = request.param
    before = os.environ.get("PRIVSLAM_NB_TINY")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        nb = RENDER.execute(path, tiny=True, shared=True, prelude=STRICT_CELL, timeout=900)
    assert os.environ.get("PRIVSLAM_NB_TINY") == before  # the kernel's settings did not leak into this process
    return path, nb


def _outputs(nb):
    return [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]


def _stream(nb, name: str) -> str:
    return "".join(o["text"] for o in _outputs(nb) if o.get("output_type") == "stream" and o.get("name") == name)


def test_notebook_executes_without_errors_or_stderr(executed):
    path, nb = executed
    outputs = _outputs(nb)
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert _stream(nb, "stderr") == "", f"{path.name} wrote to stderr"
    assert path.stem in EXPECTED, f"add the expected outputs of {path.name} to EXPECTED in {__file__}"


def test_notebook_prints_what_its_settings_imply(executed):
    path, nb = executed
    lines = _stream(nb, "stdout").splitlines()
    for pattern in EXPECTED[path.stem]["stdout"]:
        hits = [m for m in (re.search(pattern, line) for line in lines) if m]
        assert hits, f"{path.name}: no output line matches {pattern!r}; stdout was:\n" + "\n".join(lines)
        if "round trip" in pattern:  # the error it printed (4 decimals) is within the bound it states
            assert float(hits[0].group(1)) <= round(1 / 510, 4)


def test_notebook_shows_its_figures(executed):
    path, nb = executed
    figures = [o for o in _outputs(nb) if o.get("output_type") == "display_data" and "image/png" in o.get("data", {})]
    assert len(figures) == EXPECTED[path.stem]["figures"], f"{path.name} showed {len(figures)} figures"


def test_rendered_copy_holds_the_code_outputs_and_figures(executed, tmp_path):
    """``notebooks/render.py``'s export: markdown with every code cell, every printed line and a link
    to every figure, each figure a PNG file beside it; a second export replaces the first."""
    pytest.importorskip("nbconvert")
    path, nb = executed
    (tmp_path / f"{path.stem}_files").mkdir()
    (tmp_path / f"{path.stem}_files" / "stale.png").write_bytes(b"old")
    md = RENDER.export(nb, path.stem, tmp_path)
    text = md.read_text()
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.source.strip().splitlines()[0] in text
    for line in _stream(nb, "stdout").splitlines():
        assert line.strip() in text
    figures = sorted((tmp_path / f"{path.stem}_files").iterdir())
    assert len(figures) == EXPECTED[path.stem]["figures"]
    for f in figures:
        assert f.suffix == ".png" and f.read_bytes().startswith(b"\x89PNG") and f"({path.stem}_files/{f.name})" in text
