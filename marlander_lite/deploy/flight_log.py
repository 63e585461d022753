"""Flight logs: one JSON line per loop tick, appended and flushed as it happens.

A log file starts with a ``header`` record (config, policy contract, drone and pad names), then
holds one ``tick`` record per loop tick, and ends with a ``summary`` record if the flight ended
normally. Each line is written and flushed before the next tick starts, so a crash or Ctrl-C
loses nothing that was already logged; :func:`read_flight_log` reads such a file and skips a
last line cut short by a crash. Non-finite numbers are written as ``NaN``/``Infinity``, which
Python's ``json`` (and pandas) read back.

A tick record::

    {"type": "tick", "tick": k, "t": s since start, "mode": ..., "phase": [per drone],
     "poses": {body: [x, y, z, qx, qy, qz, qw] or null (not in this tick's frames)},
     "age": {body: s since its last accepted pose},
     "est": {"pos", "quat", "vel", "ang_vel", "pad_pos", "pad_vel", "goal", "pad_normal"},   # per drone lists
     "obs": N x 13 or null, "action": 3N or null,
     "cmd": [per drone: {"kind": "velocity"|"hover"|"takeoff"|"land"|"stop"|"none", ...}],
     "events": [{"t", "kind", "message", "drone"}], "compute_ms": time spent in the tick}

With the safety filter on (config ``safety_filter.enabled``), each ``velocity`` command also says
whether the filter changed it, ``"filtered": true|false``; one the fence guard changed says
``"fence_guard": true``; and when either did, the record holds what the policy asked for,
``"v_policy": [vx, vy, vz]`` (m/s; ``v`` is what was sent). Otherwise the record is as above.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from marlander_lite.deploy.config import LabConfig
    from marlander_lite.deploy.runner import Policy

FORMAT = "marlander_lite.flight_log"
VERSION = 1
ESTIMATES = ("pos", "quat", "vel", "ang_vel", "pad_pos", "pad_vel", "goal", "pad_normal")
"""Fields of the estimate logged per tick, each per drone (``pad_normal`` since 2026-11-29: logs written before have
none, and their pads were judged level)."""


def rounded(a: Any, decimals: int = 6) -> Any:
    """Arrays and numbers as JSON-ready lists, rounded to ``decimals`` (keeps the log small)."""
    return np.round(np.asarray(a, dtype=float), decimals).tolist()


def tick_record(
    *,
    tick: int,
    t: float,
    mode: str,
    phase: list[str],
    frames: list[Any],
    ages: dict[str, float],
    est: Any,
    obs: np.ndarray | None,
    action: np.ndarray | None,
    commands: list[dict[str, Any]],
    events: list[dict[str, Any]],
    compute_ms: float,
) -> dict[str, Any]:
    """The record of one loop tick (see the module docstring); ``frames`` are this tick's ``PoseFrame`` s,
    ``est`` its ``SwarmEstimate``, ``ages`` every tracked body's age (s)."""
    poses: dict[str, Any] = dict.fromkeys(ages)
    for frame in frames:
        for name, pose in frame.bodies.items():
            if name in poses:
                poses[name] = rounded(pose)
    return {
        "type": "tick",
        "tick": tick,
        "t": round(t, 6),
        "mode": mode,
        "phase": list(phase),
        "poses": poses,
        "age": {k: round(v, 4) for k, v in ages.items()},
        "est": {key: rounded(getattr(est, key)) for key in ESTIMATES},
        "obs": None if obs is None else rounded(obs),
        "action": None if action is None else rounded(action),
        "cmd": commands,
        "events": events,
        "compute_ms": round(compute_ms, 4),
    }


