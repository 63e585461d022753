"""A sweep: one preset trained with several seeds, then every seed evaluated the same way.

RL results swing between seeds (Agarwal et al., NeurIPS 2021), so a claim needs several runs and an
interval, not one lucky run. :func:`run_sweep` trains the seeds as independent jobs
(:func:`marlander_lite.distributed.map_jobs`: processes on this machine, or Ray tasks on a cluster)
and :func:`evaluate_sweep` flies each seed's policy on the same conditions. A sweep folder holds::

    sweep.json            the preset, the resolved config (seed aside) and each seed's status
    seed-0/ seed-1/ ...   ordinary run folders, exactly as ``marlander train --seed K`` writes them
    evaluation.csv        one row per seed and condition (success, landing error, time, collisions)

Nothing is ever overwritten: a finished seed is skipped when the sweep runs again, an interrupted one
(Ctrl-C or SIGTERM: its checkpoint) resumes, and the folder of a seed that failed is kept as
``seed-K.failed-N`` before that seed is trained again. A sweep folder refuses seeds of another config.
:mod:`marlander_lite.experiments.seed_stats` turns the folder into intervals and curves.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import re
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from marlander_lite.distributed import Backend, map_jobs
from marlander_lite.training.presets import TrainConfig
from marlander_lite.training.provenance import policy_digest

SWEEP_FILE = "sweep.json"
EVALUATION_FILE = "evaluation.csv"


def parse_seeds(text: str) -> tuple[int, ...]:
    """Seeds from ``"0-4"``, ``"0,2,7"`` or ``"0-2,5"``: sorted, without repeats."""
    seeds: set[int] = set()
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if match is None or (match[2] is not None and int(match[2]) < int(match[1])):
            raise ValueError(f"--seeds {text!r}: expected seeds like 0-4, 0,2,7 or 0-2,5 (non-negative integers).")
        low = int(match[1])
        seeds.update(range(low, int(match[2] or low) + 1))
    return tuple(sorted(seeds))


def seed_folder(out: Path, seed: int) -> Path:
    """Where seed ``seed`` of the sweep in ``out`` keeps its run."""
    return out / f"seed-{seed}"


@dataclass(frozen=True)
class SeedJob:
    """What a worker needs to train one seed: picklable, so it can travel to a Ray node."""

    config: dict[str, Any]
    """The run's :meth:`TrainConfig.to_dict`, seed included."""
    preset: str | None
    folder: str
    """The run folder on the machine that started the sweep."""
    resume: bool
    """Continue the interrupted run in ``folder`` instead of starting one."""
    packed_run: bytes | None = None
    """Ray: the folder's contents (a tar), shipped to a worker that does not share this file system."""


@dataclass(frozen=True)
class SeedOutcome:
    """How one seed's training ended."""

    seed: int
    status: str
    """``done``, ``interrupted`` (a checkpoint to resume from) or ``failed``."""
    message: str = ""
    seconds: float = 0.0
    packed_run: bytes | None = None
    """Ray: the run folder as a tar, to unpack where the sweep was started."""


def train_seed(job: SeedJob) -> SeedOutcome:
    """Train (or resume) one seed; runs in a worker. With ``job.packed_run`` it works in a scratch folder
    and returns that folder packed, so that a Ray node needs no shared file system."""
    from marlander_lite.training.train import TrainingInterrupted, resume, train

    seed = int(job.config["seed"])
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=f"marlander-seed{seed}-") as scratch:
        folder = Path(job.folder)
        if job.packed_run is not None:
            folder = Path(scratch) / folder.name
            _unpack(job.packed_run, folder)
        try:
            if job.resume:
                resume(folder)
            else:
                train(TrainConfig.from_dict(job.config), folder, preset=job.preset)
            status, message = "done", ""
        except TrainingInterrupted as stop:
            status, message = "interrupted", str(stop)
        except Exception as error:
            status, message = "failed", f"{type(error).__name__}: {error}"
        packed = _pack(folder) if job.packed_run is not None and folder.exists() else None
    return SeedOutcome(seed, status, message, round(time.perf_counter() - started, 1), packed)


