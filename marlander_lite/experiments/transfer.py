"""The transfer matrix: one policy flown on every simulator and velocity tracker it may meet.

A policy is judged where it will fly, not where it was trained. :func:`transfer_matrix` flies one
policy file on each *column* (the point mass; PyBullet with our cascaded PID; PyBullet with the
Crazyflie firmware's own velocity tracker; that tracker perturbed: a 15 % heavier drone, 60 ms of
command latency, velocity-loop gains x0.7 and x1.3; every PyBullet column with ground effect, drag
and downwash on) and each *row* (the pad on the floor, on the UR10 flange, moving along an arc or a
line at 0.2-0.5 m/s). Every column flies the same random starts (one seed per row and episode). Three more columns
are flown only when asked for (:data:`EXTRA_COLUMNS`): the three sluggish perturbations at once, a held-out tracker
(gym-pybullet-drones' published PID gains, no tilt limit, bare physics) that nothing here was tuned on, and RotorPy, a
simulator this project did not write.

Besides success (with a Wilson interval) and landing error, each cell measures whether the flight is
one a real Crazyflie can follow:

* ``touchdown_speed``: mean speed relative to the pad at each drone's first contact (m/s);
* ``command_near_pad_p95``: 95th percentile of the commanded speed relative to the pad while a drone
  is within 0.5 m of its goal (m/s); for a pad-frame policy (``TaskConfig.command_frame``) its own command, without
  the lead the loop adds (``pad_frame_lead``);
* ``tilt_limit_fraction``: share of flying steps with the tilt within 1 degree of the firmware's 20
  degree limit or beyond (on the firmware columns: how long the tracker is saturated);
* ``approach_height``: height above the pad when a drone first comes within 0.5 m of it horizontally (m).

And why the failed episodes failed (:class:`~marlander_lite.experiments.metrics.TrialMetrics` outcomes, the crashes
split by touchdown speed): ``collisions``, ``crashes_too_fast`` (a contact faster than the task's touchdown limit,
0.5 m/s relative to the pad), ``crashes_off_pad`` (a slow contact with anything but the drone's own pad, or off its
centre), ``out_of_arena`` and ``timeouts``.

``marlander transfer POLICY`` prints the table and writes ``transfer.csv`` and ``transfer.json``. With
``--safety-filter`` (:attr:`TransferConfig.safety_filter`) every command goes through the safety filter that
``marlander deploy`` puts after the policy (:mod:`marlander_lite.swarm.safety_filter`): the matrix of the flight a lab
flies, and the commands measured are the filtered ones. The filter reads each pad's velocity from the simulator, as
the deployment loop reads it from motion capture, and filters a pad-frame policy's world command, lead included.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent import futures
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite import task, training_aids
from marlander_lite.crazyflie.perturb import HELD_OUT_TRACKER
from marlander_lite.envs.options import policy_input
from marlander_lite.episodes import LandingEpisodes, StepOutcome
from marlander_lite.experiments.cell_journal import CellJournal
from marlander_lite.experiments.metrics import TrialMetrics, wilson_interval
from marlander_lite.experiments.protocol import trial_seed
from marlander_lite.pad_frame_lead import (
    PadFrameLead,
    describe_lead,
    describe_policy_lead,
    flies_policy_lead,
    lead_changes,
)
from marlander_lite.policy_file import MLPPolicy, load_policy
from marlander_lite.rotations import tilt_deg
from marlander_lite.simulators import simulator_entry
from marlander_lite.swarm.filtered_policy import with_safety_filter_on
from marlander_lite.swarm.policy import SharedPolicy
from marlander_lite.swarm.safety_filter import SafetyFilterConfig
from marlander_lite.swarm.tracker_lag import TrackerLag

NEAR_PAD = 0.5
"""Distance to the goal (m) within which commanded speeds are measured, and horizontal distance at which the
approach height is read."""
TILT_LIMIT_DEG = 20.0
"""The Crazyflie firmware's roll/pitch clamp (deg), the reference for ``tilt_limit_fraction``."""


