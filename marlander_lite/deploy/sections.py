"""The sections of the lab config: one frozen dataclass per YAML section (``mocap``, ``rates``, ...).

Each field carries its allowed values as a pydantic constraint (``Annotated[Real, Field(gt=0, le=3)]``:
a number in (0, 3]) and each ``__post_init__`` checks what involves several fields of its section
with :func:`~marlander_lite.deploy.schema.check`. What involves several sections (a drone without a
pad, a geofence margin too narrow for the speed limit, ...) is checked by
:class:`marlander_lite.deploy.config.LabConfig`, which puts them together and loads the file;
import them from there (``from marlander_lite.deploy.config import GeofenceConfig`` works).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields
from typing import Annotated, Any, Literal, get_args

from pydantic import BeforeValidator, Field, with_config

from marlander_lite.deploy.schema import (
    SCHEMA_CONFIG,
    ConfigError,
    Coordinate,
    Flag,
    Name,
    ParamName,
    Real,
    Text,
    Uri,
    Whole,
    check,
    validate,
)
from marlander_lite.platforms import MAX_INCLINATION_DEG, PLATFORM_KINDS, PlatformKind
from marlander_lite.simulators import SIMULATORS, SimulatorName
from marlander_lite.swarm.safety_filter import NAMED_SETTINGS, SafetyFilterConfig
from marlander_lite.task import MAX_PAD_FRAME_LEAD

MocapKind = Literal["vicon", "optitrack", "qualisys", "vrpn", "mock"]
MOCAP_KINDS: tuple[str, ...] = get_args(MocapKind)
SimulatorKind = SimulatorName
SIMULATOR_KINDS: tuple[str, ...] = SIMULATORS
"""The simulators a rehearsal can fly: those of :mod:`marlander_lite.simulators`, named as everywhere."""
RENAMED_SIMULATORS = {"pybullet": "crazyflie"}
"""Old simulator names a lab config may still use -> the current name (they load, with a ``FutureWarning``)."""


def current_simulator_name(name: Any, where: str = "simulation.simulator", stacklevel: int = 2) -> Any:
    """``name``, or its current spelling if it is an old one (:data:`RENAMED_SIMULATORS`), with a warning.

    The warning is a ``FutureWarning`` (shown by default, unlike ``DeprecationWarning``): whoever wrote the
    config reads it, not only a developer. ``stacklevel`` is ``warnings.warn``'s, counted from the caller.
    """
    new = RENAMED_SIMULATORS.get(name) if isinstance(name, str) else None
    if new is None:
        return name
    warnings.warn(
        f"{where}: {name!r} is the old name of the PyBullet Crazyflie simulator; write {new!r} instead "
        f"(the old name still works, but may be refused in a later version).",
        FutureWarning,
        stacklevel=stacklevel + 1,
    )
    return new


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class MocapConfig:
    """Where poses come from (``motioncapture.connect(kind, cfg)``)."""

    kind: MocapKind = "vicon"
    """Motion-capture system, one of ``MOCAP_KINDS``."""
    hostname: Annotated[Text, Field(max_length=253)] = ""
    """Address of the motion-capture server (required for every kind but ``mock``)."""
    connect_timeout_s: Annotated[Real, Field(gt=0, le=60)] = 5.0
    """Give up connecting after this long (s); the vicon kind blocks while no server answers."""
    options: Annotated[dict[Text, Text | Real], Field(max_length=32)] = field(default_factory=dict)
    """Extra ``cfg`` strings passed to ``motioncapture.connect`` (e.g. ``rigid_bodies`` for ``mock``)."""

    def __post_init__(self) -> None:
        check(self.kind in MOCAP_KINDS, f"mocap.kind is {self.kind!r}; allowed: {', '.join(MOCAP_KINDS)}.")
        check(
            self.kind == "mock" or bool(self.hostname),
            f"mocap.hostname is required for kind {self.kind!r} (the address of the motion-capture server).",
        )
        check(
            self.kind != "mock" or "rigid_bodies" in self.options,
            "mocap kind 'mock' needs options.rigid_bodies, e.g. 'cf1(0,0,0.01,1,0,0,0);plate(1,0,0,1,0,0,0)' "
            "(x,y,z,qw,qx,qy,qz per body).",
        )

    def connect_cfg(self) -> dict[str, str]:
        """The ``cfg`` dictionary for ``motioncapture.connect`` (every value a string)."""
        cfg = {"hostname": self.hostname} if self.hostname else {}
        cfg.update({k: str(v) for k, v in self.options.items()})
        return cfg


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class DroneConfig:
    """One Crazyflie."""

    name: Name
    """Its rigid-body name in the motion-capture system (letters, digits, ``_ . -``)."""
    uri: Uri
    """Its cflib URI, e.g. ``radio://0/80/2M/E7E7E7E701`` (``schema.URI_PATTERN``)."""
    pad: Name
    """The key of its landing pad under ``pads``."""


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class PadConfig:
    """One landing pad, located by a tracked rigid body (the pad itself, or the plate carrying it)."""

    body: Name
    """Rigid-body name of the tracked object carrying the pad (often one plate for all pads)."""
    offset: tuple[Coordinate, Coordinate, Coordinate] = (0.0, 0.0, 0.0)
    """Centre of the pad's top face in that body's frame (m)."""
    radius: Annotated[Real, Field(gt=0, le=1)] = 0.1
    """Pad radius (m): a touchdown counts as a landing within it."""


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class RatesConfig:
    """How often things happen."""

    policy_hz: Annotated[Real, Field(ge=1, le=100)] = 24.0
    """Rate the policy acts at (Hz); must equal the rate in the policy file."""
    loop_hz: Annotated[Real, Field(ge=1, le=250)] = 48.0
    """Rate of the control loop (Hz): poses to the drones, setpoints, safety, log. A whole multiple of policy_hz."""

    def __post_init__(self) -> None:
        check(
            self.policy_hz <= self.loop_hz <= 250,
            f"rates.loop_hz must be in [policy_hz, 250] = [{self.policy_hz}, 250] Hz, got {self.loop_hz} "
            "(the firmware needs a setpoint at least every 0.5 s; radios carry a few hundred packets/s).",
        )
        ratio = self.loop_hz / self.policy_hz
        check(
            abs(ratio - round(ratio)) < 1e-9,
            f"rates.loop_hz ({self.loop_hz}) must be a whole multiple of rates.policy_hz ({self.policy_hz}).",
        )

    @property
    def ticks_per_action(self) -> int:
        """Loop ticks per policy step."""
        return round(self.loop_hz / self.policy_hz)


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class LimitsConfig:
    """Speeds and heights of the flight."""

    max_speed: Annotated[Real, Field(gt=0, le=3)] = 1.0
    """Lab speed limit (m/s): every velocity setpoint is scaled down to at most this norm (the firmware
    does not clamp velocity setpoints)."""
    policy_max_speed: Annotated[Real, Field(gt=0, le=10)] = 3.0
    """What a policy action of 1.0 means (m/s); must equal the max_speed in the policy file."""
    takeoff_height: Annotated[Real, Field(ge=0.2, le=3)] = 1.0
    """Height the high-level commander takes off to before the policy starts (m, world z)."""
    takeoff_duration: Annotated[Real, Field(ge=0.5, le=10)] = 2.5
    """Time of the take-off manoeuvre (s)."""
    land_speed: Annotated[Real, Field(ge=0.05, le=1)] = 0.3
    """Descent speed of a safety landing (m/s); its duration is height / land_speed, at least 1 s."""
    touchdown_height: Annotated[Real, Field(gt=0, le=0.1)] = 0.02
    """A drone closer than this above its goal point, within its pad radius, has touched down (m)."""
    touchdown_speed: Annotated[Real, Field(gt=0, le=1)] = 0.5
    """... and slower than this relative to the pad (m/s); then its motors are stopped."""
    handover_height: Annotated[Real, Field(ge=0, le=0.3)] = 0.06
    """A drone lingering this close above its goal (m), within half its pad radius, for ``handover_dwell_s``
    over a pad slower than 0.1 m/s is landed on the pad by the high-level commander (0 disables)."""
    handover_dwell_s: Annotated[Real, Field(ge=0, le=10)] = 0.5
    """How long a drone must linger above its pad before the hand-over (s)."""
    max_flight_s: Annotated[Real, Field(ge=1, le=600)] = 60.0
    """After this long under the policy, every drone still flying is landed (s)."""
    pad_frame_lead: Annotated[Real, Field(ge=0, le=MAX_PAD_FRAME_LEAD)] | Literal["auto"] | None = None
    """Only for a policy whose commands are relative to its pad (``TaskConfig.command_frame`` ``"pad"``): how far ahead
    (s) the pad velocity its commands carry is led by the pad's acceleration, instead of the lead in the policy file;
    None: the file's; ``auto``: 0.6 times your drones' velocity-tracker lag, identified in flight from the setpoints
    sent and the velocities motion capture measures (:mod:`marlander_lite.pad_frame_lead`; the file's lead until then).
    A tracker that answers at once wants less lead than a slow one: flown with 0.3 s instead of its 0.5 s,
    `moving-slow-trackers` landed 90 % or more in 22 of the 24 moving cells of its transfer matrix instead of 20
    (docs/transfer.md, "The safety filter on a pad-frame policy, and the lead a tracker wants")."""
    vertical_bias: bool = False
    """Identify each drone's steady vertical velocity bias in flight, the climb or sink its velocity tracker adds to
    every setpoint when the drone is lighter or heavier than a controller without integral action assumes, and take it
    off the vertical setpoints sent (:mod:`marlander_lite.swarm.vertical_bias`; at most 0.4 m/s, after a second of
    flight). The Crazyflie firmware's velocity PID integrates such an error away; turn this on for a tracker that does
    not (docs/transfer.md, "A climb the controller does not know about")."""


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class GeofenceConfig:
    """The arena box (world frame, m). Crossing the inner box (shrunk by ``margin``) aborts the flight.

    The margin is the room a drone has to brake in: the lab config is refused unless it is at
    least :func:`marlander_lite.deploy.safety.required_margin` of ``limits.max_speed`` (the
    stopping distance from the firmware's overshoot of that speed, with its measured delay and
    deceleration).
    """

    x: tuple[Coordinate, Coordinate] = (-2.0, 2.0)
    y: tuple[Coordinate, Coordinate] = (-2.0, 2.0)
    z: tuple[Coordinate, Coordinate] = (0.0, 2.5)
    margin: Annotated[Real, Field(ge=0, le=4)] = 0.6
    """The soft fence lies this far inside the box (m, sides and ceiling): room to stop before the hard walls
    (0.59 m at the default max_speed of 1 m/s; 3.66 m at the largest, 3 m/s)."""

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, axis)
            check(lo < hi, f"geofence.{axis} must be [low, high] with low < high, got [{lo}, {hi}].")
            walls = 1 if axis == "z" else 2  # the floor is never raised: z loses the margin once, at the ceiling
            check(
                hi - lo > walls * self.margin,
                f"geofence.{axis} is not wider than {walls} x the margin ({self.margin} m): no room in the soft fence.",
            )

    def bounds(self, soft: bool = False) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """``(low xyz, high xyz)`` of the hard box, or of the soft box inside it (the floor is never raised)."""
        m = self.margin if soft else 0.0
        low = (self.x[0] + m, self.y[0] + m, self.z[0])
        high = (self.x[1] - m, self.y[1] - m, self.z[1] - m)
        return low, high

    def contains(self, pos: Any, soft: bool = False) -> bool:
        """Whether one point ``(3,)`` is inside the (soft) box; False for NaN."""
        low, high = self.bounds(soft)
        return all(lo <= float(p) <= hi for p, lo, hi in zip(pos, low, high, strict=True))


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class SafetyConfig:
    """Thresholds of the safety rules (see ``docs/lab_guide.md``)."""

    stale_hover_s: Real = 0.1
    """A body unseen (or invalid) for longer than this makes every flying drone hover (s)."""
    stale_land_s: Real = 0.5
    """... and for longer than this makes every flying drone land (s)."""
    geofence_hover_s: Annotated[Real, Field(ge=0, le=5)] = 0.5
    """After a geofence breach, hover this long before landing (s)."""
    max_body_speed: Annotated[Real, Field(ge=1, le=50)] = 8.0
    """A pose implying a faster jump than this is rejected as a mocap glitch (m/s)."""
    arming_timeout_s: Annotated[Real, Field(ge=0.5, le=60)] = 3.0
    """Give up the pre-flight check after this long (s)."""
    arming_max_speed: Annotated[Real, Field(gt=0, le=1)] = 0.1
    """Drones must be still before take-off (m/s)."""
    arming_max_tilt_deg: Annotated[Real, Field(gt=0, le=60)] = 20.0
    """Drones must be roughly level before take-off (degrees)."""
    arming_min_separation: Annotated[Real, Field(ge=0, le=2)] = 0.25
    """Drones must be at least this far apart before take-off (m)."""
    max_pad_tilt_deg: Annotated[Real, Field(gt=0, lt=90)] = 20.0
    """Every pad's normal (the z axis of the body carrying it) must be within this of vertical before take-off
    (degrees). The shipped policies are measured on plates tilted up to 15 degrees (``docs/scaling.md``); a pad
    tilted far more is often a rigid body whose z axis is not the pad normal (``docs/lab_guide.md``, "Tilted
    plates")."""
    land_timeout_margin_s: Annotated[Real, Field(ge=0.5, le=30)] = 3.0
    """A landing that has not ended this long after its planned duration ends with motors off (s)."""
    tumble_tilt_deg: Annotated[Real, Field(ge=30, le=90)] = 60.0
    """A flying drone tilted more than this (degrees) for ``tumble_s`` has tumbled (the firmware's velocity
    controller holds 20; PX4's failure detector flags 60)."""
    tumble_s: Annotated[Real, Field(ge=0, le=1)] = 0.1
    """How long a tilt beyond ``tumble_tilt_deg`` must last (s) before the drone's motors stop. A drone knocked over
    by another, its motors still on, is driven sideways by its own thrust (a rehearsal measured one 2.85 m beyond the
    hard fence); one bad mocap frame does not last this long."""

    def __post_init__(self) -> None:
        check(
            0 < self.stale_hover_s < self.stale_land_s <= 2.0,
            "safety thresholds must satisfy 0 < stale_hover_s < stale_land_s <= 2 s "
            f"(got {self.stale_hover_s}, {self.stale_land_s}): the firmware cuts motors after 2 s without setpoints.",
        )


