"""The mission's mode, each drone's phase, and the one table that says which change may follow which.

A flight has one :class:`MissionMode` for the whole swarm and one :class:`DronePhase` per drone. The
mode says what the loop does this tick (check, take off, run the policy, land); the phase says what
one drone is doing (a drone may already be down while the others fly, or lost with its link). Every
change of either goes through :func:`check_change` against :data:`MODE_TRANSITIONS` or
:data:`PHASE_TRANSITIONS`: ``current -> {next: what triggers it}``. A change missing from its table
is a bug and raises :class:`IllegalTransition` (inside :meth:`Mission.run <marlander_lite.deploy.mission.Mission.run>`
that lands every drone, like any error); staying in the same mode or phase is always allowed.

``docs/lab_guide.md`` shows both tables (*Mission modes and drone phases*); ``tests/test_deploy_modes.py``
checks that the page and these tables agree word for word. The triggers name the flight-log events
(``armed``, ``link_lost``, ...) that each change leaves behind.
"""

from __future__ import annotations

from enum import Enum
from typing import TypeVar


class _Named(str, Enum):
    """A string enum that prints as its value (the word the flight log and the docs use)."""

    def __str__(self) -> str:
        return self.value


class MissionMode(_Named):
    """What the whole mission does this tick (``Mission.mode``; the ``mode`` of a flight-log tick)."""

    PREFLIGHT = "preflight"
    """Stream poses to the Crazyflies, run the pre-flight check; no motor runs."""
    TAKEOFF = "takeoff"
    """Every drone climbs to ``limits.takeoff_height`` on the firmware's high-level commander."""
    POLICY = "policy"
    """The policy flies the drones (velocity setpoints), under the safety rules."""
    LANDING = "landing"
    """Every drone still flying was sent a high-level landing; waiting until each rests."""
    DONE = "done"
    """Every drone down or lost, the check given up, or stopped: the loop ends."""


class DronePhase(_Named):
    """What one drone is doing (``Mission.phase[i]``; the ``phase`` list of a flight-log tick)."""

    IDLE = "idle"
    """On the ground before take-off, motors off."""
    TAKEOFF = "takeoff"
    """Climbing on the high-level commander."""
    POLICY = "policy"
    """Flying the policy's velocity setpoint."""
    HOVER = "hover"
    """Told to hold still (velocity 0) by a safety rule; the policy resumes when the data is good again."""
    LANDING = "landing"
    """Coming down on the high-level commander onto the surface under it."""
    DOWN = "down"
    """Motors off (landed, touched something, or stopped)."""
    LOST = "lost"
    """Its radio link is lost: nothing more is sent to it (its firmware lands it blind, then cuts the motors)."""


FLYING: frozenset[DronePhase] = frozenset({DronePhase.TAKEOFF, DronePhase.POLICY, DronePhase.HOVER, DronePhase.LANDING})
"""Phases in which a drone's motors run."""
AIRBORNE: frozenset[DronePhase] = frozenset({DronePhase.TAKEOFF, DronePhase.POLICY, DronePhase.HOVER})
"""Flying phases a landing can still be sent to (a landing drone is landing already)."""
UNDER_POLICY: frozenset[DronePhase] = frozenset({DronePhase.POLICY, DronePhase.HOVER})
"""Phases in which the loop sends a velocity setpoint every tick."""
FINISHED: frozenset[DronePhase] = frozenset({DronePhase.DOWN, DronePhase.LOST})
"""Phases a drone does not leave for flight again; the mission is done when every drone is in one."""

_M, _P = MissionMode, DronePhase
_STOP = "a stop request (`k` key, a second signal: `emergency`)"
_LAND_REQUEST = "a land request (Enter, Ctrl-C, SIGTERM, SIGHUP, a time limit: `interrupt`)"
_ALL_DOWN = "every drone down or lost, or " + _STOP

