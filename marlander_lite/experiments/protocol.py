"""The trial protocol of the paper's experiments (Sec. IV-B to IV-E), seeded and run in parallel.

A *condition* is a platform set-up: the plate on the floor (``static-floor``, Fig. 7a), held
still by the UR10 (``static-elevated``, Fig. 7b), or moved by it along a straight stroke
(``moving-linear-S``, Fig. 7c) or a base swing within -pi/2..pi/2 (``moving-arc-S``) at tool
speed ``S`` in 0.2, 0.3, 0.4, 0.5 m/s (Sec. IV-C). A *trial* is one episode: the platform and the
drones are placed at random in the 4 x 4 x 4 m arena (as in training, Sec. III-E), the
controller flies until every drone has landed, something failed, or the time limit is reached.

Determinism: trial ``k`` of condition ``c`` is seeded by ``trial_seed(seed, c, k)`` alone, so
it starts from the same platform placement and drone positions, and sees the same sensor noise,
whichever controller flies it and however many worker processes share the work. Work is split
into fixed blocks of trials (independent of the worker count), each flown by a fresh
environment in one process.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from marlander_lite.distributed import Backend, map_jobs
from marlander_lite.envs.options import policy_input
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.experiments.apf import APFConfig
from marlander_lite.experiments.controllers import (
    CONTROLLERS,
    PAPER_CONTROLLERS,
    POLICY_CONTROLLERS,
    Controller,
    ControllerName,
    ControllerSpec,
    build_controller,
    check_controller_name,
)
from marlander_lite.experiments.metrics import TrialMetrics
from marlander_lite.make import SimulatorName
from marlander_lite.pad_frame_lead import PadFrameLead, describe_lead, lead_changes
from marlander_lite.platforms import PlatformConfig, PlatformKind
from marlander_lite.sensing import SensingConfig
from marlander_lite.simulators import simulator_entry
from marlander_lite.task import TaskConfig

ConditionName = Literal[
    "static-floor",
    "static-elevated",
    "moving-linear-0.2",
    "moving-linear-0.3",
    "moving-linear-0.4",
    "moving-linear-0.5",
    "moving-arc-0.2",
    "moving-arc-0.3",
    "moving-arc-0.4",
    "moving-arc-0.5",
]
CONDITION_NAMES: tuple[str, ...] = get_args(ConditionName)
Group = Literal["static", "moving"]
GROUPS: tuple[str, ...] = get_args(Group)
SensingName = Literal["vicon", "perfect"]
SENSING_NAMES: tuple[str, ...] = get_args(SensingName)

PAPER_TRIALS: dict[str, dict[str, int]] = {
    "marlander": {"static": 12, "moving": 8},
    "baseline": {"static": 10, "moving": 10},
    "single-agent-apf": {"static": 12, "moving": 8},
    "marlander-plus": {"static": 12, "moving": 8},
    "baseline-tuned": {"static": 10, "moving": 10},
}
"""Trials per controller and group in the paper: 12 static (6 floor + 6 UR10) and 8 moving for
MARLander (Sec. IV-B/C), 10 each for the baseline (Sec. IV-D). The paper gives no count for
MorphoLander: we use MARLander's."""


@dataclass(frozen=True)
class Condition:
    """One platform set-up of the experiments."""

    name: ConditionName
    """``static-floor``, ``static-elevated``, ``moving-linear-S`` or ``moving-arc-S``."""
    kind: PlatformKind
    """Platform motion (:data:`marlander_lite.platforms.PLATFORM_KINDS`)."""
    speed: float
    """Tool speed (m/s); 0 for static platforms."""

    @property
    def group(self) -> Group:
        """``static`` (Table I) or ``moving`` (Table II)."""
        return "static" if self.speed == 0 else "moving"

    def platform(self) -> PlatformConfig:
        """The :class:`PlatformConfig` of this condition (default UR10 set-up and plate)."""
        return PlatformConfig(kind=self.kind, speed=self.speed if self.speed > 0 else None)


def condition(name: str) -> Condition:
    """The :class:`Condition` called ``name``; unknown names raise listing the allowed ones."""
    if name not in CONDITION_NAMES:
        raise ValueError(f"Unknown condition {name!r}; allowed: {', '.join(CONDITION_NAMES)}.")
    if name.startswith("static"):
        return Condition(name, name, 0.0)  # type: ignore[arg-type]
    kind, _, speed = name.rpartition("-")
    return Condition(name, kind, float(speed))  # type: ignore[arg-type]


CONDITIONS: tuple[Condition, ...] = tuple(condition(name) for name in CONDITION_NAMES)


