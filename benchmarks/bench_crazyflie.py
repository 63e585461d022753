"""Speed of the PyBullet Crazyflie swarm (issue 3, deliverable 7).

Prints, as medians of ``--repeats`` runs measured in this one process:

1. simulator steps (one policy period: 2 PID ticks, 10 physics steps at 240 / 48 / 24 Hz) per
   second, PID ticks per second and the real-time factor (simulated s per wall s), for 1, 2,
   4 and 8 drones, with physics only (``bare``) and with ground effect + drag + downwash (``aero``);
2. the cost of one step of our code over a bare ``stepSimulation`` loop that advances the same
   bodies by the same time (gravity off, so the drones float as if hovering and nothing
   touches), for the simulator alone and for the full gymnasium env (which adds the shared MDP
   layer, ``LandingEpisodes``), next to the *API floor*: the same loop plus only the PyBullet
   calls that any controller ticking at ``control_hz`` outside PyBullet must make (per tick and
   drone: read pose and velocity, apply one force and one torque; per tick: one contact query),
   with constant forces and no arithmetic. No Python controller can cost less than the floor.
3. the full 2-drone gymnasium env at 30 Hz policy and PID rate (240 Hz physics), the setting
   of the nearest toolkit's RL env, without and with episode resets;
4. the stable-baselines3 ``VecEnv`` of 16 two-drone swarms that training uses, random actions,
   batched in this process (``vectorization="batched"``, the default) and one swarm per
   subprocess (``"subprocess"``).

Usage: ``python benchmarks/bench_crazyflie.py [--repeats 5] [--seconds 1.0]``. Timings on a
shared machine swing: compare numbers from the same run only.
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np
import pybullet as p

import marlander_lite  # registers the gymnasium ids
from marlander_lite.crazyflie import CrazyflieSwarm, PhysicsConfig
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import TaskConfig

ENV_ID = "marlander_lite/CrazyflieLanding-v0"


def hovering_swarm(num_drones: int, physics: str, policy_hz: float = 24.0) -> CrazyflieSwarm:
    config = PhysicsConfig.preset(physics, control_hz=48.0 if policy_hz == 24.0 else policy_hz)
    sim = CrazyflieSwarm(TaskConfig(num_drones=num_drones, policy_hz=policy_hz), PlatformConfig(), physics=config)
    grid = [(0.5 * (i % 4) - 0.75, 0.5 * (i // 4) - 0.25, 1.5) for i in range(num_drones)]
    sim.place(0, np.array(grid))
    return sim


def per_call(fn, seconds: float, repeats: int) -> float:
    """Median seconds per call of ``fn`` over ``repeats`` runs of about ``seconds`` each."""
    fn()
    start, calls = time.perf_counter(), 0
    while time.perf_counter() - start < 0.1:
        fn()
        calls += 1
    batch = max(1, int(calls * seconds / 0.1))
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(batch):
            fn()
        runs.append((time.perf_counter() - start) / batch)
    return statistics.median(runs)


def bare_physics(sim: CrazyflieSwarm) -> callable:
    """One policy period of bare PyBullet stepping over the simulator's own bodies (gravity off)."""
    ticks = round(sim.physics.control_hz / sim.task.policy_hz)

    def run() -> None:
        for _ in range(ticks):
            p.stepSimulation(physicsClientId=sim.client)

    return run


