"""Result files: per-trial CSV, summary CSVs and Markdown tables laid out like the paper's Tables I and II.

Everything here is generated from :class:`~marlander_lite.experiments.protocol.TrialRecord`\\ s,
and the Markdown files are pulled into ``docs/reproduction.md`` by
:func:`~marlander_lite.experiments.includes.update_includes`, so no
measured number is ever typed by hand. The paper's own numbers (:data:`PAPER`) sit next to ours.
"""

from __future__ import annotations

import ast
import csv
import inspect
import itertools
import math
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Literal

from marlander_lite.experiments import apf
from marlander_lite.experiments.apf import APFConfig
from marlander_lite.experiments.controllers import CONTROLLER_LABELS, CONTROLLERS
from marlander_lite.experiments.metrics import CellSummary, TrialMetrics, summarise, wilson_interval
from marlander_lite.experiments.protocol import CONDITION_NAMES, GROUPS, TrialRecord, condition


@dataclass(frozen=True)
class PaperRow:
    """One row of the paper's Table I or II (``None`` where the paper gives no number)."""

    success_pct: float | None
    precision_cm: float | None
    time_s: float | None
    trials: int | None
    per_drone_cm: tuple[float, ...] | None = None


PAPER: dict[str, dict[str, PaperRow]] = {
    "static": {
        "baseline": PaperRow(80.0, 4.8, 24.0, 10),
        "single-agent-apf": PaperRow(None, 2.35, None, None),
        "marlander": PaperRow(91.67, 2.26, 12.0, 12, (2.67, 3.26)),
        "marlander-plus": PaperRow(None, None, None, None),
        "baseline-tuned": PaperRow(None, None, None, None),
    },
    "moving": {
        "baseline": PaperRow(60.0, 7.4, 28.0, 10),
        "single-agent-apf": PaperRow(None, 3.5, None, None),
        "marlander": PaperRow(75.0, 3.93, 17.0, 8, (4.38, 3.47)),
        "marlander-plus": PaperRow(None, None, None, None),
        "baseline-tuned": PaperRow(None, None, None, None),
    },
}
"""The paper's Tables I (static) and II (moving), and the per-drone deviations of Sec. IV-B/C.
Note: Table I's 2.26 cm disagrees with the text's per-drone 2.67 and 3.26 cm (mean 2.965 cm).
Source: Aschu et al., MARLander, Tables I and II (docs/references.md)."""
TABLE_TITLES = {
    "static": "Table I: static platform (floor + UR10)",
    "moving": "Table II: moving platform (UR10, 0.2-0.5 m/s, linear + arc)",
}

# ----------------------------------------------------------------------------- per-trial CSV


def trial_columns(num_drones: int) -> list[str]:
    """Header of ``trials.csv`` for ``num_drones`` drones."""
    per_drone = [f"landed_{i}" for i in range(num_drones)] + [f"landing_error_cm_{i}" for i in range(num_drones)]
    return [
        "simulator",
        "controller",
        "condition",
        "group",
        "platform",
        "speed_m_s",
        "trial",
        "seed",
        "outcome",
        "success",
        *per_drone,
        "landing_time_s",
        "min_separation_m",
        "duration_s",
    ]


def _fmt(x: float, digits: int = 4) -> str:
    return "nan" if math.isnan(x) else ("inf" if math.isinf(x) else f"{x:.{digits}f}")


def write_trials_csv(records: Sequence[TrialRecord], path: Path) -> Path:
    """One row per trial (columns :func:`trial_columns`): SI units except landing errors in cm."""
    if not records:
        raise ValueError("No trial records to write.")
    n = len(records[0].metrics.landed)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(trial_columns(n))
        for r in records:
            m, c = r.metrics, condition(r.condition)
            writer.writerow(
                [
                    r.simulator,
                    r.controller,
                    r.condition,
                    c.group,
                    c.kind,
                    _fmt(c.speed, 1),
                    r.trial,
                    r.seed,
                    m.outcome,
                    int(m.success),
                    *(int(x) for x in m.landed),
                    *(_fmt(x) for x in m.landing_error_cm),
                    _fmt(m.landing_time_s, 3),
                    _fmt(m.min_separation_m),
                    _fmt(m.duration_s, 3),
                ]
            )
    return path


