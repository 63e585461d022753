"""Random Crazyflies: a policy flown on velocity trackers drawn at random, not picked.

The transfer matrix (:mod:`~marlander_lite.experiments.transfer`) flies a policy on a dozen simulators and trackers
that someone chose: the firmware tracker with 15 % more mass, 60 ms of latency, gains x0.7 and x1.3, and so on. A
policy can be tuned, on purpose or not, to those picks. A lab's drone, or a simulator this project does not contain,
will be none of them. This module draws ``count`` Crazyflies at random instead, each its own combination of

* the tracker: the Crazyflie firmware's PID or our cascaded PID (``controller``);
* the physics: with ground effect, drag and downwash (``"aero"``) or the rigid body alone (``"bare"``);
* a mass the tracker does not know about, a command latency, the outer (velocity / position) loop's gains and the
  inner (attitude and rate) loops' gains scaled, and the tilt clamp,

from :class:`VariantRanges`, wider than the matrix's fixed columns, and flies the policy on each (``marlander transfer
POLICY --variants 40``). The same draw can be flown in PyFlyt, a simulator this project did not write
(``--variant-simulator pyflyt``): PyFlyt's own cascaded PID with the same mass, latency, gains and tilt clamp drawn
(:class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning`), its controllers reading the state on time (as PyFlyt 0.22)
or one physics step late (as 0.21.0), with or without its body drag; or in RotorPy, a third
(``--variant-simulator rotorpy``): RotorPy's own velocity controller with the same mass (unknown to it), latency and
gains (:class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`), with or without its rotor drag and induced inflow.
RotorPy's controller has no tilt clamp, so the drawn clamp is not flown there.

What it reports is a distribution: in how many of the drawn Crazyflies the policy lands 90 % of episodes or more, the
median, and the worst variant with the parameters that broke it (docs/transfer.md, "Random Crazyflies"). Every
variant flies the same episodes (the matrix's seeds), so two policies meet the same drones.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.crazyflie.control import PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains
from marlander_lite.experiments.cell_journal import CellJournal
from marlander_lite.experiments.metrics import wilson_interval
from marlander_lite.experiments.transfer import (
    CSV_FIELDS,
    CellResult,
    Column,
    TransferConfig,
    _csv_value,
    _filter_words,
    transfer_matrix,
)
from marlander_lite.pad_frame_lead import describe_lead, describe_policy_lead
from marlander_lite.pointmass.family import checked_range
from marlander_lite.policy_file import read_contract

Range = tuple[float, float]

SUCCESS_THRESHOLD = 0.9
"""A variant counts as landed when the policy lands at least this share of its episodes (the issue's 90 %)."""

MAX_VARIANTS = 1000
"""The most variants one run draws (named ``variant 000`` to ``variant 999``)."""

VARIANT_SIMULATORS = ("crazyflie", "pyflyt", "rotorpy")
"""Where random Crazyflies are flown: our PyBullet swarm (its two trackers), PyFlyt (the optional extra ``pyflyt``) or
RotorPy (the optional extra ``rotorpy``), each under its own controller."""

PYFLYT_ORDERS = {"pyflyt 0.22": "after_physics", "pyflyt 0.21.0": "before_physics"}
"""A PyFlyt variant's ``controller``: when PyFlyt's controllers read the state (``PyFlytOptions.read_state``)."""


@dataclass(frozen=True)
class VariantRanges:
    """Where each random Crazyflie's properties are drawn from: uniform in every ``(low, high)``, a coin for the rest.

    The defaults reach beyond every fixed column of the transfer matrix (mass +15 %, 60 ms, gains x0.7 / x1.3) while
    staying a Crazyflie a lab could fly: a guard or a heavier battery, a slower radio, re-tuned loops, another tilt
    clamp. ``low == high`` fixes a property; ``firmware_share`` 1 flies only the firmware tracker.
    """

    firmware_share: float = 0.5
    """Probability that a variant flies the Crazyflie firmware's tracker; otherwise our cascaded PID (PyBullet)."""
    aero_share: float = 0.5
    """Probability that a variant's physics has ground effect, drag and downwash (``"aero"``; in PyFlyt, its body
    drag; in RotorPy, its rotor drag and induced inflow); otherwise ``"bare"``, the rigid body alone."""
    late_read_share: float = 0.5
    """PyFlyt only: probability that PyFlyt's controllers read each state one physics step late, as its pinned 0.21.0
    does (``"pyflyt 0.21.0"``); otherwise on time, as PyFlyt since 0.22 (``"pyflyt 0.22"``)."""
    mass_scale: Range = (0.85, 1.2)
    """True mass over the mass the tracker assumes (:attr:`Perturbation.mass_scale`)."""
    latency_s: Range = (0.0, 0.08)
    """Delay of every velocity command (s) (:attr:`Perturbation.latency_s`)."""
    outer_gain_scale: Range = (0.6, 1.5)
    """Factor on the velocity loop's kp and ki (firmware) or the position / velocity gains (our PID)
    (:attr:`Perturbation.gain_scale`)."""
    inner_gain_scale: Range = (0.7, 1.4)
    """Factor on the roll and pitch gains of the inner loops: the firmware's attitude kp and rate kp and ki, our PID's
    attitude kp and kd. The attitude loops answer faster or slower, as another tuning or motor set would."""
    tilt_limit_deg: Range = (15.0, 40.0)
    """The tracker's tilt clamp (deg): the firmware's roll and pitch setpoints (20 by default), our PID's thrust
    vector (30 by default); drawn but not flown in RotorPy, whose controller has none."""

    def __post_init__(self) -> None:
        for name in ("firmware_share", "aero_share", "late_read_share"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                raise ValueError(f"VariantRanges.{name} must be a probability from 0 to 1, got {value!r}.")
        for name, (lowest, highest) in RANGE_BOUNDS.items():
            object.__setattr__(self, name, checked_range("VariantRanges", name, getattr(self, name), lowest, highest))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> VariantRanges:
        """Ranges from a mapping (JSON gives lists); missing fields keep their defaults, unknown ones are refused."""
        known = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ValueError(f"Unknown VariantRanges field(s) {unknown}; allowed: {', '.join(known)}.")
        return cls(**{k: v if k.endswith("_share") else tuple(v) for k, v in values.items()})


RANGE_BOUNDS: dict[str, Range] = {
    "mass_scale": (0.5, 2.0),
    "latency_s": (0.0, 0.5),
    "outer_gain_scale": (0.1, 5.0),
    "inner_gain_scale": (0.3, 3.0),
    "tilt_limit_deg": (5.0, 80.0),
}
"""Allowed values of each range of :class:`VariantRanges` (those the simulator's options accept, or a margin)."""


@dataclass(frozen=True)
class Variant:
    """One drawn Crazyflie: its tracker, physics and the values drawn for it, and the simulator it flies in."""

    name: str
    controller: str
    physics: str
    mass_scale: float
    latency_s: float
    outer_gain_scale: float
    inner_gain_scale: float
    tilt_limit_deg: float
    simulator: str = "crazyflie"
    """One of :data:`VARIANT_SIMULATORS`."""

    def column(self) -> Column:
        """The simulator's options for this variant, as a transfer-matrix column."""
        # The hosted simulators' tunings (RotorPy's, PyFlyt's) share these four; PyFlyt's adds its clamp and drag.
        tuning: dict[str, Any] = {
            "mass_scale": self.mass_scale,
            "latency_s": self.latency_s,
            "outer_gain_scale": self.outer_gain_scale,
            "inner_gain_scale": self.inner_gain_scale,
        }
        if self.simulator == "rotorpy":
            return Column(self.name, "rotorpy", {"aero": self.physics == "aero", "tuning": tuning})
        if self.simulator == "pyflyt":
            tuning |= {"tilt_limit_deg": self.tilt_limit_deg, "body_drag": self.physics == "aero"}
            return Column(self.name, "pyflyt", {"read_state": PYFLYT_ORDERS[self.controller], "tuning": tuning})
        options: dict[str, Any] = {
            "controller": self.controller,
            "physics": self.physics,
            "perturbation": {
                "mass_scale": self.mass_scale,
                "latency_s": self.latency_s,
                "gain_scale": self.outer_gain_scale,
            },
        }
        k = self.inner_gain_scale
        if self.controller == "firmware":
            g = FirmwareGains()
            options["firmware_gains"] = dataclasses.replace(
                g,
                tilt_limit_deg=self.tilt_limit_deg,
                attitude_p=_roll_pitch(g.attitude_p, k),
                rate_p=_roll_pitch(g.rate_p, k),
                rate_i=_roll_pitch(g.rate_i, k),
            )
        else:
            g = PIDGains()
            options["gains"] = dataclasses.replace(
                g, max_tilt_deg=self.tilt_limit_deg, att_p=_roll_pitch(g.att_p, k), att_d=_roll_pitch(g.att_d, k)
            )
        return Column(self.name, "crazyflie", options)

    def describe(self) -> str:
        """One line: ``firmware, aero, mass x1.07, 43 ms, outer x0.81, inner x1.22, tilt 27 deg``."""
        tilt = "no tilt clamp" if self.simulator == "rotorpy" else f"tilt {self.tilt_limit_deg:.0f} deg"
        return (
            f"{self.controller}, {self.physics}, mass x{self.mass_scale:.2f}, {1000 * self.latency_s:.0f} ms, "
            f"outer x{self.outer_gain_scale:.2f}, inner x{self.inner_gain_scale:.2f}, {tilt}"
        )


def _roll_pitch(triple: tuple[float, float, float], factor: float) -> tuple[float, float, float]:
    return (triple[0] * factor, triple[1] * factor, triple[2])


VARIANT_FIELDS = tuple(f.name for f in dataclasses.fields(Variant))


def draw_variants(
    count: int, seed: int = 0, ranges: VariantRanges | None = None, simulator: str = "crazyflie"
) -> tuple[Variant, ...]:
    """``count`` Crazyflies drawn from ``ranges`` (the defaults if None), to fly in ``simulator``.

    Variant ``k`` draws from its own generator, ``numpy.random.SeedSequence(seed, spawn_key=(k,))``: the tracker's
    coin, the physics' coin, then each range in the order of :data:`RANGE_BOUNDS`. So a seed gives the same variants
    on every machine, and the first ten of a draw of 40 are the draw of 10. In PyFlyt the tracker's coin is the read
    order's (``late_read_share``); in RotorPy, with one controller, it is drawn and unused. The other values are those
    the same seed draws for PyBullet.
    """
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_VARIANTS:
        raise ValueError(f"--variants must be an integer from 1 to {MAX_VARIANTS}, got {count!r}.")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"--variant-seed must be an integer >= 0, got {seed!r}.")
    if simulator not in VARIANT_SIMULATORS:
        raise ValueError(f"--variant-simulator must be one of {', '.join(VARIANT_SIMULATORS)}, got {simulator!r}.")
    ranges = ranges or VariantRanges()
    tracker_share = ranges.late_read_share if simulator == "pyflyt" else ranges.firmware_share
    variants = []
    for k in range(count):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))
        first, aero = rng.random(2) < (tracker_share, ranges.aero_share)
        drawn = {name: round(float(rng.uniform(*getattr(ranges, name))), 4) for name in RANGE_BOUNDS}
        variants.append(
            Variant(
                name=f"variant {k:03d}",
                controller=_tracker(simulator, bool(first)),
                physics="aero" if aero else "bare",
                **drawn,
                simulator=simulator,
            )
        )
    return tuple(variants)


