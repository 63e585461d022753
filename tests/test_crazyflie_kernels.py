"""The compiled control ticks of the PyBullet swarm (numba) against the Python reference: the same bits, every tick.

Each test flies two swarms from the same seed, one per engine, through the same commands and events (landings,
stopped motors, placements, resets), and compares every state the simulator publishes, the rotor speeds and the
tracker's memory with ``==`` after every step.
"""

import numpy as np
import pytest

from marlander_lite.crazyflie import CrazyflieSwarm, PhysicsConfig
from marlander_lite.crazyflie.envs import CrazyflieOptions
from marlander_lite.crazyflie.ticks import CompiledTick, ControlTick
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import kernels
from marlander_lite.task import TaskConfig

pytest.importorskip("numba")

PERTURBED = {"mass_scale": 1.2, "latency_s": 0.05, "gain_scale": 1.4}


def tracker_memory(sim: CrazyflieSwarm) -> list[np.ndarray]:
    """The tracker's whole memory, copied (both engines keep it in these arrays)."""
    c = sim.controller
    arrays = [c.state] if sim.controller_kind == "pid" else [c.pid_memory, c.phase, c.setpoint]
    return [a.copy() for a in arrays]


def snapshot(sim: CrazyflieSwarm) -> list[np.ndarray]:
    """Everything that must be equal after a step: published state, rotor speeds, forces and tracker memory."""
    state = [sim.pos, sim.quat, sim.vel, sim.ang_vel, sim.pad_pos, sim.contact, sim.landed, sim.motors_stopped]
    rotors = [np.array(sim.rpm, dtype=float), np.array(sim.rpm_command, dtype=float)]
    wrench = [np.array(sim._forces, dtype=float), np.array(sim._torques, dtype=float)]
    return [np.array(a, copy=True) for a in state] + rotors + wrench + tracker_memory(sim)


def rollout(engine, controller, num_drones, physics, perturbation=None, platform="static-floor", steps=24, seed=0):
    """A seeded flight with random commands and, along the way, a landing, stopped motors, a placement and a reset."""
    sim = CrazyflieSwarm(
        TaskConfig(num_drones=num_drones),
        PlatformConfig(kind=platform),
        physics=physics,
        controller=controller,
        perturbation=perturbation,
        engine=engine,
    )
    rng = np.random.default_rng(seed)
    sim.reset(np.array([0]), rng)
    drones, records = np.arange(num_drones)[None], []
    for step in range(steps):
        sim.step(rng.uniform(-1, 1, (1, num_drones, 3)))
        if step == steps // 4:
            sim.land(drones == num_drones - 1)  # latched to its pad: idle from now on
        if step == steps // 3:
            sim.stop_motors(drones == 0)  # falls
        if step == steps // 2:
            sim.place(0, sim.pad_pos[0] + [0.0, 0.0, 0.6])  # every drone back in the air, trackers reset
        if step == 3 * steps // 4:
            sim.reset(np.array([0]), rng)
        records.append(snapshot(sim))
    sim.close()
    return sim, records


def assert_same_flights(reference, compiled):
    assert len(compiled) == len(reference)
    for step, (ours, theirs) in enumerate(zip(compiled, reference, strict=True)):
        for k, (a, b) in enumerate(zip(ours, theirs, strict=True)):
            assert a.shape == b.shape and np.array_equal(a, b), f"first difference at step {step}, array {k}"


def fly_both(*args, **kwargs):
    reference_sim, reference = rollout("numpy", *args, **kwargs)
    compiled_sim, compiled = rollout("numba", *args, **kwargs)
    assert type(reference_sim._tick) is ControlTick and isinstance(compiled_sim._tick, CompiledTick)
    assert_same_flights(reference, compiled)
    return reference


CASES = {
    "1 drone, bare": (1, PhysicsConfig.preset("bare"), None, "static-floor"),
    "3 drones, aero, motor lag, perturbed, moving plate": (
        3,
        PhysicsConfig.preset("aero", motor_time_constant=0.01),
        PERTURBED,
        "moving-linear",
    ),
    "16 drones, aero": (16, PhysicsConfig.preset("aero"), None, "static-elevated"),
}


@pytest.mark.parametrize("controller", ["pid", "firmware"])
@pytest.mark.parametrize("case", list(CASES))
def test_compiled_ticks_fly_the_reference_bit_for_bit(controller, case):
    num_drones, physics, perturbation, platform = CASES[case]
    records = fly_both(controller, num_drones, physics, perturbation, platform)
    moved = np.abs(records[-1][0] - records[0][0]).max()
    assert moved > 0.01  # the drones did fly


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["pid", "firmware"])
@pytest.mark.parametrize("num_drones", [1, 3, 16])
@pytest.mark.parametrize(
    "physics",
    [
        PhysicsConfig.preset("bare"),
        PhysicsConfig.preset("aero"),
        PhysicsConfig.preset("aero", downwash=False),
        PhysicsConfig.preset("bare", motor_time_constant=0.02, ground_effect=True),
    ],
    ids=["bare", "aero", "aero-no-downwash", "lag-ground-effect"],
)
@pytest.mark.parametrize("perturbation", [None, PERTURBED, {"mass_scale": 0.7, "latency_s": 0.02, "gain_scale": 0.6}])
def test_compiled_ticks_fly_the_reference_over_longer_flights(controller, num_drones, physics, perturbation):
    fly_both(controller, num_drones, physics, perturbation, "moving-arc", steps=96, seed=num_drones)