@dataclass(frozen=True)
class Column:
    """A simulator with its options: one column of the matrix."""

    name: str
    simulator: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Row:
    """A platform condition: one row of the matrix."""

    name: str
    platform: str
    speed: tuple[float, float] | None = None


def _firmware(**perturbation: float) -> dict[str, Any]:
    options: dict[str, Any] = {"controller": "firmware"}
    if perturbation:
        options["perturbation"] = perturbation
    return options


COLUMNS: tuple[Column, ...] = (
    Column("point mass", "pointmass"),
    Column("PyBullet PID", "crazyflie"),
    Column("PyBullet firmware", "crazyflie", _firmware()),
    Column("firmware mass +15 %", "crazyflie", _firmware(mass_scale=1.15)),
    Column("firmware latency 60 ms", "crazyflie", _firmware(latency_s=0.06)),
    Column("firmware gains x0.7", "crazyflie", _firmware(gain_scale=0.7)),
    Column("firmware gains x1.3", "crazyflie", _firmware(gain_scale=1.3)),
)
"""The simulators a policy is flown on; the PyBullet ones use the default ``aero`` physics."""

EXTRA_COLUMNS: tuple[Column, ...] = (
    Column("firmware combined", "crazyflie", _firmware(mass_scale=1.15, latency_s=0.06, gain_scale=0.7)),
    Column("held-out DSL PID", "crazyflie", HELD_OUT_TRACKER),
    Column("RotorPy Crazyflie", "rotorpy"),
    Column("PyFlyt Crazyflie", "pyflyt", {"read_state": "before_physics"}),
    Column("PyFlyt Crazyflie 0.22", "pyflyt", {"read_state": "after_physics"}),
)
"""Columns flown only when asked for (``--columns``, or ``all``):

* ``firmware combined``: the three sluggish perturbations at once, a 15 % heavier drone whose commands arrive 60 ms
  late at velocity gains x0.7, a tracker none of the columns above is;
* ``held-out DSL PID``: a tracker no policy or setting of this project was tuned on
  (:data:`~marlander_lite.crazyflie.perturb.HELD_OUT_TRACKER`: the cascaded PID with the gains gym-pybullet-drones
  publishes, no tilt limit, its under-damped attitude loop at 48 Hz, over that project's default physics). The kind of
  independent simulator a lab reaches for first;
* ``RotorPy Crazyflie``: a simulator this project did not write, RotorPy's Crazyflie under RotorPy's own velocity
  controller (:mod:`marlander_lite.rotorpy_sim.simulator`; the optional extra ``rotorpy``);
* ``PyFlyt Crazyflie``: a second one, PyFlyt's Crazyflie under PyFlyt's own cascaded PID
  (:mod:`marlander_lite.pyflyt_sim.simulator`; the optional extra ``pyflyt``), stepped as the pinned 0.21.0 steps it:
  its controllers read every state one physics step late, which leaves its ``cf2x`` wandering along y;
* ``PyFlyt Crazyflie 0.22``: the same, stepped as PyFlyt does since 0.22 (states read after the physics step), the
  PyFlyt its users fly today (``read_state`` in :class:`~marlander_lite.pyflyt_sim.envs.PyFlytOptions`)."""

ROWS: tuple[Row, ...] = (
    Row("floor", "static-floor"),
    Row("UR10", "static-elevated"),
    Row("arc 0.2-0.5 m/s", "moving-arc", (0.2, 0.5)),
    Row("line 0.2-0.5 m/s", "moving-linear", (0.2, 0.5)),
)
"""The platform conditions; moving rows draw the tool speed per episode."""