def read_trials_csv(path: Path) -> list[TrialRecord]:
    """The records of a ``trials.csv`` written by :func:`write_trials_csv`."""
    if not path.is_file():
        raise FileNotFoundError(f"No trial results at {path}; run `marlander reproduce` first.")
    records = []
    with path.open(newline="") as handle:
        for row in csv.DictReader(handle):
            n = sum(1 for key in row if key.startswith("landed_"))
            metrics = TrialMetrics(
                outcome=row["outcome"],  # type: ignore[arg-type]
                landed=tuple(row[f"landed_{i}"] == "1" for i in range(n)),
                landing_error_cm=tuple(float(row[f"landing_error_cm_{i}"]) for i in range(n)),
                landing_time_s=float(row["landing_time_s"]),
                min_separation_m=float(row["min_separation_m"]),
                duration_s=float(row["duration_s"]),
            )
            records.append(
                TrialRecord(
                    row["simulator"], row["controller"], row["condition"], int(row["trial"]), int(row["seed"]), metrics
                )
            )
    return records


# ----------------------------------------------------------------------------- summaries

Cell = Literal["condition", "group"]


@dataclass(frozen=True)
class SummaryRow:
    """Statistics of one controller on one condition or group."""

    controller: str
    cell: str
    """Condition name, or ``static`` / ``moving``."""
    summary: CellSummary


def summarise_records(records: Iterable[TrialRecord], by: Cell, n_resamples: int = 4000) -> list[SummaryRow]:
    """One :class:`SummaryRow` per (controller, condition) or (controller, group), in table order.

    Each cell's bootstrap is seeded from its controller and cell names, so the intervals are
    reproducible and do not depend on which other cells the run contains.
    """
    cells: dict[tuple[str, str], list[TrialMetrics]] = {}
    for r in records:
        cells.setdefault((r.controller, r.condition if by == "condition" else r.group), []).append(r.metrics)
    order = {name: i for i, name in enumerate((*CONDITION_NAMES, *GROUPS))}
    keys = sorted(cells, key=lambda k: (CONTROLLERS.index(k[0]), order[k[1]]))
    return [
        SummaryRow(
            c, cell, summarise(cells[(c, cell)], seed=zlib.crc32(f"{c}/{cell}".encode()), n_resamples=n_resamples)
        )
        for c, cell in keys
    ]


