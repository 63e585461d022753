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
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, Field, with_config

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
    SafetyFilterSection,
    SimulationConfig,
    SimulatorKind,
    current_simulator_name,
    expand_named_filter_settings,
)
from marlander_lite.pad_assignment import PadAssignment
from marlander_lite.pad_frame_lead import describe_lead, lead_changes
from marlander_lite.platforms import PlateGeometry
from marlander_lite.policy_file import MLPPolicy, PolicyFileError, load_policy, read_contract
from marlander_lite.task import TaskConfig

__all__ = [
    "EXAMPLE_CONFIG",
    "EXAMPLE_CONFIG_8",
    "EXAMPLE_CONFIG_16",
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
    "SafetyFilterSection",
    "SimulationConfig",
    "SimulatorKind",
    "current_simulator_name",
    "load_lab_config",
    "load_lab_policy",
]

EXAMPLE_CONFIG = Path(__file__).with_name("example_lab.yaml")
"""The example lab config shipped with the package (2 drones, the paper's lab)."""
EXAMPLE_CONFIG_8 = Path(__file__).with_name("example_lab_8.yaml")
"""The example lab config for 8 drones on a plate with a 3 x 3 grid of pads (fly it with a shared policy)."""
EXAMPLE_CONFIG_16 = Path(__file__).with_name("example_lab_16.yaml")
"""The example lab config for 16 drones on a plate with a 4 x 4 grid of pads, four Crazyradios, a wider fence."""


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
    safety_filter: Annotated[SafetyFilterSection, BeforeValidator(expand_named_filter_settings)] = field(
        default_factory=SafetyFilterSection
    )
    crazyflie: CrazyflieParamsConfig = field(default_factory=CrazyflieParamsConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    log_dir: Annotated[Text, Field(min_length=1, max_length=4096)] = "flight_logs"
    """Folder for flight logs (relative to the working directory)."""
    pad_assignment: PadAssignment = "fixed"
    """Which drone lands on which pad. ``fixed``: the pad each drone's entry names (the paper). ``shortest``: just
    before the pre-flight check the drones' pads are handed out again by the pairing of least total squared
    distance from where they rest to the pads, seen from above (CAPT's assignment, :mod:`.pairing`); fly it with a
    policy trained so (``shared-quick-paired``). The flight log header records the pairing flown."""

    def __post_init__(self) -> None:
        check(len(self.drones) >= 1, "drones: list at least one drone (name, uri, pad).")
        problem = braking_margin_problem(self.limits.max_speed, self.geofence.margin, self.rates.loop_hz)
        check(problem is None, str(problem))
        names = [d.name for d in self.drones]
        uris = [d.uri for d in self.drones]
        check(len(set(names)) == len(names), f"drones: rigid-body names must be unique, got {names}.")
        check(len(set(uris)) == len(uris), f"drones: URIs must be unique, got {uris}.")
        check(
            len(self.drones) <= len(self.pads),
            f"{len(self.drones)} drones but only {len(self.pads)} pads under pads ({', '.join(self.pads)}): every "
            "drone needs a pad of its own; add pads or remove drones.",
        )
        self._check_pads_apart()
        used: dict[str, str] = {}
        for d in self.drones:
            check(
                d.pad in self.pads,
                f"drone {d.name!r} names pad {d.pad!r}, which is not under pads; allowed: {', '.join(self.pads)}.",
            )
            check(d.pad not in used, f"drones {used.get(d.pad)!r} and {d.name!r} share pad {d.pad!r}; one each.")
            used[d.pad] = d.name
        self._check_pads_fit_the_filter()
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

    def _check_pads_apart(self) -> None:
        """Refuse two pads on the same body that overlap: centres closer than the sum of their radii."""
        pads = list(self.pads.items())
        for i, (name_a, a) in enumerate(pads):
            for name_b, b in pads[i + 1 :]:
                if a.body != b.body:
                    continue  # on different bodies: where they are depends on how those move
                gap = math.dist(a.offset, b.offset)
                check(
                    gap >= a.radius + b.radius - 1e-9,  # touching pads are allowed, as in PlateGeometry
                    f"pads {name_a!r} and {name_b!r} on body {a.body!r} overlap: their centres are {gap:.3f} m apart, "
                    f"less than the sum of their radii ({a.radius + b.radius:g} m); move them apart or make them "
                    "smaller.",
                )

    def _check_pads_fit_the_filter(self) -> None:
        """Refuse two drones' pads on the same body closer than ``safety_filter.min_distance``: drones resting on
        them, or hovering over them to land, would be pushed apart by the filter, off their pads."""
        if not self.safety_filter.enabled:
            return
        pairs = [
            (math.dist(self.pads[a.pad].offset, self.pads[b.pad].offset), a, b)
            for i, a in enumerate(self.drones)
            for b in self.drones[i + 1 :]
            if self.pads[a.pad].body == self.pads[b.pad].body  # on different bodies: the gap depends on their motion
        ]
        if not pairs:
            return
        gap, a, b = min(pairs, key=lambda pair: pair[0])
        d_s = self.safety_filter.min_distance
        check(
            gap >= d_s - 1e-9,
            f"safety_filter.min_distance is {d_s:g} m but pads {a.pad!r} and {b.pad!r} (of drones {a.name!r} and "
            f"{b.name!r}) on body {self.pads[a.pad].body!r} are {gap:.3f} m apart: the filter would push drones over "
            f"neighbouring pads apart, off their pads. Set safety_filter.min_distance to at most {gap:.3f} m, or move "
            "the pads apart.",
        )

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

    def task_config(
        self,
        observe_platform_velocity: bool = False,
        observe_previous_command: bool = False,
        observe_platform_acceleration: bool = False,
        observation_history: int = 1,
        command_frame: str = "world",
        pad_frame_lead: float = 0.0,
        pad_frame_lead_share: float = 0.0,
        vertical_bias_compensation: bool = False,
    ) -> TaskConfig:
        """The MDP constants the policy must have been trained with.

        What the observation holds beyond eq. 2, and the frame its commands are read in, are the policy's choice, not
        the lab's: pass ``**contract.interface_options()`` of its policy file (see :func:`load_lab_policy`).
        """
        return TaskConfig(
            num_drones=self.num_drones,
            max_speed=self.limits.policy_max_speed,
            policy_hz=self.rates.policy_hz,
            observe_platform_velocity=observe_platform_velocity,
            observe_previous_command=observe_previous_command,
            observe_platform_acceleration=observe_platform_acceleration,
            observation_history=observation_history,
            command_frame=command_frame,  # type: ignore[arg-type]  # TaskConfig checks it
            pad_frame_lead=pad_frame_lead,
            pad_frame_lead_share=pad_frame_lead_share,
            vertical_bias_compensation=vertical_bias_compensation or bool(self.limits.vertical_bias),
        )

    def policy_options(self, options: dict[str, Any]) -> dict[str, Any]:
        """A policy file's interface options (``PolicyContract.interface_options()``) with the lab's
        ``limits.pad_frame_lead`` in place of the file's lead, when set; :class:`ConfigError` if it is set for a
        policy whose commands are not relative to its pad."""
        lead = self.limits.pad_frame_lead
        if lead is None:
            return dict(options)
        if options.get("command_frame", "world") != "pad":
            raise ConfigError(
                f"limits.pad_frame_lead is {describe_lead(lead)}, but this policy commands velocities in the world "
                "frame, which carry no pad velocity to lead; remove limits.pad_frame_lead, or fly a pad-frame policy "
                "(e.g. data/policies/moving-slow-trackers.safetensors)."
            )
        return {**options, **lead_changes(lead)}

    def with_drones(self, num_drones: int, geometry: PlateGeometry | None = None, body: str = "plate") -> LabConfig:
        """A copy flying ``num_drones`` drones ``cf1 ... cfN``, each on its own pad of ``geometry`` on body ``body``.

        The pads are :meth:`marlander_lite.platforms.PlateGeometry.pad_offsets` of ``geometry`` (default: the
        simulators' plate, a grid 0.25 m apart), so the simulated lab of a rehearsal has the same plate; the
        URIs are ``radio://<k>/80/2M/E7E7E7E7<i>``, four drones per radio ``k``; simulated start positions are
        dropped (placed at random). Everything else is kept. Raises :class:`ConfigError` as a loaded file would.
        """
        geometry = geometry or PlateGeometry(pad_radius=self.drone_pads()[0].radius)
        offsets = geometry.pad_offsets(num_drones)
        drones = [
            {"name": f"cf{i + 1}", "uri": f"radio://{i // 4}/80/2M/E7E7E7E7{i + 1:02X}", "pad": f"pad{i + 1}"}
            for i in range(num_drones)
        ]
        pads = {
            f"pad{i + 1}": {
                "body": body,
                "offset": [round(float(v), 9) for v in offsets[i]],
                "radius": geometry.pad_radius,
            }
            for i in range(num_drones)
        }
        data = dataclasses.asdict(self) | {"drones": drones, "pads": pads}
        data["simulation"] = data["simulation"] | {"start_positions": None}
        return validate(LabConfig, data)

    @classmethod
    def from_dict(cls, data: Any) -> LabConfig:
        """Build and validate from a parsed YAML mapping; raises :class:`ConfigError`."""
        return validate(cls, data)

    def replace(self, **changes: Any) -> LabConfig:
        """A copy with some sections replaced, validated as a loaded file would be (:class:`ConfigError`)."""
        return validate(LabConfig, dataclasses.asdict(dataclasses.replace(self, **changes)))


def load_lab_policy(path: str | Path, lab: LabConfig) -> MLPPolicy:
    """Load a policy file for this lab, refusing one whose contract does not fit.

    Two kinds fly (:mod:`marlander_lite.policy_file`): a centralised policy (the paper's) only for the number of
    drones it was trained for, a shared policy (``neighbours`` set, ``num_drones: null``) for any number. Both must
    match the lab's ``limits.policy_max_speed`` and ``rates.policy_hz``, and the file's observation layout (13 or
    16 numbers per drone) sets whether the platform velocity is observed. Every refusal is a
    :class:`~marlander_lite.policy_file.PolicyFileError` naming the file.
    """
    contract = read_contract(path)
    if not contract.is_shared and contract.num_drones != lab.num_drones:
        raise PolicyFileError(
            f"{path}: a centralised policy flies exactly the number of drones it was trained for: this one "
            f"{contract.num_drones}, the lab config lists {lab.num_drones}. Fly a policy trained for "
            f"{lab.num_drones} drones, or a shared policy (any number of drones, e.g. "
            "data/policies/shared-quick-local.safetensors)."
        )
    try:
        task = lab.task_config(**lab.policy_options(contract.interface_options()))
    except ConfigError as error:
        raise PolicyFileError(f"{path}: {error}") from None
    return load_policy(path, task, shared=contract.is_shared)


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