@dataclass(frozen=True)
class CellResult:
    """How one policy did on one (row, column) cell."""

    row: str
    column: str
    episodes: int
    successes: int
    success_rate: float
    wilson_low: float
    wilson_high: float
    landing_error_cm: float
    """Mean horizontal distance from the pad centre over landed drones of successful episodes (cm)."""
    landing_time_s: float
    """Mean time until the last drone landed, successful episodes (s)."""
    collision_rate: float
    touchdown_speed: float
    command_near_pad_p95: float
    tilt_limit_fraction: float
    approach_height: float
    wall_s: float
    collisions: int | None = None
    """Episodes ended by two drones closer than the collision distance (None: matrix written before causes were
    counted; so for the four below)."""
    crashes_too_fast: int | None = None
    """Episodes ended by a touchdown faster than ``touchdown_speed_max`` relative to the pad."""
    crashes_off_pad: int | None = None
    """Episodes ended by a slower contact anywhere but within the pad radius of the drone's own pad."""
    out_of_arena: int | None = None
    """Episodes ended by a drone leaving the arena."""
    timeouts: int | None = None
    """Episodes that reached the time limit without every drone landed."""
    identified_lag_s: float | None = None
    """Median over the episodes of the velocity-tracker time constant the safety filter had identified by each
    episode's end (s, ``identified_lag_share``; the compensation flown was that times the share); None: none was."""


def find_column(name: str) -> Column:
    """The column called ``name`` (in :data:`COLUMNS` or :data:`EXTRA_COLUMNS`); unknown names raise, listing them."""
    for column in COLUMNS + EXTRA_COLUMNS:
        if column.name == name:
            return column
    allowed = ", ".join(c.name for c in COLUMNS + EXTRA_COLUMNS)
    raise ValueError(f"Unknown transfer column {name!r}; allowed: {allowed}.")


def find_row(name: str) -> Row:
    """The row called ``name`` (from :data:`ROWS`); an unknown name raises with the list."""
    for row in ROWS:
        if row.name == name:
            return row
    raise ValueError(f"Unknown transfer row {name!r}; allowed: {', '.join(r.name for r in ROWS)}.")


MAX_EPISODE_SECONDS = 120.0
"""Longest episode (s) ``TransferConfig.episode_seconds`` allows: four times the paper protocol's 30 s."""

SHARED_SWARM_SIZE = 2
"""Drones a shared policy flies in the matrix unless told otherwise: the paper's two."""


def build_episodes(
    policy: MLPPolicy,
    column: Column,
    row: Row,
    sensing: str,
    num_drones: int | None = None,
    command_frame: str | None = None,
    pad_frame_lead: PadFrameLead | None = None,
    episode_seconds: float | None = None,
    vertical_bias: bool = False,
) -> LandingEpisodes:
    """One swarm of ``column``'s simulator on ``row``'s platform, with the policy's task and no training aid.

    A shared policy flies ``num_drones`` drones from the paper's starts (its training's start separation, an aid for
    crowded swarms, is not kept); its other task fields (the pairing of starts with pads, say) stay as trained."""
    task_fields = {**policy.contract.task, **training_aids.TRAINING_AIDS_OFF}
    if command_frame is not None:  # flown in another frame than trained (TransferConfig.command_frame)
        task_fields["command_frame"] = command_frame
    if pad_frame_lead is not None:  # seconds, or "auto": set in flight from the identified tracker
        task_fields.update(lead_changes(pad_frame_lead))
    if episode_seconds is not None:  # a longer flight than the training episode (TransferConfig.episode_seconds)
        task_fields["episode_seconds"] = episode_seconds
    if vertical_bias:  # a flight setting: the tracker's steady climb or sink identified and cancelled
        task_fields["vertical_bias_compensation"] = True
    if policy.contract.is_shared:
        task_fields.pop("spawn_separation", None)
    options = dict(
        num_drones=(num_drones or SHARED_SWARM_SIZE) if policy.contract.is_shared else policy.contract.num_drones,
        platform=row.platform,
        platform_speed=row.speed,
        task=task_fields,
        sensing=sensing,
        **column.options,
    )
    options_class = simulator_entry(column.simulator).options_class()
    simulator, sensing_config = options_class.from_keywords(options, where=f"transfer column {column.name!r}").build(1)
    return LandingEpisodes(simulator, sensing_config)


