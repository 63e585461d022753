"""The safety filter's settings: :class:`SafetyFilterConfig`, the named sets the lab guide recommends
(:data:`NAMED_SETTINGS`) and the command-line form of both (:func:`parse_settings`).

What each setting does is told with the rules themselves, in :mod:`marlander_lite.swarm.safety_filter`; this module
holds the thresholds and gains and checks them once, so that the simulators' evaluation, the transfer matrix, the lab
config (``marlander_lite.deploy.sections.SafetyFilterSection``) and the deployment loop read one definition.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from marlander_lite.swarm.tracker_lag import TIME_CONSTANT_RANGE, TrackerLag

MOVING_PAD_SETTINGS: dict[str, float] = {
    "cone_radius": 0.04,
    "reaction_time": 0.35,
    "pad_lead": 0.2,
    "latency_compensation": 0.12,
}
"""Changes to :class:`SafetyFilterConfig`'s defaults for moving pads, the lab guide's (docs/transfer.md measured them:
the `moving` policies land 97.5-100 % in every moving cell of the transfer matrix through them)."""

PAD_FRAME_SETTINGS: dict[str, float] = {
    "cone_radius": 0.06,
    "reaction_time": 0.35,
    "low_velocity_step": 0.5,
    "low_velocity_step_lag": 0.45,
    "approach_climb": 1.0,
}
"""Changes to the defaults for a policy whose commands are relative to its pad (``moving-slow-trackers``) on moving
pads: the velocity step follows the tracker the flight identifies, the drone may make its last descent within 6 cm of
its pad centre, and one that trails its pad low climbs back. Through them ``moving-slow-trackers`` landed 90 % or more
in 23 of the 24 moving cells of its transfer matrix (docs/transfer.md, "Climbing back instead of touching down beside
the pad")."""

NAMED_SETTINGS: dict[str, dict[str, float]] = {"moving-pads": MOVING_PAD_SETTINGS, "pad-frame": PAD_FRAME_SETTINGS}
"""Settings a command line may give by name (:func:`parse_settings`): ``moving-pads`` for world-frame policies on
moving pads (``moving-smooth-16m``), ``pad-frame`` for pad-frame policies (``moving-slow-trackers``)."""


@dataclass(frozen=True)
class SafetyFilterConfig:
    """Thresholds and gains of :func:`filter_commands` (SI units). Tuned on the point mass, seed 1 (docs/scaling.md)."""

    min_distance: float = 0.19
    """``d_s``: the distance the filter keeps between drone centres (m); above eq. 6's 0.15 m collision
    distance and below the 0.25 m pad spacing, so drones on neighbouring pads do not push each other."""
    settled_min_distance: float = 0.19
    """The safety distance to a drone settled on its pad (m). A settled drone will not move, so eq. 6's 0.15 m plus a
    margin would do, and with ``min_distance`` a drone near its pad's edge next to a landed neighbour can be held off
    its pad centre for good (6 of 20 PyBullet 8-drone rehearsals, one drone each). Kept at ``min_distance``: 0.16 and
    0.17 m lowered the point mass at N = 16 from 96 % to 91.5 / 93.5 % (seed 1, 200 trials, more collisions)."""
    gain: float = 4.0
    """``gamma`` (1/s): largest closing speed per metre of distance left to ``min_distance``; also the rate at
    which the approach guard brakes a descent below its surface."""
    reaction_time: float = 0.2
    """``tau`` (s): positions are predicted this far ahead before the rule applies (tracker lag + latency)."""
    wake_slope: float = 0.3
    """Wake rule, 0 = off: two flying drones ``dz`` apart vertically (``0 < dz < wake_height``) must keep
    ``wake_radius + wake_slope dz`` apart horizontally, so the lower one stays out of the upper one's wake."""
    wake_radius: float = 0.12
    """Horizontal clearance of the wake rule at ``dz = 0`` (m)."""
    wake_height: float = 1.0
    """Vertical reach of the wake rule (m)."""
    activation_distance: float = 1.0
    """Pairs farther apart than this (predicted, m) are ignored: the rule cannot bind there at 3 m/s."""
    yield_distance: float = 1.5
    """A drone's weight in the split of a pair's duty is ``|p| / yield_distance`` (``p``: position minus goal,
    m), clipped to [``min_yield``, 1]: the nearer its goal, the less it yields."""
    min_yield: float = 0.02
    """Weight of a drone at its goal in the split of a pair's duty (a settled drone's weight is 0)."""
    sidestep: float = 0.5
    """Sideways (leftward) command per m/s of violation, dimensionless; 0 switches the side step off. Every
    drone turns to the same side, so two drones meeting head-on pass each other (left measured 1-5 points better
    than right at N = 8 and 16 on the point mass, seed 1)."""
    touchdown_speed: float = 0.3
    """``v_td`` of the descent guard (m/s); 0 switches the guard off. The task allows 0.5 m/s."""
    descent_deceleration: float = 1.5
    """``a`` of the descent guard (m/s^2): the deceleration the velocity tracker is trusted to brake at."""
    descent_delay: float = 0.0
    """``t_d`` of the descent guard (s): how long the tracker takes to start braking."""
    cone_slope: float = 1.0
    """``slope`` of the approach guard (m of height per m of horizontal distance); 0 switches it off."""
    cone_radius: float = 0.005
    """``r_0`` of the approach guard (m): within it the drone may descend all the way. The last centimetres of
    descent wait until the drone is this close to its pad centre: with 0.05 m the shared policy landed 2.96-3.25 cm
    from the centre, above the paper's 2.26 cm; with 0 more drones hovered off-centre until the time ran out
    (docs/scaling.md)."""
    cone_height: float = 0.3
    """``h_max`` of the approach guard (m)."""
    approach_climb: float = 0.0
    """``c`` of the approach guard, 0 = off (the default; every filtered result shipped before 2026-11-30 was flown
    without it): a drone below the guard's surface ``s`` is not only kept from descending but pushed up at
    ``c gamma (s - h)``. A tracker that answers in about a second leaves its drone trailing a pad that reverses, a few
    centimetres over the plate beside the pad, and its descent carries on after the guard has stopped it; it then
    touches down beside its pad. With 1 it climbs back onto the surface and tries again (and a drone lower than
    ``h_max`` farther than ``r_0 + h_max / slope`` from its pad climbs to ``h_max``: it approaches over the pad, not
    along the ground). ``moving-slow-trackers``
    through the tracker-step settings touched down beside its pad in 26 of the transfer matrix's 4800 moving episodes
    instead of 112 (PyFlyt's columns: 2 instead of 79), while time-outs rose from 61 to 146, most on the combined
    column's and PyFlyt's 0.21.0-order line; with ``cone_radius`` 0.06 as well, 23 of its 24 moving cells landed 90 %
    or more, all but that line (73.0 %; docs/transfer.md, "Climbing back instead of touching down beside the pad")."""
    centring_gain: float = 2.0
    """``k_c`` of the centring rule (1/s): over its pad (within the pad radius) and below ``h_max``, a drone's
    horizontal command gains ``-k_c`` times its horizontal offset from the goal; 0: no centring."""
    settled_distance: float = 0.03
    """A drone within this height of its goal (m), over its pad and slower than ``settled_speed`` is settled."""
    settled_speed: float = 0.1
    """See ``settled_distance`` (m/s)."""
    settled_sink_limit: float = 0.8
    """Fastest descent (m/s) a settled drone's own command may ask for; 0: its command passes unchanged (the default
    before 2026-11-26, with which every filtered result shipped before then was flown). A drone the approach guard held
    a few centimetres up counts as settled and then got the policy's command, up to 1.7 m/s down, which a slow tracker
    turned into touchdowns above 0.5 m/s; 0.8 cut them from 6 and 8 to 1 and 0 of 200 (docs/transfer.md, the combined
    column) and lowered no cell of another shipped filtered matrix by more than a point (``*-sink-limit``)."""
    iterations: int = 6
    """Sweeps of the cyclic projection over every drone's neighbours."""
    pad_lead: float = 0.0
    """``T_lead`` of the pad lead (s), 0 = off: every drone's command gains ``T_lead`` times its pad's acceleration
    (:class:`PadAcceleration`, from the pad velocities the loop observes). A velocity tracker with time constant
    ``T`` following a pad that accelerates at ``a`` falls ``a T`` behind in velocity, and a position loop of gain ``k``
    leaves the drone ``a T / k`` behind the pad: 17 cm for ``a`` = 1 m/s^2 (the UR10 reversing), ``T`` = 0.2 s and
    the policy's ``k`` of about 1.2 /s, where the misses along the moving line were measured, 11-17 cm behind
    (docs/transfer.md). The lead cancels that lag. 0.2 s is in the moving-pad settings. In the simulators' filter
    (:func:`with_safety_filter`) it needs a policy that observes the pad's velocity; the deployment runner takes the
    pad's velocity from motion capture, whatever the policy."""

    low_velocity_step: float = 0.0
    """``Delta`` of the velocity-step limit (m/s), 0 = off: below ``cone_height`` above its goal, a drone's horizontal
    command may differ from its horizontal velocity by at most ``max(Delta, |v_rel|)``, ``v_rel`` its horizontal
    velocity relative to its pad: it may always brake to its pad's velocity, but not be thrown the other way harder
    than ``Delta``. A velocity tracker tilts in proportion to that difference, and one without a tilt limit, asked to
    reverse a swing a few centimetres over its pad, tilts past 50 degrees, loses lift and touches down sideways
    (docs/transfer.md, "A held-out tracker")."""
    latency_compensation: float = 0.0
    """``L`` of the latency compensation (s), 0 = off: the policy and the guards act on each drone's state predicted
    ``L`` ahead at its present velocity (eq. 2's ``p + v L``, :func:`predict_observations`), where it will be when
    this command starts to act; the separation rules keep ``reaction_time``. A command the loop computes from a pose
    ``L`` old acts ``L`` late, and a drone it tells to brake over its pad has already come ``v L`` lower. 0.12 s is in
    the moving-pad settings: it covers the transfer matrix's 60 ms of command latency, Vicon's 20 ms and part of the
    tracker's response (docs/transfer.md). At most 0.5 s."""
    identified_lag_share: float = 0.0
    """``s`` of the identified latency compensation, 0 = off (``L`` is ``latency_compensation`` throughout). With
    ``s`` > 0 every flight identifies its velocity tracker's time constant ``T`` from the commands sent and the
    velocities that followed (:class:`~marlander_lite.swarm.tracker_lag.TrackerLag`; before the first samples ``T`` is
    ``latency_compensation / s``) and flies with ``L = min(s T, 0.5 s)``: the best fixed ``L`` was about half a slow
    tracker's time constant, and one that large cost a fast tracker landing accuracy (docs/transfer.md). At most 2."""
    low_velocity_step_lag: float = 0.0
    """``T_ref`` of the velocity-step limit (s), 0 = off (the step is ``low_velocity_step`` throughout). With
    ``T_ref`` > 0 every flight identifies its velocity tracker's time constant ``T`` (as ``identified_lag_share`` does;
    before the first samples ``T`` is ``T_ref``) and the step becomes ``low_velocity_step * max(1, T / T_ref)``. A
    tracker of time constant ``T`` accelerates a drone at about ``(u - v) / T`` and so tilts it by about
    ``atan((u - v) / (g T))``: the same tilt allows a step ``T / T_ref`` times larger on a slower tracker, which needs
    its command well ahead of its velocity. With 0.5 m/s at 0.45 s (the held-out and firmware trackers' identified
    time constants) ``moving-slow-trackers`` landed 89.0 / 92.5 % on the held-out tracker's moving rows (alone 83.5 /
    74.0 %) and 90.0 / 89.5 % on the combined column's and PyFlyt 0.22's line, where a fixed 0.5 m/s step left 77.5 /
    68.0 % (docs/transfer.md, "A velocity step that follows the tracker"). Needs ``low_velocity_step`` > 0."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
                raise ValueError(f"SafetyFilterConfig.{f.name} must be a finite number >= 0, got {value!r}.")
        for name in (
            "min_distance",
            "settled_min_distance",
            "gain",
            "yield_distance",
            "min_yield",
            "descent_deceleration",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"SafetyFilterConfig.{name} must be > 0, got {getattr(self, name)!r}.")
        if self.activation_distance <= self.min_distance:
            raise ValueError(
                f"SafetyFilterConfig.activation_distance ({self.activation_distance} m) must exceed min_distance "
                f"({self.min_distance} m), or the separation rule would never act."
            )
        if self.latency_compensation > 0.5:
            raise ValueError(
                "SafetyFilterConfig.latency_compensation must be within [0, 0.5] s, got "
                f"{self.latency_compensation!r}: a loop half a second late cannot land a drone, whatever it predicts."
            )
        if self.identified_lag_share > 0:
            low, high = TIME_CONSTANT_RANGE
            prior = self.latency_compensation / self.identified_lag_share
            if self.identified_lag_share > 2 or not low <= prior <= high:
                raise ValueError(
                    f"SafetyFilterConfig.identified_lag_share must be within [0, 2] and latency_compensation / "
                    f"identified_lag_share (the time constant assumed before any is identified) within [{low}, {high}] "
                    f"s; got identified_lag_share={self.identified_lag_share!r}, latency_compensation="
                    f"{self.latency_compensation!r}. Try identified_lag_share=0.5 with latency_compensation=0.12."
                )
        if self.low_velocity_step_lag > 0:
            low, high = TIME_CONSTANT_RANGE
            if not low <= self.low_velocity_step_lag <= high or self.low_velocity_step == 0:
                raise ValueError(
                    f"SafetyFilterConfig.low_velocity_step_lag must be 0 (off) or within [{low}, {high}] s with "
                    f"low_velocity_step > 0, the step it scales; got low_velocity_step_lag="
                    f"{self.low_velocity_step_lag!r}, low_velocity_step={self.low_velocity_step!r}. Try "
                    "low_velocity_step=0.5 with low_velocity_step_lag=0.45."
                )
        if not isinstance(self.iterations, int) or self.iterations < 1:
            raise ValueError(f"SafetyFilterConfig.iterations must be an integer >= 1, got {self.iterations!r}.")

    def tracker_lag(self, policy_dt: float) -> TrackerLag | None:
        """A new :class:`TrackerLag` for ``identified_lag_share`` (starting from ``latency_compensation /
        identified_lag_share``) or else ``low_velocity_step_lag`` (starting from it), for a loop acting every
        ``policy_dt`` s; None when both are 0 (off)."""
        if self.identified_lag_share:
            return TrackerLag(self.latency_compensation / self.identified_lag_share, policy_dt)
        if self.low_velocity_step_lag:
            return TrackerLag(self.low_velocity_step_lag, policy_dt)
        return None

    def velocity_step(self, time_constant: float | np.ndarray | None = None) -> float | np.ndarray:
        """The velocity-step limit (m/s) for a tracker of identified ``time_constant`` (s; a number or per env):
        ``low_velocity_step * max(1, T / low_velocity_step_lag)``, or ``low_velocity_step`` when that is off or no
        time constant is given."""
        if not self.low_velocity_step_lag or time_constant is None:
            return self.low_velocity_step
        return self.low_velocity_step * np.maximum(1.0, np.asarray(time_constant) / self.low_velocity_step_lag)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> SafetyFilterConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise with the list of allowed ones."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"Unknown safety filter option(s) {unknown}; allowed: {sorted(known)}.")
        return cls(**values)


def parse_settings(text: str) -> dict[str, float]:
    """Changes to the filter's defaults as a command line gives them: ``"cone_radius=0.04,iterations=8"`` ->
    ``{"cone_radius": 0.04, "iterations": 8}`` (``""``: none). An item may also name a set of
    :data:`NAMED_SETTINGS` (``"pad-frame,reaction_time=0.3"``); items later on the line override earlier ones.
    Raises ``ValueError`` for an item that is neither ``KEY=NUMBER`` nor such a name, and for whatever
    :class:`SafetyFilterConfig` refuses (unknown keys, values out of range)."""
    settings: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        if "=" not in item and item in NAMED_SETTINGS:
            settings.update(NAMED_SETTINGS[item])
            continue
        key, _, value = item.partition("=")
        try:
            settings[key.strip()] = int(value) if value.strip().isdigit() else float(value)
        except ValueError:
            raise ValueError(
                f"{item!r} is not KEY=NUMBER (e.g. cone_radius=0.04) nor one of the named settings "
                f"{', '.join(NAMED_SETTINGS)}"
            ) from None
    SafetyFilterConfig.from_dict(settings)
    return settings
