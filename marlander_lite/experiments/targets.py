"""The transfer targets, checked on a transfer matrix: where a policy meets them, and where it misses.

A transfer matrix (:mod:`~marlander_lite.experiments.transfer`) has up to 48 cells and a dozen numbers in each. The
question a lab asks of it is shorter: does this policy land as well as the paper's, in every simulator it may meet,
with a flight a real Crazyflie can follow? :func:`check_targets` answers it for one matrix and one set of
:class:`TransferTargets`, target by target, with the worst cell and where it is, so a miss is never averaged away.

Two sets are defined, from the issue "Policies that transfer" (docs/transfer.md, "The targets, checked"):

* :data:`QUICK_CPU_TARGETS`: the 10-minute CPU preset, on static pads: success >= 90 % and landing error <= 2.26 cm
  (the paper's Table I, MARLander) in every cell of the floor and UR10 rows;
* :data:`PAPER_AND_MOVING_TARGETS`: the paper's policy and the moving one: >= 95 % on static pads with the 95 %
  Wilson interval's lower bound >= 90 %, <= 2.26 cm; >= 90 % on the moving arc and line at 0.2-0.5 m/s, <= 3.93 cm
  (the paper's Table II, MARLander).

Both add the flight a Crazyflie can follow, judged on the columns flown through the Crazyflie firmware's velocity
tracker (``controller="firmware"``, its perturbations included): mean touchdown speed <= 0.3 m/s, commands within
0.5 m of the pad <= 1.5 m/s (95th percentile), at most 5 % of flying steps at the 20-degree tilt clamp (the issue's
"brief moments", in numbers: our reading), and >= 0.3 m above the surface when 0.5 m from the pad.

:func:`format_targets` prints them twice side by side: over the issue's seven columns (:data:`ISSUE_COLUMNS`: the point
mass, PyBullet with our PID and with the firmware tracker, and the four perturbations of the latter) and over every
column the matrix flew (RotorPy, PyFlyt, the held-out tracker when asked for).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from marlander_lite.experiments.tables import PAPER
from marlander_lite.experiments.transfer import COLUMNS, EXTRA_COLUMNS, CellResult

STATIC_ROWS = ("floor", "UR10")
"""The static rows of the matrix: the pad on the floor and on the UR10's flange."""
MOVING_ROWS = ("arc 0.2-0.5 m/s", "line 0.2-0.5 m/s")
"""The moving rows: the pad carried along an arc or a line at 0.2-0.5 m/s."""
ISSUE_COLUMNS = tuple(c.name for c in COLUMNS)
"""The matrix the issue asks for: point mass, PyBullet PID, PyBullet firmware, mass +15 %, latency 60 ms, gains x0.7
and x1.3 (``marlander transfer``'s default columns)."""
FIRMWARE_COLUMNS = tuple(c.name for c in COLUMNS + EXTRA_COLUMNS if c.options.get("controller") == "firmware")
"""Columns flown through the Crazyflie firmware's velocity tracker: where the flight targets are judged."""


