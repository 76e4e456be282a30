"""Execute the notebooks and write rendered copies (markdown + PNG figures) to read without running them.

    python notebooks/render.py                      # every notebook, full settings -> docs/notebooks/
    python notebooks/render.py --tiny               # the test suite's settings (about a minute each)
    python notebooks/render.py 03_privacy_accuracy_tradeoff --out /tmp/nb

Each ``notebooks/NN_name.py`` (jupytext percent source) runs top to bottom in a fresh ``python3``
kernel with ``notebooks/`` as its working directory (nbclient), and is exported with nbconvert's
markdown exporter: ``<out>/NN_name.md`` beside ``<out>/NN_name_files/*.png``.  A notebook that
raises, or writes to stderr, is not written.  ``../shared`` is hidden from the kernels unless
``--shared`` is given, so the rendered copies in the repository hold no real (licensed) frames: the
notebooks print that they skip their real-data cells.  Needs the ``notebooks`` extra
(``pip install -e ".[notebooks]"``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from privslam_jax.data.files import write_atomic  # noqa: E402

NOTEBOOKS = sorted(p for p in HERE.glob("[0-9][0-9]_*.py"))


def execute(path: Path, tiny: bool, shared: bool, prelude: str | None = None, timeout: int = 3600):
    """Run the notebook ``path`` in a fresh kernel; returns the executed ``nbformat`` notebook.

    ``prelude``: code run as an extra first cell (the tests turn warnings into errors with it).
    Raises ``nbclient.exceptions.CellExecutionError`` on a failing cell and ``RuntimeError`` when
    a cell wrote to stderr."""
    import jupytext
    import nbclient
    import nbformat

    nb = jupytext.read(path)
    if prelude is not None:
        nb.cells.insert(0, nbformat.v4.new_code_cell(prelude))
    env = {"PRIVSLAM_NB_TINY": "1" if tiny else "0"}
    if not shared:  # a path that does not exist: shared_dir() is None in the kernel
        env["PRIVSLAM_SHARED"] = str(Path(tempfile.gettempdir()) / "privslam-no-shared")
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the kernel inherits this process's environment
    try:
        nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
                                resources={"metadata": {"path": str(path.parent)}}).execute()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    stderr = [o["text"] for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "stream" and o.get("name") == "stderr"]
    if stderr:
        raise RuntimeError(f"{path.name} wrote to stderr:\n" + "".join(stderr)[-2000:])
    return nb


def export(nb, stem: str, out: Path, header: str = "") -> Path:
    """Write ``nb`` as ``out/<stem>.md`` (``header`` first) with its figures in ``out/<stem>_files/``;
    returns the markdown path.

    The figures are written first and the markdown last (atomically), so a half-written copy never
    looks complete; stale figures of an earlier rendering are removed."""
    from nbconvert import MarkdownExporter

    files_dir = f"{stem}_files"
    body, resources = MarkdownExporter().from_notebook_node(
        nb, resources={"output_files_dir": files_dir, "unique_key": stem})
    out.mkdir(parents=True, exist_ok=True)
    figures = out / files_dir
    shutil.rmtree(figures, ignore_errors=True)
    for name, data in resources.get("outputs", {}).items():
        write_atomic(out / name, data)
    md = out / f"{stem}.md"
    write_atomic(md, header + body)
    return md


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="notebooks to render (file stems; default: all)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "notebooks", help="output folder")
    parser.add_argument("--tiny", action="store_true", help="the tiny settings the tests use (PRIVSLAM_NB_TINY=1)")
    parser.add_argument("--shared", action="store_true", help="let the notebooks read ../shared (real frames)")
    args = parser.parse_args(argv)
    by_stem = {p.stem: p for p in NOTEBOOKS}
    unknown = [n for n in args.names if n not in by_stem]
    if unknown:
        parser.error(f"unknown notebook(s) {unknown}; choose from {sorted(by_stem)}")
    for stem in args.names or sorted(by_stem):
        nb = execute(by_stem[stem], args.tiny, args.shared)
        settings = ("tiny" if args.tiny else "full") + " settings, ../shared " + ("visible" if args.shared else "hidden")
        header = (f"> Rendered from `notebooks/{stem}.py` by `python notebooks/render.py"
                  f"{' --tiny' if args.tiny else ''}{' --shared' if args.shared else ''}` "
                  f"({settings}), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n\n")
        print(f"wrote {export(nb, stem, args.out, header)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
