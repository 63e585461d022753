"""Success, landing error, landing time, separation and collisions versus swarm size N.

Each *cell* is one controller on swarms of one size N: ``trials`` episodes of the paper's task
(random platform placement and starts in the 4 x 4 x 4 m arena, every training aid off), flown in
``num_envs`` swarms at once, measured per trial with
:class:`~marlander_lite.experiments.metrics.TrialMetrics` and summarised with Wilson intervals for
rates and cluster-bootstrap intervals for the landing error
(:func:`~marlander_lite.experiments.metrics.summarise`). Controllers (:data:`SCALING_CONTROLLERS`):

``shared``       the shared policy (:class:`~marlander_lite.swarm.policy.SharedPolicy`), at any N;
``centralised``  the paper's centralised policy, only at the N it was trained for;
``shared-apf``   the shared policy plus the APF repulsion of the baseline (as MorphoLander adds it to a
                 single-agent policy, Sec. IV-E), any N;
``shared-filter`` the shared policy through the safety filter (:mod:`marlander_lite.swarm.safety_filter`), any N;
``centralised-filter`` the centralised policy through the safety filter, as ``marlander deploy`` flies it (its own N);
``baseline``     PID + APF (:class:`~marlander_lite.experiments.controllers.PIDAPFController`, tuned gains), any N.

Command line (writes ``scaling.csv``, ``scaling.json`` and ``scaling.md`` into ``--out``)::

    python -m marlander_lite.swarm.evaluation --shared data/policies/shared-quick.safetensors \\
        --centralised data/policies/quick-cpu.safetensors --sizes 2 4 8 16 --trials 200 --out data/results/scaling
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.crazyflie.perturb import HELD_OUT_TRACKER
from marlander_lite.envs.options import policy_input
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.experiments import apf
from marlander_lite.experiments.apf import APFConfig
from marlander_lite.experiments.controllers import PIDAPFController
from marlander_lite.experiments.metrics import CellSummary, TrialMetrics, summarise, wilson_interval
from marlander_lite.pad_assignment import PAD_ASSIGNMENTS
from marlander_lite.pad_frame_lead import PadFrameLead, describe_lead, lead_argument, lead_changes
from marlander_lite.platforms import PlateGeometry, PlatformConfig
from marlander_lite.policy_file import load_policy, read_contract
from marlander_lite.sensing import SensingConfig
from marlander_lite.simulators import SIMULATORS, simulator_entry
from marlander_lite.swarm.filtered_policy import BatchAct, with_safety_filter, with_safety_filter_on
from marlander_lite.swarm.policy import SharedPolicy
from marlander_lite.swarm.safety_filter import SafetyFilterConfig, parse_settings
from marlander_lite.task import TaskConfig

SCALING_CONTROLLERS = ("shared", "shared-apf", "shared-filter", "centralised", "centralised-filter", "baseline")


@dataclass(frozen=True)
class ScalingRow:
    """One cell: a controller on swarms of ``num_drones`` drones."""

    controller: str
    num_drones: int
    simulator: str
    summary: CellSummary
    collisions: int
    """Trials that ended with two drones closer than the collision distance."""
    collision_low: float
    """Wilson 95 % interval of the collision rate, lower end."""
    collision_high: float
    seconds: float
    """Wall-clock time the cell took (s), on the machine that ran it."""
    condition: str = "static-floor"
    """The platform: its kind, tool speed (m/s) and inclination (degrees) when not 0."""

    def flat(self) -> dict[str, Any]:
        """One flat record for a CSV row."""
        s = asdict(self.summary)
        s.pop("error_per_drone_cm")
        counts = s.pop("outcome_counts")
        return {
            "controller": self.controller,
            "num_drones": self.num_drones,
            "simulator": self.simulator,
            "condition": self.condition,
            **s,
            **{f"outcome_{k}": v for k, v in counts.items()},
            "collisions": self.collisions,
            "collision_rate": self.collisions / self.summary.trials,
            "collision_low": self.collision_low,
            "collision_high": self.collision_high,
            "seconds": round(self.seconds, 1),
        }


def fly_trials(
    episodes: LandingEpisodes,
    make_actor: Callable[[np.ndarray | None], BatchAct],
    trials: int,
) -> list[TrialMetrics]:
    """Fly the first ``trials`` episodes begun in ``episodes`` (all its envs at once) and measure each.

    ``make_actor(None)`` builds the controller for every env; it is called again with the ids of envs
    that start a new episode when the controller keeps state (see :class:`BatchOfControllers`). Only the first
    ``trials`` episodes *begun* are counted, so that short episodes are not over-represented.
    """
    e, dt = episodes.num_envs, episodes.task.dt
    obs = policy_input(episodes.reset())
    act = make_actor(None)
    started, counted = e, np.arange(e) < trials
    results: list[TrialMetrics] = []
    while len(results) < trials:
        outcome = episodes.step(act(obs))
        obs = policy_input(outcome.obs)
        done = np.flatnonzero(outcome.done)
        if done.size:
            for env in done.tolist():
                if counted[env]:
                    results.append(TrialMetrics.from_outcome(outcome, dt, env))
                counted[env] = started < trials
                started += 1
            obs[done] = policy_input(episodes.reset(done))
            reset = getattr(act, "reset", None)
            if reset is not None:
                reset(done)
    return results[:trials]


class BatchOfControllers:
    """Run one stateful single-swarm controller per env (e.g. PID + APF, whose integral and observer are per swarm).

    ``factory()`` builds one controller (``reset()``, ``act(obs (13 N,)) -> (3 N,)``).
    """

    def __init__(self, factory: Callable[[], Any], num_envs: int) -> None:
        self.controllers = [factory() for _ in range(num_envs)]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([c.act(o) for c, o in zip(self.controllers, obs, strict=True)])

    def reset(self, env_ids: np.ndarray) -> None:
        for i in np.asarray(env_ids).tolist():
            self.controllers[i].reset()


def evaluation_task(num_drones: int, time_limit_s: float = 30.0, **changes: Any) -> TaskConfig:
    """The task of every evaluation trial: the defaults (no training aid), N drones, the protocol's 30 s limit;
    ``changes`` override other :class:`TaskConfig` fields (e.g. ``spawn_near_pad_fraction`` for a learning test)."""
    return TaskConfig(num_drones=num_drones, episode_seconds=time_limit_s).replace(**changes)


def make_episodes(
    num_drones: int,
    num_envs: int,
    seed: int,
    simulator: str = "pointmass",
    platform: PlatformConfig | None = None,
    sensing: SensingConfig | None = None,
    time_limit_s: float = 30.0,
    task_changes: dict[str, Any] | None = None,
    **simulator_options: Any,
) -> LandingEpisodes:
    """``num_envs`` swarms of ``num_drones`` in ``simulator`` (any registered name: ``pointmass``, ``crazyflie``,
    ``rotorpy``), static floor plate and Vicon sensing by default. ``simulator_options`` go to the swarm (e.g.
    ``controller="firmware"``)."""
    task = evaluation_task(num_drones, time_limit_s, **(task_changes or {}))
    # The registry imports the simulator's module only now: PyBullet or RotorPy only when asked for.
    sim = simulator_entry(simulator).swarm_class()(task, platform or PlatformConfig(), num_envs, **simulator_options)
    return LandingEpisodes(sim, sensing or SensingConfig.vicon(), seed)


def actor_factory(
    controller: str,
    task: TaskConfig,
    platform: PlatformConfig,
    num_envs: int,
    policy_path: str | Path | None = None,
    filter_settings: dict[str, float] | None = None,
    episodes: LandingEpisodes | None = None,
) -> Callable[[np.ndarray | None], BatchAct]:
    """A :func:`fly_trials` actor builder for ``controller`` (one of :data:`SCALING_CONTROLLERS`) on ``task``.

    ``filter_settings``: changes to :class:`SafetyFilterConfig`'s defaults for the ``*-filter`` controllers.
    ``episodes``: the swarm the actor flies, if the ``*-filter`` controllers may read each pad's velocity from its
    state (as the deployment loop reads it from motion capture) and, for a pad-frame policy, the pad velocity its
    commands carry; without it they refuse the rules that need these on moving pads.
    """
    guard = SafetyFilterConfig.from_dict(filter_settings or {})
    offsets = platform.geometry.pad_offsets(task.num_drones)

    def filtered(act: BatchAct) -> BatchAct:
        if episodes is not None:
            return with_safety_filter_on(act, episodes, guard)
        return with_safety_filter(
            act,
            task.num_drones,
            offsets,
            task.max_speed,
            guard,
            policy_dt=task.dt,
            observes_pad_velocity=task.observe_platform_velocity,
            pads_move=platform.is_moving,
            command_frame=task.command_frame,
        )

    if controller == "shared":
        if policy_path is None:
            raise ValueError("The shared controller needs its policy file (policy_path).")
        policy = SharedPolicy(policy_path, task, platform.geometry)
        return lambda _ids: policy.act
    if controller == "shared-apf":
        if policy_path is None:
            raise ValueError("The shared-apf controller needs its policy file (policy_path).")
        shared = SharedPolicy(policy_path, task, platform.geometry)
        return lambda _ids: _with_repulsion(shared, task, platform)
    if controller == "shared-filter":
        if policy_path is None:
            raise ValueError("The shared-filter controller needs its policy file (policy_path).")
        guarded = SharedPolicy(policy_path, task, platform.geometry)
        return lambda _ids: filtered(guarded.act)
    if controller in ("centralised", "centralised-filter"):
        if policy_path is None:
            raise ValueError(f"The {controller} controller needs its policy file (policy_path).")
        central = load_policy(policy_path, task)  # refuses a policy trained for another N
        if controller == "centralised-filter":
            return lambda _ids: filtered(central.act)
        return lambda _ids: central.act
    if controller == "baseline":
        return lambda _ids: BatchOfControllers(lambda: PIDAPFController(task, geometry=platform.geometry), num_envs)
    raise ValueError(f"Unknown controller {controller!r}; allowed: {', '.join(SCALING_CONTROLLERS)}.")


def _with_repulsion(policy: SharedPolicy, task: TaskConfig, platform: PlatformConfig) -> BatchAct:
    """``policy``'s actions plus the baseline's Khatib repulsion (m/s, over ``max_speed``), clipped to [-1, 1]."""
    n, config, offsets = task.num_drones, APFConfig(), platform.geometry.pad_offsets(task.num_drones)

    def act(obs: np.ndarray) -> np.ndarray:
        actions = policy.act(obs).reshape(len(obs), n, 3)
        for env, o in enumerate(obs):
            p, _ = apf.split_observation(o, n)
            actions[env] += apf.repulsion_velocity(p, offsets, config) / task.max_speed
        return np.clip(actions, -1.0, 1.0).reshape(len(obs), 3 * n)

    return act


def evaluate_cell(
    controller: str,
    num_drones: int,
    trials: int,
    seed: int = 0,
    policy_path: str | Path | None = None,
    num_envs: int = 100,
    simulator: str = "pointmass",
    platform: PlatformConfig | None = None,
    task_changes: dict[str, Any] | None = None,
    simulator_options: dict[str, Any] | None = None,
    filter_settings: dict[str, float] | None = None,
    pad_frame_lead: PadFrameLead | None = None,
) -> ScalingRow:
    """Fly ``trials`` trials of ``controller`` on swarms of ``num_drones`` and summarise them (``task_changes``:
    see :func:`evaluation_task`; ``simulator_options`` go to the swarm, e.g. ``{"controller": "firmware"}``;
    ``filter_settings``: see :func:`actor_factory`; ``pad_frame_lead``: None, or the lead (s) a pad-frame policy is
    flown with instead of the one it was trained with, ``TaskConfig.pad_frame_lead``, or ``"auto"``, a flight setting
    as in ``marlander transfer --pad-frame-lead``)."""
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ValueError(f"trials must be an integer >= 1, got {trials!r}.")
    started = time.perf_counter()
    platform = platform or PlatformConfig()
    # A PyBullet CrazyflieSwarm holds one world: its trials are flown one after another.
    num_envs = 1 if simulator == "crazyflie" else min(num_envs, trials)
    if policy_path is not None:  # what the policy asks for in its input beyond eq. 2, and its command frame
        task_changes = {**(task_changes or {}), **policy_task_changes(policy_path, pad_frame_lead)}
    elif pad_frame_lead is not None:
        raise ValueError(f"pad_frame_lead leads a pad-frame policy's commands; {controller!r} flies no policy.")
    episodes = make_episodes(
        num_drones, num_envs, seed, simulator, platform, task_changes=task_changes, **(simulator_options or {})
    )
    try:
        make_actor = actor_factory(
            controller, episodes.task, platform, num_envs, policy_path, filter_settings, episodes
        )
        results = fly_trials(episodes, make_actor, trials)
    finally:
        episodes.sim.close()
    collisions = sum(t.min_separation_m < episodes.task.collision_distance for t in results)
    low, high = wilson_interval(collisions, len(results))
    return ScalingRow(
        controller,
        num_drones,
        simulator,
        summarise(results, seed=seed),
        collisions,
        low,
        high,
        time.perf_counter() - started,
        condition_name(platform),
    )


def policy_task_changes(policy_path: str | Path, pad_frame_lead: PadFrameLead | None = None) -> dict[str, Any]:
    """What the policy file asks of the task beyond eq. 2 (its inputs, its command frame and lead), with its lead
    replaced by ``pad_frame_lead`` (s, or ``"auto"``: set in flight) if given; a world-frame policy, which carries no
    pad velocity to lead, is refused."""
    changes = read_contract(policy_path).interface_options()
    if pad_frame_lead is None:
        return changes
    lead = lead_changes(pad_frame_lead)  # the range, NaN and spelling checks
    if changes.get("command_frame", "world") != "pad":
        raise ValueError(
            f"A pad-frame lead of {describe_lead(pad_frame_lead)} was given, but {policy_path} commands in the world "
            "frame, where no pad velocity is carried to lead: drop --pad-frame-lead, or fly a policy trained with "
            "command_frame='pad' (e.g. data/policies/moving-slow-trackers-fast-vertical.safetensors)."
        )
    return {**changes, **lead}


def condition_name(platform: PlatformConfig) -> str:
    """``kind``, ``kind-speed`` for moving plates, ``+ tilt N deg`` for inclined ones."""
    name = platform.kind + (f"-{platform.resolved_speed:g}" if platform.is_moving else "")
    tilt = platform.geometry.inclination_deg
    return name + (f" tilt {tilt:g} deg" if tilt else "")


def _cell_text(row: ScalingRow) -> str:
    s = row.summary

    def num(x: float, digits: int = 2) -> str:
        return "-" if math.isnan(x) else f"{x:.{digits}f}"

    return (
        f"| {row.controller} | {row.condition} | {row.num_drones} | {s.trials} | {100 * s.success_rate:.1f} "
        f"[{100 * s.success_low:.1f}, {100 * s.success_high:.1f}] | {num(s.error_mean_cm)} "
        f"[{num(s.error_mean_low)}, {num(s.error_mean_high)}] | {num(s.time_mean_s)} | {num(s.min_separation_m, 3)} "
        f"| {100 * row.collisions / s.trials:.1f} [{100 * row.collision_low:.1f}, {100 * row.collision_high:.1f}] |"
    )


def markdown_table(rows: Sequence[ScalingRow]) -> str:
    """Rows as a markdown table with 95 % intervals (Wilson for rates, bootstrap for the error)."""
    head = (
        "| controller | platform | N | trials | success % [95 % CI] | landing error cm [95 % CI] | landing time s "
        "| min separation m | collisions % [95 % CI] |\n|---|---|---|---|---|---|---|---|---|"
    )
    return "\n".join([head, *(_cell_text(r) for r in rows)])


RESULT_SUFFIXES = (".csv", ".json", ".md")


def check_results_free(out: str | Path, stem: str, force: bool = False) -> None:
    """Refuse (``FileExistsError``) when ``out`` already holds ``{stem}.csv/.json/.md`` and ``force`` is False:
    results someone kept are not overwritten by accident. Called before any trial is flown."""
    taken = [Path(out) / f"{stem}{suffix}" for suffix in RESULT_SUFFIXES if (Path(out) / f"{stem}{suffix}").exists()]
    if taken and not force:
        names = ", ".join(str(path) for path in taken)
        raise FileExistsError(f"{names} already exist; pass --force to overwrite, or choose another --out or --stem.")


def write_results(
    rows: Sequence[ScalingRow], out: str | Path, stem: str = "scaling", note: str = "", force: bool = False
) -> Path:
    """Write ``{stem}.csv``, ``{stem}.json`` and ``{stem}.md`` into ``out``; returns the markdown path.

    Existing files of that stem are only replaced with ``force`` (:func:`check_results_free`).
    """
    import csv

    check_results_free(out, stem, force)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    flat = [r.flat() for r in rows]
    with open(out / f"{stem}.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(flat[0]))
        writer.writeheader()
        writer.writerows(flat)
    (out / f"{stem}.json").write_text(json.dumps(flat, indent=2))
    md = out / f"{stem}.md"
    md.write_text((note + "\n\n" if note else "") + markdown_table(rows) + "\n")
    return md


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``marlander swarm evaluate`` (and ``python -m marlander_lite.swarm.evaluation``)."""
    parser.add_argument("--shared", help="shared policy file")
    parser.add_argument("--centralised", help="centralised policy file (flown at its own N only)")
    parser.add_argument("--baseline", action="store_true", help="also fly PID + APF at every N")
    parser.add_argument("--shared-apf", action="store_true", help="also fly the shared policy + APF repulsion")
    parser.add_argument("--shared-filter", action="store_true", help="also fly the shared policy + safety filter")
    parser.add_argument(
        "--centralised-filter", action="store_true", help="also fly the centralised policy + safety filter"
    )
    parser.add_argument(
        "--filter-settings",
        type=_checked_settings,
        metavar="KEY=VALUE,...",
        help="changes to the safety filter's defaults for the *-filter controllers (e.g. cone_radius=0.04, or a "
        "named set: moving-pads, pad-frame)",
    )
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8, 16])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--simulator", default="pointmass", choices=SIMULATORS)
    parser.add_argument("--firmware", action="store_true", help="crazyflie: the firmware velocity tracker")
    parser.add_argument(
        "--held-out",
        action="store_true",
        help="crazyflie: the held-out tracker (gym-pybullet-drones' published PID gains, no tilt limit, bare physics)",
    )
    parser.add_argument("--num-envs", type=int, default=100)
    parser.add_argument("--out", required=True)
    parser.add_argument("--stem", default="scaling")
    parser.add_argument("--platform", default="static-floor", help="platform kind (marlander_lite.platforms)")
    parser.add_argument("--speeds", type=float, nargs="+", default=[None], help="tool speeds of a moving platform")
    parser.add_argument("--inclinations", type=float, nargs="+", default=[0.0], help="plate tilts (degrees)")
    parser.add_argument(
        "--pad-spacing",
        type=float,
        help=f"distance between neighbouring pads (m; default {PlateGeometry.pad_spacing}, the plate grows to fit)",
    )
    parser.add_argument(
        "--pad-assignment",
        default="fixed",
        choices=PAD_ASSIGNMENTS,
        help="fixed: drone i lands on pad i (the paper); shortest: each trial's starts are paired with the pads by "
        "least total squared distance (CAPT's assignment, marlander_lite.pad_assignment)",
    )
    parser.add_argument(
        "--pad-frame-lead",
        type=lead_argument,
        metavar="SECONDS|auto",
        help="fly a pad-frame policy with this lead (TaskConfig.pad_frame_lead) instead of the one it was trained "
        "with: about the tracker's velocity time constant (docs/transfer.md, 'Where a pad-frame drone touches down'); "
        "'auto': 0.6 times the tracker lag identified in flight",
    )
    parser.add_argument("--force", action="store_true", help="overwrite STEM.csv/.json/.md already in --out")


