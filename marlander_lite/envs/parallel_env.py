"""PettingZoo face: one agent per drone, each with its own eq. 2 observation and eq. 3 action."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from marlander_lite.envs.gym_env import step_info
from marlander_lite.envs.options import drone_action_space, drone_observation_space, policy_input
from marlander_lite.episodes import LandingEpisodes, Simulator
from marlander_lite.sensing import SensingConfig


class SwarmParallelEnv(ParallelEnv):
    """Decentralised view of a swarm landing: agents ``drone_0 .. drone_{N-1}``.

    Observation of agent ``i``: its own ``(13,)`` eq. 2 vector (position relative to its pad,
    quaternion, velocity relative to the platform, angular velocity; ``(16,)`` with the platform
    velocity when ``TaskConfig.observe_platform_velocity``). Action: ``(3,)`` normalised velocity.
    Reward of agent ``i``: ``r_t^i + r^c + K`` (its own eq. 5 term plus the shared
    collision penalty and final bonus), so the agents' rewards add up to more than eq. 4's
    ``R_t`` whenever a shared term is paid. All agents stay in the episode until it ends for
    the swarm; a landed drone ignores its actions.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [], "name": "marlander_swarm_v0", "is_parallelizable": True}

    def __init__(self, simulator: Simulator, sensing: SensingConfig) -> None:
        if simulator.num_envs != 1:
            raise ValueError("A PettingZoo env drives one swarm; build the simulator with num_envs=1.")
        self.simulator = simulator
        self.episodes = LandingEpisodes(simulator, sensing)
        self.num_drones = simulator.task.num_drones
        self.possible_agents = [f"drone_{i}" for i in range(self.num_drones)]
        self.agents: list[str] = []
        self._obs_space = drone_observation_space(simulator.task)
        self._act_spaces = {a: drone_action_space() for a in self.possible_agents}

    def observation_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self._act_spaces[agent]

    def _check_agent(self, agent: str) -> None:
        if agent not in self.possible_agents:
            raise KeyError(f"Unknown agent {agent!r}; agents are {self.possible_agents}.")

    def _per_agent(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        per_drone = np.ascontiguousarray(obs, dtype=np.float32)
        return {a: per_drone[i] for i, a in enumerate(self.possible_agents)}

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None:
            self.episodes.seed(seed)
        # ``options`` is accepted and unused: PettingZoo's own API test passes arbitrary ones.
        self.agents = list(self.possible_agents)
        obs = self.episodes.reset()[0]
        return self._per_agent(obs), {a: {} for a in self.agents}

    def step(self, actions: dict[str, np.ndarray]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("The episode has not started or has ended: call reset() before step().")
        missing = [a for a in self.agents if a not in actions]
        extra = [a for a in actions if a not in self.agents]
        if missing or extra:
            raise ValueError(
                f"step() needs one action per live agent {self.agents}; missing {missing}, unknown {extra}."
            )
        bad = {a: np.shape(actions[a]) for a in self.agents if np.shape(actions[a]) != (3,)}
        if bad:
            raise ValueError(f"Each agent's action must have shape (3,), entries in [-1, 1]; got shapes {bad}.")
        batch = np.stack([np.asarray(actions[a], dtype=np.float64) for a in self.possible_agents])
        outcome = self.episodes.step(batch[None])
        obs = self._per_agent(outcome.obs[0])
        rewards = {a: float(outcome.agent_rewards[0, i]) for i, a in enumerate(self.possible_agents)}
        term = {a: bool(outcome.terminated[0]) for a in self.possible_agents}
        trunc = {a: bool(outcome.truncated[0]) for a in self.possible_agents}
        shared = step_info(outcome)
        infos = {a: {**shared, "landed_self": bool(outcome.landed[0, i])} for i, a in enumerate(self.possible_agents)}
        if outcome.done[0]:
            self.agents = []
        return obs, rewards, term, trunc, infos

    def state(self) -> np.ndarray:
        """Global state: every drone's eq. 2 vector, flattened ``(13 N,)`` (the centralised input)."""
        return policy_input(self.episodes.true_observations())[0]

    def close(self) -> None:
        self.simulator.close()