@dataclass(frozen=True)
class TransferTargets:
    """What a policy must reach in every cell it is judged on; ``None`` leaves a target out."""

    name: str
    """Which policies the set is for (printed with the check)."""
    static_success: float
    """Least success share on every static cell (floor, UR10)."""
    static_wilson_low: float | None
    """Least lower bound of the 95 % Wilson interval of the success share on every static cell."""
    static_error_cm: float
    """Largest mean landing error on every static cell (cm); 2.26 is the paper's Table I (MARLander)."""
    moving_success: float | None
    """Least success share on every moving cell (arc and line, 0.2-0.5 m/s); ``None``: moving pads not asked for."""
    moving_error_cm: float | None
    """Largest mean landing error on every moving cell (cm); 3.93 is the paper's Table II (MARLander)."""
    touchdown_speed: float = 0.3
    """Largest mean touchdown speed relative to the pad on the firmware columns (m/s)."""
    command_near_pad: float = 1.5
    """Largest 95th percentile of the commanded speed within 0.5 m of the pad on the firmware columns (m/s)."""
    tilt_limit_fraction: float = 0.05
    """Largest share of flying steps at the firmware's 20-degree tilt clamp on the firmware columns."""
    approach_height: float = 0.3
    """Least height above the surface when a drone comes within 0.5 m of its pad on the firmware columns (m)."""

    def __post_init__(self) -> None:
        shares = ("static_success", "static_wilson_low", "moving_success", "tilt_limit_fraction")
        for name in shares:
            value = getattr(self, name)
            if value is not None and not 0.0 <= value <= 1.0:
                raise ValueError(f"TransferTargets.{name} is a share from 0 to 1, got {value!r}.")
        for name in ("static_error_cm", "moving_error_cm", "touchdown_speed", "command_near_pad", "approach_height"):
            value = getattr(self, name)
            if value is not None and not value > 0.0:
                raise ValueError(f"TransferTargets.{name} must be > 0, got {value!r}.")
        if (self.moving_success is None) != (self.moving_error_cm is None):
            raise ValueError("TransferTargets: give both moving_success and moving_error_cm, or neither.")


PAPER_STATIC_ERROR_CM = PAPER["static"]["marlander"].precision_cm
"""MARLander's landing error on static pads in the paper's Table I (cm)."""
PAPER_MOVING_ERROR_CM = PAPER["moving"]["marlander"].precision_cm
"""MARLander's landing error on moving pads in the paper's Table II (cm)."""

QUICK_CPU_TARGETS = TransferTargets(
    name="quick-cpu", static_success=0.90, static_wilson_low=None, static_error_cm=PAPER_STATIC_ERROR_CM,
    moving_success=None, moving_error_cm=None,
)  # fmt: skip
"""The issue's targets for the 10-minute CPU preset: static pads only."""
PAPER_AND_MOVING_TARGETS = TransferTargets(
    name="paper and moving", static_success=0.95, static_wilson_low=0.90, static_error_cm=PAPER_STATIC_ERROR_CM,
    moving_success=0.90, moving_error_cm=PAPER_MOVING_ERROR_CM,
)  # fmt: skip
"""The issue's targets for the paper's policy and the moving one: static and moving pads."""
TARGETS = {"quick-cpu": QUICK_CPU_TARGETS, "paper": PAPER_AND_MOVING_TARGETS, "moving": PAPER_AND_MOVING_TARGETS}
"""``marlander transfer --targets NAME``'s sets."""


@dataclass(frozen=True)
class TargetCheck:
    """One target on one set of cells: the worst value, where it is, and whether every cell meets the target."""

    target: str
    """What is measured, and on which cells (``"success, static rows"``)."""
    required: str
    """The bound, as text (``">= 95.0 %"``)."""
    cells: int
    """Cells the target applies to (0: none flown, so not judged)."""
    worst: float
    """The worst value over those cells (NaN: none, or a cell without the measurement)."""
    where: str
    """The worst cell, ``"row, column"``."""
    met: bool | None
    """Every cell meets the target; ``None``: no cell to judge."""
    misses: int
    """Cells that miss it."""
    missed_columns: tuple[str, ...] = ()
    """The columns of those cells, each once, in the matrix's order."""


# (target, rows, firmware columns only, CellResult field, bound field of TransferTargets, sense, unit)
_TARGETS = (
    ("success, static rows", STATIC_ROWS, False, "success_rate", "static_success", "min", "%"),
    ("Wilson lower bound, static rows", STATIC_ROWS, False, "wilson_low", "static_wilson_low", "min", "%"),
    ("landing error, static rows", STATIC_ROWS, False, "landing_error_cm", "static_error_cm", "max", "cm"),
    ("success, moving rows", MOVING_ROWS, False, "success_rate", "moving_success", "min", "%"),
    ("landing error, moving rows", MOVING_ROWS, False, "landing_error_cm", "moving_error_cm", "max", "cm"),
    ("touchdown speed, firmware columns", None, True, "touchdown_speed", "touchdown_speed", "max", "m/s"),
    ("command p95 near pad, firmware columns", None, True, "command_near_pad_p95", "command_near_pad", "max", "m/s"),
    ("time at the tilt clamp, firmware columns", None, True, "tilt_limit_fraction", "tilt_limit_fraction", "max", "%"),
    ("height 0.5 m from the pad, firmware columns", None, True, "approach_height", "approach_height", "min", "m"),
)


