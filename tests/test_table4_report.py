"""Table 4's privacy section: the paired ATE change against a direct numpy computation."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load():
    spec = importlib.util.spec_from_file_location("table4_ate", ROOT / "experiments/table4_ate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def _run(row, base, filt, mode, seed, se3, sim3):
    return {"row": row, "base": base, "filter": filt, "mode": mode, "seed": seed, "sequence": f"/x/world{seed}/sequences/synth",
            "frames": 10, "tracked": 10, "ate_se3": se3, "ate_sim3": sim3, "rpe_trans": 0.0, "rpe_rot": 0.0,
            "path": 100.0, "keyframes": 3, "events": 1, "track_ms": 1.0}


def test_privacy_section_pairs_runs_by_mode_and_seed(tmp_path):
    t4 = _load()
    rng = np.random.default_rng(0)
    base = "synthetic worlds 0-3"
    orig = {(m, s): rng.uniform(0.1, 2.0, 2) for m in ("stereo", "mono") for s in range(4)}
    filt = {(m, s): rng.uniform(0.1, 2.0, 2) for m in ("stereo", "mono") for s in range(4)}
    results = [_run(base, base, "none", m, s, *orig[m, s]) for m in ("stereo", "mono") for s in range(4)]
    # filtered runs in another order, one seed missing its original (must not be paired), one crashed
    results += [_run(f"{base}, telea filter", base, "telea", m, s, *filt[m, s]) for m in ("mono", "stereo") for s in (3, 1, 0, 2)]
    results = [r for r in results if not (r["filter"] == "none" and r["mode"] == "mono" and r["seed"] == 2)]
    results.append({"row": f"{base}, telea filter", "base": base, "filter": "telea", "mode": "stereo", "seed": 9,
                    "sequence": "/x/world9/sequences/synth", "frames": 10, "error": "RuntimeError: boom"})
    text = t4.write_markdown(t4._rows(results), tmp_path / "t4.md")
    lines = {ln.split("|")[2].strip(): ln for ln in text.splitlines() if ln.startswith(f"| {base} |") and "telea" in ln}
    for mode, k, seeds in (("stereo", 0, range(4)), ("mono", 1, (0, 1, 3))):
        d = np.asarray([filt[mode, s][k] - orig[mode, s][k] for s in seeds])
        cells = [c.strip() for c in lines[mode].split("|")[1:-1]]
        assert cells[3] == str(len(seeds))
        assert cells[7] == f"{np.median(d):+.3f} [{d.min():+.3f}, {d.max():+.3f}]"
        rel = 100 * d / np.asarray([orig[mode, s][k] for s in seeds])
        assert cells[8].startswith(f"{np.median(rel):+.1f} %")
    assert "crashed: RuntimeError: boom" in text


def test_head_to_head_names_the_winner_only_when_wilcoxon_says_so(tmp_path):
    from scipy.stats import wilcoxon

    t4 = _load()
    rng = np.random.default_rng(1)
    base = "KITTI seq1 (51 frames)"
    a = rng.uniform(0.05, 0.15, 8)
    b_far = a + rng.uniform(0.01, 0.05, 8)  # telea always worse than edgeconnect
    noise = a + rng.normal(0, 0.02, 8)  # "black": no consistent difference
    results = [_run(base, base, "none", "mono", s, 1.0, 0.1) for s in range(8)]
    for name, v in (("edgeconnect", a), ("telea", b_far), ("black", noise)):
        results += [_run(f"{base}, {name} filter", base, name, "mono", s, 1.0, float(v[s])) for s in range(8)]
    text = t4.write_markdown(t4._rows(results), tmp_path / "t4.md")
    rows = {ln.split("|")[3].strip(): [c.strip() for c in ln.split("|")[1:-1]]
            for ln in text.split("## Which filter wins")[1].split("## Every run")[0].splitlines() if ln.startswith(f"| {base}")}
    d = a - b_far
    cells = rows["edgeconnect − telea"]
    assert cells[3] == "8" and cells[5] == "8 / 0"
    assert cells[4] == f"{np.median(d):+.3f} [{d.min():+.3f}, {d.max():+.3f}]"
    assert cells[6] == f"{wilcoxon(d).pvalue:.3f}" and cells[7] == "edgeconnect"
    d2 = noise - a  # "black − edgeconnect" (alphabetical order)
    cells = rows["black − edgeconnect"]
    assert cells[6] == f"{wilcoxon(d2).pvalue:.3f}"
    assert cells[7] == ("neither (p ≥ 0.05)" if wilcoxon(d2).pvalue >= 0.05 else ("black" if np.median(d2) < 0 else "edgeconnect"))


def test_counts_of_lost_frames_relocalisations_maps_and_loops(tmp_path):
    """Issue 16 item 4's columns, per row and per run, against sums and maxima taken here; ``off`` for a
    row without loop closing and ``—`` for a run recorded before the counts existed."""
    t4 = _load()
    rng = np.random.default_rng(2)
    base = "loop worlds 7 (640 frames)"
    runs = []
    for lc in (False, True):
        for s in range(4):
            r = _run(f"{base}, loop closing" if lc else base, base, "none", "mono", s, 1.0, 0.5)
            r.update(tracked=int(rng.integers(5, 11)), relocalisations=int(rng.integers(0, 3)),
                     maps=int(rng.integers(1, 4)), loops=int(rng.integers(0, 3)) if lc else None)
            runs.append(r)
    legacy = _run("KITTI seq1 (51 frames)", "KITTI seq1 (51 frames)", "none", "mono", 0, 1.0, 0.5)
    text = t4.write_markdown(t4._rows(runs + [legacy]), tmp_path / "t4.md")
    table = text.split("## Every run")[0]
    rows = {ln.split("|")[1].split(", path")[0].strip(): [c.strip() for c in ln.split("|")[1:-1]]
            for ln in table.splitlines() if ln.startswith("| loop worlds") or ln.startswith("| KITTI")}
    for name, group in ((base, runs[:4]), (f"{base}, loop closing", runs[4:])):
        cells = rows[name][-4:]
        assert cells[0] == str(sum(10 - r["tracked"] for r in group))
        assert cells[1] == str(sum(r["relocalisations"] for r in group))
        assert cells[2] == str(max(r["maps"] for r in group))
        assert cells[3] == ("off" if group[0]["loops"] is None else str(sum(r["loops"] for r in group)))
    assert rows["KITTI seq1 (51 frames)"][-4:] == ["0", "—", "—", "—"]
    every = [ln for ln in text.split("## Every run")[1].splitlines() if ln.startswith("| world")]
    assert len(every) == 9 and sum(", loop closing |" in ln for ln in every) == 4


@pytest.mark.parametrize(("args", "message"), [
    (["--masked-modes", "stereo,rgbd"], "--masked-modes ['rgbd']: only stereo, mono run on filtered frames"),
    (["--filters", "telea,sharpen"], "unknown filter(s) ['sharpen']; choose from"),
])
def test_bad_options_are_refused_as_usage_errors(args, message):
    """``--masked-modes rgbd`` names a mode that never runs on filtered frames, ``--filters sharpen`` no
    filter: argparse's usage error (exit 2) before any rendering."""
    import subprocess

    r = subprocess.run([sys.executable, str(ROOT / "experiments/table4_ate.py"), "--skip-kitti", *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and message in r.stderr, (r.returncode, r.stderr[-500:])
    assert "rendering" not in r.stdout
