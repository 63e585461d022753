"""Does each simulator's velocity tracker hold a hover? One drone held at its start for 30 s by ``v = -(p - p0)``.

A policy can only land where the tracker under it follows commands. Before any policy is blamed, this script holds
one drone still in every simulator through the same velocity interface the policies fly
(``crazyflie.fit.position_hold``) and prints the RMS and largest position error per axis over the last 20 s. PyFlyt
is held twice, stepped as its releases since 0.22 step it and as the pinned 0.21.0 does, and also by its own position
mode (mode 7, no code of ours in the loop but the step order), which shows that a wander is PyFlyt's and not our
wrapper's (docs/transfer.md, "PyFlyt").

    python benchmarks/position_hold.py
"""

from __future__ import annotations

import numpy as np

from marlander_lite.crazyflie.fit import position_hold
from marlander_lite.pyflyt_sim.simulator import aviary_class
from marlander_lite.task import TaskConfig

SECONDS, SETTLE = 30.0, 10.0
SIMULATORS = {
    "PyBullet PID": ("crazyflie", {"controller": "pid"}),
    "PyBullet firmware": ("crazyflie", {"controller": "firmware"}),
    "RotorPy": ("rotorpy", {}),
    "PyFlyt, state read after the physics (>= 0.22)": ("pyflyt", {"read_state": "after_physics"}),
    "PyFlyt, state read before the physics (0.21.0)": ("pyflyt", {"read_state": "before_physics"}),
}


def pyflyt_own_position_mode(read_state: str) -> np.ndarray:
    """Position errors of a cf2x holding (0, 0, 1) in PyFlyt's own position mode, sampled at 24 Hz."""
    aviary = aviary_class(read_state)(
        start_pos=np.array([[0.0, 0.0, 1.0]]), start_orn=np.zeros((1, 3)), render=False, drone_type="quadx", seed=0
    )
    aviary.set_mode(7)
    aviary.set_setpoint(0, np.array([0.0, 0.0, 0.0, 1.0]))  # x, y, yaw, z
    errors = []
    try:
        for _ in range(round(SECONDS * 24)):
            for _ in range(5):  # 120 Hz control periods per 24 Hz sample
                aviary.step()
            errors.append(aviary.state(0)[3] - (0.0, 0.0, 1.0))
    finally:
        aviary.disconnect()
    return np.array(errors)


def row(name: str, errors: np.ndarray) -> str:
    held = errors[round(SETTLE * 24) :]
    rms, largest = np.sqrt(np.mean(np.square(held), axis=0)), np.abs(held).max(axis=0)
    return (
        f"| {name} | " + " | ".join(f"{r * 100:.1f} / {m * 100:.1f}" for r, m in zip(rms, largest, strict=True)) + " |"
    )


def main() -> None:
    task = TaskConfig(num_drones=1)
    held = SECONDS - SETTLE
    print(f"One drone held at its start by v = -(p - p0) for {SECONDS:g} s, seed 0; errors over the last {held:g} s")
    print()
    print("| simulator | x: RMS / largest, cm | y | z |")
    print("|---|---|---|---|")
    for name, (simulator, options) in SIMULATORS.items():
        print(row(name, position_hold(task, simulator, SECONDS, **options)), flush=True)
    for read_state, label in (("after_physics", ">= 0.22"), ("before_physics", "0.21.0")):
        print(
            row(f"PyFlyt's own position mode 7 ({label} step order)", pyflyt_own_position_mode(read_state)), flush=True
        )


if __name__ == "__main__":
    main()