def _text(value: float, unit: str) -> str:
    if unit == "%":
        return f"{100 * value:.1f} %"
    return f"{value:.2f} {unit}"


def check_targets(
    cells: Sequence[CellResult], targets: TransferTargets, columns: Sequence[str] | None = None
) -> list[TargetCheck]:
    """Every target of ``targets`` on ``cells`` (only those of ``columns`` if given), in a fixed order.

    A flight target (touchdown, commands, tilt, height) is judged on the firmware columns among them; success and
    landing error on every column. A cell whose value is NaN (e.g. no landing, so no landing error) misses its target.

    Raises:
        ValueError: ``columns`` names a column none of ``cells`` has (the message lists those it has).
    """
    if columns is not None:
        flown = list(dict.fromkeys(c.column for c in cells))
        unknown = [name for name in columns if name not in flown]
        if unknown:
            raise ValueError(f"No cells for column(s) {unknown}; the matrix has: {', '.join(flown)}.")
        cells = [c for c in cells if c.column in columns]
    checks = []
    for target, rows, firmware_only, field_name, bound_name, sense, unit in _TARGETS:
        bound = getattr(targets, bound_name)
        if bound is None:
            continue
        judged = [
            c for c in cells if (rows is None or c.row in rows) and (not firmware_only or c.column in FIRMWARE_COLUMNS)
        ]
        required = f"{'>=' if sense == 'min' else '<='} {_text(bound, unit)}"
        if not judged:
            checks.append(TargetCheck(target, required, 0, math.nan, "not flown", None, 0))
            continue
        values = [float(getattr(c, field_name)) for c in judged]

        def misses(value: float, sense: str = sense, bound: float = bound) -> bool:
            return math.isnan(value) or (value < bound if sense == "min" else value > bound)

        # The worst cell: a NaN first (it cannot be judged), then the farthest from the bound.
        worst = min(
            range(len(judged)), key=lambda i: (not math.isnan(values[i]), values[i] if sense == "min" else -values[i])
        )
        missed = [c for c, v in zip(judged, values, strict=True) if misses(v)]
        checks.append(
            TargetCheck(
                target=target,
                required=required,
                cells=len(judged),
                worst=values[worst],
                where=f"{judged[worst].row}, {judged[worst].column}",
                met=not missed,
                misses=len(missed),
                missed_columns=tuple(dict.fromkeys(c.column for c in missed)),
            )
        )
    return checks


def _unit(target: str) -> str:
    return next(unit for name, *_, unit in _TARGETS if name == target)


def _cell_text(check: TargetCheck) -> str:
    if check.met is None:
        return "not flown"
    verdict = "met"
    if not check.met:
        verdict = f"**missed** in {check.misses} of {check.cells} ({', '.join(check.missed_columns)})"
    return f"{verdict}: worst {_text(check.worst, _unit(check.target))} ({check.where})"


def format_targets(cells: Sequence[CellResult], targets: TransferTargets) -> str:
    """A markdown table: each target, its bound, and the check over the issue's columns and over every column flown."""
    flown = list(dict.fromkeys(c.column for c in cells))
    issue = [name for name in ISSUE_COLUMNS if name in flown]
    in_issue = {c.target: c for c in check_targets(cells, targets, issue)} if issue else {}
    everywhere = check_targets(cells, targets)
    lines = [
        f"| target ({targets.name}) | required | the issue's columns ({len(issue)}) | "
        f"every column flown ({len(flown)}) |",
        "|---|---|---|---|",
    ]
    for check in everywhere:
        first = _cell_text(in_issue[check.target]) if check.target in in_issue else "not flown"
        lines.append(f"| {check.target} | {check.required} | {first} | {_cell_text(check)} |")
    return "\n".join(lines)