def trial_seed(seed: int, condition_name: str, trial: int) -> int:
    """Seed of trial ``trial`` of ``condition_name``: depends on nothing else (not the controller).

    A :class:`numpy.random.SeedSequence` of ``seed`` spawned by (CRC-32 of the condition name,
    trial index), reduced to one 63-bit integer that the CSV records.
    """
    key = (zlib.crc32(condition_name.encode()), int(trial))
    state = np.random.SeedSequence(int(seed), spawn_key=key).generate_state(2, dtype=np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1]))


@dataclass(frozen=True)
class ProtocolConfig:
    """Everything that defines a reproduction run."""

    simulator: SimulatorName = "pointmass"
    """``pointmass`` (fast) or ``crazyflie`` (PyBullet, cascaded PID)."""
    controllers: tuple[ControllerName, ...] = PAPER_CONTROLLERS  # type: ignore[assignment]
    """Which controllers to fly (default: the paper's three)."""
    conditions: tuple[ConditionName, ...] = CONDITION_NAMES  # type: ignore[assignment]
    """Which conditions to fly them on."""
    trials: int | Literal["paper"] = 100
    """Trials per controller and condition, or ``"paper"`` for the paper's counts (:data:`PAPER_TRIALS`),
    spread over the selected conditions of each group."""
    seed: int = 0
    """Base seed of every trial (:func:`trial_seed`)."""
    sensing: SensingName = "vicon"
    """``vicon``: motion-capture noise and 20 ms latency (:meth:`SensingConfig.vicon`); ``perfect``: none."""
    time_limit_s: float = 30.0
    """A trial fails if the drones have not all landed after this long (s). The paper's slowest mean
    landing time is 28 s (baseline, moving platform)."""
    num_drones: int = 2
    """Drones per swarm (the paper flies 2)."""
    policy_paths: dict[str, Path] = field(default_factory=dict)
    """Policy file per controller name; defaults: the simulator's in
    :data:`~marlander_lite.experiments.controllers.DEFAULT_POLICIES`."""
    apf: APFConfig = field(default_factory=APFConfig)
    """Gains of the PID + APF baseline (and the repulsion of single-agent + APF)."""
    workers: int = 2
    """Worker processes; 1 runs everything in this process."""
    block_size: int = 10
    """Trials per unit of work; fixed, so the results do not depend on ``workers``."""
    pad_frame_lead: PadFrameLead | None = None
    """Beyond the paper: None, or the lead (s) the run's pad-frame policies fly with instead of their files'
    (``TaskConfig.pad_frame_lead``), or ``"auto"`` (set in flight from the identified tracker,
    :mod:`marlander_lite.pad_frame_lead`), a flight setting as ``marlander transfer --pad-frame-lead`` and the lab
    config's ``limits.pad_frame_lead``; 0 to 2 s, refused if no controller of the run flies a pad-frame policy."""

    def __post_init__(self) -> None:
        simulator_entry(self.simulator)  # an unknown name raises, listing the registered ones
        if not self.controllers:
            raise ValueError(f"Give at least one controller; allowed: {', '.join(CONTROLLERS)}.")
        for name in self.controllers:
            check_controller_name(name)
        if not self.conditions:
            raise ValueError(f"Give at least one condition; allowed: {', '.join(CONDITION_NAMES)}.")
        for name in self.conditions:
            condition(name)
        if self.trials != "paper" and (isinstance(self.trials, bool) or not isinstance(self.trials, int)):
            raise ValueError(f"trials must be a positive integer or 'paper', got {self.trials!r}.")
        if self.trials != "paper" and self.trials < 1:
            raise ValueError(f"trials must be a positive integer or 'paper', got {self.trials}.")
        if self.sensing not in SENSING_NAMES:
            raise ValueError(f"Unknown sensing {self.sensing!r}; allowed: {', '.join(SENSING_NAMES)}.")
        if not (np.isfinite(self.time_limit_s) and self.time_limit_s > 0):
            raise ValueError(f"time_limit_s must be > 0 s, got {self.time_limit_s!r}.")
        if self.pad_frame_lead is not None:
            lead_changes(self.pad_frame_lead)  # seconds within range, or "auto"; else a ValueError saying so
        if self.workers < 1 or self.block_size < 1:
            raise ValueError(f"workers and block_size must be >= 1, got {self.workers} and {self.block_size}.")
        unknown = sorted(set(self.policy_paths) - set(POLICY_CONTROLLERS))
        if unknown:
            raise ValueError(
                f"policy_paths has unknown controller(s) {unknown}; allowed: {', '.join(POLICY_CONTROLLERS)}."
            )

    def task(self, controller_name: str | None = None) -> TaskConfig:
        """The task of every trial: the defaults with ``num_drones`` and the time limit.

        With ``controller_name``, the observation also carries the extras that controller's policy file asks for
        (the platform velocity, the previous command, the platform acceleration: ``task.OBSERVATION_OPTIONS``), and
        its commands are read in its frame (``TaskConfig.command_frame``). The trials' starts do not depend on them.
        """
        observe = self.spec(controller_name).interface_options() if controller_name is not None else {}
        if self.pad_frame_lead is not None and observe.get("command_frame") == "pad":
            observe = {**observe, **lead_changes(self.pad_frame_lead)}
        return TaskConfig(num_drones=self.num_drones, episode_seconds=self.time_limit_s, **observe)

    def sensing_config(self) -> SensingConfig:
        return SensingConfig.vicon() if self.sensing == "vicon" else SensingConfig()

    def spec(self, controller_name: str) -> ControllerSpec:
        """The picklable description of one controller of this run."""
        path = self.policy_paths.get(controller_name)
        return ControllerSpec(controller_name, path, self.apf, self.simulator)  # type: ignore[arg-type]

    def trial_counts(self, controller_name: str) -> dict[str, int]:
        """Trials of ``controller_name`` per selected condition.

        With ``trials="paper"`` each group's paper count is dealt out over the group's selected
        conditions in order (e.g. 12 static -> 6 floor + 6 elevated; 8 moving -> 1 per moving condition).
        """
        if self.trials != "paper":
            return {name: int(self.trials) for name in self.conditions}
        counts: dict[str, int] = {}
        for group in GROUPS:
            names = [n for n in self.conditions if condition(n).group == group]
            if not names:
                continue
            total = PAPER_TRIALS[controller_name][group]
            for i, name in enumerate(names):
                counts[name] = total // len(names) + (1 if i < total % len(names) else 0)
        return {name: counts[name] for name in self.conditions if counts[name] > 0}


