"""The lab configuration: one YAML file says which Crazyflies, which rigid bodies, which rates and limits.

Every section is a frozen dataclass; :func:`load_lab_config` reads the YAML, refuses unknown
keys and wrong types, and checks the values (a drone without a pad, a rate out of range, a
geofence that does not contain the take-off height, ...). Each error names the key that is
wrong and what is allowed. ``marlander_lite/deploy/example_lab.yaml`` is a complete, commented
example.

Frames and units: the motion-capture world frame (Vicon: z up), metres, seconds, m/s.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args

import yaml

from marlander_lite.deploy.schema import ConfigError, build, check
from marlander_lite.platforms import PLATFORM_KINDS, PlatformKind
from marlander_lite.policy_file import MLPPolicy, load_policy, read_contract
from marlander_lite.task import OBS_PER_DRONE, TaskConfig

MocapKind = Literal["vicon", "optitrack", "qualisys", "vrpn", "mock"]
MOCAP_KINDS: tuple[str, ...] = get_args(MocapKind)
SimulatorKind = Literal["pybullet", "pointmass"]
SIMULATOR_KINDS: tuple[str, ...] = get_args(SimulatorKind)
EXAMPLE_CONFIG = Path(__file__).with_name("example_lab.yaml")
"""The example lab config shipped with the package."""


@dataclass(frozen=True)
class MocapConfig:
    """Where poses come from (``motioncapture.connect(kind, cfg)``)."""

    kind: MocapKind = "vicon"
    """Motion-capture system, one of ``MOCAP_KINDS``."""
    hostname: str = ""
    """Address of the motion-capture server (required for every kind but ``mock``)."""
    connect_timeout_s: float = 5.0
    """Give up connecting after this long (s); the vicon kind blocks while no server answers."""
    options: dict[str, str] = field(default_factory=dict)
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
        check(0 < self.connect_timeout_s <= 60, "mocap.connect_timeout_s must be in (0, 60] s.")

    def connect_cfg(self) -> dict[str, str]:
        """The ``cfg`` dictionary for ``motioncapture.connect`` (every value a string)."""
        cfg = {"hostname": self.hostname} if self.hostname else {}
        cfg.update({k: str(v) for k, v in self.options.items()})
        return cfg


@dataclass(frozen=True)
class DroneConfig:
    """One Crazyflie."""

    name: str
    """Its rigid-body name in the motion-capture system."""
    uri: str
    """Its cflib URI, e.g. ``radio://0/80/2M/E7E7E7E701``."""
    pad: str
    """The key of its landing pad under ``pads``."""