def fly_cell(
    policy_path: str,
    column: str | Column,
    row_name: str,
    episodes: int,
    seed: int,
    sensing: str,
    safety_filter: dict[str, float] | None = None,
    num_drones: int | None = None,
    command_frame: str | None = None,
    pad_frame_lead: PadFrameLead | None = None,
    episode_seconds: float | None = None,
    vertical_bias: bool = False,
) -> CellResult:
    """Fly ``episodes`` episodes of one cell (runs in a worker process). ``safety_filter``: None, or the settings
    (changes to :class:`SafetyFilterConfig`'s defaults, ``{}`` for none) of the deployment's safety filter
    (:mod:`marlander_lite.swarm.safety_filter`), which then changes every command before it is flown. ``column``
    is a column's name or a :class:`Column` (a simulator setting none of the named columns is). ``num_drones``:
    the swarm size a shared policy flies (a centralised one flies its own). ``command_frame``: None (the policy's
    own) or the frame its commands are flown in (``TaskConfig.command_frame``), ``pad_frame_lead`` None, its lead (s)
    or ``"auto"`` (set in flight from the identified tracker, :mod:`marlander_lite.pad_frame_lead`),
    ``episode_seconds`` None (the policy's training episode) or each episode's time limit (s), ``vertical_bias``
    whether each drone's steady vertical velocity bias is identified in flight and cancelled
    (:mod:`marlander_lite.swarm.vertical_bias`).
    """
    started = time.perf_counter()
    policy = load_policy(policy_path)
    column = column if isinstance(column, Column) else find_column(column)
    row = find_row(row_name)
    world = build_episodes(
        policy, column, row, sensing, num_drones, command_frame, pad_frame_lead, episode_seconds, vertical_bias
    )
    cfg = world.task
    lag = tracker_lag(safety_filter, world.task)
    act = cell_actor(policy, world, safety_filter, lag)
    identified: list[float] = []
    successes, collisions = 0, 0
    errors: list[float] = []
    times: list[float] = []
    touchdowns: list[float] = []
    near_commands: list[np.ndarray] = []
    heights: list[float] = []
    tilt_steps = saturated_steps = 0
    failures = dict.fromkeys(FAILURES, 0)
    try:
        for k in range(episodes):
            world.seed(trial_seed(seed, row.name, k))
            obs = world.reset()
            touched = np.zeros(cfg.num_drones, dtype=bool)
            approached = np.zeros(cfg.num_drones, dtype=bool)
            while True:
                action = act(obs)
                command = task.command_velocity(action, cfg, world.sim.state().pad_vel)[0]
                outcome = world.step(action)
                s = world.sim.state()
                flying = ~outcome.landed[0] & ~touched
                rel_pos = s.pos[0] - s.pad_pos[0]
                horizontal = np.hypot(rel_pos[:, 0], rel_pos[:, 1])
                near = flying & (np.linalg.norm(rel_pos, axis=1) <= NEAR_PAD)
                near_commands.append(np.linalg.norm(command - s.pad_vel[0], axis=1)[near])
                first_near = flying & ~approached & (horizontal <= NEAR_PAD)
                heights.extend(rel_pos[first_near, 2].tolist())
                approached |= horizontal <= NEAR_PAD
                tilt = tilt_deg(s.quat[0])
                tilt_steps += int(flying.sum())
                saturated_steps += int((flying & (tilt >= TILT_LIMIT_DEG - 1.0)).sum())
                contact = (outcome.landed_now[0] | outcome.crashed[0]) & ~touched
                touchdowns.extend(outcome.rel_speed[0][contact].tolist())
                touched |= contact
                if outcome.done[0]:
                    break
                obs = outcome.obs
            identifier = lag if lag is not None else world.lead_tracker  # the filter's, or the lead's
            if identifier is not None:
                identified.append(float(identifier.time_constant()[0]))
            collisions += bool(outcome.min_separation[0] < cfg.collision_distance)
            cause = failure_cause(outcome, cfg)
            if cause is not None:
                failures[cause] += 1
            if outcome.success[0]:
                successes += 1
                errors.extend(outcome.landing_error[0].tolist())
                times.append(float(np.nanmax(outcome.landing_time[0])))
    finally:
        world.sim.close()
    low, high = wilson_interval(successes, episodes)
    commands = np.concatenate(near_commands) if near_commands else np.zeros(0)

    def mean(values: list[float], scale: float = 1.0) -> float:
        return float(scale * np.mean(values)) if values else float("nan")

    return CellResult(
        row=row.name,
        column=column.name,
        episodes=episodes,
        successes=successes,
        success_rate=successes / episodes,
        wilson_low=low,
        wilson_high=high,
        landing_error_cm=mean(errors, 100.0),
        landing_time_s=mean(times),
        collision_rate=collisions / episodes,
        touchdown_speed=mean(touchdowns),
        command_near_pad_p95=float(np.percentile(commands, 95)) if commands.size else float("nan"),
        tilt_limit_fraction=saturated_steps / tilt_steps if tilt_steps else float("nan"),
        approach_height=mean(heights),
        wall_s=time.perf_counter() - started,
        **failures,
        identified_lag_s=float(np.median(identified)) if identified else None,
    )