@dataclass(frozen=True)
class TrialRecord:
    """One row of ``trials.csv``: which trial, and what it measured."""

    simulator: str
    controller: str
    condition: str
    trial: int
    seed: int
    metrics: TrialMetrics

    @property
    def group(self) -> Group:
        return condition(self.condition).group


@dataclass(frozen=True)
class WorkUnit:
    """A block of trials of one controller on one condition: what a worker process flies."""

    spec: ControllerSpec
    condition: ConditionName
    trials: tuple[int, ...]


@dataclass
class Trajectory:
    """Positions of one trial over time, for Fig. 7."""

    time_s: np.ndarray
    """``(T,)`` s, starting at 0."""
    drone_pos: np.ndarray
    """``(T, N, 3)`` m, world frame."""
    pad_pos: np.ndarray
    """``(T, N, 3)`` m: centre of each drone's own pad."""
    metrics: TrialMetrics


def make_episodes(config: ProtocolConfig, cond: Condition, controller_name: str | None = None) -> LandingEpisodes:
    """A one-swarm :class:`LandingEpisodes` of ``config.simulator`` for ``cond``, with ``config``'s sensing.

    The simulator is the registry's class (:func:`~marlander_lite.simulators.simulator_entry`, imported on
    first use: PyBullet only if asked), built as ``Swarm(task, platform, num_envs=1)`` with its default
    physics; the episodes are the same MDP the gym, SB3 and PettingZoo faces wrap. ``controller_name``
    picks the observation layout its policy asks for (:meth:`ProtocolConfig.task`).
    """
    swarm = simulator_entry(config.simulator).swarm_class()
    simulator = swarm(config.task(controller_name), cond.platform(), 1)
    return LandingEpisodes(simulator, config.sensing_config())


def fly_trial(
    controller: Controller, episodes: LandingEpisodes, seed: int, record: bool = False
) -> tuple[TrialMetrics, Trajectory | None]:
    """Fly one trial: reset with ``seed``, act until the episode ends, return its metrics.

    The controller sees what a policy sees: the float32 centralised observation with the
    sensing model applied. With ``record=True`` the true drone and pad positions of every step
    come back as a :class:`Trajectory`.
    """
    episodes.seed(seed)
    obs = episodes.reset()
    controller.reset()
    trace: list[tuple[np.ndarray, np.ndarray]] = []

    def snapshot() -> None:
        state = episodes.sim.state()
        trace.append((state.pos[0].copy(), state.pad_pos[0].copy()))

    if record:
        snapshot()
    while True:
        action = controller.act(policy_input(obs)[0])
        outcome = episodes.step(np.asarray(action, dtype=np.float64)[None, :])
        if record:
            snapshot()
        if outcome.done[0]:
            break
        obs = outcome.obs
    metrics = TrialMetrics.from_outcome(outcome, episodes.task.dt)
    if not record:
        return metrics, None
    drones, pads = (np.stack(x) for x in zip(*trace, strict=True))
    return metrics, Trajectory(np.arange(len(trace)) * episodes.task.dt, drones, pads, metrics)


