"""Landing platforms: the plate with one pad per drone, and how it moves.

The paper's hardware (Sec. IV-A) is a 0.5 x 0.5 m acrylic plate on the tool flange of a UR10
arm, carrying two round pads. Its text gives a pad radius of 0.2 m, which cannot fit twice
on 0.5 m; we use radius 0.1 m with 0.25 m between pad centres (see ``docs/paper_to_code.md``).
For ``N`` drones the pads form a near-square grid at the same spacing (the default), a line or a
ring (:class:`PlateGeometry`); beyond the paper, the plate may also be inclined up to 15 degrees and
more (its future work, Sec. VI: "inclined surfaces").

Four motions cover the paper's experiments (Fig. 7), and a fifth mixes the two moving ones for training:

``static-floor``     the plate lies on the floor (Fig. 7a);
``static-elevated``  the plate is held still by the UR10, 0.5-1.0 m up (Fig. 7b);
``moving-linear``    the plate moves back and forth along a straight stroke at constant speed (Fig. 7c);
``moving-arc``       the UR10 base swings the plate within -pi/2..pi/2 at a constant tool speed
                     (Sec. IV-C: 0.2 to 0.5 m/s);
``moving-mixed``     each episode draws ``moving-linear`` or ``moving-arc``, half each (for training; not in
                     the paper). The 1 m stroke turns back every 2.5 s at 0.5 m/s, the 2.8 m arc every 6 s.
                     The ``moving`` preset trained on it landed no better on the line and worse on the arc
                     than on the arc alone (one seed, docs/transfer.md), so no preset uses it.

Moving plates cruise at the tool speed and brake and speed up again at the ends of their path
with a finite acceleration (:func:`shuttle`), as an arm executing linear moves does.

The plate keeps its orientation (no yaw) in every motion; this keeps the pads' relative
positions fixed, which the centralised policy relies on to tell where the other drones are.
All positions are world-frame metres, ``z`` up; the plate position is the centre of its top face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np
from scipy.spatial.transform import Rotation

PlatformKind = Literal["static-floor", "static-elevated", "moving-linear", "moving-arc", "moving-mixed"]
PLATFORM_KINDS: tuple[str, ...] = get_args(PlatformKind)
MOVING_KINDS: tuple[str, ...] = ("moving-linear", "moving-arc", "moving-mixed")
DEFAULT_MOVING_SPEED = 0.35
"""Tool speed (m/s) used when a moving platform is asked for without a speed: the middle of
the paper's 0.2-0.5 m/s range."""


PadLayout = Literal["grid", "line", "ring"]
PAD_LAYOUTS: tuple[str, ...] = get_args(PadLayout)
MAX_INCLINATION_DEG = 90.0
"""Plates must tilt less than this from horizontal (degrees): at 90 the pads face sideways."""


