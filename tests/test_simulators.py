"""The simulator registry and the env options: one entry per simulator, one options object per env.

The registry is checked by round trips (name -> entry -> every face -> a simulator of the entry's
class) and by a toy simulator registered here, in the test, which must then be reachable through
every factory and ``gymnasium.make`` with no other file edited.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import registry as gym_registry
from gymnasium.utils.env_checker import check_env as gym_check_env
from pettingzoo.test import parallel_api_test
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.vec_env import VecEnv

import marlander_lite
from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import EnvOptions
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.envs import PointMassOptions
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.simulators import REGISTRY, SIMULATORS, SimulatorEntry, register_simulator, simulator_entry
from marlander_lite.task import TaskConfig

PACKAGE = Path(marlander_lite.__file__).parent

# ---------------------------------------------------------------------------- the built-in entries


@pytest.mark.parametrize("name", SIMULATORS)
def test_every_entry_round_trips_through_gymnasium_and_the_factories(name):
    entry = simulator_entry(name)
    assert gym_registry[entry.env_id].entry_point == entry.gym_env
    env = gym.make(entry.env_id, num_drones=2)
    assert isinstance(env.unwrapped, entry.gym_env_class())
    assert isinstance(env.unwrapped.simulator, entry.swarm_class())
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()
    parallel = marlander_lite.make_parallel_env(name, num_drones=3)
    assert isinstance(parallel.simulator, entry.swarm_class()) and parallel.num_drones == 3
    parallel.close()
    vec = marlander_lite.make_vec_env(name, num_envs=2, seed=0, num_drones=2)
    assert isinstance(vec, VecEnv) and vec.reset().shape == (2, 26)
    vec.close()
    assert issubclass(entry.options_class(), EnvOptions)
    assert marlander_lite.ENV_IDS[name] == entry.env_id


@pytest.mark.parametrize("name", SIMULATORS)
def test_the_same_seed_flies_the_same_episode_in_every_simulator(name):
    def rollout():
        simulator, sensing = simulator_entry(name).options_class()(num_drones=2, sensing="vicon").build(1)
        episodes = LandingEpisodes(simulator, sensing, seed=7)
        obs = [episodes.reset()]
        for action in np.random.default_rng(3).uniform(-0.3, 0.3, (6, 1, 6)):
            obs.append(episodes.step(action).obs)
        simulator.close()
        return np.stack(obs)

    np.testing.assert_array_equal(rollout(), rollout())


def test_the_bare_simulator_class_is_built_as_the_experiments_and_the_rehearsal_build_it():
    for name in SIMULATORS:
        swarm = simulator_entry(name).swarm_class()(TaskConfig(num_drones=2), PlatformConfig(), 1)
        assert swarm.num_envs == 1 and swarm.task.num_drones == 2
        swarm.close()


def test_an_unknown_simulator_lists_the_allowed_names():
    for call in (
        lambda: simulator_entry("mujoco"),
        lambda: marlander_lite.make_vec_env("mujoco"),
        lambda: marlander_lite.make_parallel_env("pybullet"),
    ):
        with pytest.raises(ValueError, match=r"Unknown simulator .*; allowed: pointmass, crazyflie"):
            call()


def test_point_mass_envs_never_import_pybullet():
    code = (
        "import sys, gymnasium as gym, marlander_lite\n"
        "from marlander_lite.experiments.protocol import ProtocolConfig, condition, make_episodes\n"
        "marlander_lite.make_vec_env('pointmass', num_envs=2).reset()\n"
        "marlander_lite.make_parallel_env('pointmass').reset(seed=0)\n"
        "gym.make(marlander_lite.ENV_IDS['pointmass']).reset(seed=0)\n"
        "make_episodes(ProtocolConfig(), condition('static-floor')).reset()\n"
        "assert 'pybullet' not in sys.modules, 'PyBullet was imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


def test_simulator_classes_are_named_in_the_registry_only():
    """The "module:attr" paths of the built-in entries appear in no other module of the package."""
    paths = {getattr(entry, f) for entry in REGISTRY.values() for f in ("swarm", "gym_env", "vec_env", "parallel_env")}
    registry_file = PACKAGE / "simulators.py"
    offenders = [
        f"{source.relative_to(PACKAGE)}: {path}"
        for source in PACKAGE.rglob("*.py")
        if source != registry_file
        for path in paths
        if f'"{path}"' in source.read_text()
    ]
    assert not offenders


def test_registering_clashes_are_refused():
    pointmass = simulator_entry("pointmass")
    assert register_simulator(pointmass) is pointmass  # the same entry again: nothing happens
    with pytest.raises(ValueError, match="already registered"):
        register_simulator(dataclasses.replace(pointmass, description="another point mass"))
    with pytest.raises(ValueError, match="already belongs to simulator 'pointmass'"):
        register_simulator(dataclasses.replace(pointmass, name="pointmass2"))
    with pytest.raises(ValueError, match="'module:attr'"):
        dataclasses.replace(pointmass, swarm="marlander_lite.pointmass.simulator.PointMassSwarm")
    assert list(REGISTRY) == list(SIMULATORS)


# ---------------------------------------------------------------------------- a simulator added by one entry


class SluggishSwarm(PointMassSwarm):
    """A toy new simulator: the point mass with a slower velocity loop (tau given by the options)."""


@dataclass(frozen=True)
class SluggishOptions(EnvOptions):
    tau: float = 0.5
    """Horizontal velocity time constant (s)."""

    def make_simulator(self, num_envs: int = 1) -> SluggishSwarm:
        params = PointMassParams(velocity_time_constant=self.tau)
        return SluggishSwarm(self.task_config, self.platform_config, num_envs, params)


class SluggishLandingEnv(SwarmLandingEnv):
    def __init__(self, options: SluggishOptions | None = None, **fields):
        super().__init__(*SluggishOptions.from_keywords(fields, options, "SluggishLanding-v0").build())


def sluggish_vec_env(num_envs=1, seed=None, options=None, **fields):
    return LandingVecEnv(*SluggishOptions.from_keywords(fields, options).build(num_envs), seed)


def sluggish_parallel_env(options=None, **fields):
    return SwarmParallelEnv(*SluggishOptions.from_keywords(fields, options).build())


@pytest.fixture
def sluggish():
    """The toy simulator, registered by one entry for the test and removed afterwards."""
    here = __name__
    entry = register_simulator(
        SimulatorEntry(
            name="sluggish",
            env_id="marlander_lite/SluggishLanding-v0",
            swarm=f"{here}:SluggishSwarm",
            gym_env=f"{here}:SluggishLandingEnv",
            vec_env=f"{here}:sluggish_vec_env",
            parallel_env=f"{here}:sluggish_parallel_env",
            options=f"{here}:SluggishOptions",
            description="A point mass with a slow velocity loop (test only).",
        )
    )
    yield entry
    del REGISTRY[entry.name], gym_registry[entry.env_id]


def test_a_simulator_registered_by_one_entry_is_reachable_by_every_face(sluggish):
    env = gym.make(sluggish.env_id, num_drones=2, tau=0.4, platform="moving-arc")
    assert isinstance(env.unwrapped.simulator, SluggishSwarm)
    assert env.unwrapped.simulator.params.velocity_time_constant == 0.4
    assert env.unwrapped.platform.kind == "moving-arc"
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)

    vec = marlander_lite.make_vec_env("sluggish", num_envs=3, seed=0, num_drones=2, tau=0.3)
    assert isinstance(vec.simulator, SluggishSwarm) and vec.simulator.params.velocity_time_constant == 0.3
    assert vec.reset().shape == (3, 26)

    parallel = marlander_lite.make_parallel_env("sluggish", num_drones=3)
    assert isinstance(parallel.simulator, SluggishSwarm) and parallel.possible_agents[-1] == "drone_2"
    parallel_api_test(parallel, num_cycles=50)

    with pytest.raises(TypeError, match=r"\['wind'\]; allowed options: num_drones.*, tau"):
        marlander_lite.make_vec_env("sluggish", wind=3.0)
    with pytest.raises(ValueError, match="allowed: pointmass, crazyflie, rotorpy, pyflyt, sluggish"):
        simulator_entry("mujoco")


def test_the_toy_responds_more_slowly_than_the_point_mass(sluggish):
    """The registered toy really runs its own dynamics: after 0.25 s of a 1 m/s command a loop with tau
    = 0.5 s has reached far less speed than the point mass's (tau = 0.142 s)."""
    speeds = {}
    for name in ("pointmass", "sluggish"):
        swarm = simulator_entry(name).options_class()(num_drones=1).make_simulator(1)
        swarm.reset(np.zeros(1, dtype=int), np.random.default_rng(0))
        for _ in range(6):  # 0.25 s at 24 Hz
            swarm.step(np.array([[[1.0, 0.0, 0.0]]]))
        speeds[name] = float(swarm.state().vel[0, 0, 0])
    assert speeds["sluggish"] < 0.6 * speeds["pointmass"]


