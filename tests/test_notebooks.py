"""Execute every tutorial in ``notebooks/`` from top to bottom, so that none of them rots.

Each notebook runs in a fresh ``python3`` kernel started with the interpreter running the
tests (so a virtual environment tests its own installation), in a temporary working
directory; the notebooks write their outputs into temporary folders of their own. A failure
names the notebook and the cell that raised.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))
#: Seconds one cell may take before the run is abandoned.
CELL_TIMEOUT = 300


def _kernel_manager():
    """A kernel manager whose ``python3`` kernel is this interpreter (not whichever python
    a globally registered kernel spec names)."""
    from jupyter_client.manager import KernelManager

    km = KernelManager(kernel_name="python3")
    km.kernel_spec.argv = [sys.executable, "-m", "ipykernel_launcher", "-f",
                           "{connection_file}"]
    return km


def test_kernel_is_this_interpreter(tmp_path):
    # sys.prefix tells a virtual environment from the interpreter it was made from
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(
        "import sys; print(sys.prefix)")])
    client = nbclient.NotebookClient(nb, km=_kernel_manager(), timeout=CELL_TIMEOUT,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    assert nb.cells[0].outputs[0]["text"].strip() == sys.prefix


def test_there_are_notebooks():
    names = {p.name for p in NOTEBOOKS}
    assert {"01_analyze_a_video.ipynb", "02_resynthesis.ipynb",
            "03_closed_loop_evaluation.ipynb", "04_flow_templates.ipynb",
            "05_inside_the_face_model.ipynb"} <= names


@pytest.mark.slow  # 15-45 s each; about three minutes for the five on a loaded 2-core machine
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not cell.get("outputs") and cell.get("execution_count") is None, \
                f"{path.name}: commit notebooks with their outputs stripped"
    client = nbclient.NotebookClient(nb, km=_kernel_manager(), timeout=CELL_TIMEOUT,
                                     allow_errors=False,
                                     resources={"metadata": {"path": str(tmp_path)}})
    start = time.perf_counter()
    try:
        # the notebooks write into tempfile.mkdtemp() folders: keep those under tmp_path
        client.execute(env={**os.environ, "TMPDIR": str(tmp_path)})
    except nbclient.exceptions.CellExecutionError as exc:
        index = next((i for i, c in enumerate(nb.cells) if any(
            o.get("output_type") == "error" for o in c.get("outputs", []))), None)
        source = nb.cells[index].source if index is not None else "?"
        head = "\n".join(source.splitlines()[:6])
        pytest.fail(f"{path.name}: cell {index} raised {exc.ename}: {exc.evalue}\n"
                    f"--- cell {index} ---\n{head}\n...", pytrace=False)
    elapsed = time.perf_counter() - start
    print(f"{path.name}: {elapsed:.1f} s")
    written = [p for p in path.parent.iterdir()
               if p.suffix != ".ipynb" and not p.name.startswith(".")]
    assert not written, f"{path.name} wrote into notebooks/: {written}"