def run_unit(config: ProtocolConfig, unit: WorkUnit) -> list[TrialRecord]:
    """Fly one block of trials in a fresh environment (called in a worker process)."""
    cond = condition(unit.condition)
    episodes = make_episodes(config, cond, unit.spec.name)
    try:
        controller = build_controller(unit.spec, episodes.task, cond.platform().geometry)
        records = []
        for k in unit.trials:
            seed = trial_seed(config.seed, cond.name, k)
            metrics, _ = fly_trial(controller, episodes, seed)
            records.append(TrialRecord(config.simulator, unit.spec.name, cond.name, k, seed, metrics))
        return records
    finally:
        episodes.sim.close()


def plan(config: ProtocolConfig) -> list[WorkUnit]:
    """Every block of trials of the run, in table order (controller, condition, trial)."""
    units = []
    for name in config.controllers:
        spec = config.spec(name)
        for cond_name, count in config.trial_counts(name).items():
            for start in range(0, count, config.block_size):
                trials = tuple(range(start, min(start + config.block_size, count)))
                units.append(WorkUnit(spec, cond_name, trials))  # type: ignore[arg-type]
    return units


def check_policies(config: ProtocolConfig) -> None:
    """Build each controller once here, so a missing or unfit policy file, or a lead with no pad-frame policy to
    fly it, fails before any work starts."""
    for name in config.controllers:
        build_controller(config.spec(name), config.task(name))
    if config.pad_frame_lead is not None and all(
        config.task(name).command_frame != "pad" for name in config.controllers
    ):
        raise ValueError(
            f"pad_frame_lead {describe_lead(config.pad_frame_lead)} leads the commands of a pad-frame policy, and no "
            f"controller of this run ({', '.join(config.controllers)}) flies one: drop --pad-frame-lead, or give a "
            "policy trained with command_frame='pad' (e.g. --marlander-plus-policy "
            "data/policies/paper-moving-slow-trackers-fast-vertical.safetensors)."
        )


def run_protocol(
    config: ProtocolConfig,
    progress: Callable[[int, int], Any] | None = None,
    *,
    backend: Backend = "local",
    address: str | None = None,
) -> list[TrialRecord]:
    """Fly every trial of ``config`` and return the records sorted by controller, condition, trial.

    Args:
        config: the run.
        progress: called as ``progress(done_trials, total_trials)`` after each finished block.
        backend: ``local`` (``config.workers`` processes here) or ``ray`` (one Ray task per block of trials,
            :func:`marlander_lite.distributed.map_jobs`). Every trial has its own seed, so the records are the
            same whichever backend flies them. On a multi-machine cluster every node needs the policy files at
            the paths ``config`` names (e.g. the project on a shared file system).
        address: the Ray cluster (``None``: a private one on this machine, ``auto``, or ``HOST:PORT``).
    """
    check_policies(config)
    units = plan(config)
    total = sum(len(u.trials) for u in units)
    records: list[TrialRecord] = []
    jobs = [(config, unit) for unit in units]
    for _, block in map_jobs(_run_job, jobs, backend=backend, workers=config.workers, address=address):
        if isinstance(block, Exception):
            raise block
        records.extend(block)
        if progress is not None:
            progress(len(records), total)
    order_controller = {name: i for i, name in enumerate(config.controllers)}
    order_condition = {name: i for i, name in enumerate(CONDITION_NAMES)}
    records.sort(key=lambda r: (order_controller[r.controller], order_condition[r.condition], r.trial))
    return records


def _run_job(job: tuple[ProtocolConfig, WorkUnit]) -> list[TrialRecord]:
    return run_unit(*job)


def record_trajectory(config: ProtocolConfig, controller_name: str, condition_name: str, trial: int = 0) -> Trajectory:
    """Re-fly one trial (same seed as in the tables) and record its trajectory (Fig. 7)."""
    cond = condition(condition_name)
    episodes = make_episodes(config, cond, controller_name)
    try:
        controller = build_controller(config.spec(controller_name), episodes.task, cond.platform().geometry)
        _, trajectory = fly_trial(controller, episodes, trial_seed(config.seed, cond.name, trial), record=True)
    finally:
        episodes.sim.close()
    assert trajectory is not None
    return trajectory
