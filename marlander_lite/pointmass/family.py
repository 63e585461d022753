"""The family of velocity trackers a transferable policy must fly: robust training on the point mass.

A policy trained against one velocity tracker learns that tracker: how fast it tilts, how hard it
brakes, how late it answers. Flown on another (our PyBullet PID, the Crazyflie firmware's PID, a
heavier drone, a slower radio link) it dives too fast and touches down too hard. Domain
randomisation (Tobin et al. 2017; Peng et al. 2018) trains against a *family* instead: at every
episode reset each drone draws its own member, so the only policies that score well are the ones
whose flight every member can follow.

:class:`DynamicsFamily` holds one ``(low, high)`` range per physical property of the point-mass
model (:class:`~marlander_lite.pointmass.simulator.PointMassParams`) plus the effects that model
does not have by default: command latency, a mass mismatch the tracker does not know about, rotor
drag, a ground cushion near surfaces and a tracking-gain error. The default ranges cover the
system identification of both PyBullet trackers (``marlander_lite.crazyflie.fit.identify_trackers``,
notebook 02) with a margin, and the Crazyflie variants the firmware allows (tilt limits from
15 to 35 degrees); see ``docs/transfer.md`` for the table and where each range comes from.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

Range = tuple[float, float]

GRAVITY = 9.81


@dataclass(frozen=True)
class DynamicsFamily:
    """Ranges, ``(low, high)``, from which each drone draws its dynamics at every episode reset.

    Every draw is uniform within its range; ``low == high`` fixes a property. All ranges are
    physical units, never factors, so that a reader can compare them with a data sheet.
    """

    velocity_time_constant: Range = (0.08, 0.40)
    """tau of the horizontal velocity loop (s); see ``PointMassParams.velocity_time_constant``."""
    vertical_time_constant: Range = (0.04, 0.30)
    """tau of the vertical velocity loop (s)."""
    attitude_time_constant: Range = (0.04, 0.20)
    """Time constant of the thrust axis turning towards the asked-for direction (s); motor lag adds to it."""
    max_tilt_deg: Range = (15.0, 35.0)
    """Tilt limit of the tracker (deg): the Crazyflie firmware clamps at 20, other firmware up to 30-35."""
    max_climb_acceleration: Range = (3.0, 12.0)
    """Thrust margin above hover (m/s^2): a 2.25 thrust-to-weight CF2X has ~12, a loaded one far less."""
    max_sink_acceleration: Range = (3.0, 7.5)
    """How far below g the tracker may cut thrust (m/s^2); the firmware's minimum thrust sets it."""
    latency_s: Range = (0.0, 0.06)
    """Delay between the policy's command and the tracker acting on it (s): radio, mocap, firmware rates."""
    mass_scale: Range = (0.85, 1.15)
    """True mass over the mass the tracker assumes: a heavier drone gets less acceleration per command."""
    drag: Range = (0.0, 0.3)
    """Linear drag (1/s): acceleration ``-drag * v`` that the tracker must overcome."""
    ground_cushion: Range = (0.0, 0.5)
    """Ground effect as extra upward acceleration in units of g at the surface, fading as ``(r / (r + h))^2``
    with ``r`` = :data:`CUSHION_LENGTH` and ``h`` the height above the surface below the drone."""
    command_gain: Range = (0.9, 1.1)
    """Steady-state speed over commanded speed: our PID settles 6-8 % above the command."""
    velocity_integral_gain: Range = (0.0, 0.0)
    """Integral action of the horizontal velocity loop (1/s): the loop acts on ``u + k_i * integral(u - v) dt``, as a
    PID tracker does whose integrator carries past errors into the next seconds (PyFlyt's Crazyflie: ``k_i / k_p =
    0.3 / 0.8`` = 0.375 1/s; docs/transfer.md, "An integrator in the tracker"). 0: none, the paper's point mass. An
    extension (:data:`EXTENSIONS`): at (0, 0) it is neither drawn nor written, so families without it stay as before."""

    def __post_init__(self) -> None:
        bounds = {
            "velocity_time_constant": (1e-3, 5.0),
            "vertical_time_constant": (1e-3, 5.0),
            "attitude_time_constant": (1e-3, 5.0),
            "max_tilt_deg": (1.0, 89.0),
            "max_climb_acceleration": (0.1, 50.0),
            "max_sink_acceleration": (0.1, GRAVITY - 0.1),
            "latency_s": (0.0, 0.5),
            "mass_scale": (0.5, 2.0),
            "drag": (0.0, 5.0),
            "ground_cushion": (0.0, 2.0),
            "command_gain": (0.5, 2.0),
            "velocity_integral_gain": (0.0, 5.0),
        }
        for name, (lowest, highest) in bounds.items():
            object.__setattr__(self, name, checked_range("DynamicsFamily", name, getattr(self, name), lowest, highest))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> DynamicsFamily:
        """A family from a mapping of field -> ``(low, high)`` (JSON gives lists); missing fields keep defaults."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise TypeError(f"Unknown DynamicsFamily field(s) {unknown}; allowed: {sorted(known)}.")
        return cls(**{name: tuple(value) for name, value in values.items()})

    @classmethod
    def fixed(cls, **values: float) -> DynamicsFamily:
        """A family whose every range is a single value: the given ones, else the nominal fit (no randomisation).

        Useful to fly one member exactly, e.g. ``DynamicsFamily.fixed(latency_s=0.06, max_tilt_deg=20)``.
        """
        nominal = dict(NOMINAL)
        nominal.update(values)
        return cls.from_mapping({name: (v, v) for name, v in nominal.items()})

    def to_dict(self) -> dict[str, list[float]]:
        """Field -> ``[low, high]``; an extension left at (0, 0) is left out, as families before it wrote them."""
        return {f.name: list(getattr(self, f.name)) for f in dataclasses.fields(self) if not self._unused(f.name)}

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
        """One draw per entry of ``shape`` (e.g. ``(envs, drones)``) for every property, uniform in its range.

        The properties are drawn in field order, one ``rng.uniform`` call each, so a seeded
        generator gives the same dynamics on every machine. An extension left at (0, 0) is zero without a draw,
        so a seed gives the same flights as before the extension existed.
        """
        return {
            f.name: np.zeros(shape) if self._unused(f.name) else rng.uniform(*getattr(self, f.name), size=shape)
            for f in dataclasses.fields(self)
        }

    def _unused(self, name: str) -> bool:
        return name in EXTENSIONS and getattr(self, name) == (0.0, 0.0)


Corners = tuple[tuple[DynamicsFamily, float], ...]
"""Corners of a family, each with the share of the drones that draw from it (``PointMassParams.corner``)."""


def family_corners(family: DynamicsFamily | None, corner: Any, fraction: Any) -> Corners:
    """``PointMassParams.corner`` and ``corner_fraction`` as ``((corner, share), ...)``, checked.

    ``corner`` is one corner or a list of them, each a :class:`DynamicsFamily` or a mapping of ranges that replace
    ``family``'s (every other range is the family's); ``fraction`` is one share in (0, 1] or a list of them, one per
    corner, summing to at most 1 (a drone draws from at most one corner). ``None`` and 0 give no corners.
    """
    if corner is None and not fraction:
        return ()
    if family is None:
        raise ValueError("PointMassParams.corner is a corner of the family; give a family as well.")
    several = isinstance(corner, list | tuple)
    corners = list(corner) if several else [corner]
    shares = list(fraction) if isinstance(fraction, list | tuple) else [fraction]
    if corner is None or not fraction or len(shares) != len(corners) or not corners:
        raise ValueError(
            "PointMassParams: give corner and corner_fraction in (0, 1] together (a family for both), one share per "
            f"corner, or neither; got corner {corner!r}, corner_fraction {fraction!r}."
        )
    checked = []
    for each, share in zip(corners, shares, strict=True):
        if isinstance(each, Mapping):
            each = DynamicsFamily.from_mapping({**family.to_dict(), **each})
        if not isinstance(each, DynamicsFamily):
            raise TypeError(f"PointMassParams.corner must be a DynamicsFamily or a dict of its ranges, got {each!r}.")
        if not (isinstance(share, int | float) and 0.0 < share <= 1.0):
            raise ValueError(f"PointMassParams.corner_fraction must be in (0, 1] for each corner, got {fraction!r}.")
        checked.append((each, float(share)))
    if sum(share for _, share in checked) > 1.0 + 1e-12:
        raise ValueError(f"PointMassParams.corner_fraction sums to more than 1 ({fraction!r}); a drone has one corner.")
    return tuple(checked)


def draw_with_corners(
    family: DynamicsFamily, corners: Corners, rng: np.random.Generator, shape: tuple[int, ...]
) -> dict[str, np.ndarray]:
    """One draw per entry of ``shape`` from ``family``, then each drone moved to a corner with its share.

    The family's draws come first and one uniform number per drone then picks its corner (the first corner for
    ``u < share_1``, the second for ``share_1 <= u < share_1 + share_2``, ...), each corner drawn whole after it: a
    seed keeps the family's draws of a run without corners, and one corner's the draws of the runs with one.
    """
    draw = family.sample(rng, shape)
    if not corners:
        return draw
    pick, start = rng.random(shape), 0.0
    for corner, share in corners:
        picked = (pick >= start) & (pick < start + share)
        drawn = corner.sample(rng, shape)
        draw = {name: np.where(picked, drawn[name], value) for name, value in draw.items()}
        start += share
    return draw


def checked_range(owner: str, name: str, value: Any, lowest: float, highest: float) -> Range:
    """``value`` as a ``(low, high)`` pair of floats within ``[lowest, highest]``.

    Raises a ``ValueError`` naming ``owner.name`` and what is allowed: not a pair of numbers, not finite, an empty
    range (``low > high``) or one leaving the allowed interval (a negative ``latency_s`` says why).
    """
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} must be a (low, high) pair of numbers, got {value!r}.") from None
    if not (np.isfinite(low) and np.isfinite(high)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}.")
    if low > high:
        raise ValueError(f"{owner}.{name} is an empty range: low {low} > high {high}; give (low, high).")
    if low < lowest or high > highest:
        why = " (a latency cannot be negative)" if name == "latency_s" else ""
        raise ValueError(f"{owner}.{name} = {value!r} leaves the allowed interval [{lowest}, {highest}]{why}.")
    return low, high


EXTENSIONS = ("velocity_integral_gain",)
"""Fields added after families were first shipped, off at (0, 0): such a field changes neither the draws nor the
``to_dict`` of a family that does not use it, so runs trained before it reproduce and compare equal."""


CUSHION_LENGTH = 0.04
"""Length scale of the ground cushion (m): about two Crazyflie rotor radii (0.023 m)."""

NOMINAL: dict[str, float] = {
    "velocity_time_constant": 0.142,
    "vertical_time_constant": 0.0556,
    "attitude_time_constant": 0.135,
    "max_tilt_deg": 34.0,
    "max_climb_acceleration": 10.3,
    "max_sink_acceleration": 5.39,
    "latency_s": 0.0,
    "mass_scale": 1.0,
    "drag": 0.0,
    "ground_cushion": 0.0,
    "command_gain": 1.0,
    "velocity_integral_gain": 0.0,
}
"""The default point mass (the fit to our PyBullet PID) expressed as a family member."""
