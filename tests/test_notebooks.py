"""Every notebook is committed without outputs and runs headless with the small CI budget (d2l style).

``MARLANDER_BUDGET=small`` makes each notebook take the same code path with fewer steps
(``marlander_lite.budget.scaled``). Each notebook must also print what shows it worked.
"""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
EXPECTED_TEXT = {
    "00_overview.ipynb": ["PointMassVecEnv (4, 26)"],
    "01_mdp_and_pointmass.ipynb": ["r_t^i = [[4.98  0.992]]", "success True"],
    "02_crazyflie_pybullet.ipynb": ["hover speed  sqrt(m g / 4 k_f) =    14476 RPM", "episode 0: success True"],
    "03_training_ppo.ipynb": ["budget: small"],
    "04_static_platform.ipynb": ["budget: small"],
    "05_moving_platform.ipynb": ["budget: small"],
    "06_baselines.ipynb": ["budget: small"],
    "07_deployment_rehearsal.ipynb": ["budget: small", "fault none: armed=True, on pad=[True, True]"],
    "08_transfer.ipynb": ["budget: small", "### quick-cpu", "| floor | "],
}


def test_every_notebook_is_listed_here():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(EXPECTED_TEXT)


@pytest.mark.parametrize("name", sorted(EXPECTED_TEXT))
def test_notebook_is_committed_without_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


@pytest.mark.slow
@pytest.mark.notebooks
@pytest.mark.parametrize("name", sorted(EXPECTED_TEXT))
def test_notebook_runs_with_the_small_budget(name, monkeypatch):
    monkeypatch.setenv("MARLANDER_BUDGET", "small")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute(env=dict(os.environ))  # raises CellExecutionError on any failing cell
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    for expected in EXPECTED_TEXT[name]:
        assert expected in text, f"{name} did not print {expected!r}"