def go_to_pad(obs: np.ndarray, num_drones: int) -> np.ndarray:
    """Down a cone onto the own pad (lands most drones), actions in [-1, 1]."""
    p = obs.reshape(num_drones, -1)[:, 0:3].copy()
    p[:, 2] -= np.minimum(2.0 * np.linalg.norm(p[:, :2], axis=-1), 1.0) - 0.05
    v = -2.0 * p
    v *= np.minimum(1.0, 1.0 / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9))
    return (v / 3.0).reshape(-1)


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["pid", "firmware"])
@pytest.mark.parametrize("num_drones", [3, 16])
def test_landing_episodes_are_the_same_on_both_engines(controller, num_drones):
    """Whole episodes through LandingEpisodes: touchdowns, landings, crashes and automatic resets."""
    outcomes = {}
    for engine in ("numpy", "numba"):
        sim = CrazyflieSwarm(
            TaskConfig(num_drones=num_drones, spawn_separation=0.2, spawn_near_pad_fraction=1.0),
            PlatformConfig(),
            controller=controller,
            engine=engine,
        )
        episodes = LandingEpisodes(sim, seed=5)
        obs, rng, records = episodes.reset()[0], np.random.default_rng(2), []
        for _ in range(120):
            action = go_to_pad(obs, num_drones) + 0.1 * rng.uniform(-1, 1, 3 * num_drones)
            out = episodes.step(action[None])
            obs = out.obs[0]
            records.append([out.obs, out.reward, out.landed_now, out.crashed, *snapshot(sim)])
            if out.done.any():
                obs = episodes.reset(np.array([0]))[0]
        outcomes[engine] = records
        sim.close()
    assert_same_flights(outcomes["numpy"], outcomes["numba"])
    assert any(r[2].any() for r in outcomes["numpy"]), "no drone landed: the landing branch was not reached"


def test_engine_choice_and_its_errors(monkeypatch):
    cfg, plate = TaskConfig(num_drones=2), PlatformConfig()
    monkeypatch.delenv(kernels.ENGINE_VARIABLE, raising=False)
    sim = CrazyflieSwarm(cfg, plate)
    assert sim.engine == "numba" and isinstance(sim._tick, CompiledTick)  # auto, numba installed
    assert isinstance(sim.rpm, np.ndarray) and sim.rpm.shape == (2, 4)
    sim.close()
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numpy")
    sim = CrazyflieSwarm(cfg, plate, controller="firmware")
    assert sim.engine == "numpy" and type(sim._tick) is ControlTick
    sim.close()
    sim = CrazyflieSwarm(cfg, plate, engine="numba")  # an explicit choice wins
    assert sim.engine == "numba"
    sim.close()
    with pytest.raises(ValueError, match=r"engine must be one of \('auto', 'numpy', 'numba'\), got 'jax'"):
        CrazyflieSwarm(cfg, plate, engine="jax")
    with pytest.raises(ValueError, match="engine must be one of"):
        CrazyflieOptions(engine="fortran")
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "fortran")
    with pytest.raises(ValueError, match="MARLANDER_LITE_ENGINE must be one of"):
        CrazyflieSwarm(cfg, plate)


def test_the_engine_option_reaches_every_world_of_a_batch():
    options = CrazyflieOptions(num_drones=2, physics="bare", engine="numpy")
    batch = options.make_simulator(3)
    assert [swarm.engine for swarm in batch.swarms] == ["numpy"] * 3
    batch.close()
    sim = CrazyflieOptions(num_drones=2, engine="numba").make_simulator(1)
    assert sim.engine == "numba"
    sim.close()


def test_resets_and_warm_starts_reach_the_compiled_trackers_memory():
    """The tracker object stays the one to reset and tune: the kernel reads its arrays, not copies."""
    sim = CrazyflieSwarm(TaskConfig(num_drones=2), PlatformConfig(), controller="firmware", engine="numba")
    sim.controller.warm_start_pwm = 36000.0
    sim.place(0, np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]]))  # resets the tracker
    warm = sim.controller.pid_memory[:, 2, 0].copy()
    assert np.all(warm == 0.0)  # (warm start - thrust base) / (thrust scale * ki)
    sim.step(np.zeros((1, 2, 3)))
    assert np.all(sim.controller.pid_memory[:, 2, 0] > warm)  # a cold integrator winds up as the drone sinks
    assert np.all(sim.controller.thrust_command > 36000.0) and np.all(sim.controller.phase == 0)
    sim.close()