@dataclass(frozen=True)
class PlateGeometry:
    """Size of the plate, its pads, their layout and the plate's inclination.

    Pad layouts for ``P`` pads (``num_pads``, by default one per drone), all at ``pad_spacing``
    between neighbouring centres:

    ``grid``  near-square grid, ``ceil(sqrt(P))`` columns, filled row by row along +x then +y (the
              default; for 2 pads it is the paper's pair along x);
    ``line``  one row along +x;
    ``ring``  a regular P-gon around the plate centre whose neighbouring pads are ``pad_spacing``
              apart (circumradius ``pad_spacing / (2 sin(pi / P))``), pad 0 on +x, counter-clockwise.

    The plate is a square or rectangle sized to hold the layout with half a spacing of margin around
    the outer pad centres, and at least ``plate_min_side`` wide. With ``inclination_deg`` > 0 (beyond
    the paper) the plate tilts by that angle about a horizontal axis through its centre at
    ``tilt_axis_deg`` from +x; pad centres and normals turn with it (:meth:`rotation`).
    """

    pad_radius: float = 0.1
    """Radius of each round pad (m); a landing must end within it (paper text: 0.2, see module doc)."""
    pad_spacing: float = 0.25
    """Distance between neighbouring pad centres (m); at least ``2 pad_radius`` so pads do not overlap."""
    pad_thickness: float = 0.0025
    """Pad thickness (m), as in the paper."""
    plate_thickness: float = 0.005
    """Acrylic plate thickness (m); chosen, the paper does not say."""
    plate_min_side: float = 0.5
    """Smallest plate side (m): the paper's plate is 0.5 x 0.5 m."""
    layout: PadLayout = "grid"
    """Pad layout, one of ``PAD_LAYOUTS``."""
    num_pads: int | None = None
    """Pads on the plate; ``None``: one per drone. Drone ``i`` lands on pad ``i``; a plate with fewer pads than
    drones is refused."""
    inclination_deg: float = 0.0
    """Tilt of the plate from horizontal (degrees, in [0, 90)); beyond the paper, which keeps the plate level."""
    tilt_axis_deg: float = 0.0
    """Direction of the horizontal tilt axis, degrees from world +x. 0: the plate turns about +x, right-handed, so
    its +y edge rises and its normal leans towards -y."""

    def __post_init__(self) -> None:
        sizes = (self.pad_radius, self.pad_spacing, self.pad_thickness, self.plate_thickness, self.plate_min_side)
        if not all(isinstance(v, int | float) and math.isfinite(v) and v > 0 for v in sizes):
            raise ValueError(
                "PlateGeometry: pad_radius, pad_spacing, pad_thickness, plate_thickness and plate_min_side must be "
                f"finite numbers > 0 m, got {sizes}."
            )
        if self.layout not in PAD_LAYOUTS:
            raise ValueError(f"Unknown pad layout {self.layout!r}; allowed: {', '.join(PAD_LAYOUTS)}.")
        if self.pad_spacing < 2 * self.pad_radius:
            raise ValueError(
                f"Pads overlap: pad_spacing {self.pad_spacing} m is less than twice the pad radius "
                f"({2 * self.pad_radius} m); use pad_spacing >= 2 * pad_radius."
            )
        if self.num_pads is not None and (
            isinstance(self.num_pads, bool) or not isinstance(self.num_pads, int) or self.num_pads < 1
        ):
            raise ValueError(f"num_pads must be None (one pad per drone) or an integer >= 1, got {self.num_pads!r}.")
        if not (math.isfinite(self.inclination_deg) and 0 <= self.inclination_deg < MAX_INCLINATION_DEG):
            raise ValueError(
                f"inclination_deg must be in [0, {MAX_INCLINATION_DEG:g}) degrees (a plate at 90 degrees or more "
                f"faces sideways or down), got {self.inclination_deg!r}."
            )
        if not math.isfinite(self.tilt_axis_deg):
            raise ValueError(f"tilt_axis_deg must be finite, got {self.tilt_axis_deg!r}.")

    def pad_count(self, num_drones: int) -> int:
        """Pads on the plate for ``num_drones`` drones; raises if that is fewer than the drones, or ``N < 1``."""
        if isinstance(num_drones, bool) or not isinstance(num_drones, int | np.integer) or num_drones < 1:
            raise ValueError(f"num_drones must be an integer >= 1, got {num_drones!r}.")
        pads = int(num_drones) if self.num_pads is None else self.num_pads
        if pads < num_drones:
            raise ValueError(
                f"More drones than pads: {num_drones} drones but the plate has {pads} pads (num_pads); every drone "
                "needs its own pad."
            )
        return pads

    def grid_shape(self, num_drones: int) -> tuple[int, int]:
        """(columns, rows) of the pad grid for ``num_drones`` drones (a line is one row)."""
        pads = self.pad_count(num_drones)
        if self.layout == "line":
            return pads, 1
        cols = math.ceil(math.sqrt(pads))
        return cols, math.ceil(pads / cols)

    def ring_radius(self, num_drones: int) -> float:
        """Circumradius of the ``ring`` layout (m): neighbouring pads ``pad_spacing`` apart; 0 for one pad."""
        pads = self.pad_count(num_drones)
        return 0.0 if pads == 1 else self.pad_spacing / (2 * math.sin(math.pi / pads))

    def half_extents(self, num_drones: int) -> tuple[float, float]:
        """Half the plate's side lengths (x, y) in metres, in the plate's own (untilted) frame."""
        if self.layout == "ring":
            side = 2 * self.ring_radius(num_drones) + self.pad_spacing
            side = max(side, self.plate_min_side)
            return side / 2, side / 2
        cols, rows = self.grid_shape(num_drones)
        side_x = max(cols * self.pad_spacing, self.plate_min_side)
        side_y = max(rows * self.pad_spacing, self.plate_min_side)
        return side_x / 2, side_y / 2

    def rotation(self) -> np.ndarray:
        """``(3, 3)`` rotation from the plate frame to the world frame: ``inclination_deg`` about the horizontal
        axis at ``tilt_axis_deg`` from world x.

        The identity for a level plate. Column 2 is the plate's (and every pad's) normal.
        """
        if self.inclination_deg == 0:
            return np.eye(3)
        theta, psi = math.radians(self.inclination_deg), math.radians(self.tilt_axis_deg)
        axis = np.array([math.cos(psi), math.sin(psi), 0.0])
        return Rotation.from_rotvec(theta * axis).as_matrix()

    def normal(self) -> np.ndarray:
        """Unit normal of the plate's top face (and of every pad), world frame, ``(3,)``; ``+z`` when level."""
        return self.rotation()[:, 2].copy()

    def pad_offsets(self, num_drones: int) -> np.ndarray:
        """Centre of each drone's pad top face relative to the plate position, ``(num_drones, 3)`` m, world frame.

        Pad ``i`` belongs to drone ``i`` (pads beyond ``num_drones`` stay empty). On a tilted plate the
        offsets are turned by :meth:`rotation`.
        """
        pads = self.pad_count(num_drones)
        if self.layout == "ring":
            angle = 2 * math.pi * np.arange(num_drones) / pads
            radius = self.ring_radius(num_drones)
            x, y = radius * np.cos(angle), radius * np.sin(angle)
        else:
            cols, rows = self.grid_shape(num_drones)
            idx = np.arange(num_drones)
            col, row = idx % cols, idx // cols
            x = (col - (cols - 1) / 2) * self.pad_spacing
            y = (row - (rows - 1) / 2) * self.pad_spacing
        z = np.full(num_drones, self.pad_thickness)
        offsets = np.stack((x, y, z), axis=-1)
        if self.inclination_deg == 0:
            return offsets  # bit for bit the level plate's
        return offsets @ self.rotation().T

    def lowest_corner_drop(self, num_drones: int) -> float:
        """How far below the plate position the lowest corner of the tilted top face lies (m); 0 when level.

        A tilted plate on the floor is raised by this much so that no corner goes through the floor.
        """
        if self.inclination_deg == 0:
            return 0.0
        hx, hy = self.half_extents(num_drones)
        corners = np.array([[sx * hx, sy * hy, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        return float(max(0.0, -(corners @ self.rotation().T)[:, 2].min()))


@dataclass(frozen=True)
class PlatformConfig:
    """Which platform motion, how fast, and the sizes of the UR10 set-up."""

    kind: PlatformKind = "static-floor"
    """One of ``PLATFORM_KINDS``."""
    speed: float | tuple[float, float] | None = None
    """Tool speed for moving kinds (m/s); a ``(low, high)`` pair draws it uniformly per episode (for
    training); ``None`` means 0 for static kinds, 0.35 for moving ones."""
    geometry: PlateGeometry = field(default_factory=PlateGeometry)
    """Plate and pad sizes."""
    elevated_height: tuple[float, float] = (0.5, 1.0)
    """Range of the plate's top height when held by the UR10 (m), drawn uniformly per episode. A range that
    starts at the plate thickness (on the floor) lets one training run cover floor and UR10 alike."""
    linear_stroke: float = 1.0
    """Length of the straight back-and-forth path of ``moving-linear`` (m)."""
    arc_radius: float = 0.9
    """Distance of the plate from the UR10 base axis in ``moving-arc`` (m); the UR10 reaches 1.3 m."""
    arc_half_angle: float = math.pi / 2
    """The base swings within ``[-arc_half_angle, +arc_half_angle]`` (rad), as in the paper."""
    reversal_acceleration: float = 1.0
    """Tool acceleration (m/s^2) with which the arm speeds up and brakes at the ends of a stroke or swing; the
    paper does not say, 1 m/s^2 is a moderate UR10 setting. It keeps the reversal of a 0.5 m/s move at 1 s."""

    def __post_init__(self) -> None:
        if self.kind not in PLATFORM_KINDS:
            raise ValueError(f"Unknown platform {self.kind!r}; allowed: {', '.join(PLATFORM_KINDS)}.")
        if self.speed is not None:
            low, high = self.speed_range
            if not (np.isfinite(low) and np.isfinite(high) and 0 <= low <= high):
                raise ValueError(
                    f"platform_speed must be a finite number >= 0 m/s or a (low, high) pair with 0 <= low <= high, "
                    f"got {self.speed!r}."
                )
            if self.kind not in MOVING_KINDS and high > 0:
                raise ValueError(
                    f"platform_speed={self.speed} was given for the static platform {self.kind!r}; "
                    f"use one of {MOVING_KINDS} for a moving platform, or leave the speed out."
                )
        lo, hi = self.elevated_height
        if not self.geometry.plate_thickness <= lo <= hi:
            raise ValueError(
                f"elevated_height must be (low, high) with {self.geometry.plate_thickness} m (the plate on the floor) "
                f"<= low <= high, got {self.elevated_height}."
            )
        if self.linear_stroke <= 0 or self.arc_radius <= 0 or not 0 < self.arc_half_angle <= math.pi:
            raise ValueError("linear_stroke and arc_radius must be > 0 m and arc_half_angle in (0, pi].")
        if not (np.isfinite(self.reversal_acceleration) and self.reversal_acceleration > 0):
            raise ValueError(f"reversal_acceleration must be > 0 m/s^2, got {self.reversal_acceleration!r}.")

    @property
    def speed_range(self) -> tuple[float, float]:
        """``(low, high)`` tool speed in m/s (equal for a fixed speed), defaults filled in."""
        if isinstance(self.speed, tuple | list):
            if len(self.speed) != 2:
                raise ValueError(f"platform_speed as a range must be (low, high), got {self.speed!r}.")
            return float(self.speed[0]), float(self.speed[1])
        speed = self.resolved_speed
        return speed, speed

    @property
    def resolved_speed(self) -> float:
        """Tool speed in m/s with the default for moving kinds filled in (the middle of a range)."""
        if isinstance(self.speed, tuple | list):
            return 0.5 * (float(self.speed[0]) + float(self.speed[1]))
        if self.speed is not None:
            return float(self.speed)
        return DEFAULT_MOVING_SPEED if self.kind in MOVING_KINDS else 0.0

    @property
    def is_moving(self) -> bool:
        return self.kind in MOVING_KINDS


def shuttle(
    t: np.ndarray, phase: np.ndarray, length: float, speed: np.ndarray, accel: float
) -> tuple[np.ndarray, np.ndarray]:
    """Back-and-forth motion along ``[0, length]`` with a trapezoidal speed profile.

    Each leg accelerates at ``accel`` (m/s^2) to ``speed`` (m/s), cruises, and brakes at ``accel``
    to a stop at the far end, the way an industrial arm executes a linear move. ``phase`` in
    ``[0, 2)`` says where in the cycle each env is at ``t = 0`` (one unit per leg). Returns the
    position along the path (m) and its rate (m/s), each shaped like ``t``.
    """
    speed = np.minimum(speed, np.sqrt(accel * length))  # short paths never reach full speed
    moving = speed > 1e-9
    s = np.where(moving, speed, 1.0)
    ramp = s / accel  # time to reach full speed
    leg = length / s + ramp  # duration of one leg, both ramps included
    tau = np.mod(t + phase * leg, 2.0 * leg)
    back = tau >= leg
    tau = np.where(back, tau - leg, tau)
    to_end = leg - tau
    u = np.where(
        tau < ramp,
        0.5 * accel * tau**2,
        np.where(to_end < ramp, length - 0.5 * accel * to_end**2, 0.5 * s * ramp + s * (tau - ramp)),
    )
    rate = np.where(tau < ramp, accel * tau, np.where(to_end < ramp, accel * to_end, s))
    u = np.where(back, length - u, u)
    rate = np.where(back, -rate, rate)
    return np.where(moving, u, 0.5 * length), np.where(moving, rate, 0.0)


class PlatformMotion:
    """Batched plate trajectories for ``num_envs`` environments.

    Call :meth:`sample` at reset to draw a new placement for some environments, then
    :meth:`state` with each environment's elapsed time to get the plate's position and
    velocity, each ``(num_envs, 3)`` in metres and m/s.
    """

    def __init__(self, config: PlatformConfig, num_envs: int, num_drones: int, arena_half_width: float) -> None:
        self.config = config
        self.num_envs = num_envs
        self.pad_offsets = config.geometry.pad_offsets(num_drones)
        self.pad_normal = config.geometry.normal()
        """Unit normal of every pad's top face, world frame ``(3,)``: ``+z`` unless the plate is inclined."""
        self._floor_lift = config.geometry.lowest_corner_drop(num_drones)
        hx, hy = config.geometry.half_extents(num_drones)
        self._plate_half_diag = math.hypot(hx, hy)
        self._arena_half_width = arena_half_width
        self.is_moving = config.is_moving
        self._free = arena_half_width - self._plate_half_diag - self._path_half_width()
        if self._free < 0:
            raise ValueError(
                f"The {config.kind} platform for {num_drones} drones does not fit in an arena of half width "
                f"{arena_half_width} m; enlarge the arena or shorten the stroke / arc radius."
            )
        self.anchor = np.zeros((num_envs, 3), order="F")
        """Per env: the plate position (static), the stroke midpoint (linear) or the UR10 base axis (arc)."""
        self.heading = np.zeros(num_envs)
        self.phase = np.zeros(num_envs)
        self.speed = np.full(num_envs, config.resolved_speed)
        """Per env tool speed (m/s), drawn from ``config.speed_range`` at every :meth:`sample`."""
        self.on_line = np.full(num_envs, config.kind == "moving-linear")
        """Per env: does the plate follow the straight stroke (else the arc, when moving)? Drawn per episode
        for ``moving-mixed``."""

    def _path_half_width(self) -> float:
        kind, cfg = self.config.kind, self.config
        line = cfg.linear_stroke / 2 if kind in ("moving-linear", "moving-mixed") else 0.0
        arc = cfg.arc_radius if kind in ("moving-arc", "moving-mixed") else 0.0
        return max(line, arc)

    def sample(self, rng: np.random.Generator, env_ids: np.ndarray) -> None:
        """Draw a new random placement (and phase, for moving kinds) for ``env_ids``."""
        n = len(env_ids)
        cfg = self.config
        self.anchor[env_ids, :2] = rng.uniform(-self._free, self._free, size=(n, 2))
        if cfg.kind == "static-floor":
            self.anchor[env_ids, 2] = cfg.geometry.plate_thickness + self._floor_lift
        else:
            self.anchor[env_ids, 2] = rng.uniform(*cfg.elevated_height, size=n) + self._floor_lift
        self.heading[env_ids] = rng.uniform(-math.pi, math.pi, size=n)
        self.phase[env_ids] = rng.uniform(0.0, 2.0, size=n)
        low, high = cfg.speed_range
        if high > low:
            self.speed[env_ids] = rng.uniform(low, high, size=n)
        if cfg.kind == "moving-mixed":  # drawn last: the other kinds keep their random streams
            self.on_line[env_ids] = rng.random(n) < 0.5

    def state(self, t: np.ndarray, env_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Plate position and velocity at elapsed times ``t`` (s), each ``(len(t), 3)``.

        ``t`` holds one time per env, or per env of ``env_ids`` when given.
        """
        cfg = self.config
        sel = slice(None) if env_ids is None else env_ids
        speed = self.speed[sel]
        pos = np.asfortranarray(self.anchor[sel]).copy(order="F")
        vel = np.zeros_like(pos)
        phase, heading = self.phase[sel], self.heading[sel]
        if not self.is_moving:
            return pos, vel
        on_line = self.on_line[sel]
        # Whole-batch slices for the single kinds: the same numbers as masks, without copying every array.
        line = slice(None) if on_line.all() else on_line
        arc_ids = slice(None) if not on_line.any() else ~on_line
        if on_line.any():
            u, rate = shuttle(t[line], phase[line], cfg.linear_stroke, speed[line], cfg.reversal_acceleration)
            cos, sin = np.cos(heading[line]), np.sin(heading[line])
            along = u - 0.5 * cfg.linear_stroke
            pos[line, 0] += cos * along
            pos[line, 1] += sin * along
            vel[line, 0], vel[line, 1] = cos * rate, sin * rate
        if not on_line.all():
            arc = 2.0 * cfg.arc_half_angle * cfg.arc_radius
            u, rate = shuttle(t[arc_ids], phase[arc_ids], arc, speed[arc_ids], cfg.reversal_acceleration)
            theta = heading[arc_ids] - cfg.arc_half_angle + u / cfg.arc_radius
            cos, sin = np.cos(theta), np.sin(theta)
            pos[arc_ids, 0] += cfg.arc_radius * cos
            pos[arc_ids, 1] += cfg.arc_radius * sin
            vel[arc_ids, 0], vel[arc_ids, 1] = -sin * rate, cos * rate
        return pos, vel
