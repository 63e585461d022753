"""What else in PyFlyt stops a policy: its motor noise, and the angular velocity the policy reads, each taken away.

A policy that lands on point masses with PyFlyt's fitted velocity response still lands rarely in PyFlyt itself
(docs/transfer.md, "PyFlyt"). Two candidates a point mass does not model can be switched off in a diagnostic run
(never in the transfer column, which flies PyFlyt as published): the 2 % multiplicative motor noise
(``motors.noise_ratio`` set to zero in every drone), and the jitter of the body rates the policy observes (eq. 2's
angular velocity replaced by zeros before the policy reads it). Floor row, seed 0, Vicon sensing, the transfer
matrix's episodes.

    python benchmarks/pyflyt_diagnostics.py POLICY [--episodes 40]
"""

from __future__ import annotations

import argparse

import numpy as np

from marlander_lite.episodes import StepOutcome
from marlander_lite.experiments.transfer import build_episodes, cell_actor, find_column, find_row, fly_episodes
from marlander_lite.policy_file import load_policy

ANGULAR_VELOCITY = slice(10, 13)  # eq. 2 per drone: position 0:3, quaternion 3:7, velocity 7:10, angular velocity


def fly(policy_path: str, episodes: int, motor_noise: bool, observe_rates: bool) -> tuple[int, float]:
    """Successes of ``episodes`` PyFlyt floor episodes, and the median largest body rate (rad/s) over flown steps."""
    policy = load_policy(policy_path)
    world = build_episodes(policy, find_column("PyFlyt Crazyflie"), find_row("floor"), "vicon")
    if not motor_noise:
        for aviary in world.sim.aviaries:
            for quad in aviary.drones:
                quad.motors.noise_ratio = quad.motors.noise_ratio * 0.0
    policy_act = cell_actor(policy, world, None)
    rates: list[float] = []

    def act(obs: np.ndarray) -> np.ndarray:
        seen = np.array(obs, copy=True)
        if not observe_rates:
            seen[..., ANGULAR_VELOCITY] = 0.0
        return policy_act(seen)

    def watch(_outcome: StepOutcome) -> None:
        rates.append(float(np.abs(world.sim.state().ang_vel[0]).max()))

    successes = fly_episodes(world, act, "floor", episodes, watch=watch)
    return successes, float(np.median(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("--episodes", type=int, default=40)
    args = parser.parse_args()
    print(f"{args.policy}, PyFlyt Crazyflie, floor, {args.episodes} episodes each, seed 0, Vicon sensing")
    print("| PyFlyt | landed | median largest body rate, rad/s |")
    print("|---|---|---|")
    for label, noise, rates in (
        ("as published", True, True),
        ("motor noise off", False, True),
        ("angular velocity hidden from the policy", True, False),
    ):
        successes, rate = fly(args.policy, args.episodes, noise, rates)
        print(f"| {label} | {successes} of {args.episodes} | {rate:.2f} |")


if __name__ == "__main__":
    main()