def tracker_lag(safety_filter: dict[str, float] | None, cfg: task.TaskConfig) -> TrackerLag | None:
    """The :class:`TrackerLag` a cell's safety filter identifies its tracker with, so that the cell can report what it
    identified; None without a filter or with ``identified_lag_share`` 0."""
    return None if safety_filter is None else SafetyFilterConfig.from_dict(safety_filter).tracker_lag(cfg.dt)


def fly_episodes(
    world: LandingEpisodes,
    act: Callable[[np.ndarray], np.ndarray],
    row_name: str,
    episodes: int,
    seed: int = 0,
    watch: Callable[[StepOutcome], None] | None = None,
) -> int:
    """Fly ``episodes`` episodes of one cell with ``act`` (each seeded by :func:`trial_seed` from ``seed`` and
    ``row_name``, as :func:`fly_cell` seeds them), calling ``watch(outcome)`` after every step; returns how many
    ended with every drone landed. Closes ``world``'s simulator at the end."""
    successes = 0
    try:
        for k in range(episodes):
            world.seed(trial_seed(seed, row_name, k))
            obs = world.reset()
            while True:
                outcome = world.step(act(obs))
                if watch is not None:
                    watch(outcome)
                if outcome.done[0]:
                    break
                obs = outcome.obs
            successes += bool(outcome.success[0])
    finally:
        world.sim.close()
    return successes