def _pack(folder: Path) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        tar.add(folder, arcname=".")
    return buffer.getvalue()


def _unpack(data: bytes, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(folder, filter="data")


def _write_json(path: Path, record: dict[str, Any]) -> None:
    """Write atomically: an interrupted write leaves the previous file, never half of one."""
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(record, indent=2))
    partial.replace(path)


def run_state(folder: Path) -> str:
    """``new``, ``done``, ``resumable`` or ``broken`` (a folder neither finished nor resumable)."""
    from marlander_lite.training.resume import RESUME_DIR, has_checkpoint

    config = folder / "config.json"
    if not folder.exists():
        return "new"
    if config.is_file() and "finished" in json.loads(config.read_text()):
        return "done"
    if has_checkpoint(folder / RESUME_DIR):
        return "resumable"
    return "broken"


def open_sweep(out: Path, config: TrainConfig, preset: str | None) -> dict[str, Any]:
    """The sweep record of ``out``, created if new; refuses a folder that holds a sweep of another config."""
    wanted = {k: v for k, v in config.to_dict().items() if k != "seed"}
    path = out / SWEEP_FILE
    if path.is_file():
        record = json.loads(path.read_text())
        recorded = TrainConfig.from_dict({**record["config"], "seed": 0}).to_dict()
        differs = sorted(k for k, v in wanted.items() if recorded.get(k) != v)
        if differs:
            raise ValueError(
                f"--out {out} holds a sweep of another config (it differs in {', '.join(differs)}); "
                "choose another --out, or run the same preset and options to add or resume seeds."
            )
        return record
    if out.exists() and any(not entry.name.startswith(".") for entry in out.iterdir()):  # a lock file is fine
        raise FileExistsError(f"--out {out} exists and is not a sweep folder; choose another --out.")
    out.mkdir(parents=True, exist_ok=True)
    record = {"preset": preset, "config": wanted, "seeds": {}, "created": time.strftime("%Y-%m-%dT%H:%M:%S")}
    _write_json(path, record)
    return record


def set_aside(folder: Path) -> Path:
    """Rename a failed run folder to ``<name>.failed-N`` (the first free N) and return the new path."""
    n = 1
    while folder.with_name(f"{folder.name}.failed-{n}").exists():
        n += 1
    target = folder.with_name(f"{folder.name}.failed-{n}")
    folder.rename(target)
    return target