def _checked_settings(text: str) -> str:
    """``--filter-settings`` as given (so that the tables' command repeats it), once the filter has accepted it."""
    try:
        parse_settings(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def command_line(args: argparse.Namespace, program: str = "marlander swarm evaluate") -> str:
    """The command that flies ``args`` again: every option of :func:`add_arguments` that is set, with its value."""
    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    parts = [program]
    for dest in (action.dest for action in parser._actions if action.dest != "force"):
        value = getattr(args, dest)
        unset = value is None or value is False or value == [None]
        if unset or (dest == "pad_assignment" and value == "fixed"):  # the paper's pairing: the old tables' command
            continue
        flag = "--" + dest.replace("_", "-")
        values = value if isinstance(value, list) else [] if value is True else [value]
        parts += [flag, *(f"{v:g}" if isinstance(v, float) else str(v) for v in values)]
    return " ".join(parts)


def run(args: argparse.Namespace, program: str = "marlander swarm evaluate") -> Path:
    """Fly every requested cell and write the tables (their note says how to fly them again); returns the .md."""
    if not (args.shared or args.centralised or args.baseline):
        raise ValueError("Nothing to fly: give --shared FILE, --centralised FILE and/or --baseline.")
    if args.centralised_filter and not args.centralised:
        raise ValueError("--centralised-filter flies the policy given with --centralised FILE; give it.")
    if args.filter_settings and not (args.shared_filter or args.centralised_filter):
        raise ValueError("--filter-settings sets the filter of --shared-filter or --centralised-filter; give one.")
    if args.firmware and args.held_out:
        raise ValueError("--firmware and --held-out name two trackers: give one.")
    if (args.firmware or args.held_out) and args.simulator != "crazyflie":
        raise ValueError("--firmware and --held-out choose the PyBullet tracker: add --simulator crazyflie.")
    lead = getattr(args, "pad_frame_lead", None)
    for path in (p for p in (args.shared, args.centralised) if lead is not None and p):
        policy_task_changes(path, lead)  # a world-frame policy given a lead: refused before any trial is flown
    check_results_free(args.out, args.stem, args.force)
    options = {"controller": "firmware"} if args.firmware else dict(HELD_OUT_TRACKER) if args.held_out else {}
    tracker = " (firmware tracker)" if args.firmware else " (held-out tracker)" if args.held_out else ""
    settings = parse_settings(args.filter_settings or "")
    spacing = {} if getattr(args, "pad_spacing", None) is None else {"pad_spacing": args.pad_spacing}
    platforms = [
        PlatformConfig(kind=args.platform, speed=speed, geometry=PlateGeometry(inclination_deg=tilt, **spacing))
        for speed in args.speeds
        for tilt in args.inclinations
    ]
    cells: list[tuple[str, int, str | None, PlatformConfig]] = []
    for platform in platforms:
        for n in args.sizes:
            if args.shared:
                cells.append(("shared", n, args.shared, platform))
            if args.shared and args.shared_apf:
                cells.append(("shared-apf", n, args.shared, platform))
            if args.shared and args.shared_filter:
                cells.append(("shared-filter", n, args.shared, platform))
            if args.centralised and load_policy(args.centralised).contract.num_drones == n:
                cells.append(("centralised", n, args.centralised, platform))
                if args.centralised_filter:
                    cells.append(("centralised-filter", n, args.centralised, platform))
            if args.baseline:
                cells.append(("baseline", n, None, platform))
    pairing = getattr(args, "pad_assignment", "fixed")
    rows = []
    for controller, n, path, platform in cells:
        row = evaluate_cell(
            controller, n, args.trials, args.seed, path, args.num_envs, args.simulator, platform,
            task_changes={"pad_assignment": pairing}, simulator_options=options, filter_settings=settings,
            pad_frame_lead=lead if path is not None else None,
        )  # fmt: skip
        print(_cell_text(row), f"({row.seconds:.0f} s)", flush=True)
        rows.append(row)
    starts = "the paper's random starts"
    if pairing == "shortest":
        starts += " paired with the pads by the shortest pairing"
    note = (
        f"{args.simulator}{tracker}, Vicon sensing, {starts}, "
        f"{args.trials} trials per cell, seed {args.seed}, 30 s limit: `{command_line(args, program)}`."
    )
    if args.shared_filter or args.centralised_filter:
        # Every setting as flown, defaults included, so that a later change of a default leaves this note true.
        resolved = SafetyFilterConfig.from_dict(settings).to_dict()
        note += " Safety filter as flown: " + ", ".join(f"{k} {v:g}" for k, v in resolved.items()) + "."
    md = write_results(rows, args.out, args.stem, note, force=args.force)
    print(md)
    return md


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Evaluate swarm landing versus the number of drones.")
    add_arguments(parser)
    args = parser.parse_args(argv)
    run(args, "python -m marlander_lite.swarm.evaluation")


if __name__ == "__main__":
    main()