def cell_actor(
    policy: MLPPolicy,
    world: LandingEpisodes,
    safety_filter: dict[str, float] | None,
    lag: TrackerLag | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """Observations ``(1, N, obs_per_drone)`` -> the actions flown ``(1, 3 N)``: the policy's, through the safety
    filter with ``safety_filter``'s settings unless it is None (identifying the tracker with ``lag``, if given)."""

    flown: Any = policy
    if policy.contract.is_shared:  # one network per drone, each with its own input (marlander_lite.swarm)
        flown = SharedPolicy(policy, world.task, world.sim.platform.geometry)

    def act(obs: np.ndarray) -> np.ndarray:
        return flown.act(policy_input(obs))

    if safety_filter is None:
        return act
    return with_safety_filter_on(act, world, SafetyFilterConfig.from_dict(safety_filter), lag)


FAILURES = ("collisions", "crashes_too_fast", "crashes_off_pad", "out_of_arena", "timeouts")
"""The :class:`CellResult` fields that count failed episodes by cause."""


def failure_cause(outcome: StepOutcome, cfg: task.TaskConfig) -> str | None:
    """Which of :data:`FAILURES` ended a failed episode (None for a success), from its last step."""
    result = TrialMetrics.from_outcome(outcome, cfg.dt).outcome
    if result == "crash":
        too_fast = outcome.rel_speed[0][outcome.crashed[0]] > cfg.touchdown_speed_max
        return "crashes_too_fast" if too_fast.any() else "crashes_off_pad"
    return {"collision": "collisions", "out-of-arena": "out_of_arena", "timeout": "timeouts"}.get(result)


@dataclass(frozen=True)
class TransferConfig:
    """One transfer run: which policy, how many episodes a cell, which cells."""

    policy: str
    """Path of the policy file."""
    episodes: int = 200
    """Episodes per cell."""
    seed: int = 0
    """Base seed; episode ``k`` of row ``r`` starts from ``trial_seed(seed, r, k)`` in every column."""
    columns: tuple[str, ...] = tuple(c.name for c in COLUMNS)
    """The matrix's columns, :data:`COLUMNS` by default; :data:`EXTRA_COLUMNS` only when named."""
    rows: tuple[str, ...] = tuple(r.name for r in ROWS)
    sensing: str = "vicon"
    """``vicon`` (the lab's noise and latency) or ``perfect``."""
    workers: int = 2
    """Worker processes; 1 flies every cell in this process."""
    safety_filter: dict[str, float] | None = None
    """None: the policy's commands are flown as they are. A dict: every command goes through the safety filter that
    ``marlander deploy`` puts after the policy (on by default there), with these changes to
    :class:`SafetyFilterConfig`'s defaults (``{}``: none)."""
    num_drones: int | None = None
    """Swarm size a shared policy flies (None: 2, the paper's); a centralised policy flies its own, no other."""
    command_frame: str | None = None
    """None: the policy's commands are read in the frame it was trained with. ``"world"`` or ``"pad"``: in that frame
    (``TaskConfig.command_frame``); ``"pad"`` adds each pad's velocity to its drone's command, so that a policy
    trained on static pads can follow a moving one."""
    pad_frame_lead: PadFrameLead | None = None
    """None: the policy's own ``TaskConfig.pad_frame_lead``. A number of seconds: the lead on the pads' acceleration
    of a pad-frame command, flown instead. ``"auto"``: the lead set in flight, a share of the velocity tracker's lag
    identified from the commands and velocities (:mod:`marlander_lite.pad_frame_lead`)."""
    episode_seconds: float | None = None
    """None: each episode lasts as long as the policy's training episodes (``TaskConfig.episode_seconds``, 10 s for
    every shipped policy). A number of seconds: that time limit instead, e.g. the paper protocol's 30 s
    (``marlander reproduce --time-limit``), for a tracker so slow that its drones land but take longer."""
    vertical_bias: bool = False
    """Whether each drone's steady vertical velocity bias (the climb or sink its tracker adds to every command) is
    identified in flight and taken off its commands (``TaskConfig.vertical_bias_compensation``)."""

    def __post_init__(self) -> None:
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"--episodes must be an integer >= 1, got {self.episodes!r}.")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"--seed must be an integer >= 0, got {self.seed!r}.")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"--workers must be an integer >= 1, got {self.workers!r}.")
        if self.sensing not in ("vicon", "perfect"):
            raise ValueError(f"--sensing must be 'vicon' or 'perfect', got {self.sensing!r}.")
        if not self.columns or not self.rows:
            raise ValueError("Give at least one column and one row.")
        for name in self.columns:
            find_column(name)
        for name in self.rows:
            find_row(name)
        if self.safety_filter is not None:
            SafetyFilterConfig.from_dict(self.safety_filter)  # unknown or invalid settings fail before any flight
        if self.pad_frame_lead is not None:
            try:
                lead_changes(self.pad_frame_lead)
            except ValueError as error:
                raise ValueError(f"--pad-frame-lead: {error}") from None
        seconds = self.episode_seconds
        if seconds is not None and (isinstance(seconds, bool) or not 1.0 <= seconds <= MAX_EPISODE_SECONDS):
            raise ValueError(f"--episode-seconds must be from 1 to {MAX_EPISODE_SECONDS:g} s, got {seconds!r}.")
        if not isinstance(self.vertical_bias, bool):
            raise ValueError(f"vertical_bias must be True or False, got {self.vertical_bias!r}.")
        if self.command_frame is not None and self.command_frame not in task.COMMAND_FRAMES:
            raise ValueError(
                f"--command-frame must be one of {', '.join(task.COMMAND_FRAMES)}, got {self.command_frame!r}."
            )
        n = self.num_drones
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 64):
            raise ValueError(f"--num-drones must be an integer from 1 to 64, got {n!r}.")

    def swarm_size(self) -> int | None:
        """The N a shared policy flies (None for a centralised policy, which flies its own); refuses a ``num_drones``
        a centralised policy was not trained for."""
        contract = load_policy(self.policy).contract
        if contract.is_shared:
            return self.num_drones or SHARED_SWARM_SIZE
        if self.num_drones not in (None, contract.num_drones):
            raise ValueError(
                f"--num-drones {self.num_drones}: {self.policy} is a centralised policy for {contract.num_drones} "
                "drones and flies only that many; leave --num-drones out, or give a shared policy."
            )
        return None