MODE_TRANSITIONS: dict[MissionMode, dict[MissionMode, str]] = {
    _M.PREFLIGHT: {
        _M.TAKEOFF: "the pre-flight check passes and every drone has had poses for `min_preflight_s` (`armed`)",
        _M.DONE: "no pass within `safety.arming_timeout_s` (`arming_failed`), " + _LAND_REQUEST + ", or " + _STOP,
    },
    _M.TAKEOFF: {
        _M.POLICY: "after `limits.takeoff_duration`, every drone within 0.1 m of `limits.takeoff_height` "
        "(`policy_start`)",
        _M.LANDING: "a safety rule says land (`stale_land`, `land` after `geofence_breach`), the height not reached "
        "`takeoff_duration` + 3 s after take-off (`land`), a lost link (`link_lost`), a drone tumbled (`tumbled`), or "
        + _LAND_REQUEST,
        _M.DONE: _ALL_DOWN,
    },
    _M.POLICY: {
        _M.LANDING: "a safety rule says land (`stale_land`, `land` after `geofence_breach` or bad actions), "
        "`limits.max_flight_s` under the policy (`flight_timeout`), a lost link (`link_lost`), a drone tumbled "
        "(`tumbled`), or " + _LAND_REQUEST,
        _M.DONE: _ALL_DOWN,
    },
    _M.LANDING: {
        _M.DONE: _ALL_DOWN,
    },
    _M.DONE: {},
}
"""Mission mode -> {next mode: what triggers the change}. ``done`` is final."""

PHASE_TRANSITIONS: dict[DronePhase, dict[DronePhase, str]] = {
    _P.IDLE: {
        _P.TAKEOFF: "the mission takes off (`armed`)",
        _P.DOWN: _STOP,
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.TAKEOFF: {
        _P.POLICY: "the policy takes over (`policy_start`)",
        _P.LANDING: "the mission lands every drone (also after a program error)",
        _P.DOWN: _STOP + ", it tumbles (`tumbled`), or the best-effort landing after a program error",
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.POLICY: {
        _P.HOVER: "a safety rule says hover (`stale_hover`, `invalid_pose`, `invalid_action`, `geofence_breach`)",
        _P.LANDING: "the mission lands every drone (also after a program error), or it lingers above its pad "
        "(`handover`)",
        _P.DOWN: "it touches its pad or anything else (`touchdown`, `hard_touchdown`, `off_pad_contact`), tumbles "
        "(`tumbled`), " + _STOP + ", or the best-effort landing after a program error",
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.HOVER: {
        _P.POLICY: "every pose fresh and valid, every action valid again (`recovered`)",
        _P.LANDING: "the mission lands every drone (also after a program error), or it lingers above its pad "
        "(`handover`)",
        _P.DOWN: "it touches its pad or anything else (`touchdown`, `hard_touchdown`, `off_pad_contact`), tumbles "
        "(`tumbled`), " + _STOP + ", or the best-effort landing after a program error",
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.LANDING: {
        _P.DOWN: "it rests on the surface (`touchdown` after a hand-over, `motors_off`), its landing overran by "
        "`safety.land_timeout_margin_s` (`land_timeout`), it tumbles (`tumbled`), " + _STOP + ", or the best-effort "
        "landing after a program error",
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.DOWN: {
        _P.LOST: "its radio link is lost (`link_lost`)",
    },
    _P.LOST: {},
}
"""Drone phase -> {next phase: what triggers the change}. ``lost`` is final."""

State = TypeVar("State", MissionMode, DronePhase)


class IllegalTransition(RuntimeError):
    """A mode or phase change that its transition table does not allow: a bug in the loop."""


def check_change(table: dict[State, dict[State, str]], current: State, new: State, what: str) -> State:
    """``new`` if ``current -> new`` is in ``table`` (or ``new == current``); else :class:`IllegalTransition`.

    ``what`` names the thing that changes in the message (``"mission mode"``, ``"phase of cf1"``).
    """
    if new != current and new not in table[current]:
        allowed = ", ".join(str(s) for s in table[current]) or "nothing (it is final)"
        raise IllegalTransition(
            f"{what}: {current} -> {new} is not in the transition table; from {current}: {allowed}."
        )
    return new
