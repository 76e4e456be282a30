"""Execute every notebook (jupytext ``.py`` percent sources) on tiny settings; any error fails.

Each ``notebooks/*.py`` is converted with jupytext and run by nbclient in a ``python3`` kernel
with ``PRIVSLAM_NB_TINY=1``.  A first injected cell turns warnings raised by privslam_jax code
into errors inside the kernel; jupyter's own DeprecationWarnings in this process are tolerated
by a local filter.
"""

import os
import warnings
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.py"))
STRICT_CELL = 'import warnings\nwarnings.filterwarnings("error", module=r"privslam_jax(\\..*)?$")'


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    nbformat = pytest.importorskip("nbformat")
    monkeypatch.setenv("PRIVSLAM_NB_TINY", "1")
    nb = jupytext.read(path)
    nb.cells.insert(0, nbformat.v4.new_code_cell(STRICT_CELL))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        client = nbclient.NotebookClient(
            nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
        )
        client.execute()  # raises CellExecutionError (with the traceback) on any failing cell
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert os.environ["PRIVSLAM_NB_TINY"] == "1"
