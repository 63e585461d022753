"""Fixtures shared by several test files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from marlander_lite.policy_file import PolicyContract, save_policy


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