def run_sweep(
    config: TrainConfig,
    seeds: Iterable[int],
    out: str | Path,
    *,
    preset: str | None = None,
    backend: Backend = "local",
    workers: int | None = None,
    address: str | None = None,
    report: Callable[[str], Any] = print,
) -> list[SeedOutcome]:
    """Train ``config`` once per seed into ``out/seed-K``; returns each seed's outcome (finished seeds: ``done``).

    Args:
        config: the training config; its ``seed`` is replaced by each of ``seeds``.
        seeds: the seeds to have trained (already finished ones are skipped).
        out: the sweep folder.
        preset: the preset's name, recorded with each run.
        backend: ``local`` (processes here) or ``ray``.
        workers: local backend: runs at a time; default: CPU cores / the config's torch threads.
        address: ray backend: see :func:`marlander_lite.distributed.map_jobs`.
        report: called with one line per event.
    """
    out = Path(out)
    record = open_sweep(out, config, preset)
    outcomes, jobs = [], []
    for seed in seeds:
        folder = seed_folder(out, seed)
        state = run_state(folder)
        if state == "done":
            report(f"seed {seed}: already trained ({folder})")
            outcomes.append(SeedOutcome(seed, "done", "already trained"))
            continue
        if state == "broken":
            report(f"seed {seed}: an earlier attempt failed; its folder is kept as {set_aside(folder)}")
        packed = _pack(folder) if backend == "ray" and state == "resumable" else None
        config_dict = config.replace(seed=seed).to_dict()
        jobs.append(SeedJob(config_dict, preset, str(folder), state == "resumable", packed))
    if not jobs:
        return outcomes
    workers = workers or max(1, (os.cpu_count() or 1) // config.torch_threads)
    report(
        f"Training {len(jobs)} seed(s) of {preset or 'a custom config'} on {backend}"
        + (f" ({min(workers, len(jobs))} at a time)" if backend == "local" else "")
    )
    for job, result in map_jobs(
        train_seed, jobs, backend=backend, workers=workers, address=address, cpus_per_job=config.torch_threads
    ):
        seed = int(job.config["seed"])
        outcome = result if isinstance(result, SeedOutcome) else SeedOutcome(seed, "failed", repr(result))
        if outcome.packed_run is not None:
            receive_run(outcome.packed_run, Path(job.folder))
        entry: dict[str, Any] = {"status": outcome.status, "seconds": outcome.seconds}
        if outcome.message:
            entry["message"] = outcome.message
        policy = Path(job.folder) / "policy.safetensors"
        if outcome.status == "done" and policy.is_file():
            entry["policy_digest"] = policy_digest(policy)
        record["seeds"][str(seed)] = entry
        _write_json(out / SWEEP_FILE, record)
        report(f"seed {seed}: {outcome.status} in {outcome.seconds:.0f} s {outcome.message}".rstrip())
        outcomes.append(dataclasses.replace(outcome, packed_run=None))
    return sorted(outcomes, key=lambda o: o.seed)


def sweep_runs(folder: str | Path) -> list[Path] | None:
    """The finished seed runs of the sweep in ``folder``, by seed; ``None`` if ``folder`` is not a sweep."""
    folder = Path(folder)
    if not (folder / SWEEP_FILE).is_file():
        return None
    runs = finished_seeds(folder)
    if not runs:
        raise ValueError(f"The sweep {folder} has no finished seed yet.")
    return runs


def finished_seeds(folder: Path) -> list[Path]:
    """The run folders of the seeds that finished training, by seed."""
    runs = [p for p in folder.glob("seed-*") if re.fullmatch(r"seed-\d+", p.name) and run_state(p) == "done"]
    return sorted(runs, key=lambda p: int(p.name.split("-")[1]))


def receive_run(packed: bytes, folder: Path) -> None:
    """Unpack a run that came back from a Ray worker into ``folder``, replacing only our own earlier copy."""
    incoming = folder.with_name(folder.name + ".incoming")
    _unpack(packed, incoming)
    if folder.exists():  # the resumable copy we shipped out; the incoming one continues it
        set_aside(folder)
    incoming.rename(folder)


@dataclass(frozen=True)
class EvalCondition:
    """One evaluation condition of a sweep: a simulator with its env options and an episode count."""

    name: str
    simulator: str
    options: dict[str, Any]
    episodes: int


_VICON = {"sensing": "vicon"}
_FIRMWARE = {"controller": "firmware", "sensing": "vicon"}


def protocol_conditions(episodes: int = 200) -> tuple[EvalCondition, ...]:
    """The ten platform set-ups of the paper's Tables I and II (:data:`marlander_lite.experiments.protocol.
    CONDITIONS`: floor, UR10, linear and arc tool paths at 0.2-0.5 m/s) on the point mass through ``vicon``
    sensing. Their names are ``point mass, floor``, ``point mass, elevated``, ``point mass, linear 0.3 m/s``..."""
    from marlander_lite.experiments.protocol import CONDITIONS

    table = []
    for cond in CONDITIONS:
        if cond.group == "static":
            name, options = cond.kind.removeprefix("static-"), {"platform": cond.kind}
        else:
            name = f"{cond.kind.removeprefix('moving-')} {cond.speed:g} m/s"
            options = {"platform": cond.kind, "platform_speed": cond.speed}
        table.append(EvalCondition(f"point mass, {name}", "pointmass", {**options, **_VICON}, episodes))
    return tuple(table)


SWEEP_CONDITIONS: dict[str, tuple[EvalCondition, ...]] = {
    "quick": (
        EvalCondition("point mass, floor", "pointmass", {"platform": "static-floor", **_VICON}, 200),
        EvalCondition("point mass, elevated", "pointmass", {"platform": "static-elevated", **_VICON}, 200),
        EvalCondition("point mass, floor, true state", "pointmass", {"platform": "static-floor"}, 200),
        EvalCondition("firmware, floor", "crazyflie", {"platform": "static-floor", **_FIRMWARE}, 50),
        EvalCondition("firmware, elevated", "crazyflie", {"platform": "static-elevated", **_FIRMWARE}, 50),
    ),
    "pointmass": (
        EvalCondition("point mass, floor", "pointmass", {"platform": "static-floor", **_VICON}, 200),
        EvalCondition("point mass, elevated", "pointmass", {"platform": "static-elevated", **_VICON}, 200),
    ),
    "protocol": protocol_conditions(),
}
"""Named sets of evaluation conditions. ``quick``: the point mass and PyBullet with the Crazyflie firmware's
velocity tracker (where the policy will fly), observed through the lab's motion capture (``vicon``: noise and
20 ms of delay), plus the point mass observed without noise or delay (``true state``, as simulators that do not
model sensing show it). ``pointmass``: the point mass only (seconds per seed). ``protocol``: every platform
set-up of the paper's Tables I and II on the point mass (:func:`protocol_conditions`, about a minute per seed),
the conditions of the performance profiles (:func:`marlander_lite.experiments.seed_stats.sweep_profile`)."""

EVALUATION_FIELDS = (
    "seed",
    "condition",
    "episodes",
    "success_rate",
    "landing_error_mean_cm",
    "landing_time_mean_s",
    "collision_rate",
)


def evaluate_sweep(
    out: str | Path,
    conditions: str = "quick",
    seed: int = 12345,
    episodes: int | None = None,
    report: Callable[[str], Any] = print,
) -> Path:
    """Fly every finished seed of the sweep in ``out`` on ``SWEEP_CONDITIONS[conditions]``; returns the CSV.

    Rows already in ``evaluation.csv`` are kept and not flown again, so an interrupted evaluation resumes.
    Every seed flies the same starts (``seed``), with every training aid off; ``episodes`` replaces each
    condition's episode count.
    """
    from marlander_lite.training.evaluation import evaluate_policy_file

    if conditions not in SWEEP_CONDITIONS:
        raise ValueError(f"Unknown evaluation set {conditions!r}; allowed: {', '.join(SWEEP_CONDITIONS)}.")
    out = Path(out)
    path = out / EVALUATION_FILE
    rows = read_evaluation(path) if path.is_file() else []
    have = {(int(r["seed"]), r["condition"]) for r in rows}
    for folder in finished_seeds(out):
        run_seed = int(folder.name.split("-")[1])
        for cond in SWEEP_CONDITIONS[conditions]:
            if (run_seed, cond.name) in have:
                continue
            summary = evaluate_policy_file(
                folder / "policy.safetensors", cond.simulator, episodes or cond.episodes, seed, **cond.options
            )
            rows.append({"seed": run_seed, "condition": cond.name, **_summary_fields(summary)})
            report(f"seed {run_seed}, {cond.name}: {summary}")
            write_evaluation(path, rows)
    return path


def _summary_fields(summary: Any) -> dict[str, Any]:
    values = summary.to_dict()
    return {k: values[k] for k in EVALUATION_FIELDS if k in values}


def read_evaluation(path: Path) -> list[dict[str, Any]]:
    """The rows of a sweep's ``evaluation.csv`` with numbers as numbers."""
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        for key in EVALUATION_FIELDS[2:]:
            row[key] = float(row[key])
        row["seed"] = int(row["seed"])
    return rows


def write_evaluation(path: Path, rows: list[dict[str, Any]]) -> None:
    """Write ``rows`` (:data:`EVALUATION_FIELDS`) sorted by seed and condition, atomically (a partial file is
    renamed over ``path``), so an interrupted evaluation never leaves a half-written CSV."""
    partial = path.with_suffix(".partial")
    with partial.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, EVALUATION_FIELDS)
        writer.writeheader()
        writer.writerows(sorted(rows, key=lambda r: (int(r["seed"]), r["condition"])))
    partial.replace(path)
