"""Speed of the PyBullet Crazyflie swarm (issue 3, deliverable 7).

Prints, as medians of ``--repeats`` rounds measured in this one process (a round times each of
the functions compared in turn, and a ratio is the median of the ratios within the rounds, so
that both sides of it ran under the same load from the rest of the machine):

1. simulator steps (one policy period, 10 physics steps at 240 / 24 Hz) per second, control
   ticks per second and the real-time factor (simulated s per wall s), for 1, 2, 4, 8 and 16
   drones, with both velocity trackers (``pid``: 2 ticks at 48 Hz of 5 physics steps each;
   ``firmware``, which evaluations use: 10 ticks of one physics step) and with physics only
   (``bare``) and with ground effect + drag + downwash (``aero``). ``bare x`` is the step's
   cost over a bare ``stepSimulation`` loop that advances the same bodies by the same time in
   the same number of calls (gravity off, so the drones float as if hovering and nothing
   touches), ``floor x`` the API floor's (below) over the same loop. Each setting is flown by
   both engines of the control ticks in the same rounds (``numpy``: the Python reference,
   ``numba``: the compiled kernels of ``crazyflie/tick_kernels.py``, same results bit for bit);
   ``numba gain`` is the numpy step's time over the numba step's. The PyBullet calls are
   passed the client id by position, as the simulator passes it (keywords cost ~10 % more);
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

Usage: ``python benchmarks/bench_crazyflie.py [--repeats 5] [--seconds 1.0]`` (about 10 minutes).
Timings on a shared machine swing: compare numbers from the same run only.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pybullet as p

import marlander_lite  # registers the gymnasium ids
from marlander_lite.crazyflie import CrazyflieSwarm, PhysicsConfig
from marlander_lite.crazyflie.timing import bare_physics, hover_grid, with_gravity_off
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import TaskConfig

ENV_ID = "marlander_lite/CrazyflieLanding-v0"


def hovering_swarm(
    num_drones: int, physics: str, controller: str = "pid", policy_hz: float = 24.0, engine: str = "auto"
) -> CrazyflieSwarm:
    """A swarm hovering at :func:`hover_grid` (``firmware`` ticks at ``physics_hz``)."""
    config = PhysicsConfig.preset(physics, control_hz=48.0 if policy_hz == 24.0 else policy_hz)
    task_config = TaskConfig(num_drones=num_drones, policy_hz=policy_hz)
    sim = CrazyflieSwarm(task_config, PlatformConfig(), physics=config, controller=controller, engine=engine)
    sim.place(0, hover_grid(num_drones))
    return sim


def interleaved(fns: dict, seconds: float, repeats: int, setup: Callable[[], None] | None = None) -> dict:
    """Seconds per call of each of ``fns`` in each of ``repeats`` rounds, ``{name: [s, ...]}``.

    A round times every function in turn, for about ``seconds`` each, so that a ratio of two of them
    taken within a round compares runs made under the same load from the rest of the machine.
    ``setup`` (untimed) runs before each function's turn, e.g. to put a swarm back in its place.
    """
    batches = {}
    for name, fn in fns.items():
        if setup is not None:
            setup()
        fn()
        start, calls = time.perf_counter(), 0
        while time.perf_counter() - start < 0.1:
            fn()
            calls += 1
        batches[name] = max(1, int(calls * seconds / 0.1))
    runs = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            if setup is not None:
                setup()
            start = time.perf_counter()
            for _ in range(batches[name]):
                fn()
            runs[name].append((time.perf_counter() - start) / batches[name])
    return runs


def per_call(fn, seconds: float, repeats: int) -> float:
    """Median seconds per call of ``fn`` over ``repeats`` runs of about ``seconds`` each."""
    return statistics.median(interleaved({"fn": fn}, seconds, repeats)["fn"])


def ratio(runs: dict, over: str, under: str) -> float:
    """Median over the rounds of ``runs[over] / runs[under]`` (:func:`interleaved`)."""
    return statistics.median(a / b for a, b in zip(runs[over], runs[under], strict=True))


def api_floor(sim: CrazyflieSwarm) -> callable:
    """The bare loop plus the PyBullet calls a controller ticking at ``control_hz`` cannot avoid."""
    ticks = round(sim.physics.control_hz / sim.task.policy_hz)
    cid, bodies, zero = sim.client, sim.world.drones, (0.0, 0.0, 0.0)
    link_frame = p.LINK_FRAME

    def run() -> None:  # the client id by position, as the simulator passes it: keywords cost more
        for _ in range(ticks):
            for body in bodies:
                p.applyExternalForce(body, -1, zero, zero, link_frame, cid)
                p.applyExternalTorque(body, -1, zero, link_frame, cid)
            p.stepSimulation(cid)
            p.getContactPoints(physicsClientId=cid)
            for body in bodies:
                p.getBasePositionAndOrientation(body, cid)
                p.getBaseVelocity(body, cid)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one timed run")
    args = parser.parse_args()
    reps, secs = args.repeats, args.seconds
    print(f"PyBullet {p.getAPIVersion()}, medians of {reps} runs of ~{secs:.1f} s\n")

    print("1. Simulator step (policy 24 Hz = 10 physics steps at 240 Hz), hovering; pid: 2 ticks at 48 Hz,")
    print("   firmware: 10 ticks at 240 Hz")
    header = f"{'drones':>6} {'tracker':>8} {'physics':>8} {'engine':>6} {'steps/s':>8} {'ticks/s':>8}"
    print(f"{header} {'real-time x':>11} {'bare x':>7} {'floor x':>7} {'numba gain':>10}")
    for n in (1, 2, 4, 8, 16):
        for controller in ("pid", "firmware"):
            for physics in ("bare", "aero"):
                sims = {e: hovering_swarm(n, physics, controller, engine=e) for e in ("numpy", "numba")}
                hover, grid, sim = np.zeros((1, n, 3)), hover_grid(n), sims["numba"]
                fns = {e: lambda s=s, hover=hover: s.step(hover) for e, s in sims.items()}
                fns["bare"] = with_gravity_off(sim, bare_physics(sim))
                if physics == "bare":
                    fns["floor"] = with_gravity_off(sim, api_floor(sim))

                def setup(sims=sims, grid=grid) -> None:  # the gravity-free loops let the drones drift: put them back
                    for s in sims.values():
                        s.place(0, grid)

                runs = interleaved(fns, secs, reps, setup=setup)
                floor = f"{ratio(runs, 'floor', 'bare'):7.2f}" if "floor" in runs else f"{'':>7}"
                for engine in ("numpy", "numba"):
                    step = statistics.median(runs[engine])
                    ticks = round(sim.physics.control_hz / sim.task.policy_hz) / step
                    row = f"{n:>6} {controller:>8} {physics:>8} {engine:>6} {1 / step:8.0f} {ticks:8.0f}"
                    row += f" {sim.task.dt / step:11.1f} {ratio(runs, engine, 'bare'):7.2f}"
                    if engine == "numba":
                        row += f" {floor} {ratio(runs, 'numpy', 'numba'):10.2f}"
                    print(row, flush=True)
                for s in sims.values():
                    s.close()
    print("   'bare x': simulator step / bare stepSimulation loop over the same bodies, one call per tick")
    print("   (gravity off); 'floor x': API floor (the PyBullet calls a controller ticking at that rate")
    print("   must make) / the same bare loop; 'numba gain': the numpy engine's step / the numba engine's;")
    print("   all medians of the ratios within each round. Sections 2-4 run the default engine (auto: numba)\n")

    print("2. Where a 2-drone env step goes (policy 24 Hz, aero physics), microseconds per step")
    forever = {"episode_seconds": 1e5}  # no episode end while timing a hovering swarm
    env = gym.make(ENV_ID, num_drones=2, physics="aero", task=forever).unwrapped
    env.reset(seed=0)
    sim, pair = env.simulator, np.array([[-0.5, 0.0, 1.5], [0.5, 0.0, 1.5]])
    zero = np.zeros(6, dtype=np.float32)
    hover = np.zeros((1, 2, 3))
    fns = {"env": lambda: env.step(zero), "sim": lambda: sim.step(hover)}
    fns |= {"bare": with_gravity_off(sim, bare_physics(sim)), "floor": with_gravity_off(sim, api_floor(sim))}
    runs = interleaved(fns, secs, reps, setup=lambda: sim.place(0, pair))
    labels = {
        "bare": "bare stepSimulation loop (10 physics steps):",
        "floor": "API floor (+ the unavoidable PyBullet calls):",
        "sim": "CrazyflieSwarm.step (PID, forces, contacts): ",
        "env": "gymnasium env step (+ LandingEpisodes, face):",
    }
    for name, label in labels.items():
        times = f"{statistics.median(runs[name]) * 1e6:7.0f}"
        print(f"   {label} {times}" + ("" if name == "bare" else f"  = {ratio(runs, name, 'bare'):.2f} x bare"))
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