def _tracker(simulator: str, coin: bool) -> str:
    if simulator == "rotorpy":
        return "rotorpy"
    if simulator == "pyflyt":
        return "pyflyt 0.21.0" if coin else "pyflyt 0.22"
    return "firmware" if coin else "pid"


def fly_variants(
    config: TransferConfig, variants: Sequence[Variant], journal: CellJournal | None = None
) -> list[CellResult]:
    """Fly ``config``'s policy, rows and episodes on every variant (its columns are not flown): rows outer.
    ``journal``: resume from and record into it (:func:`~marlander_lite.experiments.transfer.transfer_matrix`)."""
    return transfer_matrix(config, [v.column() for v in variants], journal)


@dataclass(frozen=True)
class RowSummary:
    """How a policy did over the drawn variants on one row."""

    row: str
    variants: int
    landed_variants: int
    """Variants in which the policy landed at least :data:`SUCCESS_THRESHOLD` of the episodes."""
    median_success: float
    worst_success: float
    worst_variant: str
    pooled_success: float
    pooled_low: float
    pooled_high: float
    """All the row's episodes together, with their 95 % Wilson interval."""
    landing_error_cm: float
    """Median over the variants of the mean landing error (cm)."""


def summarize(results: Sequence[CellResult], threshold: float = SUCCESS_THRESHOLD) -> list[RowSummary]:
    """One :class:`RowSummary` per row of ``results``, in their order."""
    summaries = []
    for row in dict.fromkeys(r.row for r in results):
        cells = [r for r in results if r.row == row]
        rates = np.array([r.success_rate for r in cells])
        worst = cells[int(np.argmin(rates))]
        successes, episodes = sum(r.successes for r in cells), sum(r.episodes for r in cells)
        low, high = wilson_interval(successes, episodes)
        errors = [r.landing_error_cm for r in cells if np.isfinite(r.landing_error_cm)]
        summaries.append(
            RowSummary(
                row=row,
                variants=len(cells),
                landed_variants=int((rates >= threshold - 1e-12).sum()),
                median_success=float(np.median(rates)),
                worst_success=float(rates.min()),
                worst_variant=worst.column,
                pooled_success=successes / episodes,
                pooled_low=low,
                pooled_high=high,
                landing_error_cm=float(np.median(errors)) if errors else float("nan"),
            )
        )
    return summaries


