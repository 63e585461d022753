"""A safety filter: the smallest change to the drones' velocity commands that keeps them apart and lands them softly.

Not in the paper. The paper's policy and ours learn to avoid each other through eq. 6's collision penalty
alone, and with 8 or 16 drones converging on pads 0.25 m apart they often do not (docs/scaling.md). A lab
flying a swarm wants rules that hold whatever the policy does. This module holds them, written once for the
simulators' evaluation (:mod:`marlander_lite.swarm.evaluation`, controller ``shared-filter``) and for the
deployment loop (:mod:`marlander_lite.deploy.runner`). It sits between any controller and the velocity
tracker, like a safety filter in the control-barrier-function literature, and works for any N.

**Separation** (a velocity-level control barrier function, after Wang, Ames and Egerstedt's safety
barrier certificates [Wang2016], docs/references.md). For two drones ``i`` and ``j`` let ``r = x_i - x_j`` be
their relative position *predicted* ``tau`` seconds ahead (``x + v tau``: a new command takes about that long
to change the velocity, through the tracker's lag and the sensing latency), ``d = |r|`` and ``n = r / d``.
The pair stays apart if its commands ``u`` satisfy

    ``n . (u_i - u_j) >= -gamma (d - d_s)``

the closing speed along ``n`` may be at most ``gamma`` times the distance left to the safety distance
``d_s``; once closer than ``d_s`` the pair must separate. The duty is split *reciprocally*: drone ``i``
takes a share ``s_ij``, ``n . u_i >= -s_ij gamma (d - d_s)``, with ``s_ij + s_ji = 1``, so no drone needs
the other's command. Shares are weighted by how far each drone still is from its goal
(``yield_distance``): the drone about to land keeps its line and the one passing by goes round; a drone
settled on its pad will not move, so the flying one takes all of it. Each drone's command is moved onto
the intersection of its half-spaces by cyclic projection (``iterations`` sweeps over its neighbours, nearest
first, so that renumbering the drones only renumbers the commands), which changes nothing when no rule
is violated. A violated pair also turns each drone to its left
(``sidestep``), so two drones flying straight at each other pass rather than stall nose to nose (the
classic deadlock of barrier functions). The filter never pushes a drone *down*: the lower drone of a
stacked pair, pushed down, touched its pad faster than 0.5 m/s.

**Wake.** Two flying drones ``dz`` apart vertically keep ``wake_radius + wake_slope dz`` apart horizontally
(the same cyclic projection, on horizontal normals): a drone's downwash pushes the one under it down, in
PyBullet's wake model with up to its whole weight.

**Descent guard.** The downward command is capped at the speed ``v`` from which the drone brakes to
``v_td`` within its height ``h`` above the goal: ``v^2 = v_td^2 + 2 a h`` without a response delay (the training
aid ``command_speed_penalty`` asks the same of the policy; here it is enforced).

**Approach guard.** A drone may not descend below ``min(slope (r - r_0), h_max)`` above its goal, ``r`` its
horizontal distance from it: it comes down over its pad, not beside it (issue "Policies that transfer"
asks for >= 0.3 m of height 0.5 m from the pad; clutter, ground effect and other pads do not forgive a
low approach). Below that surface its descent is braked at rate ``gamma``; by default it is never pushed up, and with
``approach_climb`` ``c`` it climbs back at ``c gamma`` per metre below the surface (a drone trailing its pad low over
the plate, on a slow tracker). With ``r_0`` = 5 mm the surface is almost a cone whose tip is the goal: the drone
centres itself over its pad as it comes down.

**Pad lead** (``pad_lead``, off by default). On a moving pad every command first gains ``T_lead`` times the pad's
acceleration, estimated from the pad velocities the loop observes (:class:`PadAcceleration`): a velocity tracker
with time constant ``T`` trails a pad that brakes or turns, and the lead cancels that lag when ``T_lead = T``.

**Latency compensation** (``latency_compensation``, off by default). A command computed from a pose ``L`` seconds
old acts ``L`` seconds late. With ``L`` set, the policy and the guards (descent, approach, centring) read each drone's
observation predicted ``L`` ahead at its present velocity (eq. 2's ``p + v L``, :func:`predict_observations`), as a
Smith predictor acts on the output predicted past a known delay [Smith1957] (docs/references.md), here from the
measured velocity, not a model. The separation and wake rules keep the measured positions: they predict ``tau``
ahead on their own, and predicting from the predicted positions too added collisions (docs/transfer.md). With
``identified_lag_share`` ``s`` each flight identifies its velocity tracker's time constant ``T`` from the commands it
sent and the velocities that followed (:mod:`marlander_lite.swarm.tracker_lag`) and ``L`` becomes ``min(s T, 0.5 s)``,
so that one setting fits fast and slow trackers.

**Velocity-step limit** (``low_velocity_step``, off by default). A velocity tracker tilts a drone in proportion to the
difference between its command and its velocity. Below ``h_max`` above its goal, a drone's horizontal command is
moved towards its horizontal velocity until the two differ by at most ``max(Delta, |v_rel|)``, ``v_rel`` its velocity
relative to its pad: it may always brake to its pad's velocity, but a swing across the pad is not reversed harder than
``Delta``. Through a tracker without a tilt limit such reversals tilted drones past 50 degrees a few centimetres over
their pads, and they met the floor sideways (docs/transfer.md, "A held-out tracker").

**Centring.** Over its pad (within the pad radius) and below ``h_max``, a drone's horizontal command gains
``-k_c`` times its horizontal offset from the goal. A policy that hovers a few centimetres off its pad centre
would otherwise wait at the approach guard until the flight time ran out; with the rule it is drawn to the
centre and lands there. It acts after the separation rule, at most ``k_c`` times the 0.1 m pad radius
(0.2 m/s with the default), and a drone a neighbour's separation rule holds off its pad centre is drawn back
towards it. Together with the approach guard it is what brings the shared policy's landing error
under the paper's 2.26 cm: the learned policy alone lands 3.4 cm from the centre (docs/scaling.md).

Measured with the shared policy, 200 trials, seed 0 (docs/scaling.md, where the tuning is described): at
N = 8 on the point mass it lands 36 % of swarms alone (57.5 % end in a collision) and 98.0 % through this
filter, without a collision, 1.27 cm from the pad centres; at N = 16, 7.5 % and 95.5 %; in PyBullet through
the firmware's velocity tracker at N = 8 (100 trials), 22 % and 98 %. Only relative positions and velocities
enter the separation and wake rules, so any common frame will do.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from marlander_lite.platforms import PlateGeometry
from marlander_lite.swarm.pad_acceleration import PadAcceleration
from marlander_lite.swarm.tracker_lag import TIME_CONSTANT_RANGE, TrackerLag
from marlander_lite.task import EQ2_POSITION, EQ2_VELOCITY, PLATFORM_VELOCITY

if TYPE_CHECKING:
    from marlander_lite.episodes import LandingEpisodes

_EPS = 1e-9
PAD_RADIUS = PlateGeometry().pad_radius
"""m: a drone within this horizontal distance of its goal, low and slow, counts as settled (the plate's pad radius)."""


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


def predict_observations(obs: np.ndarray, seconds: float | np.ndarray) -> np.ndarray:
    """Eq. 2 observations ``(..., N, >= 13)`` predicted ``seconds`` ahead at constant velocity: ``p + v seconds``.

    ``p`` is the drone's position minus its goal and ``v`` its velocity relative to the pad, so ``dp/dt = v``
    whether the pad moves or not; attitude, velocities and the extras are kept. ``seconds`` is a number or an array
    that broadcasts against ``(..., N, 1)`` (one per env: ``(E, 1, 1)``). With ``seconds`` > 0 a new array; with 0
    (compensation off, the default) ``obs`` itself as floats, so that every filtered step does not copy it."""
    if np.ndim(seconds) == 0 and not seconds:
        return np.asarray(obs, dtype=float)
    predicted = np.array(obs, dtype=float)
    predicted[..., EQ2_POSITION] += seconds * predicted[..., EQ2_VELOCITY]
    return predicted


def settled_drones(rel_goal: np.ndarray, vel: np.ndarray, config: SafetyFilterConfig) -> np.ndarray:
    """Drones resting on their pads, ``(..., N)`` bool, from eq. 2's ``p`` (position minus goal, m) and ``v``
    (velocity relative to the pad, m/s), both ``(..., N, 3)``."""
    rel_goal, vel = np.asarray(rel_goal, dtype=float), np.asarray(vel, dtype=float)
    low = np.abs(rel_goal[..., 2]) < config.settled_distance
    over_pad = np.hypot(rel_goal[..., 0], rel_goal[..., 1]) < PAD_RADIUS
    slow = np.linalg.norm(vel, axis=-1) < config.settled_speed
    return low & over_pad & slow


def filter_commands(
    positions: np.ndarray,
    velocities: np.ndarray,
    commands: np.ndarray,
    config: SafetyFilterConfig | None = None,
    settled: np.ndarray | None = None,
    rel_goal: np.ndarray | None = None,
    max_speed: float | None = None,
    pad_acceleration: np.ndarray | None = None,
    pad_velocity: np.ndarray | None = None,
    velocity_step: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity commands changed as little as the rules allow (module docstring).

    Args:
        positions: drone positions ``(..., N, 3)`` m, any common frame.
        velocities: drone velocities ``(..., N, 3)`` m/s.
        commands: the controller's velocity commands ``(..., N, 3)`` m/s.
        config: thresholds; :class:`SafetyFilterConfig` defaults when None.
        settled: ``(..., N)`` bool, drones resting on their pads (left alone; their partners take the whole
            duty); None: nobody settled.
        rel_goal: each drone's position minus its goal ``(..., N, 3)`` m (eq. 2's ``p``), for the split of the
            duty and the guards; None: equal split, no guards. With latency compensation the callers pass it
            predicted (``p + v L``) while ``positions`` stay as measured.
        max_speed: commands are scaled down to this speed (m/s) at the end; None: no cap.
        pad_acceleration: each drone's pad's acceleration ``(..., N, 3)`` m/s^2 (:class:`PadAcceleration`); with
            ``config.pad_lead`` > 0 every command first gains ``pad_lead`` times it (the pad lead); None: no lead.
        pad_velocity: each drone's pad's velocity ``(..., N, 3)`` m/s, in the frame of ``velocities``, for the
            velocity-step limit (which needs each drone's velocity in that frame and relative to its pad); None: the
            pads are at rest in that frame.
        velocity_step: the velocity-step limit's step (m/s), a number or ``(..., 1)`` (one per env, as
            :meth:`SafetyFilterConfig.velocity_step` scales it); None: ``config.low_velocity_step``. Only with
            ``config.low_velocity_step`` > 0.

    Returns:
        ``(filtered, acted)``: commands ``(..., N, 3)`` m/s and ``(..., N)`` bool, True where a drone's command
        was changed.
    """
    config = config or SafetyFilterConfig()
    pos, vel = np.asarray(positions, dtype=float), np.asarray(velocities, dtype=float)
    command = np.asarray(commands, dtype=float)
    if pos.shape != command.shape or vel.shape != command.shape or command.shape[-1:] != (3,):
        raise ValueError(
            f"positions, velocities and commands must share one (..., N, 3) shape; got {pos.shape}, {vel.shape} "
            f"and {command.shape}."
        )
    for name, array in (("positions", pos), ("velocities", vel), ("commands", command)):
        if not np.isfinite(array).all():
            raise ValueError(f"filter_commands() got a NaN or infinite value in {name}; the filter needs finite input.")
    n = command.shape[-2]
    settled = np.zeros(command.shape[:-1], bool) if settled is None else np.asarray(settled, dtype=bool)
    goal = None if rel_goal is None else np.asarray(rel_goal, dtype=float)
    requested = command
    if config.pad_lead > 0 and pad_acceleration is not None:
        lead = config.pad_lead * np.asarray(pad_acceleration, dtype=float)
        if lead.shape != command.shape or not np.isfinite(lead).all():
            raise ValueError(f"pad_acceleration must be a finite {command.shape} array, got shape {lead.shape}.")
        command = command + lead  # the policy's command with the feed-forward, which every rule below starts from
    if config.low_velocity_step > 0 and goal is not None:
        relative = vel
        if pad_velocity is not None:
            pad_vel = np.asarray(pad_velocity, dtype=float)
            if pad_vel.shape != command.shape or not np.isfinite(pad_vel).all():
                raise ValueError(f"pad_velocity must be a finite {command.shape} array, got shape {pad_vel.shape}.")
            relative = vel - pad_vel
        step = config.low_velocity_step if velocity_step is None else velocity_step
        command = _limit_velocity_step(command, vel, relative, goal, config, step)
    u = command.copy()
    if n >= 2:
        u = _separate(pos, vel, u, settled, goal, config)
        u[..., 2] = np.maximum(u[..., 2], command[..., 2])  # never pushed down
    if goal is not None:
        u[..., 2] = np.maximum(u[..., 2], _lowest_vertical_command(goal, config))
        if config.centring_gain > 0:
            offset = goal[..., :2]
            over_pad = (np.hypot(offset[..., 0], offset[..., 1]) < PAD_RADIUS) & (goal[..., 2] < config.cone_height)
            u[..., :2] -= config.centring_gain * offset * over_pad[..., None]
    if max_speed is not None:
        speed = np.linalg.norm(u, axis=-1, keepdims=True)
        u *= np.minimum(1.0, max_speed / np.maximum(speed, _EPS))
    u = np.where(settled[..., None], command, u)
    if config.settled_sink_limit > 0:
        u[..., 2] = np.where(settled, np.maximum(u[..., 2], -config.settled_sink_limit), u[..., 2])
    return u, np.linalg.norm(u - requested, axis=-1) > 1e-9


def _separate(
    pos: np.ndarray,
    vel: np.ndarray,
    u: np.ndarray,
    settled: np.ndarray,
    goal: np.ndarray | None,
    config: SafetyFilterConfig,
) -> np.ndarray:
    """The separation rule: ``u`` projected onto every drone's half-spaces ``n_ij . u_i >= b_ij``."""
    n = u.shape[-2]
    predicted = pos + config.reaction_time * vel
    r = predicted[..., :, None, :] - predicted[..., None, :, :]  # (..., N, N, 3): x_i - x_j
    dist = np.linalg.norm(r, axis=-1)
    normal = r / np.maximum(dist, _EPS)[..., None]
    if goal is None:
        weight = np.ones(u.shape[:-1])
    else:
        weight = np.clip(np.linalg.norm(goal, axis=-1) / config.yield_distance, config.min_yield, 1.0)
    weight = np.where(settled, 0.0, weight)
    share = weight[..., :, None] / np.maximum(weight[..., :, None] + weight[..., None, :], _EPS)
    safety = np.where(settled[..., None, :], config.settled_min_distance, config.min_distance)
    bound = -share * config.gain * (dist - safety)
    pair = (dist < config.activation_distance) & ~np.eye(n, dtype=bool) & ~settled[..., :, None]
    bound = np.where(pair, bound, -np.inf)
    wake = _wake_rule(r, share, settled, config) if config.wake_slope > 0 else None
    if config.sidestep:
        violation = np.maximum(bound - np.einsum("...ijk,...ik->...ij", normal, u), 0.0)
        # n points from j to i, against i's approach: n x z is the approaching drone's left-hand side
        left = np.stack([normal[..., 1], -normal[..., 0], np.zeros_like(dist)], axis=-1)
        left /= np.maximum(np.linalg.norm(left, axis=-1, keepdims=True), _EPS)
        u = u + config.sidestep * np.einsum("...ij,...ijk->...ik", violation, left)
    # every drone visits its neighbours nearest first, so numbering the drones differently changes nothing
    order = np.argsort(dist, axis=-1, kind="stable")[..., 1:]  # (..., N, N - 1); position 0 is the drone itself
    rules = [(normal, bound)] + ([] if wake is None else [wake])
    rules = [
        (np.take_along_axis(m, order[..., None], axis=-2), np.take_along_axis(b, order, axis=-1)) for m, b in rules
    ]
    rules = [(m, b) for m, b in rules if np.isfinite(b).any()]  # rules with no pair in reach change nothing
    for _ in range(config.iterations if rules else 0):
        moved = False
        for k in range(n - 1):
            for m, b in rules:
                mk = m[..., :, k, :]
                short = np.maximum(b[..., :, k] - np.einsum("...ik,...ik->...i", mk, u), 0.0)
                if short.any():
                    u = u + short[..., None] * mk
                    moved = True
        if not moved:  # a sweep that changed nothing: every later one would repeat it exactly
            break
    return u


def _wake_rule(
    r: np.ndarray, share: np.ndarray, settled: np.ndarray, config: SafetyFilterConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Half-spaces ``m_ij . u_i >= c_ij`` of the wake rule: horizontal normals ``(..., N, N, 3)`` and bounds."""
    n = r.shape[-2]
    horizontal = np.hypot(r[..., 0], r[..., 1])
    height = np.abs(r[..., 2])
    width = config.wake_radius + config.wake_slope * height
    # stacked exactly: part along x, by index, so the two drones choose opposite sides
    tie = np.where(np.arange(n)[:, None] > np.arange(n)[None, :], 1.0, -1.0)
    side = np.where(horizontal[..., None] > 1e-3, r / np.maximum(horizontal, _EPS)[..., None], 0.0)
    side[..., 0] = np.where(horizontal > 1e-3, side[..., 0], tie)
    side[..., 2] = 0.0
    flying = ~settled[..., :, None] & ~settled[..., None, :]
    active = flying & (height < config.wake_height) & (horizontal < width + 0.3) & ~np.eye(n, dtype=bool)
    bound = np.where(active, -share * config.gain * (horizontal - width), -np.inf)
    return side, bound


def _limit_velocity_step(
    command: np.ndarray,
    vel: np.ndarray,
    relative: np.ndarray,
    goal: np.ndarray,
    config: SafetyFilterConfig,
    allowed: float | np.ndarray,
) -> np.ndarray:
    """The velocity-step limit: below ``cone_height`` above its goal, the horizontal command moved towards the drone's
    horizontal velocity ``vel`` until the two differ by at most ``max(allowed, |relative|)`` (``allowed``: the step,
    m/s, a number or ``(..., 1)``; ``relative``: the velocity relative to the pad, so braking to the pad's velocity is
    always allowed); others unchanged."""
    step = command[..., :2] - vel[..., :2]
    size = np.hypot(step[..., 0], step[..., 1])
    bound = np.maximum(allowed, np.hypot(relative[..., 0], relative[..., 1]))
    low = goal[..., 2] < config.cone_height
    scale = np.where(low, np.minimum(1.0, bound / np.maximum(size, _EPS)), 1.0)
    limited = command.copy()
    limited[..., :2] = vel[..., :2] + step * scale[..., None]
    return limited


def _lowest_vertical_command(goal: np.ndarray, config: SafetyFilterConfig) -> np.ndarray:
    """The most negative vertical command the descent and approach guards allow, ``(..., N)`` m/s."""
    lowest = np.full(goal.shape[:-1], -np.inf)
    height = goal[..., 2]
    if config.touchdown_speed > 0:
        a, t_d = config.descent_deceleration, config.descent_delay
        reach = np.maximum(height, 0.0)
        # the speed v from which v t_d + (v^2 - v_td^2) / (2 a) = h: braking starts t_d late and ends at v_td
        brake = a * (-t_d + np.sqrt(t_d**2 + (config.touchdown_speed**2 + 2.0 * a * reach) / a**2))
        lowest = np.maximum(lowest, -np.maximum(brake, config.touchdown_speed))
    if config.cone_slope > 0:
        radius = np.hypot(goal[..., 0], goal[..., 1])
        surface = np.minimum(config.cone_slope * np.maximum(radius - config.cone_radius, 0.0), config.cone_height)
        # below the surface the drone's descent is braked; with approach_climb it is also pushed back up
        floor = config.gain * (surface - height)
        lowest = np.maximum(lowest, np.where(floor > 0, config.approach_climb * floor, floor))
    return lowest


BatchAct = Callable[[np.ndarray], np.ndarray]
"""Centralised observations of every env ``(E, 13 N)`` -> actions ``(E, 3 N)`` in [-1, 1]."""


def with_safety_filter(
    act: BatchAct,
    num_drones: int,
    pad_offsets: np.ndarray,
    max_speed: float,
    config: SafetyFilterConfig | None = None,
    policy_dt: float | None = None,
    observes_pad_velocity: bool = False,
    pads_move: bool = False,
    tracker_lag: TrackerLag | None = None,
    command_frame: str = "world",
    pad_velocity: Callable[[], np.ndarray] | None = None,
    carried_pad_velocity: Callable[[], np.ndarray] | None = None,
) -> BatchAct:
    """Wrap a batch actor (centralised observations ``(E, 13 N)`` -> actions ``(E, 3 N)`` in [-1, 1]) with
    :func:`filter_commands`: actions are read as commands of ``max_speed`` m/s per unit (eq. 3).

    Positions are eq. 2's goal-relative ``p`` plus each drone's pad offset ``(N, 3)`` m (the plate never yaws,
    so their differences are the drones' relative positions); velocities are eq. 2's ``v``.

    Some rules need each pad's velocity (m/s, world frame). The wrapper reads it from the observations when the policy
    observes it (``observes_pad_velocity``, the policy's ``TaskConfig.observe_platform_velocity``), or else from
    ``pad_velocity`` (no arguments -> ``(E, N, 3)``, read once per call): where the loop knows it otherwise, as the
    deployment loop does from motion capture whatever the policy (in a simulator, its state).
    With ``config.pad_lead`` > 0 the wrapper estimates each pad's acceleration (:class:`PadAcceleration`) from those
    pad velocities, which needs them and the time between two calls, ``policy_dt`` (s).
    With ``config.latency_compensation`` > 0 the policy reads the observations predicted that far ahead
    (:func:`predict_observations`), and so do the filter's guards (:func:`filter_actions`).
    With ``config.identified_lag_share`` > 0 the wrapper identifies the tracker with ``tracker_lag`` (pass one to read
    what it identified; None: a new :class:`TrackerLag` starting from ``latency_compensation / identified_lag_share``)
    and sets ``L`` per env from it.
    With ``config.low_velocity_step`` > 0 the velocity-step limit compares commands with each drone's velocity in the
    world frame: eq. 2's ``v`` plus the pad velocity, or ``v`` itself on pads at rest. On pads that move
    (``pads_move``) it therefore needs the pad velocities. With ``config.low_velocity_step_lag`` > 0 it identifies the
    tracker as above (starting from ``low_velocity_step_lag`` unless ``identified_lag_share`` is set) and scales the
    step per env (:meth:`SafetyFilterConfig.velocity_step`).
    With ``command_frame`` ``"pad"`` (``TaskConfig.command_frame``) an action is a velocity relative to the pad: the
    filter works on the world command, the action plus the pad velocity the command carries, and hands back the
    filtered command relative to the pad again. That velocity comes from ``carried_pad_velocity`` (no arguments ->
    ``(E, N, 3)`` m/s, read once per call: what the loop will add, lead included, as the deployment loop filters
    the command it sends; e.g. :meth:`~marlander_lite.episodes.LandingEpisodes.carried_pad_velocity`), or else is the
    pad velocity itself (without a lead). On moving pads it needs one of them.
    """
    config = config or SafetyFilterConfig()
    knows_pad_velocity = observes_pad_velocity or pad_velocity is not None
    how = (
        "pass pad_velocity (the loop's, e.g. the simulator's state), or fly a policy trained with "
        "observe_platform_velocity, as the moving preset is"
    )
    if command_frame == "pad" and pads_move and not knows_pad_velocity and carried_pad_velocity is None:
        raise ValueError(
            "A pad-frame policy (command_frame='pad') on moving pads needs the pad velocity its commands carry for "
            f"the safety filter to see the world command: pass carried_pad_velocity (the loop's, e.g. "
            f"LandingEpisodes.carried_pad_velocity), or {how}; or fly it without the filter, or on static pads."
        )
    if config.low_velocity_step > 0 and pads_move and not knows_pad_velocity:
        raise ValueError(
            "low_velocity_step > 0 on moving pads needs each pad's velocity: without it the limit would hold the drone "
            f"to its velocity relative to the pad. {how[0].upper()}{how[1:]}; or fly it on static pads, or set "
            "low_velocity_step=0."
        )
    lag = None
    if config.identified_lag_share > 0 or config.low_velocity_step_lag > 0:
        if not policy_dt or (pads_move and not knows_pad_velocity):
            raise ValueError(
                "identified_lag_share > 0 or low_velocity_step_lag > 0 needs the policy period (policy_dt) and, on "
                "moving pads, each pad's velocity (the tracker is identified from world-frame velocities): "
                f"{how}. Or set both to 0."
            )
        lag = tracker_lag or config.tracker_lag(policy_dt)
    lead = None
    if config.pad_lead > 0:
        if not (knows_pad_velocity and policy_dt):
            raise ValueError(
                f"pad_lead > 0 needs each pad's velocity ({how}) and the policy period (policy_dt); or set pad_lead=0."
            )
        lead, calls = PadAcceleration(), itertools.count()
    offsets = np.asarray(pad_offsets, dtype=float)
    if offsets.shape != (num_drones, 3):
        raise ValueError(f"pad_offsets must be ({num_drones}, 3), got shape {offsets.shape}.")

    def filtered(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=float)
        per_drone = obs.reshape(len(obs), num_drones, -1)
        pad_vel = None
        if observes_pad_velocity:
            pad_vel = per_drone[..., PLATFORM_VELOCITY]
        elif pad_velocity is not None:
            pad_vel = np.asarray(pad_velocity(), dtype=float)
        latency: float | np.ndarray = config.latency_compensation
        step = None
        if lag is not None:
            lags = lag.observe(per_drone[..., EQ2_POSITION], per_drone[..., EQ2_VELOCITY], pad_vel)
            if config.identified_lag_share > 0:
                latency = np.minimum(config.identified_lag_share * lags, 0.5)[:, None, None]  # (E, 1, 1) s
            if config.low_velocity_step_lag > 0:
                step = np.asarray(config.velocity_step(lags))[:, None]  # (E, 1) m/s
        ahead = predict_observations(per_drone, latency).reshape(obs.shape)
        command = np.asarray(act(ahead), dtype=float).reshape(len(obs), num_drones, 3)
        accel = None if lead is None else lead.update(pad_vel, next(calls) * policy_dt)
        frame_offset = None
        if command_frame == "pad":
            frame_offset = pad_vel if carried_pad_velocity is None else np.asarray(carried_pad_velocity(), dtype=float)
        actions, _ = filter_actions(
            per_drone, command, offsets, max_speed, config, accel, pad_vel, latency, frame_offset, step
        )
        if lag is not None:
            lag.commanded(actions * max_speed + (0.0 if frame_offset is None else frame_offset))
        return actions.reshape(len(obs), 3 * num_drones)

    return filtered


def with_safety_filter_on(
    act: BatchAct,
    episodes: LandingEpisodes,
    config: SafetyFilterConfig | None = None,
    tracker_lag: TrackerLag | None = None,
) -> BatchAct:
    """:func:`with_safety_filter` for an actor flying ``episodes``, the way the deployment loop filters its commands:
    the swarm size, speed, period, observations and command frame are the episodes' task's, the pad offsets and
    motion its plate's, and each pad's velocity comes from the simulator's state (motion capture's, in the lab), with
    what a pad-frame command carries (:meth:`~marlander_lite.episodes.LandingEpisodes.carried_pad_velocity`)."""
    task, sim = episodes.task, episodes.sim
    n = task.num_drones

    def pad_velocity() -> np.ndarray:
        return sim.state().pad_vel

    return with_safety_filter(
        act,
        n,
        sim.platform.geometry.pad_offsets(n),
        task.max_speed,
        config,
        policy_dt=task.dt,
        observes_pad_velocity=task.observe_platform_velocity,
        pads_move=sim.platform.is_moving,
        tracker_lag=tracker_lag,
        command_frame=task.command_frame,
        pad_velocity=pad_velocity,
        carried_pad_velocity=episodes.carried_pad_velocity if task.command_frame == "pad" else None,
    )


def filter_actions(
    obs: np.ndarray,
    actions: np.ndarray,
    pad_offsets: np.ndarray,
    max_speed: float,
    config: SafetyFilterConfig,
    pad_acceleration: np.ndarray | None = None,
    pad_velocity: np.ndarray | None = None,
    latency: float | np.ndarray | None = None,
    command_offset: np.ndarray | None = None,
    velocity_step: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`filter_commands` on eq. 3 actions, with positions and velocities read from eq. 2 observations.

    Args:
        obs: each drone's observation ``(..., N, >= 13)``, as measured (eq. 2's ``p`` and ``v`` are read from it; the
            guards read ``p`` predicted ``config.latency_compensation`` ahead, :func:`predict_observations`).
        actions: normalised actions ``(..., N, 3)``; entries beyond [-1, 1] are clipped first, as eq. 3 does.
        pad_offsets: each drone's pad offset on the plate ``(N, 3)`` m: ``p + offset`` places the drones in one frame.
        max_speed: eq. 3's speed of action 1 (m/s).
        config: the filter's settings.
        pad_acceleration: each drone's pad's acceleration ``(..., N, 3)`` m/s^2 for the pad lead (``config.pad_lead``);
            None: no lead.
        pad_velocity: each drone's pad's velocity ``(..., N, 3)`` m/s (from observations that hold it), for the
            velocity-step limit (``config.low_velocity_step``); None: the pads are taken to be at rest.
        latency: the latency compensation ``L`` (s) the guards predict ``p`` by: a number, or ``(..., 1, 1)`` (one
            per env, as ``config.identified_lag_share`` identifies it); None: ``config.latency_compensation``.
        command_offset: ``(..., N, 3)`` m/s added to ``actions * max_speed`` to make the world command, and taken off
            the filtered one: the pad velocities of a pad-frame policy (``TaskConfig.command_frame``); None: none.
        velocity_step: the velocity-step limit's step (m/s), a number or ``(..., 1)`` per env
            (:meth:`SafetyFilterConfig.velocity_step`); None: ``config.low_velocity_step``.

    Returns:
        ``(filtered, correction)``: actions ``(..., N, 3)`` in [-1, 1], and how far the filter moved each drone's
        command, ``(..., N)`` m/s.
    """
    rel_goal, vel = obs[..., EQ2_POSITION], obs[..., EQ2_VELOCITY]
    command = np.clip(actions, -1.0, 1.0) * max_speed
    if command_offset is not None:
        command = command + command_offset
    # Eq. 2's v is relative to the pad; the velocity-step limit compares commands (world frame) with world velocities.
    # Only the differences of velocities keep drones apart, so the other rules read the same either way; without the
    # limit the velocities stay as observed, so that filtered flights without it are what they were before it.
    world_frame = pad_velocity is not None and config.low_velocity_step > 0
    lead = config.latency_compensation if latency is None else latency
    u, _ = filter_commands(
        rel_goal + pad_offsets,
        vel + pad_velocity if world_frame else vel,
        command,
        config,
        settled=settled_drones(rel_goal, vel, config),
        rel_goal=rel_goal + lead * vel,  # where the guards act: p + v L
        max_speed=max_speed,
        pad_acceleration=pad_acceleration,
        pad_velocity=pad_velocity if world_frame else None,
        velocity_step=velocity_step,
    )
    correction = np.linalg.norm(u - command, axis=-1)
    if command_offset is not None:
        u = u - command_offset
    return np.clip(u / max_speed, -1.0, 1.0), correction
