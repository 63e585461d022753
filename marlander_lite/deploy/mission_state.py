"""What a :class:`~marlander_lite.deploy.mission.Mission` remembers between ticks, in named pieces.

Besides its mode and each drone's phase (:mod:`marlander_lite.deploy.modes`), a mission keeps:

=================  =====================================================================================
``times``          :class:`Milestones`: when the flight started, took off, handed over to the policy
``stream``         :class:`PoseStream`: the poses forwarded to each Crazyflie, the latest estimate
``output``         :class:`PolicyOutput`: observation, action, velocity setpoints (safety-filtered)
``landings``       :class:`Landings`: each drone's landing under way, and how it ended
``requests``       :class:`Requests`: land and stop requests from keys, signals and hooks
``book``           :class:`TickBook`: the current tick's commands, and what is already in the flight log
=================  =====================================================================================

Times are mission times (s since :meth:`Mission.run` started) unless said otherwise; arrays are per drone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from marlander_lite.deploy.interrupts import describe

if TYPE_CHECKING:
    from marlander_lite.deploy.estimation import SwarmEstimate


@dataclass
class Milestones:
    """When the flight passed its milestones."""

    start: float = 0.0
    """The clock's reading when :meth:`Mission.run` started (s on the loop's clock): mission time 0."""
    takeoff: float | None = None
    """Take-off time (s); None: the pre-flight check has not passed (the drones were never armed)."""
    policy: float | None = None
    """Time the policy took over (s); None before."""
    policy_tick: int = 0
    """Tick at which the policy took over: a new action is due every ``rates.ticks_per_action`` ticks from it."""


@dataclass
class PoseStream:
    """Poses on their way from the motion-capture system to the estimator and the Crazyflies."""

    forwarded: np.ndarray
    """Arrival time of the last pose forwarded to each drone's Crazyflie (``send_extpose``) ``(N,)`` s; -inf: none."""
    streaming_since: np.ndarray
    """Mission time of each drone's first forwarded pose ``(N,)`` s; inf: none yet (its Kalman filter has none)."""
    rejected: set[str] = field(default_factory=set)
    """Bodies whose latest pose was rejected, already logged (``invalid_pose``: once per bad spell)."""
    last: SwarmEstimate | None = None
    """This tick's estimate (the best-effort landing after an error starts from it)."""

    @classmethod
    def empty(cls, n: int) -> PoseStream:
        """Nothing forwarded yet to ``n`` drones."""
        return cls(forwarded=np.full(n, -np.inf), streaming_since=np.full(n, np.inf))


FILTER_SPELL_GAP_S = 0.5
"""A drone's spell of safety filtering (or of the fence guard) ends when the filter has left its setpoint alone this
long (s); the next change starts a new spell, and a new ``safety_filter`` (``fence_guard``) event (one per spell, not
one per step)."""


def _new_spells(last: np.ndarray | None, changed: np.ndarray, t: float) -> tuple[np.ndarray, list[int]]:
    """``(last change times updated, drones starting a spell)`` for setpoints ``changed`` ``(N,)`` at time ``t``."""
    last = np.full(len(changed), -np.inf) if last is None else last
    new = changed & (t - last > FILTER_SPELL_GAP_S)
    last[changed] = t
    return last, [int(i) for i in np.flatnonzero(new)]


@dataclass
class PolicyOutput:
    """What the policy last said (eq. 2 observation in, velocity setpoints out)."""

    velocity: np.ndarray
    """The velocity setpoint of each drone ``(N, 3)`` m/s, world frame, re-sent every tick until the next action."""
    obs: np.ndarray | None = None
    """This tick's observation ``(N, obs_per_drone)``; None when the policy did not run this tick."""
    action: np.ndarray | None = None
    """This tick's action ``(3N,)`` in [-1, 1]; None when the policy did not run this tick."""
    valid: bool = True
    """The latest action was valid (finite, in range); False: hover until it is again."""
    unfiltered: np.ndarray | None = None
    """The policy's setpoints before the safety filter and the fence guard ``(N, 3)`` m/s."""
    filtered: np.ndarray | None = None
    """Whether the safety filter changed each drone's setpoint ``(N,)`` bool; None: no filter."""
    guarded: np.ndarray | None = None
    """Whether the fence guard (:meth:`~marlander_lite.deploy.safety.SafetyMonitor.keep_inside`) changed each drone's
    setpoint ``(N,)`` bool."""
    last_filtered: np.ndarray | None = None
    """Mission time the safety filter last changed each drone's setpoint ``(N,)`` s; -inf: never; None: no filter."""
    last_guarded: np.ndarray | None = None
    """Mission time the fence guard last changed each drone's setpoint ``(N,)`` s; -inf: never; None: not yet."""

    def starts(self, changed: np.ndarray, t: float) -> list[int]:
        """Drones whose setpoint the filter ``changed`` ``(N,)`` now, at mission time ``t`` (s), after leaving it
        alone for :data:`FILTER_SPELL_GAP_S` or more: a new spell of filtering, worth an event."""
        self.last_filtered, new = _new_spells(self.last_filtered, changed, t)
        return new

    def guard_starts(self, changed: np.ndarray, t: float) -> list[int]:
        """As :meth:`starts`, for the fence guard: drones it starts to slow down now, worth a ``fence_guard`` event."""
        self.last_guarded, new = _new_spells(self.last_guarded, changed, t)
        return new

    def annotate(self, i: int, command: dict[str, Any]) -> None:
        """Add to drone ``i``'s velocity record of the flight log whether the filter changed it (``filtered``; with
        the filter on), ``fence_guard: true`` if the fence guard did, and if either did, the policy's setpoint
        (``v_policy``, m/s); without a filter and the guard idle the record stays as it is."""
        guarded = self.guarded is not None and bool(self.guarded[i])
        filtered = self.filtered is not None and bool(self.filtered[i])
        if self.filtered is not None:
            command["filtered"] = filtered
        if guarded:
            command["fence_guard"] = True
        if (filtered or guarded) and self.unfiltered is not None:
            command["v_policy"] = np.round(self.unfiltered[i], 6).tolist()


