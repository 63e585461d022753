"""Fixtures shared by several test files."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from marlander_lite.policy_file import PolicyContract, save_policy

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.fixture(scope="module")
def p_controller_policy(tmp_path_factory) -> Path:
    """A real policy file: linear, a P-controller on each drone's position relative to a point 5 cm under its
    goal, stiffer horizontally so that the drone is over its pad before it is down (v_xy = -3 p_xy,
    v_z = -1.2 (p_z + 0.05) m/s before the lab limit)."""
    weight, bias = np.zeros((6, 26)), np.zeros(6)
    for i in range(2):
        weight[3 * i : 3 * i + 3, 13 * i : 13 * i + 3] = -np.diag([1.0, 1.0, 0.4])
        bias[3 * i + 2] = -0.4 * 0.05
    contract = PolicyContract(
        num_drones=2, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(), normalize_observations=False
    )
    path = tmp_path_factory.mktemp("policy") / "p_controller.safetensors"
    return save_policy(path, contract, {"actor.0.weight": weight, "actor.0.bias": bias})


@pytest.fixture(scope="session")
def executed_notebook(tmp_path_factory) -> Callable[[str], Path]:
    """``executed_notebook("04_static_platform.ipynb")`` -> that notebook run with ``MARLANDER_BUDGET=small``, saved.

    Each notebook runs once per test session, however many tests read it: the notebook tests check what it shows,
    the documentation-site test renders it. Under ``pytest -n`` the copies sit in the session's directory shared by
    every worker, and a file lock per notebook makes a second reader wait for the first run instead of starting
    its own. A failed run is kept too (as its error), so that its second reader fails at once with the same error.
    """
    nbformat = pytest.importorskip("nbformat", reason="the notebooks extra is not installed")
    nbclient = pytest.importorskip("nbclient", reason="the notebooks extra is not installed")
    from filelock import FileLock  # a dependency of torch

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # this session's directory, shared by its workers (pytest-xdist's documented recipe)
    folder = root / "executed-notebooks" / "notebooks"
    folder.mkdir(parents=True, exist_ok=True)

    def run(name: str) -> Path:
        executed, error = folder / name, folder / f"{name}.error"
        with FileLock(str(folder / f"{name}.lock")):
            if not executed.exists() and not error.exists():
                nb = nbformat.read(NOTEBOOKS / name, as_version=4)
                client = nbclient.NotebookClient(
                    nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
                )
                try:
                    client.execute(env={**os.environ, "MARLANDER_BUDGET": "small"})
                except Exception as exc:  # CellExecutionError, a dead kernel, a timeout: all fail every reader
                    error.write_text(f"{type(exc).__name__}: {exc}", encoding="utf-8")
                else:  # written whole, then renamed: an interrupted write leaves no half notebook for the next reader
                    partial = folder / f"{name}.partial"
                    nbformat.write(nb, partial)
                    partial.replace(executed)
        if error.exists():
            pytest.fail(f"{name} failed with MARLANDER_BUDGET=small:\n{error.read_text(encoding='utf-8')}")
        return executed

    return run
