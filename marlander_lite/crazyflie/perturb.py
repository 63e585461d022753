"""Which tracker flies the simulated Crazyflie, and how the simulated drone differs from the one it assumes.

A policy that transfers to hardware must cope with a velocity tracker that is not the one it was
trained with, and with a drone that is not the one its controller was tuned for. Two knobs give
the PyBullet swarm those differences (GitHub issue "Policies that transfer"):

* ``controller``: one of :data:`CONTROLLERS`. ``"pid"`` is our cascaded PID
  (:class:`~marlander_lite.crazyflie.control.CascadedPID`, 48 Hz, tracks ``p + u dt`` and ``u``);
  ``"firmware"`` models the Crazyflie firmware's own PID, which is what really follows
  ``send_velocity_world_setpoint`` on hardware
  (:class:`~marlander_lite.crazyflie.firmware.FirmwareTracker`).
* :class:`Perturbation`: a heavier drone whose controller still assumes the nominal mass, a late
  command, and stiffer or softer outer gains.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, get_args

from marlander_lite.crazyflie.control import PUBLISHED_DSL_GAINS, CascadedPID, PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains, FirmwareTracker
from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig

Controller = Literal["pid", "firmware"]
"""Names of the velocity trackers the PyBullet swarm can fly with."""
CONTROLLERS: tuple[str, ...] = get_args(Controller)
"""``("pid", "firmware")``."""


HELD_OUT_TRACKER: dict[str, Any] = {"controller": "pid", "gains": PUBLISHED_DSL_GAINS, "physics": "bare"}
"""Options of the PyBullet swarm for a tracker nothing in this project was tuned on: the cascaded PID with the gains
gym-pybullet-drones publishes (:data:`~marlander_lite.crazyflie.control.PUBLISHED_DSL_GAINS`: no tilt limit, its
under-damped attitude loop at 48 Hz) over that project's default physics (no ground effect, drag or downwash). The
transfer matrix's ``held-out DSL PID`` column and ``marlander swarm evaluate --held-out`` fly it."""


def check_controller(controller: object) -> Controller:
    """``controller`` if it is one of :data:`CONTROLLERS`, else a ``ValueError`` listing them."""
    if not isinstance(controller, str) or controller not in CONTROLLERS:
        raise ValueError(f"Unknown controller {controller!r}; allowed: {', '.join(repr(c) for c in CONTROLLERS)}.")
    return controller  # type: ignore[return-value]