def format_summary(results: Sequence[CellResult], variants: Sequence[Variant]) -> str:
    """A markdown table, one line per row: variants landed at 90 % or more, median, worst (named), pooled."""
    described = {v.name: v.describe() for v in variants}
    lines = [
        "| row | variants at 90 % or more | median success % | worst variant | all episodes % [95 % Wilson] | "
        "median landing error cm |",
        "|---|---|---|---|---|---|",
    ]
    for s in summarize(results):
        lines.append(
            f"| {s.row} | {s.landed_variants} of {s.variants} | {100 * s.median_success:.1f} | "
            f"{100 * s.worst_success:.1f} ({s.worst_variant}: {described.get(s.worst_variant, '?')}) | "
            f"{100 * s.pooled_success:.1f} [{100 * s.pooled_low:.1f}, {100 * s.pooled_high:.1f}] | "
            f"{s.landing_error_cm:.2f} |"
        )
    return "\n".join(lines)


def format_variant_table(results: Sequence[CellResult], variants: Sequence[Variant]) -> str:
    """A markdown table, one line per variant: its parameters and ``success % / error cm`` on each row."""
    rows = list(dict.fromkeys(r.row for r in results))
    by_cell = {(r.row, r.column): r for r in results}
    lines = ["| variant | drawn | " + " | ".join(rows) + " |", "|---" * (len(rows) + 2) + "|"]
    for v in variants:
        cells = [by_cell[(row, v.name)] for row in rows]
        text = " | ".join(f"{100 * c.success_rate:.0f} / {c.landing_error_cm:.2f}" for c in cells)
        lines.append(f"| {v.name} | {v.describe()} | {text} |")
    return "\n".join(lines)


