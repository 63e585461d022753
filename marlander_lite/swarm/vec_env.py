"""Parameter sharing in stable-baselines3: every (swarm, drone) pair is one entry of a ``VecEnv``.

PPO never learns that the entries belong together: it sees ``sum_g E_g N_g`` independent
environments, each with the shared input of :mod:`marlander_lite.swarm.observation` and a 3-number
action, and fits one actor and one critic to all of them. That is multi-agent PPO with parameter
sharing (MAPPO's decentralised-critic variant, also called IPPO; Yu et al. 2022, de Witt et al.
2020), written as a VecEnv so the library's tested PPO does the learning.

Several swarm sizes train at once: the VecEnv holds one batched point-mass simulator per size (a
*group* of ``E_g`` swarms of ``N_g`` drones), concatenated. Each swarm restarts as soon as its
episode ends, so the swarm size of an episode is drawn from the fixed mixture of groups.

**Reward per entry.** Drone ``i``'s entry earns ``r_t^i + r^c + K`` (``StepOutcome.agent_rewards``):
its own eq. 5 term plus the shared eq. 6 collision penalty and eq. 4's final bonus. The paper's team
reward ``sum_i r_t^i`` would hand every drone the other drones' shaping as well, whose variance
grows with N and drowns the drone's own credit; the per-drone term keeps the return's scale the
same for 2 and 16 drones (one critic serves every size), and the shared terms keep what is
cooperative about the task: a collision costs both drones, and every drone gains when the last one lands.

**Separation aids (training only, not in the paper; off by default).** ``collision_credit="involved"``
charges eq. 6's ``alpha_c`` only to the drones closer than ``collision_distance`` to another drone, not to the
whole swarm: in a swarm of 8 a drone would otherwise pay for collisions it had no part in, and the penalty
stops telling it what it did wrong. ``separation_penalty`` ``w`` takes ``w * max(0, d_s - d_i)`` per step
from every flying drone whose nearest other drone is ``d_i < d_s`` (``separation_margin``) away: a dense
signal before the sparse collision, with ``d_s`` below the 0.25 m pad spacing so that neighbours landing on
adjacent pads cost nothing.

**Shield (training only, not in the paper; off by default).** With ``shield`` set, the safety filter
(:mod:`marlander_lite.swarm.safety_filter`, the one evaluation and deployment put after the policy) changes the
commands before they are flown, as a *shield* does in safe RL [Alshiekh2018]: collisions become rare in training,
so drones in swarms of 8 live long enough to practise landing beside each other, where one collision used to end
the episode of all of them. PPO still learns from the policy's own actions, and ``shield_penalty`` ``w_s`` takes
``w_s |u_filtered - u|`` (m/s) per step from every flying drone whose command the filter changed: the policy is
taught to fly so that the filter has nothing to do, and the network alone is what is evaluated.

**Episodes.** A swarm's episode ends for all its drones at once (eq. 4's termination: all landed, a
crash, a collision, a drone out of the arena, or the time limit). Drones that landed earlier stay
entries until then; their actions are ignored and they earn only the shared terms.

**Per-drone episode ends (training only, not in the paper; off by default).** With ``drone_episode_ends`` a crash,
a collision or an exit ends the episode of the flying drones it happened to, not the swarm's: their entries end
there (``done``, their last input as ``terminal_observation``), each is relaunched at once from a new random start
(``LandingEpisodes.relaunch``, the same airframe taking off again) and begins its next episode in the same entry,
while the other drones fly on. The swarm's episode then ends only when every drone is on its pad, or at the time
limit. One collision used to end the episode of every drone in the swarm, so in swarms of 8 the drones that had no
part in it never practised the rest of their approach, nor landing beside the others. eq. 6's ``alpha_c`` is
charged to the drones in the collision only (this needs ``collision_credit="involved"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from marlander_lite.envs.vec_env import InProcessVecEnv
from marlander_lite.episodes import LandingEpisodes, StepOutcome
from marlander_lite.pointmass.envs import build_simulator
from marlander_lite.pointmass.simulator import PointMassParams
from marlander_lite.swarm.observation import pairwise_offsets, shared_obs_size, shared_observations
from marlander_lite.swarm.safety_filter import SafetyFilterConfig, filter_actions
from marlander_lite.task import ACT_PER_DRONE, OBS_LIMITS, TaskConfig

_NO_INFO = MappingProxyType({})


class SharedSwarmVecEnv(InProcessVecEnv):
    """Point-mass swarms of several sizes as one SB3 ``VecEnv`` of drones (see the module doc).

    Args:
        swarm_sizes: drones per swarm of each group, e.g. ``(2, 4, 8)``.
        swarms_per_size: swarms simulated in parallel in each group (one number for all, or one per size).
        neighbours: ``k``, the nearest neighbours each drone senses.
        task, platform, platform_speed, sensing, dynamics: as :class:`~marlander_lite.pointmass.envs.PointMassVecEnv`
            (``task`` a dict of :class:`TaskConfig` overrides; ``num_drones`` is set per group).
        seed: seeds group ``g`` with ``seed + g``.
        neighbour_radius: sensing range of the neighbour features (m); None: any distance.
        collision_credit: ``"swarm"`` (eq. 6: every drone of the swarm pays ``alpha_c``) or ``"involved"``
            (only the drones in the collision pay; a training aid).
        separation_penalty: ``w >= 0`` of the separation aid (reward per metre inside ``separation_margin``).
        separation_margin: ``d_s`` (m), the distance below which the separation aid charges a flying drone.
        shield: a :class:`SafetyFilterConfig` (or its dict) to filter the commands with in training; None: no shield.
        shield_penalty: ``w_s >= 0``, reward lost per m/s of command change by the shield (needs ``shield``).
        drone_episode_ends: end a crashing, colliding or escaping drone's episode alone (see the module doc).

    Entries are ordered group by group, then swarm by swarm, then drone by drone. ``infos`` of a
    finished swarm's drone 0 carry the swarm's episode (``episode``: mean per-drone return and length,
    ``is_success``, ``landing_error`` mean over landed drones (m), ``landing_time`` of the last drone (s),
    ``min_separation`` (m), ``num_drones``), so SB3's logs count swarm episodes, not drones; every
    finished entry carries ``terminal_observation`` and ``TimeLimit.truncated``.
    """

    def __init__(
        self,
        swarm_sizes: Sequence[int] = (2, 4, 8),
        swarms_per_size: int | Sequence[int] = 32,
        neighbours: int = 3,
        task: dict[str, Any] | None = None,
        platform: Any = "static-floor",
        platform_speed: float | tuple[float, float] | None = None,
        sensing: Any = None,
        dynamics: PointMassParams | dict | None = None,
        seed: int | None = None,
        neighbour_radius: float | None = None,
        collision_credit: Literal["swarm", "involved"] = "swarm",
        separation_penalty: float = 0.0,
        separation_margin: float = 0.22,
        shield: SafetyFilterConfig | dict[str, Any] | None = None,
        shield_penalty: float = 0.0,
        drone_episode_ends: bool = False,
    ) -> None:
        if collision_credit not in ("swarm", "involved"):
            raise ValueError(f"collision_credit must be 'swarm' or 'involved', got {collision_credit!r}.")
        if not (np.isfinite(separation_penalty) and separation_penalty >= 0):
            raise ValueError(f"separation_penalty must be a finite number >= 0, got {separation_penalty!r}.")
        if not (np.isfinite(separation_margin) and separation_margin > 0):
            raise ValueError(f"separation_margin must be a finite distance > 0 m, got {separation_margin!r}.")
        self.collision_credit, self.separation_penalty = collision_credit, float(separation_penalty)
        self.separation_margin = float(separation_margin)
        if not (np.isfinite(shield_penalty) and shield_penalty >= 0):
            raise ValueError(f"shield_penalty must be a finite number >= 0, got {shield_penalty!r}.")
        if shield_penalty and shield is None:
            raise ValueError("shield_penalty needs a shield: pass shield=SafetyFilterConfig() (or its dict).")
        self.shield = SafetyFilterConfig.from_dict(shield) if isinstance(shield, dict) else shield
        if self.shield is not None and self.shield.pad_lead > 0:
            raise ValueError(
                "The training shield has no pad lead (the shared policy sees no pad velocity); set pad_lead=0."
            )
        if self.shield is not None and self.shield.latency_compensation > 0:
            raise ValueError(
                "The training shield has no latency compensation (the policy learns on the observations as they "
                "come, and the latency it trains with is the dynamics family's); set latency_compensation=0."
            )
        if self.shield is not None and self.shield.low_velocity_step > 0:
            raise ValueError(
                "The training shield has no velocity-step limit (the shared policy sees no pad velocity, and the limit "
                "is a rule of the flight, not of training); set low_velocity_step=0."
            )
        self.shield_penalty = float(shield_penalty)
        if drone_episode_ends and collision_credit != "involved":
            raise ValueError(
                "drone_episode_ends needs collision_credit='involved': eq. 6 is charged to the drones whose episode "
                f"it ends, not to the swarm flying on; got collision_credit={collision_credit!r}."
            )
        self.drone_episode_ends = bool(drone_episode_ends)
        sizes = tuple(swarm_sizes)
        if not sizes or any(isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1 for n in sizes):
            raise ValueError(f"swarm_sizes must be a non-empty sequence of integers >= 1, got {swarm_sizes!r}.")
        counts = (swarms_per_size,) * len(sizes) if isinstance(swarms_per_size, int | np.integer) else swarms_per_size
        counts = tuple(counts)
        if len(counts) != len(sizes) or any(not isinstance(c, int | np.integer) or c < 1 for c in counts):
            raise ValueError(
                f"swarms_per_size must be an integer >= 1 or one per swarm size {sizes}, got {swarms_per_size!r}."
            )
        if isinstance(neighbours, bool) or not isinstance(neighbours, int | np.integer) or neighbours < 1:
            raise ValueError(f"neighbours must be an integer >= 1, got {neighbours!r}.")
        self.swarm_sizes, self.swarms_per_size, self.neighbours = sizes, counts, int(neighbours)
        self.neighbour_radius = neighbour_radius
        self.groups: list[LandingEpisodes] = []
        self.pad_offsets: list[np.ndarray] = []
        for g, (n, e) in enumerate(zip(sizes, counts, strict=True)):
            options: dict[str, Any] = {"task": dict(task or {}), "sensing": sensing, "platform": platform}
            if platform_speed is not None:
                options["platform_speed"] = platform_speed
            if dynamics is not None:
                options["dynamics"] = dynamics
            sim, sensing_config = build_simulator(int(e), num_drones=int(n), **options)
            self.groups.append(LandingEpisodes(sim, sensing_config, None if seed is None else seed + g))
            self.pad_offsets.append(sim.motion.pad_offsets)
        self.task: TaskConfig = self.groups[0].task
        if self.drone_episode_ends and self.task.observe_platform_acceleration:
            raise ValueError(
                "drone_episode_ends cannot relaunch a drone whose input holds the pad-acceleration estimate; "
                "set observe_platform_acceleration=False."
            )
        self.render_mode = None
        bounds = np.ones(shared_obs_size(self.neighbours, self.task.obs_per_drone), dtype=np.float32) * np.float32(
            max(OBS_LIMITS) * 2
        )
        self._slices = np.cumsum([0] + [n * e for n, e in zip(sizes, counts, strict=True)])
        self._actions: np.ndarray | None = None
        self._elapsed = 0.0
        self._last_obs: list[np.ndarray] = [np.empty(0)] * len(self.groups)
        """Each group's latest eq. 2 observations ``(E_g, N_g, 13)``, what the shield reads."""
        super().__init__(
            int(self._slices[-1]),
            spaces.Box(-bounds, bounds, dtype=np.float32),
            spaces.Box(-1.0, 1.0, shape=(ACT_PER_DRONE,), dtype=np.float32),
        )

    # ------------------------------------------------------------------ helpers
    def _inputs(self, g: int, obs: np.ndarray) -> np.ndarray:
        """``(E_g, N_g, 13)`` observations -> ``(E_g N_g, 13 + 7 k)`` float32 entries."""
        shared = shared_observations(obs, self.pad_offsets[g], self.neighbours, self.neighbour_radius)
        return shared.reshape(-1, shared.shape[-1]).astype(np.float32)

    def group_of(self, entry: int) -> tuple[int, int, int]:
        """``(group, swarm, drone)`` of entry ``entry``."""
        g = int(np.searchsorted(self._slices, entry, side="right") - 1)
        swarm, drone = divmod(entry - int(self._slices[g]), int(self.swarm_sizes[g]))
        return g, swarm, drone

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> np.ndarray:
        if self._seeds[0] is not None:
            for g, episodes in enumerate(self.groups):
                episodes.seed(self._seeds[0] + g)
        self._reset_seeds()
        self._reset_options()
        self._last_obs = [ep.reset() for ep in self.groups]
        return np.concatenate([self._inputs(g, obs) for g, obs in enumerate(self._last_obs)])

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async().")
        actions, self._actions = self._actions, None
        if actions.shape != (self.num_envs, ACT_PER_DRONE):
            raise ValueError(f"Actions have shape {actions.shape}; expected ({self.num_envs}, {ACT_PER_DRONE}).")
        self._elapsed += self.task.dt
        obs, rewards, dones = [], [], []
        infos: list[Any] = [_NO_INFO] * self.num_envs
        for g, episodes in enumerate(self.groups):
            n, e = self.swarm_sizes[g], self.swarms_per_size[g]
            lo, hi = int(self._slices[g]), int(self._slices[g + 1])
            group_actions = actions[lo:hi].reshape(e, n, ACT_PER_DRONE)
            correction = None
            if self.shield is not None:
                group_actions, correction = filter_actions(
                    self._last_obs[g], group_actions, self.pad_offsets[g], self.task.max_speed, self.shield
                )
            outcome = episodes.step(group_actions)
            nearest = self._nearest(episodes)
            group_rewards = self._separation_aids(outcome, nearest)  # before the resets below
            if self.shield_penalty:
                flying = ~outcome.landed | outcome.landed_now
                group_rewards = group_rewards - self.shield_penalty * correction * flying
            rewards.append(group_rewards.reshape(-1))
            raw = outcome.obs
            group_obs = self._inputs(g, raw)
            done, ended = outcome.done, None
            truncated = np.broadcast_to(outcome.truncated[:, None], outcome.landed.shape)
            if self.drone_episode_ends:
                settled = outcome.landed.all(axis=-1)
                time_up = (episodes.steps >= self.task.max_steps) & ~settled
                done = settled | time_up
                assert nearest is not None  # drone_episode_ends implies collision_credit="involved"
                hit = outcome.crashed | outcome.out_of_arena | (nearest < self.task.collision_distance)
                truncated = time_up[:, None] & ~hit  # a drone that crashed at the last step did not run out of time
                ended = hit & ~outcome.landed & ~done[:, None]
                if ended.any():
                    entries = np.flatnonzero(ended.reshape(-1))
                    for entry in entries.tolist():
                        infos[lo + entry] = {
                            "terminal_observation": group_obs[entry].copy(),
                            "TimeLimit.truncated": False,
                        }
                    raw = raw.copy()
                    raw[ended] = episodes.relaunch(ended)
                    group_obs = self._inputs(g, raw)
            if done.any():
                ids = np.flatnonzero(done)
                self._finish(infos, lo, n, ids, outcome, group_obs, truncated)
                raw = raw.copy()
                raw[ids] = episodes.reset(ids)
                group_obs = group_obs.reshape(e, n, -1)
                group_obs[ids] = self._inputs(g, raw[ids]).reshape(len(ids), n, -1)
                group_obs = group_obs.reshape(e * n, -1)
            self._last_obs[g] = raw
            obs.append(group_obs)
            entry_done = np.repeat(done, n)
            dones.append(entry_done if ended is None else entry_done | ended.reshape(-1))
        return np.concatenate(obs), np.concatenate(rewards).astype(np.float32), np.concatenate(dones), infos

    def _nearest(self, episodes: LandingEpisodes) -> np.ndarray | None:
        """Each drone's distance to its nearest other drone ``(E, N)`` m, from the true positions (the aids judge the
        flight, not its noisy measurement); None where no aid needs it."""
        if self.collision_credit == "swarm" and not self.separation_penalty:
            return None
        pos = episodes.sim.state().pos
        return np.sqrt(pairwise_offsets(pos)[1].min(axis=-1))  # sqrt is monotone: the nearest's distance

    def _separation_aids(self, outcome: StepOutcome, nearest: np.ndarray | None) -> np.ndarray:
        """``outcome.agent_rewards`` ``(E, N)`` with the separation aids of the module doc applied (``nearest`` from
        :meth:`_nearest`)."""
        rewards = outcome.agent_rewards
        if nearest is None:
            return rewards
        rewards = rewards.copy()
        if self.collision_credit == "involved":
            alpha_c = self.task.alpha_c
            rewards += alpha_c * outcome.collided[:, None]  # undo eq. 6's charge to the whole swarm ...
            rewards -= alpha_c * (nearest < self.task.collision_distance)  # ... and charge the drones in it
        if self.separation_penalty:
            flying = ~outcome.landed | outcome.landed_now
            rewards -= self.separation_penalty * np.maximum(self.separation_margin - nearest, 0.0) * flying
        return rewards

    def _finish(
        self,
        infos: list[Any],
        lo: int,
        n: int,
        ids: np.ndarray,
        outcome: StepOutcome,
        entries: np.ndarray,
        truncated: np.ndarray,
    ) -> None:
        """Fill the infos of the drones of the swarms ``ids`` whose episodes just ended (``truncated`` ``(E, N)``: each
        drone cut off by the time limit)."""
        for swarm in ids.tolist():
            landed = outcome.landed[swarm]
            errors = outcome.landing_error[swarm][landed]
            base = lo + swarm * n
            for drone in range(n):
                infos[base + drone] = {
                    "terminal_observation": entries[swarm * n + drone].copy(),
                    "TimeLimit.truncated": bool(truncated[swarm, drone]),
                }
            infos[base].update(
                is_success=bool(outcome.success[swarm]),
                landing_error=float(errors.mean()) if errors.size else float("nan"),
                landing_time=float(outcome.landing_time[swarm].max()) if landed.all() else float("nan"),
                min_separation=float(outcome.min_separation[swarm]),
                num_drones=n,
                episode={
                    "r": float(outcome.episode_return[swarm]) / n,
                    "l": int(outcome.episode_length[swarm]),
                    "t": self._elapsed,
                },
            )

    def close(self) -> None:
        for episodes in self.groups:
            episodes.sim.close()