def write_summary_csv(rows: Sequence[SummaryRow], path: Path) -> Path:
    """One row per cell: every :class:`CellSummary` field (percentages as fractions, errors in cm)."""
    names = [f.name for f in fields(CellSummary) if f.name not in ("error_per_drone_cm", "outcome_counts")]
    n = max(len(r.summary.error_per_drone_cm) for r in rows)
    header = [
        "controller",
        "cell",
        *names,
        *(f"error_drone_{i}_cm" for i in range(n)),
        *(f"n_{o}" for o in rows[0].summary.outcome_counts),
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        for r in rows:
            s = asdict(r.summary)
            values = [s[k] if isinstance(s[k], int) else _fmt(s[k]) for k in names]
            writer.writerow(
                [
                    r.controller,
                    r.cell,
                    *values,
                    *(_fmt(x) for x in s["error_per_drone_cm"]),
                    *s["outcome_counts"].values(),
                ]
            )
    return path


# ----------------------------------------------------------------------------- Markdown


def _pct(x: float) -> str:
    return "n/a" if math.isnan(x) else f"{100 * x:.1f}"


def _num(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else ("n/a" if math.isnan(x) else f"{x:.{digits}f}")


def _paper(x: float | None) -> str:
    """A number of the paper as printed there (no padding zeros); ``-`` where it gives none."""
    return "-" if x is None else f"{x:g}"


def paper_table(rows: Sequence[SummaryRow], group: str, simulator: str) -> str:
    """Markdown like the paper's Table I (``group="static"``) or II (``"moving"``), ours next to the paper's.

    Success: rate with its Wilson 95 % interval. Precision: mean landing error of every landed
    drone with its bootstrap 95 % interval, then the median. Time: mean landing time of the
    successful trials. Controllers not run show ``not run``.
    """
    by_controller = {r.controller: r.summary for r in rows if r.cell == group}
    lines = [
        f"**{TABLE_TITLES[group]}, {simulator}.** Ours: success rate [Wilson 95 % CI]; precision = mean "
        "landing error of the landed drones [bootstrap 95 % CI] and median; time = mean landing time of the "
        "successful trials.",
        "",
        "| controller | trials (ours / paper) | success % (ours) | success % (paper) | precision cm (ours) "
        "| median cm (ours) | precision cm (paper) | time s (ours) | time s (paper) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    extras = [name for name in ("baseline-tuned", "marlander-plus") if name in by_controller]
    names = ["baseline", "single-agent-apf", "marlander", *extras]
    for name in names:
        paper = PAPER[group][name]
        paper_cells = [_paper(paper.success_pct), _paper(paper.precision_cm), _paper(paper.time_s)]
        s = by_controller.get(name)
        trials = f"{s.trials if s else 0} / {paper.trials if paper.trials else '-'}"
        if s is None:
            ours = ["not run", "not run", "not run", "not run"]
        else:
            ours = [
                f"{_pct(s.success_rate)} [{_pct(s.success_low)}, {_pct(s.success_high)}]",
                f"{_num(s.error_mean_cm)} [{_num(s.error_mean_low)}, {_num(s.error_mean_high)}]",
                _num(s.error_median_cm),
                _num(s.time_mean_s, 1),
            ]
        cells = [
            CONTROLLER_LABELS[name],
            trials,
            ours[0],
            paper_cells[0],
            ours[1],
            ours[2],
            paper_cells[1],
            ours[3],
            paper_cells[2],
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def conditions_table(rows: Sequence[SummaryRow], simulator: str) -> str:
    """Markdown: every (controller, condition) cell with success, errors, time, separation and failure counts."""
    lines = [
        f"**Per condition, {simulator}.** Failures: collision / crash / out of arena / timeout.",
        "",
        "| controller | condition | trials | success % [95 % CI] | mean error cm [95 % CI] | median cm "
        "| time s | min separation m | failures |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s, o = r.summary, r.summary.outcome_counts
        failures = f"{o['collision']} / {o['crash']} / {o['out-of-arena']} / {o['timeout']}"
        lines.append(
            f"| {r.controller} | {r.cell} | {s.trials} | {_pct(s.success_rate)} [{_pct(s.success_low)}, "
            f"{_pct(s.success_high)}] | {_num(s.error_mean_cm)} [{_num(s.error_mean_low)}, {_num(s.error_mean_high)}] "
            f"| {_num(s.error_median_cm)} | {_num(s.time_mean_s, 1)} | {_num(s.min_separation_m, 3)} | {failures} |"
        )
    return "\n".join(lines) + "\n"


def per_drone_table(rows: Sequence[SummaryRow], simulator: str) -> str:
    """Markdown: mean landing error per drone index, next to the paper's per-drone figures (Sec. IV-B/C)."""
    lines = [
        f"**Per-drone mean landing error, {simulator}** (the paper's text: 2.67 / 3.26 cm static, "
        "whose mean 2.965 cm disagrees with Table I's 2.26 cm; 4.38 / 3.47 cm moving).",
        "",
        "| controller | group | drone 1 cm (ours) | drone 2 cm (ours) | mean of drones (ours) | paper drone 1 / 2 "
        "| paper mean of drones | paper table |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.cell not in GROUPS:
            continue
        per = r.summary.error_per_drone_cm
        paper = PAPER[r.cell][r.controller]
        paper_per = " / ".join(f"{x:.2f}" for x in paper.per_drone_cm) if paper.per_drone_cm else "-"
        paper_mean = f"{sum(paper.per_drone_cm) / len(paper.per_drone_cm):.3f}" if paper.per_drone_cm else "-"
        with_nan = [x for x in per if not math.isnan(x)]
        mean = sum(with_nan) / len(with_nan) if with_nan else math.nan
        cells = [_num(per[0]), _num(per[1]) if len(per) > 1 else "-", _num(mean), paper_per, paper_mean]
        lines.append(f"| {r.controller} | {r.cell} | " + " | ".join(cells) + f" | {_num(paper.precision_cm)} |")
    return "\n".join(lines) + "\n"


def paper_intervals_table() -> str:
    """Markdown: the paper's success rates with the Wilson 95 % intervals their trial counts allow."""
    lines = [
        "**How much the paper's trial counts can tell:** its success rates with Wilson 95 % intervals.",
        "",
        "| group | controller | paper success | trials | successes | Wilson 95 % CI (%) |",
        "|---|---|---|---|---|---|",
    ]
    for group in GROUPS:
        for name, row in PAPER[group].items():
            if row.success_pct is None or row.trials is None:
                continue
            k = round(row.success_pct / 100 * row.trials)
            low, high = wilson_interval(k, row.trials)
            lines.append(
                f"| {group} | {CONTROLLER_LABELS[name]} | {_paper(row.success_pct)} % | {row.trials} | {k} "
                f"| {_pct(low)} - {_pct(high)} |"
            )
    return "\n".join(lines) + "\n"


def run_table(record: dict[str, Any]) -> str:
    """Markdown: what a run flew and how long it took (from its ``run.json`` record)."""
    c = record["config"]
    policies = record.get("policies", {})  # records written before policies were recorded have none
    return (
        f"**Run:** {record['trials']} trials on the {c['simulator']} simulator ({', '.join(c['controllers'])}; "
        f"{len(c['conditions'])} conditions; trials per cell: {c['trials']}; sensing {c['sensing']}; time limit "
        f"{c['time_limit_s']:g} s; seed {c['seed']}), flown in {record['flight_seconds']:.0f} s by {c['workers']} "
        f"worker process(es); {record['total_seconds']:.0f} s with tables and figures. Command: "
        f"`{record['command']}`."
        + "".join(f" `{name}` flew `{p['file']}` (sha256 {p['sha256'][:12]}...)." for name, p in policies.items())
        + "\n"
    )


def _field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings of a dataclass (the string literal under each field), read from its source."""
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for node, after in itertools.pairwise(body):
        if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
            docs[node.target.id] = " ".join(str(after.value.value).split())  # type: ignore[attr-defined]
    return docs


def gains_table(config: APFConfig | None = None) -> str:
    """Markdown: every gain of the PID + APF baseline with its value and meaning (from :mod:`apf`)."""
    config = config or APFConfig()
    docs = _field_docs(APFConfig)
    lines = [
        f"**Gains of the PID + APF baseline** (`{apf.__name__}.APFConfig`).",
        "",
        "| gain | value | meaning |",
        "|---|---|---|",
    ]
    lines += [f"| `{k}` | {v:g} | {docs.get(k, '').replace('|', chr(92) + '|')} |" for k, v in config.as_dict().items()]
    return "\n".join(lines) + "\n"


def write_markdown(text: str, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def record_json(config: Any) -> dict[str, Any]:
    """A JSON-able record of a :class:`~marlander_lite.experiments.protocol.ProtocolConfig`."""
    out = asdict(config)
    out["policy_paths"] = {k: str(v) for k, v in config.policy_paths.items()}
    return out