def transfer_matrix(
    config: TransferConfig, columns: Sequence[Column] | None = None, journal: CellJournal | None = None
) -> list[CellResult]:
    """Fly every cell of ``config`` and return the results, rows outer, columns inner, in the given order.

    ``columns``: simulator settings to fly instead of ``config.columns`` (e.g. the random Crazyflies of
    :mod:`~marlander_lite.experiments.variants`). ``journal``: the cells it holds are taken from it, not flown, and
    each cell flown is recorded in it as soon as it is finished (:mod:`~marlander_lite.experiments.cell_journal`)."""
    n = config.swarm_size()  # fails before any worker starts
    flown: Sequence[str | Column] = config.columns if columns is None else columns
    cells = [(c, r) for r in config.rows for c in flown]
    args = [
        (
            str(config.policy),
            c,
            r,
            config.episodes,
            config.seed,
            config.sensing,
            config.safety_filter,
            n,
            config.command_frame,
            config.pad_frame_lead,
            config.episode_seconds,
            config.vertical_bias,
        )
        for c, r in cells
    ]
    done = {} if journal is None else journal.done
    results: list[CellResult | None] = [done.get((r, c if isinstance(c, str) else c.name)) for c, r in cells]
    todo = [i for i, result in enumerate(results) if result is None]

    def finished(i: int, result: CellResult) -> None:
        results[i] = result
        if journal is not None:
            journal.record(result)

    if config.workers == 1 or len(todo) <= 1:
        for i in todo:
            finished(i, fly_cell(*args[i]))
    else:
        method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
        workers = min(config.workers, len(todo))
        with futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method)) as pool:
            pending = {pool.submit(fly_cell, *args[i]): i for i in todo}
            for done_future in futures.as_completed(pending):
                finished(pending[done_future], done_future.result())
    return [r for r in results if r is not None]


