"""Which part of PyFlyt's velocity tracker costs a policy its precision? Each one changed in turn.

A policy that lands 0.6-1.6 cm from its pad centre in ten columns of the transfer matrix lands 2.5-3.5 cm from it in
PyFlyt 0.22, and under 1 cm on a point mass given PyFlyt's fitted response (this script's last row; docs/transfer.md,
"An integrator in the tracker"). PyFlyt's ground-velocity mode is a cascade the point mass does not have: a horizontal
velocity PID (``kp`` 0.8, ``ki`` 0.3, ``kd`` 0.5) whose integrator carries past errors forward, an attitude P loop of
gain 2 (a 0.5 s time constant), and 2 % motor noise. This script flies the floor row of the ``PyFlyt Crazyflie 0.22``
column as published and with one part changed at a time (never in the transfer column itself): the velocity
integrator off, the attitude loop four times faster, the motor noise off; and, for comparison, on the point mass
fitted to PyFlyt's response. The transfer matrix's episodes, seed 0, Vicon sensing. (``pyflyt_diagnostics.py`` asks
the same of what the policy observes: motor noise off, body rates hidden, in 0.21.0's step order.)

    python benchmarks/pyflyt_tracker_parts.py POLICY [--episodes 100] [--workers 2]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from marlander_lite.experiments import transfer

COLUMN = "PyFlyt Crazyflie 0.22"
CHANGES: dict[str, str] = {
    "as published": "",
    "velocity integrator off (ki 0)": "no_integrator",
    "attitude loop 4x faster (kp 8)": "fast_attitude",
    "motor noise off": "no_motor_noise",
    "none of it: a point mass with PyFlyt's fitted response": "point_mass_fit",
}
PYFLYT_FIT = {
    "velocity_time_constant": 0.762,
    "vertical_time_constant": 0.062,
    "attitude_time_constant": 0.131,
    "max_tilt_deg": 12.7,
    "max_climb_acceleration": 12.0,
    "max_sink_acceleration": 9.62,
}
"""The point mass fitted to PyFlyt 0.22's go-and-brake answers (``benchmarks/identify_simulators.py``,
``benchmarks/results/identify_simulators_2026-11-27-pyflyt-0.22.txt``): a proportional velocity loop, a first-order
tilt, no noise. Its climb of 40 m/s^2 is capped at 12, the training family's largest, so that the row asks only how
the policy flies a member of the kind it trained on."""


def _changed_world(change: str) -> Any:
    """``transfer.build_episodes`` with every PyFlyt drone of the swarm changed by ``change``: PyFlyt's ``QuadX``
    rebuilds its PIDs from these gains at each ``set_mode`` (every reset), so changing them once holds."""
    build = transfer.build_episodes

    def build_changed(*args: Any, **kwargs: Any) -> Any:
        world = build(*args, **kwargs)
        for aviary in world.sim.aviaries:
            for quad in aviary.drones:
                if change == "no_integrator":
                    quad.Ki_lin_vel = quad.Ki_lin_vel * 0.0
                elif change == "fast_attitude":
                    quad.Kp_ang_pos = quad.Kp_ang_pos * 4.0
                elif change == "no_motor_noise":
                    quad.motors.noise_ratio = quad.motors.noise_ratio * 0.0
        return world

    return build_changed


def fly(policy: str, change: str, episodes: int) -> transfer.CellResult:
    """The floor cell of :data:`COLUMN` with PyFlyt changed by ``change`` ('' : as published)."""
    if change == "point_mass_fit":
        column = transfer.Column("point mass, PyFlyt's fit", "pointmass", {"dynamics": PYFLYT_FIT})
        return transfer.fly_cell(policy, column, "floor", episodes, 0, "vicon")
    published = transfer.build_episodes
    if change:
        transfer.build_episodes = _changed_world(change)
    try:
        return transfer.fly_cell(policy, COLUMN, "floor", episodes, 0, "vicon")
    finally:  # a pool's worker flies the next change on PyFlyt as published
        transfer.build_episodes = published


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    print(f"{args.policy}, {COLUMN}, floor, {args.episodes} episodes each, seed 0, Vicon sensing")
    print("| PyFlyt | success % | landing error cm | collisions / out of the arena / off pad / too fast |")
    print("|---|---|---|---|")
    with ProcessPoolExecutor(args.workers) as pool:  # one process per change: each patches its own module
        results = pool.map(fly, [args.policy] * len(CHANGES), CHANGES.values(), [args.episodes] * len(CHANGES))
        for label, r in zip(CHANGES, results, strict=True):
            causes = f"{r.collisions} / {r.out_of_arena} / {r.crashes_off_pad} / {r.crashes_too_fast}"
            print(f"| {label} | {100 * r.success_rate:.1f} | {r.landing_error_cm:.2f} | {causes} |", flush=True)


if __name__ == "__main__":
    main()
