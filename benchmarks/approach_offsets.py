"""Where a landing's error comes from: how far from its pad centre a drone is in the seconds before it touches down.

For each landing (a drone that touches down on its own pad, episodes flown as one cell of the transfer matrix:
:func:`marlander_lite.experiments.transfer.build_episodes`, seeds from
:func:`marlander_lite.experiments.protocol.trial_seed`, Vicon sensing) it records the horizontal distance from the
pad centre (cm) at touchdown and 0.5, 1, 1.5 and 2 s before, the height above the pad 1 s before, and, over the last
second, how fast the drone moved horizontally per m/s commanded (the least-squares ratio of its horizontal velocity
relative to the pad to the command's). Prints the mean and the 90th percentile of each, per column.

    python benchmarks/approach_offsets.py POLICY [--columns "point mass,PyBullet firmware"] [--row UR10]
        [--episodes 30]
"""

from __future__ import annotations

import argparse

import numpy as np

from marlander_lite import task
from marlander_lite.experiments.protocol import trial_seed
from marlander_lite.experiments.transfer import build_episodes, cell_actor, find_column, find_row
from marlander_lite.policy_file import load_policy

BEFORE_S = (0.5, 1.0, 1.5, 2.0)


def landings(policy_path: str, column: str, row: str, episodes: int) -> np.ndarray:
    """One row per landing: error, the offsets ``BEFORE_S`` seconds before (m), height 1 s before (m), the ratio."""
    policy = load_policy(policy_path)
    world = build_episodes(policy, find_column(column), find_row(row), "vicon")
    cfg, act = world.task, cell_actor(policy, world, None)
    found = []
    try:
        for k in range(episodes):
            world.seed(trial_seed(0, row, k))
            obs, offsets, motion = world.reset(), [], []
            while True:
                action = act(obs)
                command = task.action_to_velocity(action, cfg.num_drones, cfg.max_speed)[0]
                outcome = world.step(action)
                s = world.sim.state()
                offsets.append(s.pos[0] - s.pad_pos[0])
                motion.append(np.stack([command - s.pad_vel[0], s.vel[0] - s.pad_vel[0]]))
                for i in np.flatnonzero(outcome.landed_now[0]):
                    rel, moved = np.array(offsets)[:, i], np.array(motion)[-25:-1, :, i, :2]
                    back = [rel[max(len(rel) - 1 - round(t * cfg.policy_hz), 0)] for t in (1.0, *BEFORE_S)]
                    ratio = np.sum(moved[:, 0] * moved[:, 1]) / max(np.sum(moved[:, 0] ** 2), 1e-9)
                    horizontal = [float(np.hypot(*b[:2])) for b in back[1:]]
                    found.append([float(outcome.landing_error[0, i]), *horizontal, float(back[0][2]), float(ratio)])
                if outcome.done[0]:
                    break
                obs = outcome.obs
    finally:
        world.sim.close()
    return np.array(found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("--columns", default="point mass,PyBullet firmware,RotorPy Crazyflie")
    parser.add_argument("--row", default="UR10")
    parser.add_argument("--episodes", type=int, default=30)
    args = parser.parse_args()
    names = ["error cm", *(f"{t:g} s before cm" for t in BEFORE_S), "height 1 s before cm", "v / command"]
    print(f"{args.policy}, row {args.row}, {args.episodes} episodes a column, seed 0, Vicon: mean (90th percentile)")
    print(f"| column | landings | {' | '.join(names)} |")
    print("|---|---|" + "---|" * len(names))
    for column in args.columns.split(","):
        found = landings(args.policy, column, args.row, args.episodes)
        scale = np.array([100.0] * (len(names) - 1) + [1.0])
        means, p90 = scale * found.mean(0), scale * np.quantile(found, 0.9, 0)
        cells = [f"{m:.2f} ({p:.2f})" for m, p in zip(means, p90, strict=True)]
        print(f"| {column} | {len(found)} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