OUTPUT_NAMES = ("variants.csv", "variants.json", "variants.md")


def write_variants(
    config: TransferConfig,
    ranges: VariantRanges,
    variant_seed: int,
    variants: Sequence[Variant],
    results: Sequence[CellResult],
    out: Path,
    wall_s: float,
) -> list[Path]:
    """``variants.csv`` (one line per variant and row: the drawn values, then the cell's results), ``variants.json``
    (config, ranges, policy hash, variants, cells) and ``variants.md`` (the summary and the per-variant table)."""
    out.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, md_path = (out / name for name in OUTPUT_NAMES)
    by_name = {v.name: v for v in variants}
    with csv_path.open("w") as f:
        f.write(",".join(("variant", *VARIANT_FIELDS[1:], *CSV_FIELDS)) + "\n")
        for r in results:
            v = by_name[r.column]
            values = [getattr(v, name) for name in VARIANT_FIELDS] + [getattr(r, name) for name in CSV_FIELDS]
            f.write(",".join(_csv_value(value) for value in values) + "\n")
    meta = {
        "config": {k: val for k, val in asdict(config).items() if k != "columns"},
        "ranges": asdict(ranges),
        "variant_seed": variant_seed,
        "policy_sha256": hashlib.sha256(Path(config.policy).read_bytes()).hexdigest(),
        "wall_s": round(wall_s, 1),
        "variants": [asdict(v) for v in variants],
        "cells": [asdict(r) for r in results],
    }
    json_path.write_text(json.dumps(meta, indent=2) + "\n")
    where = {"pyflyt": " in PyFlyt", "rotorpy": " in RotorPy"}.get(variants[0].simulator, "") if variants else ""
    flown = f"seed {config.seed}, sensing {config.sensing}{_filter_words(config.safety_filter)}"
    own = read_contract(config.policy).interface_options()
    if config.pad_frame_lead is not None:
        flown += f", a pad lead of {describe_lead(config.pad_frame_lead)}"
    elif own["pad_frame_lead_share"] > 0:  # the file's own lead, set in flight: say so
        flown += f", its own pad lead, {describe_policy_lead(own)}"
    if config.episode_seconds is not None:
        flown += f", {config.episode_seconds:g} s episodes"
    if config.vertical_bias:
        flown += ", the vertical bias identified in flight and cancelled"
    md_path.write_text(
        f"`{config.policy}` on {len(variants)} random Crazyflies{where} (variant seed {variant_seed}; "
        f"{config.episodes} episodes a variant and row, {flown}).\n\n{format_summary(results, variants)}\n\n"
        "Each variant, success % / mean landing error cm:\n\n"
        f"{format_variant_table(results, variants)}\n"
    )
    return [csv_path, json_path, md_path]