_FILTER_DEFAULTS = SafetyFilterConfig()
NamedFilterSettings = Literal["moving-pads", "pad-frame"]
"""The names of :data:`~marlander_lite.swarm.safety_filter.NAMED_SETTINGS` a lab config's ``safety_filter.settings``
may give (a test keeps the two lists equal)."""


def expand_named_filter_settings(section: Any) -> Any:
    """A ``safety_filter`` section as parsed from YAML, with the keys of its ``settings`` name filled in where the
    section does not give them itself: ``{settings: pad-frame, reaction_time: 0.3}`` flies the ``pad-frame`` set with
    ``reaction_time`` 0.3, as ``--filter-settings pad-frame,reaction_time=0.3`` does on a command line. Anything else
    (no name, an unknown one, not a mapping) is passed on unchanged, for the schema to accept or refuse."""
    if not isinstance(section, dict) or section.get("settings") not in NAMED_SETTINGS:
        return section
    return NAMED_SETTINGS[section["settings"]] | section


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class SafetyFilterSection:
    """The in-flight safety filter (:mod:`marlander_lite.swarm.safety_filter`): every policy command is changed as
    little as needed to keep the drones ``min_distance`` apart and to land softly over the pad (``docs/lab_guide.md``).

    The keys override the fields of the same name of
    :class:`~marlander_lite.swarm.safety_filter.SafetyFilterConfig`; its other fields keep their defaults. Pads of
    neighbouring drones closer than ``min_distance`` are refused by :class:`~marlander_lite.deploy.config.LabConfig`.
    """

    enabled: Flag = True
    """Filter every policy command (false: the policy's commands go out as they are, only speed-clamped)."""
    settings: NamedFilterSettings | None = None
    """A named set of the keys below (``marlander_lite.swarm.safety_filter.NAMED_SETTINGS``, the same names as
    ``--filter-settings``): ``pad-frame`` for a pad-frame policy on moving pads (``moving-slow-trackers``),
    ``moving-pads`` for a world-frame one (``moving-smooth-16m``); keys given in the section override the set's.
    None: the filter's defaults, for static pads (docs/lab_guide.md, "Which policy to fly")."""
    min_distance: Annotated[Real, Field(gt=0, le=2)] = _FILTER_DEFAULTS.min_distance
    """``d_s``: the distance kept between drone centres (m); at most the distance between any two drones' pads on one
    body, and less than the filter's 1 m activation distance."""
    settled_min_distance: Annotated[Real, Field(gt=0, le=2)] = _FILTER_DEFAULTS.settled_min_distance
    """The distance kept from a drone already down on its pad (m). Lower it (not below eq. 6's 0.15 m) if a drone
    hovers beside its pad next to landed neighbours until the flight time runs out."""
    gain: Annotated[Real, Field(gt=0, le=50)] = _FILTER_DEFAULTS.gain
    """``gamma`` (1/s): largest closing speed per metre left to ``min_distance``; also how hard a descent below the
    approach cone is braked."""
    reaction_time: Annotated[Real, Field(ge=0, le=1)] = _FILTER_DEFAULTS.reaction_time
    """``tau`` (s): positions are predicted this far ahead (tracker lag + mocap and radio latency)."""
    touchdown_speed: Annotated[Real, Field(ge=0, le=1)] = _FILTER_DEFAULTS.touchdown_speed
    """``v_td`` of the descent guard (m/s): the drone can always brake to it before touching down; 0: no guard."""
    cone_slope: Annotated[Real, Field(ge=0, le=10)] = _FILTER_DEFAULTS.cone_slope
    """Approach guard: no descent below ``cone_slope`` m of height per m of horizontal distance from the pad (up to
    0.3 m); 0: no guard."""
    cone_radius: Annotated[Real, Field(ge=0, le=0.1)] = _FILTER_DEFAULTS.cone_radius
    """Approach guard: within this horizontal distance of its pad centre (m) a drone may descend all the way. On a
    moving pad the drone trails its pad by a few centimetres; 0.04 lifted moving-pad landings (docs/transfer.md)."""
    approach_climb: Annotated[Real, Field(ge=0, le=2)] = _FILTER_DEFAULTS.approach_climb
    """Approach guard: a drone below its surface (low beside its pad) is pushed back up at this share of ``gain`` per
    metre below it, instead of only having its descent stopped; 0: off. 1 for a slow tracker on moving pads, where a
    drone trailing its pad low over the plate sank on and touched down beside its pad (docs/transfer.md, "Climbing back
    instead of touching down beside the pad")."""
    centring_gain: Annotated[Real, Field(ge=0, le=10)] = _FILTER_DEFAULTS.centring_gain
    """Centring (1/s): over its pad and below 0.3 m, a drone's horizontal command gains this times its offset from
    the pad centre, so that a policy hovering off-centre still lands on the centre; 0: no centring."""
    settled_sink_limit: Annotated[Real, Field(ge=0, le=3)] = _FILTER_DEFAULTS.settled_sink_limit
    """Fastest descent (m/s) the policy may command a drone the filter counts as settled (within 3 cm of its goal,
    over its pad, slow); 0: no limit, as before 2026-11-26. With a slow tracker 0.8 (the default) cut touchdowns above
    0.5 m/s from 14 to 1 in 400 episodes (docs/transfer.md)."""
    pad_lead: Annotated[Real, Field(ge=0, le=1)] = _FILTER_DEFAULTS.pad_lead
    """Pad lead (s): every command gains this times its pad's acceleration, estimated from the pad's tracked velocity,
    so that a lagging tracker keeps up with a pad that brakes, reverses or turns; 0: off. On moving pads 0.2 (with
    ``cone_radius`` 0.04 and ``reaction_time`` 0.35; docs/transfer.md)."""
    low_velocity_step: Annotated[Real, Field(ge=0, le=3)] = _FILTER_DEFAULTS.low_velocity_step
    """Velocity-step limit (m/s): below 0.3 m above its goal, a drone's horizontal setpoint may differ from its tracked
    velocity by at most this, which bounds how far its velocity tracker tilts it; 0: off. 0.5 for a tracker without a
    tilt limit (the Crazyflie firmware clamps at 20 degrees): through such a tracker it lifted `paper-robust`'s static
    landings in simulation (docs/transfer.md, "A held-out tracker")."""
    latency_compensation: Annotated[Real, Field(ge=0, le=0.5)] = _FILTER_DEFAULTS.latency_compensation
    """Latency compensation (s): the policy and the filter's guards act on each drone and pad predicted this far ahead
    at their tracked velocities, where they will be when the command acts; 0: off. On moving pads 0.12, with the other
    moving-pad settings: with it, 60 ms of command latency cost the `moving` policy at most 2.5 points on moving pads
    in the simulators (docs/transfer.md, "Latency compensation")."""
    identified_lag_share: Annotated[Real, Field(ge=0, le=2)] = _FILTER_DEFAULTS.identified_lag_share
    """Identified latency compensation: the runner identifies the drones' velocity tracker in flight, from the setpoints
    sent and the velocities that followed, and sets the latency compensation to this share of its time constant (at
    most 0.5 s), starting from ``latency_compensation``; 0: off, the compensation stays ``latency_compensation``. For a
    tracker whose lag you have not measured (docs/transfer.md, "A compensation the flight identifies")."""
    low_velocity_step_lag: Annotated[Real, Field(ge=0, le=2)] = _FILTER_DEFAULTS.low_velocity_step_lag
    """Reference time constant (s) of the velocity-step limit: the runner identifies the drones' velocity tracker in
    flight and scales ``low_velocity_step`` by ``max(1, T / this)``, so that a slow tracker, which tilts less for the
    same step and needs its setpoint well ahead of its velocity, gets a larger one; 0: off. 0.45 with
    ``low_velocity_step`` 0.5 (docs/transfer.md, "A velocity step that follows the tracker")."""

    def __post_init__(self) -> None:
        self.filter_config()  # the filter's own checks, as a ConfigError naming this section

    def with_settings(self, settings: dict[str, Any]) -> SafetyFilterSection:
        """These keys with ``settings`` changed (e.g. a command line's, ``safety_filter.parse_settings``), checked as
        the config loader checks them: an unknown key or a value out of range raises :class:`ConfigError`."""
        return validate(SafetyFilterSection, {f.name: getattr(self, f.name) for f in fields(self)} | settings)

    def filter_config(self) -> SafetyFilterConfig:
        """The :class:`SafetyFilterConfig` these keys set (its defaults for the rest); :class:`ConfigError` if the
        filter refuses them."""
        overrides = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("enabled", "settings")}
        try:
            return SafetyFilterConfig(**overrides)
        except ValueError as error:
            raise ConfigError(f"the safety filter refuses these settings: {error}") from None


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class CrazyflieParamsConfig:
    """Firmware parameters set on every Crazyflie after connecting (cflib ``param.set_value``)."""

    estimator: Whole = 2
    """``stabilizer.estimator``: 2 is the Kalman filter, the only one that fuses ``send_extpose``."""
    controller: Whole = 1
    """``stabilizer.controller``: 1 is PID, which tracks velocity setpoints well."""
    ext_quat_std_dev: Annotated[Real, Field(gt=0, le=1)] = 0.008
    """``locSrv.extQuatStdDev``: trust in the mocap attitude (rad)."""
    extra: Annotated[dict[ParamName, Real], Field(max_length=64)] = field(default_factory=dict)
    """More parameters, ``group.name: value``, set after the ones above."""
    arm: Flag = False
    """Send an arming request after connecting (``supervisor.send_arming_request``): needed by the
    Crazyflie 2.1 Brushless; the brushed Crazyflie 2.x of the paper arms itself."""
    param_timeout_s: Annotated[Real, Field(gt=0, le=60)] = 5.0
    """Each parameter write must be confirmed by the Crazyflie within this long (s)."""

    def __post_init__(self) -> None:
        check(
            self.estimator == 2,
            f"crazyflie.estimator must be 2 (Kalman), got {self.estimator}: only Kalman fuses external poses.",
        )
        check(self.controller in (1, 2, 3, 4), "crazyflie.controller must be 1 (PID, recommended), 2, 3 or 4.")

    def as_params(self) -> dict[str, float]:
        """Every parameter to set, in order."""
        return {
            "stabilizer.estimator": self.estimator,
            "stabilizer.controller": self.controller,
            "locSrv.extQuatStdDev": self.ext_quat_std_dev,
            **self.extra,
        }