def flight_header(lab: LabConfig, policy: Policy, **extra: Any) -> dict[str, Any]:
    """The header record of a flight log: start time (UTC), drone and pad names, rates, the whole lab config,
    the policy's contract, and ``extra`` (``source``, and for a rehearsal ``simulator``, ``seed``, ``fault``)."""
    contract = getattr(policy, "contract", None)
    return {
        "started": datetime.datetime.now(datetime.timezone.utc).isoformat(),
        "drones": lab.drone_names,
        "pads": [d.pad for d in lab.drones],
        "pad_bodies": [p.body for p in lab.drone_pads()],
        "loop_hz": lab.rates.loop_hz,
        "policy_hz": lab.rates.policy_hz,
        "config": dataclasses.asdict(lab),
        "policy": None if contract is None else dataclasses.asdict(contract),
        **extra,
    }


def jsonable(value: Any) -> Any:
    """``value`` with numpy scalars turned into Python numbers (for ``json``)."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class FlightLogWriter:
    """Appends records to a JSON-lines file, flushing after every record.

    Args:
        path: the log file (its folder is created).
        header: what to record about the flight (config, policy, ...).
        fsync: also ask the OS to write to disk every tick (survives a power cut; slower).
        overwrite: replace an existing file; otherwise an existing file is refused (a flight log
            is never overwritten by accident).
    """

    def __init__(self, path: str | Path, header: dict[str, Any], fsync: bool = False, overwrite: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fsync = fsync
        try:  # "x": refused by the OS if the file exists, even if it appeared a moment ago
            self._file: IO[str] | None = self.path.open("w" if overwrite else "x", encoding="utf-8")
        except FileExistsError:
            raise FileExistsError(f"The flight log {self.path} exists already; choose another path.") from None
        self.records = 0
        self.last_tick: int | None = None
        """The ``tick`` of the last tick record written (the loop checks it after an interrupt)."""
        self.write({"type": "header", "format": FORMAT, "version": VERSION, **header})

    def write(self, record: dict[str, Any]) -> None:
        """Append one record and flush it."""
        if self._file is None:
            raise ValueError(f"The flight log {self.path} is closed.")
        self._file.write(json.dumps(record, separators=(",", ":")) + "\n")
        if record.get("type") == "tick":
            self.last_tick = record["tick"]
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self.records += 1

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


@dataclass
class FlightLog:
    """A flight log read back."""

    header: dict[str, Any]
    ticks: list[dict[str, Any]]
    summary: dict[str, Any] | None
    truncated: bool = False
    """The last line was cut short (the program died while writing it) and was skipped."""
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def drones(self) -> list[str]:
        return list(self.header["drones"])

    def times(self) -> np.ndarray:
        """Tick times ``(T,)`` s."""
        return np.array([t["t"] for t in self.ticks])

    def estimates(self, key: str) -> np.ndarray:
        """An estimate over time, e.g. ``"pos"`` -> ``(T, N, 3)``; ``"pad_normal"`` is ``+z`` in a log written
        before it was logged (its pads were judged level)."""
        if key == "pad_normal" and self.ticks and key not in self.ticks[0]["est"]:
            return np.broadcast_to([0.0, 0.0, 1.0], (len(self.ticks), len(self.drones), 3)).copy()
        return np.array([t["est"][key] for t in self.ticks], dtype=float)


def read_flight_log(path: str | Path) -> FlightLog:
    """Read a flight log; a last line cut short by a crash is skipped with a warning."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines()
    header, ticks, summary, truncated = None, [], None, False
    for number, line in enumerate(lines, start=1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):
                truncated = True
                message = f"{path}: the last line is incomplete (the flight ended abruptly); skipped."
                warnings.warn(message, stacklevel=2)
                break
            raise ValueError(f"{path}:{number} is not a JSON record; the file is damaged.") from None
        kind = record.get("type")
        if kind == "header":
            if header is not None:
                raise ValueError(f"{path}:{number} starts a second flight; a log holds one flight.")
            header = record
        elif kind == "tick":
            ticks.append(record)
        elif kind == "summary":
            summary = record
    if header is None or header.get("format") != FORMAT:
        raise ValueError(f"{path} is not a marlander_lite flight log (no header record).")
    events = [e for t in ticks for e in t.get("events", [])]
    return FlightLog(header=header, ticks=ticks, summary=summary, truncated=truncated, events=events)
