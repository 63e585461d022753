"""Notebook 02 (the PyBullet Crazyflie) is committed without outputs and runs headless with the small budget."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "02_crazyflie_pybullet.ipynb"


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


@pytest.mark.slow
@pytest.mark.notebooks
def test_notebook_runs_with_the_small_budget(monkeypatch):
    monkeypatch.setenv("MARLANDER_BUDGET", "small")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    resources = {"metadata": {"path": str(NOTEBOOK.parent)}}
    client = NotebookClient(nb, timeout=300, kernel_name="python3", resources=resources)
    client.execute(env=dict(os.environ))  # raises CellExecutionError on any failing cell
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "hover speed  sqrt(m g / 4 k_f) =    14476 RPM" in text
    assert "episode 0: success True" in text