@with_config(SCHEMA_CONFIG)
@dataclass(frozen=True)
class SimulationConfig:
    """The simulated lab of ``marlander deploy --sim`` (ignored on hardware)."""

    simulator: Annotated[SimulatorKind, BeforeValidator(lambda name: current_simulator_name(name))] = "crazyflie"
    """Physics: ``crazyflie`` (the PyBullet Crazyflie model) or ``pointmass`` (fast); the old name ``pybullet``
    still loads, with a warning."""
    platform: PlatformKind = "static-floor"
    """Platform motion, one of ``marlander_lite.platforms.PLATFORM_KINDS``."""
    platform_speed: Annotated[Real, Field(gt=0, le=2)] | None = None
    """Tool speed of a moving platform (m/s)."""
    inclination_deg: Annotated[Real, Field(ge=0, lt=MAX_INCLINATION_DEG)] = 0.0
    """The simulated plate tilts by this (degrees; beyond the paper, ``platforms.PlateGeometry.inclination_deg``).
    The pads' offsets stay in the plate's frame; the simulated mocap reports the plate body tilted."""
    tilt_axis_deg: Annotated[Real, Field(ge=-360, le=360)] = 0.0
    """Direction of the horizontal axis the plate tilts about (degrees from +x; 0: its +y edge rises)."""
    start_positions: Annotated[tuple[tuple[Coordinate, Coordinate], ...], Field(max_length=64)] | None = None
    """Where the drones stand on the floor (x, y per drone, m); random when left out."""
    seed: Annotated[Whole, Field(ge=0, lt=2**32)] = 0
    """Seed of the simulated lab (platform placement, start positions, mocap noise)."""
    pos_noise_std: Annotated[Real, Field(ge=0, le=1)] = 0.001
    """Mocap position noise (m)."""
    quat_noise_std: Annotated[Real, Field(ge=0, le=1)] = 0.002
    """Mocap quaternion noise per component."""
    latency_s: Annotated[Real, Field(ge=0, le=1)] = 0.01
    """Mocap latency (s), rounded up to whole loop ticks."""
    drop_rate: Annotated[Real, Field(ge=0, lt=1)] = 0.0
    """Probability that a mocap frame is lost."""
    occlusion_rate: Annotated[Real, Field(ge=0, lt=1)] = 0.0
    """Probability that a body is missing from a frame."""
    max_time_s: Annotated[Real, Field(ge=1, le=600)] = 60.0
    """Simulated time after which the rehearsal stops (s)."""

    def __post_init__(self) -> None:
        if self.simulator in RENAMED_SIMULATORS:  # built in Python, not loaded: pydantic did not rename it
            object.__setattr__(self, "simulator", current_simulator_name(self.simulator, stacklevel=3))
        check(
            self.simulator in SIMULATOR_KINDS,
            f"simulation.simulator is {self.simulator!r}; allowed: {', '.join(SIMULATOR_KINDS)}.",
        )
        check(
            self.platform in PLATFORM_KINDS,
            f"simulation.platform is {self.platform!r}; allowed: {', '.join(PLATFORM_KINDS)}.",
        )