def format_table(results: list[CellResult]) -> str:
    """A markdown table: one line per row, one column per simulator, ``success % [low, high] / error cm``."""
    columns = list(dict.fromkeys(r.column for r in results))
    rows = list(dict.fromkeys(r.row for r in results))
    by_cell = {(r.row, r.column): r for r in results}
    lines = ["| | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for row in rows:
        cells = []
        for column in columns:
            r = by_cell[(row, column)]
            cells.append(
                f"{100 * r.success_rate:.1f} [{100 * r.wilson_low:.0f}, {100 * r.wilson_high:.0f}] / "
                f"{r.landing_error_cm:.2f} cm"
            )
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_flight_table(results: list[CellResult]) -> str:
    """Flight quality per cell: touchdown speed, p95 command near the pad, tilt-limit share, approach height."""
    lines = [
        "| row | column | touchdown m/s | command p95 near pad m/s | at tilt limit % | height at 0.5 m | "
        "collisions % | failed: collision / crash too fast / crash off pad / out / timeout |",
        "|---|---|---|---|---|---|---|---|",
    ]
    identified = any(r.identified_lag_s is not None for r in results)
    if identified:  # a column only for matrices flown with the identified latency compensation
        lines = [lines[0] + " identified lag s |", lines[1] + "---|"]
    for r in results:
        counts = [getattr(r, name) for name in FAILURES]
        failed = " / ".join("-" if n is None else str(n) for n in counts)
        line = (
            f"| {r.row} | {r.column} | {r.touchdown_speed:.2f} | {r.command_near_pad_p95:.2f} | "
            f"{100 * r.tilt_limit_fraction:.1f} | {r.approach_height:.2f} | {100 * r.collision_rate:.1f} | {failed} |"
        )
        lag = "-" if r.identified_lag_s is None else f"{r.identified_lag_s:.2f}"
        lines.append(line + f" {lag} |" if identified else line)
    return "\n".join(lines)


CSV_FIELDS = tuple(CellResult.__dataclass_fields__)


def write_results(config: TransferConfig, results: list[CellResult], out: Path, wall_s: float) -> list[Path]:
    """``transfer.csv`` (one line per cell), ``transfer.json`` (config, policy hash, cells) and ``transfer.md``."""
    out.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, md_path = out / "transfer.csv", out / "transfer.json", out / "transfer.md"
    with csv_path.open("w") as f:
        f.write(",".join(CSV_FIELDS) + "\n")
        for r in results:
            f.write(",".join(_csv_value(getattr(r, name)) for name in CSV_FIELDS) + "\n")
    digest = hashlib.sha256(Path(config.policy).read_bytes()).hexdigest()
    meta: dict[str, Any] = {"config": asdict(config), "policy_sha256": digest, "wall_s": round(wall_s, 1)}
    if config.safety_filter is not None:
        # The settings as flown, defaults included: a later change of a default must not change what this file says.
        meta["safety_filter_resolved"] = SafetyFilterConfig.from_dict(config.safety_filter).to_dict()
    json_path.write_text(json.dumps({**meta, "cells": [asdict(r) for r in results]}, indent=2) + "\n")
    n = config.swarm_size()
    swarm = "" if n is None else f"a shared policy flying {n} drones, "
    contract = load_policy(config.policy).contract
    if contract.task.get("pad_assignment", "fixed") == "shortest":  # as it was trained
        swarm += "starts paired with the pads by the shortest pairing, "
    trained = contract.interface_options()
    if config.command_frame not in (None, trained["command_frame"]):
        swarm += (
            f"commands flown in the {config.command_frame} frame (trained in the {trained['command_frame']} frame), "
        )
    if not flies_policy_lead(trained, config.pad_frame_lead):
        lead, trained_lead = describe_lead(config.pad_frame_lead), describe_policy_lead(trained)
        swarm += f"a pad lead of {lead} (trained with {trained_lead}), "
    elif trained["pad_frame_lead_share"] > 0:  # the file's own lead, set in flight: say so
        swarm += f"its own pad lead, {describe_policy_lead(trained)}, "
    if config.episode_seconds is not None:
        trained_seconds = contract.task.get("episode_seconds", task.TaskConfig().episode_seconds)
        swarm += f"episodes of {config.episode_seconds:g} s (trained with {trained_seconds:g} s), "
    if config.vertical_bias:
        swarm += "the vertical bias identified in flight and cancelled, "
    md_path.write_text(
        f"Transfer matrix of `{config.policy}` ({swarm}{config.episodes} episodes a cell, seed {config.seed}, "
        f"sensing {config.sensing}{_filter_words(config.safety_filter)}): success % [95 % Wilson] / mean landing "
        "error.\n\n" + format_table(results) + "\n\n" + format_flight_table(results) + "\n"
    )
    return [csv_path, json_path, md_path]


def _filter_words(settings: dict[str, float] | None) -> str:
    if settings is None:
        return ""
    changes = ", ".join(f"{k} {v:g}" for k, v in settings.items())
    return f", through the safety filter ({changes or 'default settings'})"


def _csv_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    text = str(value)
    return f'"{text}"' if "," in text else text


def read_results(path: str | Path) -> list[CellResult]:
    """The cells of a ``transfer.json`` written by :func:`write_results`."""
    data = json.loads(Path(path).read_text())
    return [CellResult(**cell) for cell in data["cells"]]
