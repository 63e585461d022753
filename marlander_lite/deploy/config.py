"""The lab configuration: one YAML file says which Crazyflies, which rigid bodies, which rates and limits.

Every section is a frozen dataclass (:mod:`marlander_lite.deploy.sections`, re-exported here) whose
fields carry their allowed values as pydantic constraints (``Annotated[Real, Field(gt=0, le=3)]``: a
number in (0, 3]); :class:`LabConfig` puts them together.
:func:`load_lab_config` reads the YAML with a loader that refuses duplicate keys, YAML bombs and
deep nesting, validates it with pydantic (unknown keys, wrong types, values out of range), then
each dataclass checks what involves several fields (a drone without a pad, a geofence whose
margin is too narrow to brake in at the lab speed limit, a take-off height arming would
refuse, ...). Each error is a :class:`ConfigError` naming the key that is wrong, e.g.
``limits.max_speed``, and what is allowed. ``marlander_lite/deploy/example_lab.yaml`` is a
complete, commented example.

Frames and units: the motion-capture world frame (Vicon: z up), metres, seconds, m/s.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, with_config

from marlander_lite.deploy.safety import TAKEOFF_CLEARANCE, braking_margin_problem
from marlander_lite.deploy.schema import (
    MAX_FILE_BYTES,
    SCHEMA_CONFIG,
    ConfigError,
    Name,
    Text,
    check,
    read_yaml,
    validate,
)
from marlander_lite.deploy.sections import (
    MOCAP_KINDS,
    RENAMED_SIMULATORS,
    SIMULATOR_KINDS,
    CrazyflieParamsConfig,
    DroneConfig,
    GeofenceConfig,
    LimitsConfig,
    MocapConfig,
    MocapKind,
    PadConfig,
    RatesConfig,
    SafetyConfig,
    SimulationConfig,
    SimulatorKind,
    current_simulator_name,
)
from marlander_lite.policy_file import MLPPolicy, load_policy, read_contract
from marlander_lite.task import OBS_PER_DRONE, TaskConfig

__all__ = [
    "EXAMPLE_CONFIG",
    "MOCAP_KINDS",
    "RENAMED_SIMULATORS",
    "SIMULATOR_KINDS",
    "ConfigError",
    "CrazyflieParamsConfig",
    "DroneConfig",
    "GeofenceConfig",
    "LabConfig",
    "LimitsConfig",
    "MocapConfig",
    "MocapKind",
    "PadConfig",
    "RatesConfig",
    "SafetyConfig",
    "SimulationConfig",
    "SimulatorKind",
    "current_simulator_name",
    "load_lab_config",
    "load_lab_policy",
]

EXAMPLE_CONFIG = Path(__file__).with_name("example_lab.yaml")
"""The example lab config shipped with the package."""


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class LabConfig:
    """Everything the deployment needs to know about the lab."""

    drones: Annotated[tuple[DroneConfig, ...], Field(max_length=64)]
    pads: Annotated[dict[Name, PadConfig], Field(max_length=64)]
    mocap: MocapConfig
    rates: RatesConfig = field(default_factory=RatesConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    geofence: GeofenceConfig = field(default_factory=GeofenceConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    crazyflie: CrazyflieParamsConfig = field(default_factory=CrazyflieParamsConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    log_dir: Annotated[Text, Field(min_length=1, max_length=4096)] = "flight_logs"
    """Folder for flight logs (relative to the working directory)."""

    def __post_init__(self) -> None:
        check(len(self.drones) >= 1, "drones: list at least one drone (name, uri, pad).")
        problem = braking_margin_problem(self.limits.max_speed, self.geofence.margin, self.rates.loop_hz)
        check(problem is None, str(problem))
        names = [d.name for d in self.drones]
        uris = [d.uri for d in self.drones]
        check(len(set(names)) == len(names), f"drones: rigid-body names must be unique, got {names}.")
        check(len(set(uris)) == len(uris), f"drones: URIs must be unique, got {uris}.")
        used: dict[str, str] = {}
        for d in self.drones:
            check(
                d.pad in self.pads,
                f"drone {d.name!r} names pad {d.pad!r}, which is not under pads; allowed: {', '.join(self.pads)}.",
            )
            check(d.pad not in used, f"drones {used.get(d.pad)!r} and {d.name!r} share pad {d.pad!r}; one each.")
            used[d.pad] = d.name
        bodies = {p.body for p in self.pads.values()}
        check(not bodies & set(names), f"a pad body is also a drone name: {sorted(bodies & set(names))}.")
        low, high = self.geofence.bounds(soft=True)
        check(
            self.limits.takeoff_height < high[2],
            f"limits.takeoff_height {self.limits.takeoff_height} m is above the soft geofence ceiling {high[2]} m.",
        )
        check(
            self.limits.takeoff_height >= low[2] + TAKEOFF_CLEARANCE,
            f"limits.takeoff_height {self.limits.takeoff_height} m is less than {TAKEOFF_CLEARANCE} m above the "
            f"floor (geofence.z[0] = {low[2]} m): arming always refuses a take-off height not "
            f"{TAKEOFF_CLEARANCE} m above the pads.",
        )
        sim = self.simulation
        if sim.start_positions is not None:
            check(len(sim.start_positions) == len(self.drones), "simulation.start_positions: one (x, y) per drone.")
            for xy in sim.start_positions:
                check(self.geofence.contains((*xy, low[2]), soft=True), f"start position {xy} is outside the fence.")

    @property
    def num_drones(self) -> int:
        return len(self.drones)

    @property
    def drone_names(self) -> list[str]:
        return [d.name for d in self.drones]

    @property
    def pad_bodies(self) -> list[str]:
        """Distinct rigid bodies carrying pads, in order of first use."""
        return list(dict.fromkeys(self.pads[d.pad].body for d in self.drones))

    def drone_pads(self) -> list[PadConfig]:
        """The pad of each drone, in drone order."""
        return [self.pads[d.pad] for d in self.drones]

    def task_config(self, observe_platform_velocity: bool = False) -> TaskConfig:
        """The MDP constants the policy must have been trained with.

        ``observe_platform_velocity`` is the policy's choice, not the lab's: pass
        ``contract.obs_per_drone > 13`` of its policy file (see :func:`load_lab_policy`).
        """
        return TaskConfig(
            num_drones=self.num_drones,
            max_speed=self.limits.policy_max_speed,
            policy_hz=self.rates.policy_hz,
            observe_platform_velocity=observe_platform_velocity,
        )

    @classmethod
    def from_dict(cls, data: Any) -> LabConfig:
        """Build and validate from a parsed YAML mapping; raises :class:`ConfigError`."""
        return validate(cls, data)

    def replace(self, **changes: Any) -> LabConfig:
        """A copy with some sections replaced, validated as a loaded file would be (:class:`ConfigError`)."""
        return validate(LabConfig, dataclasses.asdict(dataclasses.replace(self, **changes)))


def load_lab_policy(path: str | Path, lab: LabConfig) -> MLPPolicy:
    """Load a policy file for this lab, refusing one whose contract does not fit (drones, speed, rate)."""
    contract = read_contract(path)
    return load_policy(path, lab.task_config(contract.obs_per_drone > OBS_PER_DRONE))


def load_lab_config(path: str | Path) -> LabConfig:
    """Read and validate a lab config YAML file; every problem with it is a one-line :class:`ConfigError`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No lab config at {path}; start from {EXAMPLE_CONFIG}.")
    try:
        with path.open("rb") as handle:
            raw = handle.read(MAX_FILE_BYTES + 1)  # never more: a huge file is refused unread
        with warnings.catch_warnings(record=True) as caught:  # re-issued below, naming the file
            warnings.simplefilter("always")
            lab = LabConfig.from_dict(read_yaml(raw))
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot be read ({error}).") from None
    for warning in caught:  # an old spelling (``simulator: pybullet``): loaded, and the user told how to update it
        warnings.warn(f"{path}: {warning.message}", warning.category, stacklevel=2)
    return lab