def api_floor(sim: CrazyflieSwarm) -> callable:
    """The bare loop plus the PyBullet calls a controller ticking at ``control_hz`` cannot avoid."""
    ticks = round(sim.physics.control_hz / sim.task.policy_hz)
    cid, bodies, zero = sim.client, sim.world.drones, (0.0, 0.0, 0.0)
    link_frame = p.LINK_FRAME

    def run() -> None:
        for _ in range(ticks):
            for body in bodies:
                p.applyExternalForce(body, -1, zero, zero, link_frame, physicsClientId=cid)
                p.applyExternalTorque(body, -1, zero, link_frame, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
            p.getContactPoints(physicsClientId=cid)
            for body in bodies:
                p.getBasePositionAndOrientation(body, physicsClientId=cid)
                p.getBaseVelocity(body, physicsClientId=cid)

    return run


def with_gravity_off(sim: CrazyflieSwarm, fn) -> callable:
    def run() -> None:
        p.setGravity(0, 0, 0, physicsClientId=sim.client)
        try:
            fn()
        finally:
            p.setGravity(0, 0, -9.81, physicsClientId=sim.client)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one timed run")
    args = parser.parse_args()
    reps, secs = args.repeats, args.seconds
    print(f"PyBullet {p.getAPIVersion()}, medians of {reps} runs of ~{secs:.1f} s\n")

    print("1. Simulator step (policy 24 Hz = 2 PID ticks at 48 Hz = 10 physics steps at 240 Hz), hovering")
    header = f"{'drones':>6} {'physics':>8} {'steps/s':>9} {'PID ticks/s':>12} {'real-time x':>12}"
    print(f"{header} {'bare x':>8} {'floor x':>8}")
    for n in (1, 2, 4, 8):
        for physics in ("bare", "aero"):
            sim = hovering_swarm(n, physics)
            hover = np.zeros((1, n, 3))
            step = per_call(lambda sim=sim, hover=hover: sim.step(hover), secs, reps)
            ratios = f"{'':>8} {'':>8}"
            if physics == "bare":
                bare = per_call(with_gravity_off(sim, bare_physics(sim)), secs, reps)
                floor = per_call(with_gravity_off(sim, api_floor(sim)), secs, reps)
                ratios = f"{step / bare:8.2f} {floor / bare:8.2f}"
            print(f"{n:>6} {physics:>8} {1 / step:9.0f} {2 / step:12.0f} {sim.task.dt / step:12.1f} {ratios}")
            sim.close()
    print("   'bare x': simulator step / bare stepSimulation loop over the same bodies (gravity off)")
    print("   'floor x': API floor (the PyBullet calls a 48 Hz controller must make) / the same bare loop\n")

    print("2. Where a 2-drone env step goes (policy 24 Hz, aero physics), microseconds per step")
    forever = {"episode_seconds": 1e5}  # no episode end while timing a hovering swarm
    env = gym.make(ENV_ID, num_drones=2, physics="aero", task=forever).unwrapped
    env.reset(seed=0)
    sim = env.simulator
    sim.place(0, np.array([[-0.5, 0.0, 1.5], [0.5, 0.0, 1.5]]))
    zero = np.zeros(6, dtype=np.float32)
    hover = np.zeros((1, 2, 3))
    t_env = per_call(lambda: env.step(zero), secs, reps)
    t_sim = per_call(lambda: sim.step(hover), secs, reps)
    t_bare = per_call(with_gravity_off(sim, bare_physics(sim)), secs, reps)
    t_floor = per_call(with_gravity_off(sim, api_floor(sim)), secs, reps)
    print(f"   bare stepSimulation loop (10 physics steps): {t_bare * 1e6:7.0f}")
    print(f"   API floor (+ the unavoidable PyBullet calls): {t_floor * 1e6:7.0f}  = {t_floor / t_bare:.2f} x bare")
    print(f"   CrazyflieSwarm.step (PID, forces, contacts):  {t_sim * 1e6:7.0f}  = {t_sim / t_bare:.2f} x bare")
    print(f"   gymnasium env step (+ LandingEpisodes, face): {t_env * 1e6:7.0f}  = {t_env / t_bare:.2f} x bare")
    env.close()
    print()

    print("3. 2-drone gymnasium env at 30 Hz policy and PID, 240 Hz physics (the nearest toolkit's setting)")
    physics = {"preset": "aero", "control_hz": 30}
    env = gym.make(ENV_ID, num_drones=2, physics=physics, task={"policy_hz": 30, **forever}).unwrapped
    env.reset(seed=0)
    env.simulator.place(0, np.array([[-0.5, 0.0, 1.5], [0.5, 0.0, 1.5]]))
    t_hover = per_call(lambda: env.step(zero), secs, reps)
    env.close()
    env = gym.make(ENV_ID, num_drones=2, physics=physics, task={"policy_hz": 30}).unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    episodes = [0]

    def random_step() -> None:
        *_, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
        if terminated or truncated:
            env.reset()
            episodes[0] += 1

    t_random = per_call(random_step, secs, reps)
    t_reset = per_call(env.reset, secs / 4, reps)
    print(f"   hovering, no resets:        {1 / t_hover:6.0f} env steps/s")
    print(f"   random actions with resets: {1 / t_random:6.0f} env steps/s ({episodes[0]} episodes ended)")
    print(f"   one reset:                  {t_reset * 1e3:6.2f} ms")
    env.close()
    print()

    print("4. SB3 VecEnv of 16 two-drone swarms (24 Hz policy, aero physics), random actions")
    for vectorization in ("batched", "subprocess"):
        vec = marlander_lite.make_vec_env("crazyflie", num_envs=16, seed=0, vectorization=vectorization)
        vec.reset()
        actions = np.random.default_rng(0).uniform(-1, 1, (16, 6)).astype(np.float32)
        t_vec = per_call(lambda vec=vec, actions=actions: vec.step(actions), secs, reps)
        print(f"   {vectorization:<10} {16 / t_vec:7.0f} env steps/s ({t_vec / 16 * 1e6:5.0f} us per swarm step)")
        vec.close()


if __name__ == "__main__":
    main()