@dataclass(frozen=True)
class PadConfig:
    """One landing pad, located by a tracked rigid body (the pad itself, or the plate carrying it)."""

    body: str
    """Rigid-body name of the tracked object carrying the pad (often one plate for all pads)."""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Centre of the pad's top face in that body's frame (m)."""
    radius: float = 0.1
    """Pad radius (m): a touchdown counts as a landing within it."""

    def __post_init__(self) -> None:
        check(0 < self.radius <= 1.0, f"pad radius must be in (0, 1] m, got {self.radius}.")


@dataclass(frozen=True)
class RatesConfig:
    """How often things happen."""

    policy_hz: float = 24.0
    """Rate the policy acts at (Hz); must equal the rate in the policy file."""
    loop_hz: float = 48.0
    """Rate of the control loop (Hz): poses to the drones, setpoints, safety, log. A whole multiple of policy_hz."""

    def __post_init__(self) -> None:
        check(1 <= self.policy_hz <= 100, f"rates.policy_hz must be in [1, 100] Hz, got {self.policy_hz}.")
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


@dataclass(frozen=True)
class LimitsConfig:
    """Speeds and heights of the flight."""

    max_speed: float = 1.0
    """Lab speed limit (m/s): every velocity setpoint is scaled down to at most this norm (the firmware
    does not clamp velocity setpoints)."""
    policy_max_speed: float = 3.0
    """What a policy action of 1.0 means (m/s); must equal the max_speed in the policy file."""
    takeoff_height: float = 1.0
    """Height the high-level commander takes off to before the policy starts (m, world z)."""
    takeoff_duration: float = 2.5
    """Time of the take-off manoeuvre (s)."""
    land_speed: float = 0.3
    """Descent speed of a safety landing (m/s); its duration is height / land_speed, at least 1 s."""
    touchdown_height: float = 0.02
    """A drone closer than this above its goal point, within its pad radius, has touched down (m)."""
    touchdown_speed: float = 0.5
    """... and slower than this relative to the pad (m/s); then its motors are stopped."""
    handover_height: float = 0.06
    """A drone lingering this close above its goal (m), within half its pad radius, for ``handover_dwell_s``
    over a pad slower than 0.1 m/s is landed on the pad by the high-level commander (0 disables)."""
    handover_dwell_s: float = 0.5
    """How long a drone must linger above its pad before the hand-over (s)."""
    max_flight_s: float = 60.0
    """After this long under the policy, every drone still flying is landed (s)."""

    def __post_init__(self) -> None:
        check(0 < self.max_speed <= 3.0, f"limits.max_speed must be in (0, 3] m/s, got {self.max_speed}.")
        check(0 < self.policy_max_speed <= 10.0, "limits.policy_max_speed must be in (0, 10] m/s.")
        check(0.2 <= self.takeoff_height <= 3.0, "limits.takeoff_height must be in [0.2, 3] m.")
        check(0.5 <= self.takeoff_duration <= 10.0, "limits.takeoff_duration must be in [0.5, 10] s.")
        check(0.05 <= self.land_speed <= 1.0, "limits.land_speed must be in [0.05, 1] m/s.")
        check(0 < self.touchdown_height <= 0.1, "limits.touchdown_height must be in (0, 0.1] m.")
        check(0 < self.touchdown_speed <= 1.0, "limits.touchdown_speed must be in (0, 1] m/s.")
        check(0 <= self.handover_height <= 0.3, "limits.handover_height must be in [0, 0.3] m (0 disables it).")
        check(0 <= self.handover_dwell_s <= 10, "limits.handover_dwell_s must be in [0, 10] s.")
        check(1 <= self.max_flight_s <= 600, "limits.max_flight_s must be in [1, 600] s.")


@dataclass(frozen=True)
class GeofenceConfig:
    """The arena box (world frame, m). Crossing the inner box (shrunk by ``margin``) aborts the flight."""

    x: tuple[float, float] = (-2.0, 2.0)
    y: tuple[float, float] = (-2.0, 2.0)
    z: tuple[float, float] = (0.0, 2.5)
    margin: float = 0.3
    """The soft fence lies this far inside the box (m): room to stop before the hard walls."""

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, axis)
            check(lo < hi, f"geofence.{axis} must be [low, high] with low < high, got [{lo}, {hi}].")
            check(hi - lo > 2 * self.margin, f"geofence.{axis} is narrower than twice the margin ({self.margin} m).")
        check(0 <= self.margin <= 1.0, f"geofence.margin must be in [0, 1] m, got {self.margin}.")

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


@dataclass(frozen=True)
class SafetyConfig:
    """Thresholds of the safety rules (see ``docs/lab_guide.md``)."""

    stale_hover_s: float = 0.1
    """A body unseen (or invalid) for longer than this makes every flying drone hover (s)."""
    stale_land_s: float = 0.5
    """... and for longer than this makes every flying drone land (s)."""
    geofence_hover_s: float = 0.5
    """After a geofence breach, hover this long before landing (s)."""
    max_body_speed: float = 8.0
    """A pose implying a faster jump than this is rejected as a mocap glitch (m/s)."""
    arming_timeout_s: float = 3.0
    """Give up the pre-flight check after this long (s)."""
    arming_max_speed: float = 0.1
    """Drones must be still before take-off (m/s)."""
    arming_max_tilt_deg: float = 20.0
    """Drones must be roughly level before take-off (degrees)."""
    arming_min_separation: float = 0.25
    """Drones must be at least this far apart before take-off (m)."""
    land_timeout_margin_s: float = 3.0
    """A landing that has not ended this long after its planned duration ends with motors off (s)."""

    def __post_init__(self) -> None:
        check(
            0 < self.stale_hover_s < self.stale_land_s <= 2.0,
            "safety thresholds must satisfy 0 < stale_hover_s < stale_land_s <= 2 s "
            f"(got {self.stale_hover_s}, {self.stale_land_s}): the firmware cuts motors after 2 s without setpoints.",
        )
        check(0 <= self.geofence_hover_s <= 5, "safety.geofence_hover_s must be in [0, 5] s.")
        check(1 <= self.max_body_speed <= 50, "safety.max_body_speed must be in [1, 50] m/s.")
        check(0.5 <= self.arming_timeout_s <= 60, "safety.arming_timeout_s must be in [0.5, 60] s.")
        check(0 < self.arming_max_speed <= 1, "safety.arming_max_speed must be in (0, 1] m/s.")
        check(0 < self.arming_max_tilt_deg <= 60, "safety.arming_max_tilt_deg must be in (0, 60] degrees.")
        check(0 <= self.arming_min_separation <= 2, "safety.arming_min_separation must be in [0, 2] m.")
        check(0.5 <= self.land_timeout_margin_s <= 30, "safety.land_timeout_margin_s must be in [0.5, 30] s.")


@dataclass(frozen=True)
class CrazyflieParamsConfig:
    """Firmware parameters set on every Crazyflie after connecting (cflib ``param.set_value``)."""

    estimator: int = 2
    """``stabilizer.estimator``: 2 is the Kalman filter, the only one that fuses ``send_extpose``."""
    controller: int = 1
    """``stabilizer.controller``: 1 is PID, which tracks velocity setpoints well."""
    ext_quat_std_dev: float = 0.008
    """``locSrv.extQuatStdDev``: trust in the mocap attitude (rad)."""
    extra: dict[str, float] = field(default_factory=dict)
    """More parameters, ``group.name: value``, set after the ones above."""
    arm: bool = False
    """Send an arming request after connecting (``supervisor.send_arming_request``): needed by the
    Crazyflie 2.1 Brushless; the brushed Crazyflie 2.x of the paper arms itself."""
    param_timeout_s: float = 5.0
    """Each parameter write must be confirmed by the Crazyflie within this long (s)."""

    def __post_init__(self) -> None:
        check(
            self.estimator == 2,
            f"crazyflie.estimator must be 2 (Kalman), got {self.estimator}: only Kalman fuses external poses.",
        )
        check(self.controller in (1, 2, 3, 4), "crazyflie.controller must be 1 (PID, recommended), 2, 3 or 4.")
        check(0 < self.ext_quat_std_dev <= 1, "crazyflie.ext_quat_std_dev must be in (0, 1] rad.")
        for name in self.extra:
            check(name.count(".") == 1, f"crazyflie.extra key {name!r} must be 'group.name'.")

    def as_params(self) -> dict[str, float]:
        """Every parameter to set, in order."""
        return {
            "stabilizer.estimator": self.estimator,
            "stabilizer.controller": self.controller,
            "locSrv.extQuatStdDev": self.ext_quat_std_dev,
            **self.extra,
        }


@dataclass(frozen=True)
class SimulationConfig:
    """The simulated lab of ``marlander deploy --sim`` (ignored on hardware)."""

    simulator: SimulatorKind = "pybullet"
    """Physics: ``pybullet`` (the Crazyflie model) or ``pointmass`` (fast)."""
    platform: PlatformKind = "static-floor"
    """Platform motion, one of ``marlander_lite.platforms.PLATFORM_KINDS``."""
    platform_speed: float | None = None
    """Tool speed of a moving platform (m/s)."""
    start_positions: tuple[tuple[float, float], ...] | None = None
    """Where the drones stand on the floor (x, y per drone, m); random when left out."""
    seed: int = 0
    """Seed of the simulated lab (platform placement, start positions, mocap noise)."""
    pos_noise_std: float = 0.001
    """Mocap position noise (m)."""
    quat_noise_std: float = 0.002
    """Mocap quaternion noise per component."""
    latency_s: float = 0.01
    """Mocap latency (s), rounded up to whole loop ticks."""
    drop_rate: float = 0.0
    """Probability that a mocap frame is lost."""
    occlusion_rate: float = 0.0
    """Probability that a body is missing from a frame."""
    max_time_s: float = 60.0
    """Simulated time after which the rehearsal stops (s)."""

    def __post_init__(self) -> None:
        check(
            self.simulator in SIMULATOR_KINDS,
            f"simulation.simulator is {self.simulator!r}; allowed: {', '.join(SIMULATOR_KINDS)}.",
        )
        check(
            self.platform in PLATFORM_KINDS,
            f"simulation.platform is {self.platform!r}; allowed: {', '.join(PLATFORM_KINDS)}.",
        )
        for name in ("pos_noise_std", "quat_noise_std", "latency_s"):
            check(0 <= getattr(self, name) <= 1, f"simulation.{name} must be in [0, 1].")
        check(0 <= self.drop_rate < 1 and 0 <= self.occlusion_rate < 1, "simulation drop/occlusion rates: [0, 1).")
        check(1 <= self.max_time_s <= 600, "simulation.max_time_s must be in [1, 600] s.")


@dataclass(frozen=True)
class LabConfig:
    """Everything the deployment needs to know about the lab."""

    drones: tuple[DroneConfig, ...]
    pads: dict[str, PadConfig]
    mocap: MocapConfig
    rates: RatesConfig = field(default_factory=RatesConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    geofence: GeofenceConfig = field(default_factory=GeofenceConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    crazyflie: CrazyflieParamsConfig = field(default_factory=CrazyflieParamsConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    log_dir: str = "flight_logs"
    """Folder for flight logs (relative to the working directory)."""

    def __post_init__(self) -> None:
        check(len(self.drones) >= 1, "drones: list at least one drone (name, uri, pad).")
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
        return build(cls, data, "config")

    def replace(self, **changes: Any) -> LabConfig:
        """A copy with some sections replaced."""
        return dataclasses.replace(self, **changes)


def load_lab_policy(path: str | Path, lab: LabConfig) -> MLPPolicy:
    """Load a policy file for this lab, refusing one whose contract does not fit (drones, speed, rate)."""
    contract = read_contract(path)
    return load_policy(path, lab.task_config(contract.obs_per_drone > OBS_PER_DRONE))


def load_lab_config(path: str | Path) -> LabConfig:
    """Read and validate a lab config YAML file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No lab config at {path}; start from {EXAMPLE_CONFIG}.")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ConfigError(f"{path} is not valid YAML: {error}") from None
    try:
        return LabConfig.from_dict(data)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