# ---------------------------------------------------------------------------- the options object


def rollout(env, steps=40):
    rng = np.random.default_rng(1)
    frames = [env.reset()]
    for _ in range(steps):
        obs, reward, _, _ = env.step(rng.uniform(-1, 1, (env.num_envs, env.action_space.shape[0])))
        frames.extend([obs, reward])
    return frames


def test_keywords_and_an_options_object_build_the_same_env():
    keywords = dict(
        num_drones=2, platform="moving-arc", platform_speed=0.4, sensing="vicon", dynamics={"max_tilt_deg": 30}
    )
    by_keywords = rollout(marlander_lite.make_vec_env("pointmass", num_envs=8, seed=3, **keywords))
    by_object = rollout(
        marlander_lite.make_vec_env("pointmass", num_envs=8, seed=3, options=PointMassOptions(**keywords))
    )
    for a, b in zip(by_keywords, by_object, strict=True):
        np.testing.assert_array_equal(a, b)


def test_keywords_change_the_fields_of_an_options_object():
    options = PointMassOptions(num_drones=2, platform="static-elevated")
    env = marlander_lite.make_vec_env("pointmass", num_envs=2, options=options, num_drones=3)
    assert env.observation_space.shape == (39,) and env.platform.kind == "static-elevated"
    common = EnvOptions(num_drones=4)  # the common options carry over to any simulator's
    assert marlander_lite.make_parallel_env("pointmass", options=common).num_drones == 4
    with pytest.raises(TypeError, match="PointMassOptions options, got CrazyflieOptions"):
        marlander_lite.make_vec_env("pointmass", options=simulator_entry("crazyflie").options_class()())


def test_options_are_frozen_and_checked_when_made():
    options = PointMassOptions()
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.num_drones = 3  # type: ignore[misc]
    with pytest.raises(ValueError, match="allowed: static-floor"):
        PointMassOptions(platform="trampoline")
    with pytest.raises(ValueError, match="num_drones"):
        EnvOptions(num_drones=0)
    with pytest.raises(TypeError, match=r"\['x'\]; allowed options: velocity_time_constant"):
        PointMassOptions(dynamics={"x": 1.0})
    with pytest.raises(NotImplementedError, match="common options only"):
        EnvOptions().make_simulator()
