"""The library does not depend on the command line: nothing outside ``commands/`` and ``cli.py`` imports ``commands``."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def test_nothing_outside_the_cli_imports_commands():
    offenders = []
    for folder in ("privslam_jax", "experiments", "train", "benchmarks", "notebooks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith("privslam_jax/commands/") or rel == "privslam_jax/cli.py":
                continue
            bad = sorted(n for n in _imports(path) if n.startswith("privslam_jax.commands"))
            if bad:
                offenders.append(f"{rel}: {', '.join(bad)}")
    assert not offenders, "library code imports the CLI:\n" + "\n".join(offenders)


def test_the_walk_sees_an_import_of_commands(tmp_path):
    """The check above is not vacuous: both import forms are found."""
    f = tmp_path / "m.py"
    f.write_text("from privslam_jax.commands import filter\nimport privslam_jax.commands.slam\n")
    assert {"privslam_jax.commands.filter", "privslam_jax.commands.slam"} <= _imports(f)