@dataclass
class Requests:
    """Land and stop requests from outside the tick: emergency keys (a thread), signals (handlers), hooks.

    They are only appended to or set from there; the next tick acts on them and empties them.
    """

    land: list[str] = field(default_factory=list)
    """Reasons to land every drone (a list: Ctrl-C and a time limit in the same tick are both logged)."""
    kill: str | None = None
    """Reason to stop every motor; None: no such request."""
    signals: int = 0
    """Signals received during the flight: the first lands every drone, any later one stops every motor."""
    interrupted_by: str | None = None
    """The first signal (``"SIGINT"`` for Ctrl-C, ``"SIGTERM"``, ``"SIGHUP"``); None: none came."""

    def on_signal(self, name: str) -> None:
        """Ctrl-C or a signal (``"SIGINT"``, ``"SIGTERM"``, ``"SIGHUP"``): the first asks to land every drone,
        any later one to stop every motor. Runs inside a signal handler: it only sets requests."""
        self.signals += 1
        if self.interrupted_by is None:
            self.interrupted_by = name
        if self.signals == 1:
            self.land.append(describe(name))
        else:
            self.kill = f"second interrupt ({describe(name)})"

    def take_land_reasons(self) -> list[str]:
        """Empty :attr:`land`, oldest first (a key thread or a signal may append while this runs)."""
        reasons = []
        while self.land:
            reasons.append(self.land.pop(0))
        return reasons


@dataclass
class TickBook:
    """The current tick's commands, and the bookkeeping that puts every tick in the flight log exactly once."""

    commands: list[dict[str, Any]] = field(default_factory=list)
    """What each drone was sent this tick: ``{"kind": ...}``, kind ``velocity``, ``hover``, ``takeoff``, ``land``,
    ``stop`` or ``none``."""
    open: int | None = None
    """Index of the tick being worked on; None between ticks."""
    events_logged: int = 0
    """``Mission.events[:events_logged]`` are in tick records already ..."""
    events_marked: int = 0
    """... and ``[:events_marked]`` once the record being written is."""
    loop_ms: list[float] = field(default_factory=list)
    """Wall-clock work of every tick so far (ms)."""


class PlannedLanding(NamedTuple):
    """A high-level landing the loop sent to one drone."""

    start: float
    """Mission time the land command was sent (s)."""
    duration: float
    """How long the firmware's planner takes to come down (s)."""
    surface: float
    """Height of the surface it lands on (m)."""


@dataclass
class Landings:
    """What the loop knows about each drone's landing: the one under way, and how it ended. Arrays are ``(N,)``."""

    pad_radius: np.ndarray
    """Radius of each drone's pad (m): a touchdown counts inside it."""
    planned: dict[int, PlannedLanding] = field(default_factory=dict)
    """Drones in a high-level landing (phase ``landing``) -> that landing."""
    near_since: np.ndarray = field(init=False)
    """Mission time each drone began to linger above its pad (s); NaN: not lingering."""
    handover: np.ndarray = field(init=False)
    """Handed over to a high-level landing onto its pad: resting on the pad at its end counts as a touchdown."""
    on_pad: np.ndarray = field(init=False)
    """Touched down on its own pad under the policy (or rests on it after a hand-over)."""
    error: np.ndarray = field(init=False)
    """Horizontal distance from the pad centre at touchdown (m); NaN: not on its pad."""
    time: np.ndarray = field(init=False)
    """Touchdown time since the policy took over (s); NaN: not on its pad."""

    def __post_init__(self) -> None:
        n = len(self.pad_radius)
        self.near_since, self.handover = np.full(n, np.nan), np.zeros(n, dtype=bool)
        self.on_pad, self.error, self.time = np.zeros(n, dtype=bool), np.full(n, np.nan), np.full(n, np.nan)