def read_variants(path: str | Path) -> tuple[tuple[Variant, ...], list[CellResult]]:
    """The variants and cells of a ``variants.json`` written by :func:`write_variants`."""
    data = json.loads(Path(path).read_text())
    return tuple(Variant(**v) for v in data["variants"]), [CellResult(**cell) for cell in data["cells"]]


def plot_variants(variants: Sequence[Variant], results: Sequence[CellResult], row: str) -> Any:
    """Success on ``row`` against each drawn property, one panel each; one colour per tracker (the firmware's and our
    PID, or PyFlyt's two read orders), the 90 % line dashed. Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    success = {r.column: 100 * r.success_rate for r in results if r.row == row}
    if not success:
        raise ValueError(f"No results for row {row!r}; rows: {sorted({r.row for r in results})}.")
    names = list(RANGE_BOUNDS)
    fig, axes = plt.subplots(1, len(names), figsize=(3.0 * len(names), 2.8), sharey=True)
    trackers = sorted({v.controller for v in variants})
    for ax, name in zip(axes, names, strict=True):
        for controller, colour in zip(trackers, ("tab:blue", "tab:orange"), strict=False):
            chosen = [v for v in variants if v.controller == controller and v.name in success]
            scale = 1000.0 if name == "latency_s" else 1.0
            ax.scatter(
                [scale * getattr(v, name) for v in chosen],
                [success[v.name] for v in chosen],
                s=14,
                c=colour,
                label=f"{controller} tracker",
            )
        ax.axhline(100 * SUCCESS_THRESHOLD, color="grey", linestyle="--", linewidth=0.8)
        ax.set_xlabel(name.replace("_s", " (ms)") if name == "latency_s" else name)
    axes[0].set_ylabel(f"success % ({row})")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return fig