@dataclass(frozen=True)
class Perturbation:
    """How the simulated drone differs from the one its velocity tracker was tuned for.

    All three default to "no difference"; a default ``Perturbation()`` leaves the simulator
    bit-identical to one built without it.
    """

    mass_scale: float = 1.0
    """Factor on the drone's mass and inertia, in [0.5, 2] (1.15: a heavier battery). The tracker is
    NOT told: it keeps the nominal mass (the PID's weight feed-forward, the firmware's thrust base),
    as a real drone whose battery is heavier. Inertia scales with the mass (same shape, denser).
    The firmware's z integrator starts warm for the true mass (an episode begins after take-off)
    and keeps it in hover. The ``"pid"`` tracker cannot absorb it: its target ``p + u dt`` moves
    with the drone, so only its velocity term acts, and at 1.15 a zero command sinks at 8 cm/s."""
    latency_s: float = 0.0
    """How late each velocity command reaches the tracker (s), in [0, 0.5]: radio and motion-capture
    delays. Rounded to whole control ticks (1/48 s for ``"pid"``, one physics step for ``"firmware"``).
    For ``"pid"`` the delayed command carries its target ``p + u dt`` as computed when it was sent."""
    gain_scale: float = 1.0
    """Factor on the tracker's outer, velocity-loop gains, in (0, 5]: for ``"firmware"`` the velocity
    PID's kp and ki on all three axes, for ``"pid"`` the position / velocity gains ``pos_p``, ``pos_i``,
    ``pos_d``. Below 1 the drone answers a command more slowly, above 1 faster."""

    def __post_init__(self) -> None:
        for name in ("mass_scale", "latency_s", "gain_scale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"Perturbation.{name} must be a finite number, got {value!r}.")
        if not 0.5 <= self.mass_scale <= 2.0:
            raise ValueError(f"mass_scale must be in [0.5, 2] (a factor on the nominal mass), got {self.mass_scale!r}.")
        if self.latency_s < 0:
            raise ValueError(
                f"latency_s must be >= 0 s (a command cannot arrive before it is sent) and <= 0.5 s, "
                f"got {self.latency_s!r}."
            )
        if self.latency_s > 0.5:
            raise ValueError(f"latency_s must be >= 0 s and <= 0.5 s, got {self.latency_s!r}.")
        if not 0 < self.gain_scale <= 5.0:
            raise ValueError(f"gain_scale must be in (0, 5] (a factor on the outer gains), got {self.gain_scale!r}.")

    @property
    def is_nominal(self) -> bool:
        """True when nothing is perturbed."""
        return self.mass_scale == 1.0 and self.latency_s == 0.0 and self.gain_scale == 1.0

    def delay_ticks(self, tick_hz: float) -> int:
        """The latency in whole control ticks of ``1 / tick_hz`` s (nearest)."""
        return round(self.latency_s * tick_hz)


def build_perturbation(perturbation: Perturbation | Mapping[str, Any] | None) -> Perturbation:
    """The option ``perturbation`` as a :class:`Perturbation`: one, a mapping of its fields
    (``{"mass_scale": 1.15}``), or ``None`` for none."""
    if perturbation is None:
        return Perturbation()
    if isinstance(perturbation, Perturbation):
        return perturbation
    if isinstance(perturbation, Mapping):
        known = [f.name for f in dataclasses.fields(Perturbation)]
        unknown = sorted(set(perturbation) - set(known))
        if unknown:
            raise TypeError(f"Unknown perturbation field(s) {unknown}; allowed: {', '.join(known)}.")
        return Perturbation(**perturbation)
    raise TypeError(
        f"perturbation must be a Perturbation, a mapping of its fields or None, got {type(perturbation).__name__}."
    )


class CommandDelay:
    """A first-in first-out line of ``ticks`` commands: what goes in comes out ``ticks`` control ticks later.

    :meth:`fill` loads it with one command (what the drone was doing before, e.g. "hold still");
    each :meth:`push` adds the newest command and returns the one sent ``ticks`` ticks ago.
    """

    def __init__(self, ticks: int) -> None:
        if ticks < 1:
            raise ValueError(f"A command delay holds at least 1 tick, got {ticks}.")
        self.ticks = ticks
        self._line: deque = deque()

    def fill(self, command: Any) -> None:
        """Forget every command in flight; the next ``ticks`` pushes return ``command``."""
        self._line = deque([command] * self.ticks)

    def push(self, command: Any) -> Any:
        """Send ``command``; return the one that arrives now."""
        self._line.append(command)
        return self._line.popleft()


POS_GAINS = ("pos_p", "pos_i", "pos_d")
"""The :class:`~marlander_lite.crazyflie.control.PIDGains` fields that ``Perturbation.gain_scale`` multiplies."""


@dataclass(frozen=True)
class Tracker:
    """What :func:`build_tracker` hands the simulator."""

    physics: PhysicsConfig
    """The physics with ``control_hz`` the tracker's tick rate (``physics_hz`` for ``"firmware"``)."""
    body: CF2XParams
    """The simulated drone: the nominal one with ``mass_scale`` applied to its mass and inertia."""
    controller: CascadedPID | FirmwareTracker
    """The tracker; it believes in the nominal drone."""
    delay: CommandDelay | None
    """The command line of ``latency_s``, or None without latency."""


def build_tracker(
    controller: Controller,
    perturbation: Perturbation,
    params: CF2XParams,
    gains: PIDGains,
    physics: PhysicsConfig,
    num_drones: int,
    firmware_gains: FirmwareGains | None = None,
) -> Tracker:
    """The tracker named ``controller`` for ``num_drones`` drones of type ``params``, with ``perturbation`` applied."""
    if controller == "firmware":
        physics = physics.replace(control_hz=physics.physics_hz)
    dt = 1.0 / physics.control_hz
    scale = perturbation.gain_scale
    tracker: CascadedPID | FirmwareTracker
    body, s = params, perturbation.mass_scale
    if s != 1.0:
        ixx, iyy, izz = (float(v) for v in params.inertia * s)
        body = dataclasses.replace(params, mass=params.mass * s, ixx=ixx, iyy=iyy, izz=izz)
    if controller == "firmware":
        # Warm start: the z integrator holds what a hover of the simulated (heavier) drone taught it.
        warm = (body.hover_rpm - params.pwm_to_rpm_offset) / params.pwm_to_rpm_scale
        tracker = FirmwareTracker(params, firmware_gains or FirmwareGains(), num_drones, dt, scale, warm)
    else:
        if scale != 1.0:
            gains = dataclasses.replace(gains, **{k: tuple(scale * g for g in getattr(gains, k)) for k in POS_GAINS})
        tracker = CascadedPID(params, gains, num_drones, dt)
    ticks = perturbation.delay_ticks(physics.control_hz)
    return Tracker(physics, body, tracker, CommandDelay(ticks) if ticks > 0 else None)
