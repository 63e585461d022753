"""Every notebook is committed without outputs and runs headless with the small CI budget (d2l style).

``MARLANDER_BUDGET=small`` makes each notebook take the same code path with fewer steps
(``marlander_lite.budget.scaled``). Each notebook must print what shows it worked (``EXPECTED_TEXT``), and
``VALUE_CHECKS`` compares what it shows with something it did not compute: the shipped results in
``data/results`` and ``data/runs`` (written by ``marlander reproduce``, ``evaluate`` and ``transfer``), the
paper's numbers (docs/reproduction.md), or hand-derived values. The live samples of notebooks 04-06 fly the
shipped tables' first seeds, so their rows must repeat the shipped ``trials.csv`` rows.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import nbformat
import pytest

from marlander_lite.experiments.controllers import CONTROLLER_LABELS
from marlander_lite.pointmass.family import DynamicsFamily

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
RESULTS = ROOT / "data" / "results"
MOVING_ROWS = ("arc 0.2-0.5 m/s", "line 0.2-0.5 m/s")
PAD_RADIUS_CM = 10.0  # PlateGeometry.pad_radius: a landing farther from the pad centre is a crash
TOUCHDOWN_SPEED_MAX = 0.5  # m/s relative to the pad (TaskConfig.touchdown_speed_max)
EXPECTED_TEXT = {
    "00_overview.ipynb": ["PointMassVecEnv (4, 26)"],
    "01_mdp_and_pointmass.ipynb": ["r_t^i = [[4.98  0.992]]", "success True"],
    "02_crazyflie_pybullet.ipynb": ["hover speed  sqrt(m g / 4 k_f) =    14476 RPM", "episode 0: success True"],
    "03_training_ppo.ipynb": ["budget: small"],
    "04_static_platform.ipynb": ["budget: small"],
    "05_moving_platform.ipynb": ["budget: small"],
    "06_baselines.ipynb": ["budget: small"],
    "07_deployment_rehearsal.ipynb": [
        "budget: small",
        "fault none: armed=True, on pad=[True, True]",
        "Pads paired with the drones by the shortest paths: cf1 -> ",
        "on their pads: 8 of 8; safe: True",
        "tilted 15 degrees: on their pads: 8 of 8; safe: True",
    ],
    "08_transfer.ipynb": ["budget: small", "### quick-cpu", "| floor | "],
    "09_scaling.ipynb": ["budget: small", "| shared | static-floor | 16 |", "| shared-filter | static-floor | 16 |"],
}


@dataclass
class Shown:
    """What an executed notebook showed."""

    text: str
    """Printed text and the plain-text values of cells."""
    markdown: list[str]
    """Every Markdown output (``display(Markdown(...))``)."""
    figures: int
    """Number of PNG images."""

    @classmethod
    def of(cls, nb: nbformat.NotebookNode) -> Shown:
        outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
        # Streams as printed; a cell's value on its own line (not the "<Figure ...>" text of displayed figures).
        text = "".join(
            o.get("text", "") + (o["data"].get("text/plain", "") + "\n" if o.output_type == "execute_result" else "")
            for o in outputs
        )
        markdown = [o["data"]["text/markdown"] for o in outputs if "text/markdown" in o.get("data", {})]
        return cls(text, markdown, sum("image/png" in o.get("data", {}) for o in outputs))

    def table(self, *title: str) -> list[dict[str, str]]:
        """Rows of the one Markdown table whose first line contains every part of ``title``, as header -> cell."""
        matches = [m for m in self.markdown if all(part in m.split("\n", 1)[0] for part in title)]
        assert len(matches) == 1, f"expected one table titled {title}, found {len(matches)}"
        return markdown_rows(matches[0])

    def numbers(self, pattern: str) -> list[tuple[float, ...]]:
        """Every match of ``pattern`` in the printed text, its groups as floats."""
        found = [tuple(float(g) for g in m.groups()) for m in re.finditer(pattern, self.text, re.MULTILINE)]
        assert found, f"nothing printed matches {pattern!r}"
        return found


def markdown_rows(text: str) -> list[dict[str, str]]:
    lines = [line for line in text.splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    return [dict(zip(header, (cell.strip() for cell in line.strip("|").split("|")), strict=True)) for line in lines[2:]]


def first_number(cell: str) -> float:
    """``"98.0 [95.0, 99.2]"`` -> 98.0; ``"n/a ..."`` -> nan."""
    match = re.match(r"-?\d+(\.\d+)?", cell)
    return float(match.group()) if match else float("nan")


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def controller_of(label: str) -> str:
    return next(name for name, text in CONTROLLER_LABELS.items() if text == label)


def close(shown: float, expected: float, tolerance: float) -> bool:
    """Equal to the shown digits; both NaN (``n/a``, nothing landed) counts as equal."""
    return (math.isnan(shown) and math.isnan(expected)) or abs(shown - expected) <= tolerance


# ----------------------------------------------------------------------------- shared checks


def assert_table_repeats_summary(rows: list[dict[str, str]], summary_csv: Path, group: str) -> None:
    """A paper table made from shipped trials shows the shipped summary (``summary_by_group.csv``) to its digits."""
    summary = {(r["controller"], r["cell"]): r for r in read_csv(summary_csv)}
    assert {controller_of(row["controller"]) for row in rows} >= {"marlander", "baseline", "single-agent-apf"}
    flown = [row for row in rows if row["success % (ours)"] != "not run"]
    assert flown and {(controller_of(row["controller"]), group) for row in flown} == {
        k for k in summary if k[1] == group
    }
    for row in flown:
        s = summary[(controller_of(row["controller"]), group)]
        assert first_number(row["trials (ours / paper)"]) == int(s["trials"])
        assert close(first_number(row["success % (ours)"]), 100 * float(s["success_rate"]), 0.051), row
        assert close(first_number(row["precision cm (ours)"]), float(s["error_mean_cm"]), 0.0051), row
        assert close(first_number(row["time s (ours)"]), float(s["time_mean_s"]), 0.051), row


def assert_paper_columns(rows: list[dict[str, str]], group: str) -> None:
    """The paper's Table I / II, typed here from the paper (docs/reproduction.md)."""
    paper = {
        "static": {"marlander": ("91.67", "2.26", "12"), "baseline": ("80", "4.8", "24")},
        "moving": {"marlander": ("75", "3.93", "17"), "baseline": ("60", "7.4", "28")},
    }[group]
    for row in rows:
        if (name := controller_of(row["controller"])) in paper:
            shown = (row["success % (paper)"], row["precision cm (paper)"], row["time s (paper)"])
            assert shown == paper[name], row


def assert_shipped_tables(shown: Shown, group: str) -> None:
    """Both simulators' shipped Table I or II, the PyBullet fine-tunes', the paper's network in the pad frame, the
    paper's network trained on the point mass only and on late commands (its moving fine-tune with its own lead, with
    0.3 s and with the lead set in flight): our columns from the shipped summary, the paper's from the paper."""
    shipped = (
        ("point-mass simulator, shipped", "pointmass"),
        ("PyBullet Crazyflie", "crazyflie"),
        ("PyBullet fine-tunes, the comparison rows", "crazyflie-finetunes"),
        ("PyBullet, the paper's network in the pad frame", "crazyflie-pad-frame"),
        ("PyBullet, the paper's network trained on the point mass only", "crazyflie-paper-slow-trackers"),
        ("PyBullet, late commands (the paper's network and its moving fine-tune)", "crazyflie-late-commands"),
        ("PyBullet, the moving fine-tune flown with a 0.3 s pad lead", "crazyflie-late-commands-lead-0.3"),
        ("PyBullet, the moving fine-tune with the lead set in flight", "crazyflie-late-commands-lead-auto"),
        ("PyBullet, its seed 1 with the lead set in flight", "crazyflie-late-commands-seed1-lead-auto"),
        ("PyBullet, the paper's network's seed 2 on late commands", "crazyflie-late-commands-seed2"),
        ("PyBullet, its moving recipe's seed 2 with the lead set in flight", "crazyflie-late-commands-seed2-lead-auto"),
    )
    for title, simulator in shipped:
        rows = shown.table(title)
        assert_table_repeats_summary(rows, RESULTS / simulator / "summary_by_group.csv", group)
        assert_paper_columns(rows, group)


@functools.cache
def shipped_trials(simulator: str = "pointmass") -> dict[tuple[str, str, int], dict[str, str]]:
    return {(r["controller"], r["condition"], int(r["trial"])): r for r in read_csv(RESULTS / simulator / "trials.csv")}


def shipped_cell(controller: str, conditions: tuple[str, ...], per_condition: int) -> tuple[float, float]:
    """Success % and mean landing error (cm, landed drones) of trials ``0..per_condition-1`` in the shipped CSV."""
    trials = shipped_trials()
    rows = [trials[(controller, c, k)] for c in conditions for k in range(per_condition)]
    errors = [float(r[f"landing_error_cm_{i}"]) for r in rows for i in (0, 1) if r[f"landed_{i}"] == "1"]
    success = 100 * sum(r["success"] == "1" for r in rows) / len(rows)
    return success, (sum(errors) / len(errors) if errors else float("nan"))


def assert_live_rows_repeat_shipped(rows: list[dict[str, str]], conditions: tuple[str, ...]) -> None:
    """Trial k flies the seed of the shipped trial k: a live paper-table row repeats those shipped trials."""
    assert rows
    for row in rows:
        if row["success % (ours)"] == "not run":
            continue
        trials = int(first_number(row["trials (ours / paper)"]))
        assert trials % len(conditions) == 0, row
        success, error = shipped_cell(controller_of(row["controller"]), conditions, trials // len(conditions))
        assert close(first_number(row["success % (ours)"]), success, 0.051), (row, success)
        assert close(first_number(row["precision cm (ours)"]), error, 0.0051), (row, error)


def assert_step_by_step_trial(shown: Shown, condition: str) -> None:
    """The trial flown step by step lands both drones on their pads and is the shipped trial 0."""
    match = re.search(
        rf"trial 0 of {re.escape(condition)} \(seed (\d+)\): (\S+); landing error (\S+) cm and (\S+) cm; "
        r"all landed after (\S+) s",
        shown.text,
    )
    assert match, "the step-by-step trial printed no result line"
    seed, outcome, *numbers = match.groups()
    errors, landing_time = [float(x) for x in numbers[:2]], float(numbers[2])
    assert outcome == "success" and all(e < PAD_RADIUS_CM for e in errors)
    row = shipped_trials()[("marlander", condition, 0)]
    assert int(seed) == int(row["seed"]) and outcome == row["outcome"]
    assert errors == pytest.approx([float(row["landing_error_cm_0"]), float(row["landing_error_cm_1"])], abs=5e-5)
    assert landing_time == pytest.approx(float(row["landing_time_s"]), abs=1e-3)
    speeds = [s for (s,) in shown.numbers(r"touched down at t = .*?, (\d+\.\d+) m/s relative to the pad")]
    assert len(speeds) == 2 and all(s < TOUCHDOWN_SPEED_MAX for s in speeds)


# ----------------------------------------------------------------------------- per notebook


def check_00(shown: Shown) -> None:
    printed = {
        (group, name): (success, precision, time)
        for group, name, success, precision, time in re.findall(
            r"^(static|moving)\s+(\S+)\s+success (\S+) %\s+precision (\S+) cm\s+time (\S+) s", shown.text, re.MULTILINE
        )
    }
    # Table I and II of the paper, and Sec. IV-E's 2.35 / 3.5 cm for MorphoLander.
    assert printed[("static", "marlander")] == ("91.67", "2.26", "12.0")
    assert printed[("moving", "marlander")] == ("75.0", "3.93", "17.0")
    assert printed[("static", "baseline")] == ("80.0", "4.8", "24.0")
    assert printed[("moving", "baseline")] == ("60.0", "7.4", "28.0")
    assert printed[("static", "single-agent-apf")][1] == "2.35" and printed[("moving", "single-agent-apf")][1] == "3.5"
    # Eq. 2: 13 numbers per drone, both drones in one input; eq. 3 and Fig. 3: six outputs in [-1, 1].
    assert "(26,), float32) Box(-1.0, 1.0, (6,), float32)" in shown.text
    assert "SwarmParallelEnv ['drone_0', 'drone_1']" in shown.text


def check_01(shown: Shown) -> None:
    assert "R_t with a collision: [-14.028]" in shown.text  # eqs. 4 and 6 by hand: 4.98 + 0.992 - alpha_c (20)
    assert "landed: [[ True False False]] crashed: [[False  True  True]]" in shown.text  # 0.9 m/s and another surface
    [(n, success, error)] = shown.numbers(r"^(\d+) episodes: success (\S+) %, landing error (\S+) cm")
    assert n == 64 and success >= 90.0 and error < PAD_RADIUS_CM
    assert shown.figures == 1


def check_02(shown: Shown) -> None:
    radii = shown.numbers(r"^\s+(\d+)\s+\[\s*(\S+)\s+(\S+)\s+(\S+)\s*\]\s+\[\s*(\S+)\s+(\S+)\s+(\S+)\s*\]$")
    assert [hz for hz, *_ in radii] == [30, 48, 60, 120, 240]
    assert all(max(r[1:4]) < 1.0 for r in radii)  # ours: stable at every rate
    assert max(radii[1][4:]) > 1.0  # the published damping: unstable at the 48 Hz the simulator runs
    episodes = re.findall(r"episode \d+: success (\w+), landing error \(cm\) \[([^\]]*)\]", shown.text)
    assert len(episodes) == 2
    assert all(s == "True" and max(map(float, errors.split())) < PAD_RADIUS_CM for s, errors in episodes)
    [(difference, command)] = shown.numbers(r"RMS velocity difference (\S+) m/s \(RMS command (\S+) m/s\)")
    assert difference < 0.2 * command  # the fitted point mass follows PyBullet on unseen commands
    fits = markdown_rows("\n".join(line for line in shown.text.splitlines() if line.startswith("|")))
    assert {f["tracker"] for f in fits} == {"pid", "firmware"} and all(float(f["RMS (m/s)"]) < 0.1 for f in fits)
    assert shown.figures == 6


def seed_stats_iqm(values: list[float]) -> float:
    """The interquartile mean by hand: sort, drop the lowest and highest int(n / 4) runs, average the rest."""
    cut = len(values) // 4
    middle = sorted(values)[cut : len(values) - cut]
    return sum(middle) / len(middle)


def check_03(shown: Shown) -> None:
    # Fig. 3 / Sec. III-D: both drones' 13 observations in, 512-512-256-128 ReLU layers.
    assert re.search(r"^paper\s+drones 2, inputs 26, layers \(512, 512, 256, 128\)", shown.text, re.MULTILINE)
    steps = re.search(r"^trained (\d[\d,]*) steps", shown.text, re.MULTILINE)
    assert steps and int(steps.group(1).replace(",", "")) >= 8192  # scaled(..., 8192) steps at least
    for platform in ("static-floor", "static-elevated"):  # 40 episodes against the shipped 1000-episode evaluation
        shipped = json.loads((ROOT / f"data/runs/quick-cpu/eval_pointmass_{platform}_vicon.json").read_text())
        [(success, error)] = shown.numbers(
            rf"^point mass {platform} \d+ episodes: success (\S+) %, landing error mean (\S+)"
        )
        assert success >= 100 * shipped["success_rate"] - 15 and abs(error - shipped["landing_error_mean_cm"]) < 1.0
    [(success,)] = shown.numbers(r"^PyBullet\s+\d+ episodes: success (\S+) %")
    assert success >= 50.0  # the shipped fine-tune lands 95 % of 200 episodes (data/runs/crazyflie-finetune)
    [action] = shown.numbers(r"action \(fraction of 3 m/s\): \[\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\]")
    assert action[2] < 0 and action[5] < 0  # both drones above their goals descend
    # The live two-seed sweep shows a table with one row per condition and the pooled row.
    live = [r for r in markdown_rows(shown.text[shown.text.index("| condition | seeds |") :]) if r["seeds"] == "2"]
    assert [r["condition"] for r in live] == ["point mass, elevated", "point mass, floor"]
    # The shipped sweep: every seed's printed success equals its evaluation.csv row, and the table's mean is theirs.
    from marlander_lite.training.sweep import SWEEP_CONDITIONS

    quick = {c.name for c in SWEEP_CONDITIONS["quick"]}
    rows = [r for r in read_csv(ROOT / "data/sweeps/quick-cpu/evaluation.csv") if r["condition"] in quick]
    printed = shown.numbers(r"^seed (\d+)\s+(?:point mass|firmware), [\w ,]+?\s+success\s+(\S+) %")
    assert sorted(printed) == sorted((float(r["seed"]), round(100 * float(r["success_rate"]), 1)) for r in rows)
    shipped_table = shown.text[shown.text.rindex("| condition | seeds |") :]
    for row in markdown_rows(shipped_table.split("\n\n")[0]):
        chosen = [float(r["success_rate"]) for r in rows if r["condition"] == row["condition"]]
        if chosen and "success mean" in row:
            assert close(first_number(row["success mean"]), 100 * sum(chosen) / len(chosen), 0.051), row
    # The performance profile's per-condition IQM of every shipped sweep equals the IQM of its evaluation.csv rows.
    for sweep in ("quick-cpu", "paper"):
        flown = read_csv(ROOT / f"data/sweeps/{sweep}/evaluation.csv")
        for condition in SWEEP_CONDITIONS["protocol"]:
            scores = [float(r["success_rate"]) for r in flown if r["condition"] == condition.name]
            [(value,)] = shown.numbers(rf"^\s+{sweep}\s+{re.escape(condition.name)}\s+IQM success\s+(\S+) %")
            assert len(scores) >= 3 and close(value, 100 * seed_stats_iqm(scores), 0.051), (sweep, condition.name)
    assert shown.figures == 3  # Fig. 5/6 from the shipped runs, the sweep's curves, the performance profiles


def check_04(shown: Shown) -> None:
    assert_step_by_step_trial(shown, "static-floor")
    for name in ("eq. 5 by hand vs the library's r_t^i", "eq. 4 by hand vs the library's R_t"):
        [(difference,)] = shown.numbers(rf"^{re.escape(name)}:\s+largest difference (\S+)")
        assert difference < 1e-9
    assert_shipped_tables(shown, "static")
    live = shown.table("Table I:", "point-mass simulator, live sample")
    assert_live_rows_repeat_shipped(live, ("static-floor", "static-elevated"))
    assert shown.figures == 2  # the step-by-step trial, Fig. 7 (a, b)


def check_05(shown: Shown) -> None:
    assert_step_by_step_trial(shown, "moving-linear-0.5")
    pad_speeds = shown.numbers(r"which moved at (\S+) m/s")
    assert [s for (s,) in pad_speeds] == pytest.approx([0.5, 0.5], abs=0.005)
    assert_shipped_tables(shown, "moving")
    # The paper's network's moving fine-tune lands more moving trials, nearer the pad centre, with the 0.3 s lead.
    fine_tune = {
        lead: next(r for r in shown.table(title) if r["controller"].startswith("MARLander + platform velocity"))
        for lead, title in (
            (0.5, "PyBullet, late commands (the paper's network and its moving fine-tune)"),
            (0.3, "PyBullet, the moving fine-tune flown with a 0.3 s pad lead"),
        )
    }
    success, error = (
        {lead: first_number(row[column]) for lead, row in fine_tune.items()}
        for column in ("success % (ours)", "precision cm (ours)")
    )
    assert success[0.3] > success[0.5] >= 90.0 and error[0.3] < error[0.5] <= 3.93, (success, error)
    conditions = ("moving-linear-0.2", "moving-linear-0.5", "moving-arc-0.2", "moving-arc-0.5")
    assert_live_rows_repeat_shipped(shown.table("Table II:", "point-mass simulator, live sample"), conditions)
    per_condition = shown.table("Per condition, point-mass simulator, live sample")
    assert len(per_condition) == 4 * len(conditions)
    for row in per_condition:
        success, error = shipped_cell(row["controller"], (row["condition"],), int(row["trials"]))
        assert close(first_number(row["success % [95 % CI]"]), success, 0.051), row
        assert close(first_number(row["mean error cm [95 % CI]"]), error, 0.0051), row
    assert shown.figures == 5  # the step-by-step trial, success vs speed (shipped x 2, live), Fig. 7 (c)


def check_06(shown: Shown) -> None:
    shipped_gains = (RESULTS / "pointmass" / "gains_baseline.md").read_text().strip()
    assert any(m.strip() == shipped_gains for m in shown.markdown), "the gains differ from the shipped run's"
    ablation = dict(shown.numbers(r"^feed-forward (\d): success (\S+) %"))
    assert ablation[1.0] == 100.0 and ablation[0.0] < ablation[1.0]  # on a moving pad the feed-forward is needed
    static = shown.table("Table I:", "live sample")
    moving = shown.table("Table II:", "live sample")
    assert len(static) == len(moving) == 5
    assert_live_rows_repeat_shipped(static, ("static-floor", "static-elevated"))
    assert_live_rows_repeat_shipped(moving, ("moving-arc-0.3", "moving-linear-0.3"))
    assert shown.figures == 1  # the APF velocity field


def check_08(shown: Shown) -> None:
    # Every cell of each shipped matrix printed (success % / mean error) is the one in its transfer.csv.
    sections = re.split(r"^### (\S+)$", shown.text, flags=re.MULTILINE)
    pairs = zip(sections[1::2], sections[2::2], strict=True)
    matrices = {name: body for name, body in pairs if body.lstrip().startswith("| | ")}  # success tables
    assert set(matrices) == {p.parent.name for p in (RESULTS / "transfer").glob("*/transfer.csv")}
    for name, body in matrices.items():
        matrix = body.strip().split("\n\n")[0]  # the success table; the flight-quality table follows it
        shown_cells = {(r[""], column): cell for r in markdown_rows(matrix) for column, cell in r.items() if column}
        for r in read_csv(RESULTS / "transfer" / name / "transfer.csv"):
            cell = shown_cells[(r["row"], r["column"])]
            assert close(first_number(cell), 100 * float(r["success_rate"]), 0.051), (name, cell)
            error = float(cell.rsplit("/", 1)[1].split()[0])
            assert close(error, float(r["landing_error_cm"]), 0.0051), (name, cell)
    # Section 4c: the worst line cell flown with and without the safety filter; the causes shown are failed episodes.
    for label in ("policy alone", "through the filter"):
        pattern = rf"^ *{label}: (\S+) % of (\d+) at \S+ cm; failed: (\d+) collision, (\d+) off the pad, (\d+) timeout"
        [(rate, episodes, collisions, off_pad, timeouts)] = shown.numbers(pattern)
        assert episodes >= 2 and collisions + off_pad + timeouts <= round(episodes * (1 - rate / 100))
    # Section 4d: the combined column. paper-robust-smooth, 90.5-100 % in every single-perturbation column, lands under
    # 90 % on both static rows there, and 96.5-98 % through the filter (data/results/transfer/*-combined*).
    combined = {
        name: {row: rate for row, rate in re.findall(r"(floor|UR10|arc 0.2-0.5 m/s|line 0.2-0.5 m/s) (\S+) %", cells)}
        for name, cells in re.findall(r"^(\S+-combined\S*): (.+)$", shown.text, flags=re.MULTILINE)
    }
    assert set(combined) == {p.parent.name for p in (RESULTS / "transfer").glob("*-combined*/transfer.csv")}
    alone, filtered = combined["paper-robust-smooth-combined"], combined["paper-robust-smooth-combined-safety-filter"]
    assert max(float(alone[row]) for row in ("floor", "UR10")) < 90.0 <= min(float(filtered[r]) for r in alone)
    # Section 4e: the cap worked by hand (1.5 m/s down passes with 0, becomes 0.8 m/s with the default), then each
    # filtered matrix flown without and with it: the numbers shown are the files', and the cap adds no fast touchdown.
    assert dict(shown.numbers(r"settled True, settled_sink_limit (\S+): sent \[\S+, \S+, (\S+)\] m/s")) == {
        0.0: -1.5,
        0.8: -0.8,
    }
    title = "| matrix | worst cell, no cap |"
    capped = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    bases = {p.parent.name.removesuffix("-sink-limit") for p in (RESULTS / "transfer").glob("*-sink-limit/*.csv")}
    assert {r["matrix"] for r in capped} == {name for name in bases if (RESULTS / "transfer" / name).is_dir()}
    for r in capped:
        for name, worst, fast in ((r["matrix"], "worst cell, no cap", "touchdowns > 0.5 m/s, no cap"),
                                  (r["matrix"] + "-sink-limit", "worst cell, cap 0.8 m/s", "cap 0.8 m/s")):  # fmt: skip
            cells = read_csv(RESULTS / "transfer" / name / "transfer.csv")
            assert close(first_number(r[worst]), 100 * min(float(c["success_rate"]) for c in cells), 0.051), r
            assert int(r[fast]) == sum(int(c["crashes_too_fast"]) for c in cells), r
        assert int(r["cap 0.8 m/s"]) <= int(r["touchdowns > 0.5 m/s, no cap"]), r
    # Section 4f: the pad lead. The estimate follows the line's 1 m/s^2 reversals and stays low while cruising; each
    # matrix flown with the lead is shown beside its twin without it, the numbers the files'; the live cell adds up.
    pattern = r"reversing \S+ % of the time at (\S+) m/s\^2; estimate there (\S+) m/s\^2, while cruising (\S+)"
    [(true, estimated, cruising)] = shown.numbers(pattern)
    assert abs(true - 1.0) < 0.05 and 0.6 * true < estimated <= true and cruising < 0.3
    title = "| matrix | worst moving cell, no lead |"
    led = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    twins = {p.parent.name.removesuffix("-pad-lead") for p in (RESULTS / "transfer").glob("*-pad-lead/transfer.csv")}
    assert {r["matrix"] for r in led} == twins
    for r in led:
        for suffix, worst, misses in (("-sink-limit", "worst moving cell, no lead", "off the pad + timeouts, no lead"),
                                      ("-pad-lead", "with pad_lead 0.2 s", "with the lead")):  # fmt: skip
            rows = read_csv(RESULTS / "transfer" / (r["matrix"] + suffix) / "transfer.csv")
            cells = [c for c in rows if c["row"].startswith(("arc", "line"))]
            assert close(first_number(r[worst]), 100 * min(float(c["success_rate"]) for c in cells), 0.051), r
            assert int(r[misses]) == sum(int(c["crashes_off_pad"]) + int(c["timeouts"]) for c in cells), r
    pattern = (
        r"^ *with the pad lead: (\S+) % of (\d+) at \S+ cm; failed: (\d+) collision, (\d+) off the pad, (\d+) timeout"
    )
    [(rate, episodes, collisions, off_pad, timeouts)] = shown.numbers(pattern)
    assert episodes >= 2 and collisions + off_pad + timeouts <= round(episodes * (1 - rate / 100))
    # Section 4g: the latency compensation. By hand p + v L; the late drone touches down too fast without it and within
    # the descent guard's 0.3 m/s with it; each compensated matrix is shown beside its twin, the numbers the files'.
    assert shown.numbers(r"p \+ v L, .*: \[(\S+) +(\S+) +(\S+) *\]") == [(0.95, 0.02, 1.9)]
    late = dict(shown.numbers(r"latency_compensation (\S+) s: touchdown at (\S+) m/s after \S+ s"))
    assert set(late) == {0.0, 0.08} and late[0.0] > 0.5 and late[0.08] <= 0.3
    title = "| matrix | flown without as |"
    compensated = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    latency = {p.parent.name for p in (RESULTS / "transfer").glob("*-latency/transfer.csv")}
    assert latency and {r["matrix"] + "-latency" for r in compensated} == latency
    for r in compensated:
        with_l = read_csv(RESULTS / "transfer" / (r["matrix"] + "-latency") / "transfer.csv")
        flown = {(c["row"], c["column"]) for c in with_l}
        assert r["flown without as"] in (r["matrix"] + "-pad-lead", r["matrix"] + "-sink-limit"), r
        without = [c for c in read_csv(RESULTS / "transfer" / r["flown without as"] / "transfer.csv")
                   if (c["row"], c["column"]) in flown]  # fmt: skip
        assert len(without) == len(with_l), r
        for cells, side in ((without, "without"), (with_l, "with")):
            worst = r["worst cell, without"] if side == "without" else r["with latency_compensation 0.12 s"]
            assert close(first_number(worst), 100 * min(float(c["success_rate"]) for c in cells), 0.051), r
            failed = sum(int(c["episodes"]) - int(c["successes"]) for c in cells)
            assert int(r[f"failed, {side}"]) == failed, r
            error = max(float(c["landing_error_cm"]) for c in cells)
            assert close(first_number(r[f"worst error, {side}"]), error, 0.0051), r
            touchdowns = [float(c["touchdown_speed"]) for c in cells if c["column"] == "firmware latency 60 ms"]
            shown_touchdown = r[f"60 ms touchdown, {side}"]
            assert (
                close(first_number(shown_touchdown), max(touchdowns), 0.00051) if touchdowns else shown_touchdown == "-"
            )
    pattern = (
        r"^ *60 ms, [a-z ]+: (\S+) % of (\d+) at \S+ cm, touchdown \S+ m/s; "
        r"failed: (\d+) collision, (\d+) off the pad, (\d+) timeout"
    )
    live_60ms = shown.numbers(pattern)
    assert len(live_60ms) == 2
    for rate, episodes, collisions, off_pad, timeouts in live_60ms:
        assert episodes >= 2 and collisions + off_pad + timeouts <= round(episodes * (1 - rate / 100))
    live = markdown_rows("\n".join(shown.text.rstrip().splitlines()[-3:]))
    assert len(live) == 1 and live[0][""] == "UR10"
    for column in ("point mass", "PyBullet firmware", "PyBullet PID"):
        # 96.5, 98.5 and 91.5 % of 200 episodes in these cells (data/results/transfer/quick-cpu-all-heights)
        assert first_number(live[0][column]) >= 50.0, live[0]
    # Section 4h: the held-out tracker hovers at the thrust balance (sqrt(m g / 4 k_f), docs/references.md) and tilts
    # far past our tracker's 30 degrees; the swing tilts past 50 degrees and lands too fast through the filter's
    # defaults, and stays under 40 degrees with the velocity-step limit. The tables are the files'.
    [(rpm, drift, tilt)] = shown.numbers(
        r"^held-out \(published gains\): hover at (\S+) RPM, drift (\S+) cm; chasing 3 m/s: tilt up to (\S+) deg$"
    )
    assert abs(rpm - math.sqrt(0.027 * 9.81 / (4 * 3.16e-10))) < 145 and drift < 2.0 and tilt > 45.0
    [(ours,)] = shown.numbers(r"^our pid tracker: hover at \S+ RPM, drift \S+ cm; chasing 3 m/s: tilt up to (\S+) deg$")
    assert ours < 31.0
    [(tilt, speed)] = shown.numbers(r"^low_velocity_step 0\.0 m/s: tilt up to (\S+) deg, touchdown at (\S+) m/s")
    assert tilt > 50.0 and speed > 0.5
    [limited] = re.findall(r"^low_velocity_step 0\.5 m/s: tilt up to (\S+) deg, (.+) after", shown.text, re.MULTILINE)
    assert float(limited[0]) < 40.0 and (limited[1] == "no touchdown" or first_number(limited[1].split()[-2]) <= 0.5)
    title = "| policy | alone | through the filter |"
    held_out = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    folders = {p.parent.name for p in (RESULTS / "transfer").glob("*-held-out*/transfer.csv")}
    assert {r["policy"] + "-held-out" for r in held_out} == {f for f in folders if f.endswith("-held-out")}
    for r in held_out:
        shown_fast = r["touchdowns > 0.5 m/s: alone / filter / step"].split(" / ")
        for side, suffix, fast in zip(("alone", "through the filter", "with low_velocity_step 0.5 m/s"),
                                      ("-held-out", "-held-out-safety-filter", "-held-out-safety-filter-velocity-step"),
                                      shown_fast, strict=True):  # fmt: skip
            if r[side] == "-":
                assert r["policy"] + suffix not in folders and fast == "-", r
                continue
            cells = {c["row"]: c for c in read_csv(RESULTS / "transfer" / (r["policy"] + suffix) / "transfer.csv")}
            for row, rate in re.findall(r"(floor|UR10|arc 0.2-0.5 m/s|line 0.2-0.5 m/s) (\S+) %", r[side]):
                assert close(float(rate), 100 * float(cells[row]["success_rate"]), 0.051), (r, row)
            rows = re.findall(r"(floor|UR10|arc 0.2-0.5 m/s|line 0.2-0.5 m/s) \S+ %", r[side])
            assert int(fast) == sum(int(cells[row]["crashes_too_fast"]) for row in rows), r
    title = "| matrix | worst cell, without | with low_velocity_step 0.5 m/s |"
    stepped = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    assert {r["matrix"] + "-velocity-step" for r in stepped} == {
        f for f in folders | {p.parent.name for p in (RESULTS / "transfer").glob("*-velocity-step/transfer.csv")}
        if f.endswith("-safety-filter-velocity-step") and "-held-out" not in f
    }  # fmt: skip
    for r in stepped:
        with_step = read_csv(RESULTS / "transfer" / (r["matrix"] + "-velocity-step") / "transfer.csv")
        flown = {(c["row"], c["column"]) for c in with_step}
        without = [c for c in read_csv(RESULTS / "transfer" / (r["matrix"] + "-latency") / "transfer.csv")
                   if (c["row"], c["column"]) in flown]  # fmt: skip
        assert len(without) == len(with_step), r
        for cells, worst, failed, error in ((without, "worst cell, without", "failed, without", "worst error, without"),
                                            (with_step, "with low_velocity_step 0.5 m/s", "failed, with",
                                             "worst error, with")):  # fmt: skip
            assert close(first_number(r[worst]), 100 * min(float(c["success_rate"]) for c in cells), 0.051), r
            assert int(r[failed]) == sum(int(c["episodes"]) - int(c["successes"]) for c in cells), r
            assert close(first_number(r[error]), max(float(c["landing_error_cm"]) for c in cells), 0.0051), r
    # Section 4i: RotorPy, a simulator we did not write. Its step response overshoots the 1.5 m/s command and returns
    # towards rest after the stop; the table is the shipped -rotorpy files'; a few episodes flown here.
    response = r"^RotorPy: peak (\S+) m/s at (\S+) s; after the stop, (\S+) m/s at 1 s$"
    [(peak, peak_time, after)] = shown.numbers(response)
    assert peak > 1.5 and 0.2 < peak_time <= 0.75 and abs(after) < 0.5
    title = "| policy | alone | through the filter | landing error alone, cm |"
    on_rotorpy = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    folders = {p.parent.name for p in (RESULTS / "transfer").glob("*-rotorpy*/transfer.csv")}
    assert on_rotorpy
    assert {r["policy"] + "-rotorpy" for r in on_rotorpy} == {f for f in folders if f.endswith("-rotorpy")}
    for r in on_rotorpy:
        for side, suffix in (("alone", "-rotorpy"), ("through the filter", "-rotorpy-safety-filter")):
            if r[side] == "-":
                assert r["policy"] + suffix not in folders, r
                continue
            cells = {c["row"]: c for c in read_csv(RESULTS / "transfer" / (r["policy"] + suffix) / "transfer.csv")}
            assert {c["column"] for c in cells.values()} == {"RotorPy Crazyflie"}
            for row, rate in re.findall(r"(floor|UR10|arc 0.2-0.5 m/s|line 0.2-0.5 m/s) (\S+) %", r[side]):
                assert close(float(rate), 100 * float(cells[row]["success_rate"]), 0.051), (r, row)
    [(landed, flown)] = shown.numbers(r"^flown here: quick-cpu-smooth on RotorPy, floor: (\d+) of (\d+) landed")
    assert flown >= 1 and 0 <= landed <= flown
    # Section 4j: the steeper approach cone. The table's extremes are the shipped matrices' own, and both slope-2
    # seeds meet the quick-cpu targets in every cell; the slope-1 policy misses the landing error in RotorPy.
    title = "| policy | cells | lowest success % | largest landing error, cm |"
    cone = {r["policy"]: r for r in markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])}
    sources = {
        "slope 1 (quick-cpu-smooth)": ["quick-cpu-smooth", "quick-cpu-smooth-combined", "quick-cpu-smooth-held-out",
                                       "quick-cpu-smooth-rotorpy"],
        "slope 2, seed 0": ["quick-cpu-smooth-cone2"],
        "slope 2, seed 1": ["quick-cpu-smooth-cone2-seed1"],
        "slope 2, seed 2": ["quick-cpu-smooth-cone2-seed2"],  # its ten columns before PyFlyt's, as the others'
        "slope 2, the preset (two threads)": ["quick-cpu-smooth-cone2-bench"],
    }  # fmt: skip
    assert set(cone) == set(sources)
    for name, folders in sources.items():
        cells = [c for f in folders for c in read_csv(RESULTS / "transfer" / f / "transfer.csv")]
        cells = [c for c in cells if not c["column"].startswith("PyFlyt")]
        assert int(cone[name]["cells"]) == len(cells) == 20, name
        lowest, largest = (float(cone[name][k]) for k in ("lowest success %", "largest landing error, cm"))
        assert close(lowest, 100 * min(float(c["success_rate"]) for c in cells), 0.051), name
        assert close(largest, max(float(c["landing_error_cm"]) for c in cells), 0.0051), name
        assert (lowest >= 90.0 and largest <= 2.26) == name.startswith("slope 2"), name
    # Section 4k: PyFlyt, a second simulator we did not write. Its step response is far slower than the command; its
    # fitted horizontal time constant lies beyond the family's slowest; the table is the shipped -pyflyt files'; on the
    # point mass the same policy lands fewer episodes with a 0.8 s horizontal loop than with a 0.2 s one.
    [(half_second, _)] = shown.numbers(r"^PyFlyt: (\S+) m/s after 0.5 s of a 1.5 m/s command, peak (\S+) m/s$")
    assert 0.2 < half_second < 1.0
    [(tau, family_slowest)] = shown.numbers(
        r"^PyFlyt's horizontal velocity time constant: (\S+) s \(family up to (\S+) s\)$"
    )
    assert family_slowest == DynamicsFamily().velocity_time_constant[1] and tau > 1.5 * family_slowest
    title = "| policy | alone | through the filter | touchdown alone, m/s |"
    on_pyflyt = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    folders = {p.parent.name for p in (RESULTS / "transfer").glob("*-pyflyt*/transfer.csv")}
    assert {r["policy"] + "-pyflyt" for r in on_pyflyt} == {f for f in folders if f.endswith("-pyflyt")} != set()
    causes = ("collisions", "crashes_too_fast", "crashes_off_pad", "out_of_arena", "timeouts")
    for r in on_pyflyt:
        for side, suffix in (("alone", "-pyflyt"), ("through the filter", "-pyflyt-safety-filter")):
            if r[side] == "-":
                assert r["policy"] + suffix not in folders, r
                continue
            cells = {c["row"]: c for c in read_csv(RESULTS / "transfer" / (r["policy"] + suffix) / "transfer.csv")}
            assert {c["column"] for c in cells.values()} == {"PyFlyt Crazyflie"}
            for row, rate in re.findall(r"(floor|UR10|arc 0.2-0.5 m/s|line 0.2-0.5 m/s) (\S+) %", r[side]):
                assert close(float(rate), 100 * float(cells[row]["success_rate"]), 0.051), (r, row)
            if side == "alone":
                failed = [int(n) for n in r["alone: collisions / too fast / off pad / out / timeouts"].split(" / ")]
                assert failed == [sum(int(c[cause]) for c in cells.values()) for cause in causes], r
    landed = dict(shown.numbers(r"^point mass with a (\S+) s horizontal velocity loop: (\d+) of \d+ landed"))
    assert set(landed) == {0.2, 0.8} and landed[0.8] < landed[0.2]
    # PyFlyt held still: in 0.21.0's step order y wanders far more than x; in the later order both hold.
    pattern = r"^PyFlyt held still, (0\.\S+) step: RMS x (\S+) cm, y (\S+) cm$"
    held = {order: (x, y) for order, x, y in re.findall(pattern, shown.text, re.MULTILINE)}
    (x_021, y_021), (x_022, y_022) = ((float(v) for v in held[order]) for order in ("0.21.0", "0.22"))
    assert y_021 > 5 * max(x_021, 0.1) and y_021 > 3 * y_022 and max(x_022, y_022) < 3.0
    # The 0.22 table is the shipped files' cells of that column, beside the 0.21.0 cells of the same policy.
    title = "| results | PyFlyt 0.22 step order | landing error, cm | PyFlyt 0.21.0 step order |"
    on_022 = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    folders_022 = {
        p.parent.name
        for p in (RESULTS / "transfer").glob("*/transfer.csv")
        if any(c["column"] == "PyFlyt Crazyflie 0.22" for c in read_csv(p))
    }
    assert {r["results"] for r in on_022} == folders_022 and "quick-cpu-smooth-cone2-slow-trackers" in folders_022
    for r in on_022:
        cells = {c["row"]: c for c in read_csv(RESULTS / "transfer" / r["results"] / "transfer.csv")
                 if c["column"] == "PyFlyt Crazyflie 0.22"}  # fmt: skip
        for row, rate in re.findall(r"(floor|UR10) (\S+) %", r["PyFlyt 0.22 step order"]):
            assert close(float(rate), 100 * float(cells[row]["success_rate"]), 0.051), (r, row)
    # The text on the preset's own run: about 30 % alone, 86-89 % through the filter, the rest leaving the arena.
    bench = {kind: read_csv(RESULTS / "transfer" / f"quick-cpu-smooth-cone2-bench-pyflyt-0.22{kind}" / "transfer.csv")
             for kind in ("", "-safety-filter")}  # fmt: skip
    assert all(0.25 <= float(c["success_rate"]) <= 0.35 for c in bench[""])
    filtered = bench["-safety-filter"]
    assert all(0.86 <= float(c["success_rate"]) < 0.9 for c in filtered)
    lost = sum(int(c["episodes"]) - int(c["successes"]) for c in filtered)
    assert sum(int(c["out_of_arena"]) for c in filtered) >= 0.9 * lost
    # ... and with the latency compensation at 0.25 and 0.4 s: 93-96 %, then 98-99 %, fewer drones leaving the arena.
    for compensation, (low, high) in (("0.25", (0.93, 0.96)), ("0.4", (0.98, 0.99))):
        folder = f"quick-cpu-smooth-cone2-bench-pyflyt-0.22-safety-filter-latency-{compensation}"
        cells = read_csv(RESULTS / "transfer" / folder / "transfer.csv")
        assert all(low <= float(c["success_rate"]) <= high for c in cells), folder
        assert sum(int(c["out_of_arena"]) for c in cells) < sum(int(c["out_of_arena"]) for c in filtered)
    # The slow-tracker policies' matrices: every column, their worst cell and largest error the shipped csv's.
    for name in ("quick-cpu-smooth-cone2-slow-trackers", "quick-cpu-smooth-cone5-slow-trackers"):
        slow = read_csv(RESULTS / "transfer" / name / "transfer.csv")
        [(cells, columns)] = shown.numbers(rf"^{name} matrix: (\d+) cells, (\d+) columns$")
        assert cells == len(slow) == 24 and columns == 12
        [(worst,)] = shown.numbers(rf"^{name} worst cell: (\S+) % \(.+\)$")
        assert close(worst, 100 * min(float(c["success_rate"]) for c in slow), 0.051)
        [(widest,)] = shown.numbers(rf"^{name} largest landing error: (\S+) cm \(.+\)$")
        assert close(widest, max(float(c["landing_error_cm"]) for c in slow), 0.0051)
    # Section 4l: the identified compensation. The live cells: the lag identified grows with the point mass's loop and
    # the compensation is half of it; the shipped matrix: every column, its worst cell and largest error the csv's.
    pattern = r"^velocity time constant (\S+) s: identified (\S+) s, compensation (\S+) s; (\S+) % of (\d+) at"
    live = {tau: (lag, compensation) for tau, lag, compensation, _, _ in shown.numbers(pattern)}
    assert set(live) == {0.2, 0.8} and live[0.8][0] > live[0.2][0] + 0.2
    assert all(close(compensation, min(0.5 * lag, 0.5), 0.0051) for lag, compensation in live.values())
    identified = read_csv(
        RESULTS / "transfer" / "quick-cpu-smooth-cone2-bench-safety-filter-identified-lag" / "transfer.csv"
    )
    assert len(identified) == 24 and len({c["column"] for c in identified}) == 12
    [(worst,)] = shown.numbers(r"^identified compensation worst cell: (\S+) % \(.+\)$")
    assert close(worst, 100 * min(float(c["success_rate"]) for c in identified), 0.051) and worst >= 90.0
    [(widest,)] = shown.numbers(r"^identified compensation largest landing error: (\S+) cm \(.+\)$")
    assert close(widest, max(float(c["landing_error_cm"]) for c in identified), 0.0051) and widest <= 2.26
    lags = {(c["row"], c["column"]): float(c["identified_lag_s"]) for c in identified}
    assert lags[("floor", "PyFlyt Crazyflie 0.22")] > 2 * lags[("floor", "PyBullet firmware")]  # the text's claim
    # Section 4m: the slow-tracker preset. The opening began where its run's log says and lasts 30 % of its steps; its
    # matrix's worst cell and largest error are the csv's; alone in PyFlyt 0.22 it lands where quick-cpu-smooth does
    # not.
    [(opened, length)] = shown.numbers(r"^the preset's run: the opening began at (\d+) steps, (\d+) steps long$")
    log = read_csv(ROOT / "data" / "runs" / "quick-cpu-slow-trackers" / "logs" / "progress.csv")
    assert opened == next(float(r["train/family_opened_at"]) for r in log if r["train/family_opened_at"])
    assert length == 3_600_000
    pyflyt = shown_matrix_and_pyflyt_flight(shown, "quick-cpu-slow-trackers")
    assert min(pyflyt) >= 0.8  # quick-cpu-smooth's own run: 31.5 / 28.0 %
    # Section 4n: the integrator. Against drag a proportional loop settles where the hand's force balance says and an
    # integrating one at the command; after a brake the integrator carries the drone past where its commands lead, the
    # further the larger k_i.
    [(hand,)] = shown.numbers(r"^worked by hand, a proportional loop against drag: u / \(1 \+ drag tau\) = (\S+) m/s$")
    pattern = r"^k_i (\S+): settles at (\S+) m/s against drag; overshoots the 1.5 m its commands add up to by (\S+) cm$"
    loops = shown.numbers(pattern)
    assert [gain for gain, _, _ in loops] == [0.0, 0.375, 0.8]
    assert close(loops[0][1], hand, 0.0011) and all(close(speed, 0.3, 0.0011) for _, speed, _ in loops[1:])
    assert loops[0][2] < loops[1][2] < loops[2][2], loops
    on_022 = shown_matrix_and_pyflyt_flight(shown, "quick-cpu-slow-trackers-integral")
    assert min(on_022) > max(pyflyt)  # the integrator's preset lands more of PyFlyt 0.22 than the first version
    # Section 4o: 20 M steps. The table's PyFlyt 0.22 errors are the csvs'; every seed of 20 M steps lands closer there
    # than the same seed of 12 M did; over the three seeds' columns but the 0.21.0 order the worst cell and the largest
    # error are the csvs' and meet the issue's 90 % and 2.26 cm.
    title = "| run | PyFlyt 0.22, floor / UR10 | landing error there, cm |"
    runs = {r["run"]: r for r in markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])}
    errors = {}
    for name, r in runs.items():
        cells = [
            c for c in read_csv(RESULTS / "transfer" / name / "transfer.csv") if c["column"] == "PyFlyt Crazyflie 0.22"
        ]
        errors[name] = [float(e) for e in r["landing error there, cm"].split(" / ")]
        assert all(close(e, float(c["landing_error_cm"]), 0.0051) for e, c in zip(errors[name], cells, strict=True))
    for seed in ("", "-seed1", "-seed2"):
        assert max(errors[f"quick-cpu-slow-trackers-20m{seed}"]) < min(
            errors[f"quick-cpu-slow-trackers-integral{seed}"]
        )
    pattern = r"^20 M steps, three seeds, every column but PyFlyt's 0.21.0 order: worst cell (\S+) %, largest"
    [(worst, widest)] = shown.numbers(pattern + r" landing error (\S+) cm$")
    matrices = [
        RESULTS / "transfer" / f"quick-cpu-slow-trackers-20m{seed}" / "transfer.csv"
        for seed in ("", "-seed1", "-seed2")
    ]
    cells = [c for path in matrices for c in read_csv(path) if c["column"] != "PyFlyt Crazyflie"]
    assert close(worst, 100 * min(float(c["success_rate"]) for c in cells), 0.051) and worst >= 90.0
    assert close(widest, max(float(c["landing_error_cm"]) for c in cells), 0.0051) and widest <= 2.26
    shown_matrix_and_pyflyt_flight(shown, "quick-cpu-slow-trackers-20m")
    # Section 4p: the paper's network on the same recipe. Its worst cell, Wilson bound and largest errors are the
    # csv's and meet the issue's `paper` target (>= 95 %, lower bound >= 90 %; 2.26 cm but in the 0.21.0 order); in
    # PyFlyt 0.22 it lands where paper-robust-smooth does not.
    for name in ("paper-slow-trackers", "paper-slow-trackers-seed1", "paper-slow-trackers-seed2"):  # seeds 0-2
        paper = read_csv(RESULTS / "transfer" / name / "transfer.csv")
        [(worst,)] = shown.numbers(rf"^{name} worst cell: (\S+) % \(.+\)$")
        [(lowest,)] = shown.numbers(rf"^{name} lowest Wilson lower bound: (\S+) %$")
        [(below, cells)] = shown.numbers(rf"^{name} cells below 95 %: (\d+) of (\d+) .*$")
        assert close(worst, 100 * min(float(c["success_rate"]) for c in paper), 0.051), name
        assert close(lowest, 100 * min(float(c["wilson_low"]) for c in paper), 0.051), name
        assert below == sum(float(c["success_rate"]) < 0.95 for c in paper) and cells == len(paper) == 24, name
        # seeds 0 and 1 meet the target in every cell; seed 2 misses the 95 % in one cell, by one episode (94.5 %)
        assert lowest >= 90.0 and (worst >= 95.0 if name != "paper-slow-trackers-seed2" else below == 1), name
        assert worst >= 94.5, name
        pattern = rf"^{name}, every column but PyFlyt's 0.21.0 order: largest landing error (\S+) cm$"
        [(widest,)] = shown.numbers(pattern)
        eleven = [c for c in paper if c["column"] != "PyFlyt Crazyflie"]
        assert close(widest, max(float(c["landing_error_cm"]) for c in eleven), 0.0051) and widest <= 2.26, name
    on_022 = shown_matrix_and_pyflyt_flight(shown, "paper-slow-trackers")
    before = [
        c
        for f in ("-pyflyt", "-pyflyt-0.22")
        for c in read_csv(RESULTS / "transfer" / f"paper-robust-smooth{f}" / "transfer.csv")
    ]
    assert len(before) == 4 and max(float(c["success_rate"]) for c in before) < 0.1 < 0.9 < min(on_022)
    # Section 4q: commands relative to the pad. Action 0 keeps a drone with its pad only in the pad frame; each moving
    # matrix's count of cells at 90 %, worst cell and largest error are its csv's; the world-frame cells shown are
    # paper-slow-trackers-moving's, and in the pad frame the same policy lands far more of them, untrained.
    text = shown.text
    carried = dict(
        re.findall(r"^action 0 for 1 s in the (\w+) frame: drone speed relative to its pad (\S+) m/s", text, re.M)
    )
    assert float(carried["world"]) > 0.3 > 0.1 > float(carried["pad"])
    for name in ("quick-cpu-slow-trackers-20m-pad-frame", "paper-slow-trackers-pad-frame", "moving-slow-trackers"):
        cells = [c for c in transfer_csv(name) if c["row"].startswith(("arc", "line"))]
        pattern = rf"^{name}, moving rows: (\d+) of (\d+) cells at 90 % or more; worst (\S+) % \(.+\); "
        [(at_90, count, worst, widest)] = shown.numbers(pattern + r"largest landing error (\S+) cm$")
        assert count == len(cells) == 24 and at_90 == sum(float(c["success_rate"]) >= 0.9 for c in cells), name
        assert close(worst, 100 * min(float(c["success_rate"]) for c in cells), 0.051), name
        assert close(widest, max(float(c["landing_error_cm"]) for c in cells), 0.0051), name
    world = {(c["row"], c["column"]): c for c in transfer_csv("paper-slow-trackers-moving")}
    pad = {(c["row"], c["column"]): c for c in transfer_csv("paper-slow-trackers-pad-frame")}
    pattern = r"^paper-slow-trackers, (.+ m/s), (.+): world frame (\S+) %, pad frame (\S+) %$"
    compared = re.findall(pattern, text, re.M)
    assert len(compared) == len(world) == 4
    for row, column, in_world, in_pad in compared:
        assert close(float(in_world), 100 * float(world[row, column]["success_rate"]), 0.051)
        assert close(float(in_pad), 100 * float(pad[row, column]["success_rate"]), 0.051)
        assert float(in_pad) > float(in_world) + 50
    static = [c for c in transfer_csv("moving-slow-trackers") if c["row"] in ("floor", "UR10")]
    pattern = r"^moving-slow-trackers, static rows: worst (\S+) %, largest landing error (\S+) cm$"
    [(worst, widest)] = shown.numbers(pattern)
    assert close(worst, 100 * min(float(c["success_rate"]) for c in static), 0.051)
    assert close(widest, max(float(c["landing_error_cm"]) for c in static), 0.0051)
    pattern = r"^flown here: moving-slow-trackers on the firmware tracker's moving line: (\d+) of (\d+)"
    [(landed, flown)] = shown.numbers(pattern)
    assert flown >= 2 and landed >= 0.5 * flown
    # Section 4r: a velocity step that follows the tracker. Each flight's count of moving cells at 90 % and worst cell
    # are its csv's; each column's step is 0.5 m/s * max(1, T / 0.45 s) for the lag T its flights identified.
    for name in (
        "moving-slow-trackers",
        "moving-slow-trackers-lead-0.3",
        "moving-slow-trackers-velocity-step-filter",
        "moving-slow-trackers-tracker-step-filter",
        "moving-slow-trackers-lead-0.3-tracker-step-filter",
    ):
        cells = [c for c in transfer_csv(name) if c["row"].startswith(("arc", "line"))]
        pattern = rf"^{name} \(.+\): (\d+) of (\d+) moving cells at 90 % or more; worst (\S+) %"
        [(at_90, count, worst)] = shown.numbers(pattern)
        assert count == len(cells) == 24 and at_90 == sum(float(c["success_rate"]) >= 0.9 for c in cells), name
        assert close(worst, 100 * min(float(c["success_rate"]) for c in cells), 0.051), name
    steps = re.findall(r"^(.+): identified lag (\S+) s -> velocity step (\S+) m/s; the line (\S+) %$", text, re.M)
    following = transfer_csv("moving-slow-trackers-tracker-step-filter")
    lines = {c["column"]: c for c in following if c["row"].startswith("line")}
    assert len(steps) == len(lines) == 12
    for column, lag, step, rate in steps:
        assert close(float(lag), float(lines[column]["identified_lag_s"]), 0.0051)
        assert close(float(step), 0.5 * max(1.0, float(lines[column]["identified_lag_s"]) / 0.45), 0.0051)
        assert close(float(rate), 100 * float(lines[column]["success_rate"]), 0.051)
    # Section 4s: the approach guard's climb. The hand-worked drone (10 cm off centre, 2 cm up, surface 6 cm): held at
    # 0 m/s without the climb, 4 * (0.06 - 0.02) = 0.16 m/s up with it; each matrix's counts are its csv's.
    climbs = dict(shown.numbers(r"^approach_climb (\S+): vertical command (\S+) m/s$"))
    assert climbs == pytest.approx({0.0: 0.0, 1.0: 0.16}, abs=0.005), climbs
    for name in (
        f"{policy}-{setting}"
        for policy in ("moving-slow-trackers", "paper-moving-slow-trackers")
        for setting in ("tracker-step-filter", "climb-filter", "wide-climb-filter")
    ):
        cells = [c for c in transfer_csv(name) if c["row"].startswith(("arc", "line"))]
        counts = r"(\d+) of (\d+) moving cells at 90 % or more; (\d+) touchdowns beside the pad and (\d+) time-outs"
        [(at_90, count, beside_pad, timeouts)] = shown.numbers(rf"^{name}: {counts}")
        assert count == len(cells) == 24 and at_90 == sum(float(c["success_rate"]) >= 0.9 for c in cells), name
        assert beside_pad == sum(int(c["crashes_off_pad"]) for c in cells), name
        assert timeouts == sum(int(c["timeouts"]) for c in cells), name
    static = transfer_csv("moving-slow-trackers-wide-climb-filter-static")
    pattern = r"^moving-slow-trackers-wide-climb-filter-static: worst (\S+) % \(.+\), largest landing error (\S+) cm$"
    [(worst, widest)] = shown.numbers(pattern)
    assert close(worst, 100 * min(float(c["success_rate"]) for c in static), 0.051)
    assert close(widest, max(float(c["landing_error_cm"]) for c in static), 0.0051)
    long = transfer_csv("moving-slow-trackers-wide-climb-filter-30s")
    pattern = (
        r"^moving-slow-trackers-wide-climb-filter-30s: (\d+) of (\d+) moving cells at 90 % or more; worst (\S+) % "
        r"\(.+\); largest landing error (\S+) cm$"
    )
    [(at_90, count, worst, widest)] = shown.numbers(pattern)
    assert count == len(long) == 24 and at_90 == sum(float(c["success_rate"]) >= 0.9 for c in long)
    assert close(worst, 100 * min(float(c["success_rate"]) for c in long), 0.051)
    assert close(widest, max(float(c["landing_error_cm"]) for c in long), 0.0051)
    # Section 4t: each shipped run on random Crazyflies, its summary recounted from its variants.csv.
    shown_runs = re.findall(r"^random Crazyflies: (\S+)\n((?:\|.*\n)+)", shown.text, flags=re.MULTILINE)
    assert {name for name, _ in shown_runs} == {p.parent.name for p in (RESULTS / "variants").glob("*/variants.csv")}
    for name, table in shown_runs:
        lines = read_csv(RESULTS / "variants" / name / "variants.csv")
        for r in markdown_rows(table):
            row = [line for line in lines if line["row"] == r["row"]]
            landed = sum(float(line["success_rate"]) >= 0.9 for line in row)
            assert r["variants at 90 % or more"] == f"{landed} of {len(row)}", (name, r)
            pooled = sum(int(line["successes"]) for line in row) / sum(int(line["episodes"]) for line in row)
            assert close(first_number(r["all episodes % [95 % Wilson]"]), 100 * pooled, 0.051), (name, r)
            worst = 100 * min(float(line["success_rate"]) for line in row)
            assert close(first_number(r["worst variant"]), worst, 0.051), (name, r)
    # Section 4u: the preset on late commands. The family lines are the presets'; each seed's worst cell and largest
    # error are its csv's and meet the issue's 90 % and 2.26 cm (but PyFlyt's 0.21.0 order); every seed of it lands
    # in more random PyFlyt Crazyflies, on both rows, than any seed of the 20 M-step version shown.
    from marlander_lite.training.presets import LATE_COMMANDS_FAST_VERTICAL, QUICK_SLOW_TRACKERS_20M

    pattern = r"^family (\w+): \[(\S+), (\S+)\] until 2026-12-01, \[(\S+), (\S+)\] now$"
    changed = {m[0]: [float(v) for v in m[1:]] for m in re.findall(pattern, shown.text, flags=re.MULTILINE)}
    assert changed == {
        k: [*QUICK_SLOW_TRACKERS_20M.dynamics["family"][k], *v] for k, v in LATE_COMMANDS_FAST_VERTICAL.items()
    }
    late = [f"quick-cpu-slow-trackers-fast-vertical-20m{seed}" for seed in ("", "-seed1", "-seed2")]
    for name in late:
        cells = transfer_csv(name)
        pattern = rf"^{name}: worst cell (\S+) % \(.+\), largest landing error in eleven columns (\S+) cm, .*$"
        [(worst, widest)] = shown.numbers(pattern)
        eleven = [c for c in cells if c["column"] != "PyFlyt Crazyflie"]
        assert close(worst, 100 * min(float(c["success_rate"]) for c in cells), 0.051) and worst >= 90.0, name
        assert close(widest, max(float(c["landing_error_cm"]) for c in eleven), 0.0051) and widest <= 2.26, name
    title = "| policy | random PyFlyt Crazyflies at 90 % or more, floor / UR10 |"
    table = {r["policy"]: r for r in markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])}
    counts = {}
    for name, r in table.items():
        lines = read_csv(RESULTS / "variants" / f"{name}-pyflyt" / "variants.csv")
        counts[name] = [
            sum(float(c["success_rate"]) >= 0.9 for c in lines if c["row"] == row) for row in ("floor", "UR10")
        ]
        shown_counts = r["random PyFlyt Crazyflies at 90 % or more, floor / UR10"]
        assert shown_counts == " / ".join(map(str, counts[name])) + " of 40", name
    before = [c for name, row in counts.items() if name not in late for c in row]
    assert set(late) < set(table) and len(before) >= 4
    assert min(c for name in late for c in counts[name]) > max(before)
    # Section 4v: the moving fine-tune on late commands. Each fine-tune's counts are its csv's; the worst static cell of
    # each one on late commands is above every earlier one's; the random-PyFlyt counts on the moving rows are the
    # variant runs'.
    moving_late = ("moving-slow-trackers-fast-vertical", "moving-slow-trackers-fast-vertical-seed1")
    static_worsts = {}
    for name in ("moving-slow-trackers", "moving-slow-trackers-seed1", *moving_late):
        static_worsts[name] = shown_fine_tune_counts(shown, name)
    assert min(static_worsts[n] for n in moving_late) > max(w for n, w in static_worsts.items() if n not in moving_late)
    title = "| policy | random PyFlyt Crazyflies at 90 % or more, arc / line |"
    table = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    assert [r["policy"] for r in table] == [
        "moving-slow-trackers",
        moving_late[0],
        "paper-moving-slow-trackers-fast-vertical",
    ]
    for r in table:
        lines = read_csv(RESULTS / "variants" / f"{r['policy']}-pyflyt-moving" / "variants.csv")
        rows = [[c for c in lines if c["row"] == row] for row in ("arc 0.2-0.5 m/s", "line 0.2-0.5 m/s")]
        landed = " / ".join(str(sum(float(c["success_rate"]) >= 0.9 for c in row)) for row in rows)
        assert r["random PyFlyt Crazyflies at 90 % or more, arc / line"] == f"{landed} of 40", r
    [(landed, flown, _)] = shown.numbers(
        rf"^flown here: {moving_late[0]} on the held-out tracker's arc: (\d+) of (\d+) landed at (\S+) cm$"
    )
    assert flown >= 2 and landed >= 0.5 * flown
    # Section 4w: the paper's network on late commands. Each static matrix's worst cell, lowest Wilson bound and
    # largest error in eleven columns are its csv's, and the new one meets the issue's `paper` target (>= 95 %, bound
    # >= 90 %, 2.26 cm); each moving fine-tune's counts are its csv's; the random-PyFlyt counts are the variant runs',
    # and on late commands the paper's network lands in more random PyFlyt Crazyflies, on both rows, than before.
    paper_late = "paper-slow-trackers-fast-vertical"
    for name in ("paper-slow-trackers", paper_late, f"{paper_late}-seed1", f"{paper_late}-seed2"):
        static = [c for c in transfer_csv(name) if c["row"] in ("floor", "UR10")]
        pattern = (
            rf"^{name}: worst cell (\S+) % \(.+\), lowest Wilson lower bound (\S+) %, largest landing error in eleven "
            r"columns (\S+) cm$"
        )
        [(worst, lowest, widest)] = shown.numbers(pattern)
        eleven = [c for c in static if c["column"] != "PyFlyt Crazyflie"]
        assert close(worst, 100 * min(float(c["success_rate"]) for c in static), 0.051), name
        assert close(lowest, 100 * min(float(c["wilson_low"]) for c in static), 0.051), name
        assert close(widest, max(float(c["landing_error_cm"]) for c in eleven), 0.0051), name
        assert worst >= 95.0 and lowest >= 90.0 and widest <= 2.26, name
    for name in ("paper-moving-slow-trackers", "paper-moving-slow-trackers-fast-vertical"):
        shown_fine_tune_counts(shown, name)
    title = "| policy | rows | random PyFlyt Crazyflies at 90 % or more |"
    table = markdown_rows(title + shown.text.split(title, 1)[1].split("\n\n", 1)[0])
    random_policies = [
        "paper-slow-trackers",
        paper_late,
        f"{paper_late}-seed1",
        "quick-cpu-slow-trackers-fast-vertical-20m",
    ]
    assert [r["policy"] for r in table] == random_policies
    landed = {}
    for r, policy in zip(table, random_policies, strict=True):
        run = f"{policy}-pyflyt"
        lines = read_csv(RESULTS / "variants" / run / "variants.csv")
        rows = [[c for c in lines if c["row"] == row] for row in r["rows"].split(" / ")]
        landed[run] = [sum(float(c["success_rate"]) >= 0.9 for c in row) for row in rows]
        assert r["random PyFlyt Crazyflies at 90 % or more"] == " / ".join(map(str, landed[run])) + " of 40", r
        on_022 = [[c for c in row if c["controller"] == "pyflyt 0.22"] for row in rows]
        shown_022 = " / ".join(str(sum(float(c["success_rate"]) >= 0.9 for c in row)) for row in on_022)
        assert r["of those read as PyFlyt 0.22"] == f"{shown_022} of {len(on_022[0])}", r
    for seed in ("", "-seed1"):  # both seeds of the late-command recipe
        assert min(landed[f"{paper_late}{seed}-pyflyt"]) > max(landed["paper-slow-trackers-pyflyt"])
    [(landed_here, flown, _)] = shown.numbers(
        rf"^flown here: {paper_late} on PyFlyt 0.22's UR10 plate: (\d+) of (\d+) landed at (\S+) cm$"
    )
    assert flown >= 2 and landed_here >= 0.5 * flown
    # Section 4x: each printed count and range is the shipped matrices'; with 0.3 s the paper's network lands every
    # Crazyflie-like moving cell at 98 % or more. Where a drone touches down moves ahead of the pad as the lead grows,
    # in every shipped column and on the point mass flown here.
    pattern = (
        r"^(\S+), lead (\S+)(?: \(trained\))? s: moving cells at 90 % or more (\d+) of (\d+); ten columns "
        r"(\S+)-(\S+) % at (\S+)-(\S+) cm"
    )
    summaries = re.findall(pattern, shown.text, re.MULTILINE)
    assert len(summaries) == 4
    for name, lead, *numbers in summaries:
        count, total, low, high, err_low, err_high = map(float, numbers)
        folder = name if lead == "0.5" else f"{name}-lead-{lead}"
        moving = [
            c for c in read_csv(RESULTS / "transfer" / folder / "transfer.csv") if c["row"][:4] in ("arc ", "line")
        ]
        ten = [c for c in moving if not c["column"].startswith("PyFlyt")]
        assert count == sum(float(c["success_rate"]) >= 0.9 for c in moving) and total == len(moving) == 24, folder
        assert close(low, 100 * min(float(c["success_rate"]) for c in ten), 0.051), folder
        assert close(high, 100 * max(float(c["success_rate"]) for c in ten), 0.051), folder
        assert close(err_low, min(float(c["landing_error_cm"]) for c in ten), 0.0051), folder
        assert close(err_high, max(float(c["landing_error_cm"]) for c in ten), 0.0051), folder
        if (name, lead) == ("paper-moving-slow-trackers-fast-vertical", "0.3"):
            assert low >= 98.0, low
    [(count, total, low, high)] = shown.numbers(
        r"through the pad-frame settings, its own lead, 30 s flights: moving cells at 90 % or more (\d+) of (\d+), "
        r"(\S+)-(\S+) %$"
    )
    cells = read_csv(
        RESULTS / "transfer" / "paper-moving-slow-trackers-fast-vertical-wide-climb-filter-30s" / "transfer.csv"
    )
    rates = [100 * float(c["success_rate"]) for c in cells]
    assert (count, total) == (sum(r >= 90.0 for r in rates), len(rates)) == (24, 24), (count, total)
    assert close(low, min(rates), 0.051) and close(high, max(rates), 0.051)
    random_pybullet = shown_variant_counts(
        shown, r"^(\S+) on the moving rows of 40 random PyBullet Crazyflies: (\d+) / (\d+) of 40"
    )
    trained, led = random_pybullet.values()
    assert len(random_pybullet) == 2 and all(a >= b for a, b in zip(led, trained, strict=True)), random_pybullet
    offsets = {}
    for line in (ROOT / "benchmarks" / "results" / "pad_frame_lead_2026-12-01.txt").read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if line.startswith("| ") and cells[0] != "column":
            offsets.setdefault(cells[0], []).append(float(cells[3].split(",")[0]))
    assert len(offsets) == 4 and all(along == sorted(along) and along[0] < 0 < along[-1] for along in offsets.values())
    here = [
        along
        for (_, along) in shown.numbers(r"^flown here: point mass, line at 0.5 m/s, lead (\S+) s: touchdowns (\S+) cm")
    ]
    assert len(here) == 3 and here[0] < 0 < here[2] and here == sorted(here), here
    check_08_auto_lead(shown)
    check_08_auto_trained(shown)
    check_08_rotorpy_variants(shown)
    check_08_vertical_bias(shown)
    check_08_stiff_loops(shown)
    check_08_two_corners(shown)
    check_08_two_corners_random(shown)
    # step responses (with and without RotorPy, and with PyFlyt), transfer bars, the pad's acceleration, the late
    # descent, the swing, the steeper cone's landing errors, PyFlyt held still, the opening family, the integrator,
    # the landing errors of 12 and 20 M steps in PyFlyt 0.22, the two networks on the same recipe, moving pads in the
    # pad frame, success on random Crazyflies in PyBullet and in PyFlyt, the preset before and since 2026-12-01 there,
    # the moving fine-tune before and on late commands, the paper's network before and on late commands, where a
    # pad-frame drone touches down for each lead, the line's success by lead, the line on random RotorPy Crazyflies,
    # the two-corner policy's line on them
    assert shown.figures == 23


def shown_variant_counts(shown: Shown, pattern: str) -> dict[str, list[int]]:
    """The random-Crazyflie counts a notebook prints (``pattern`` finds the folder and the arc and line counts), checked
    against each folder's variants.csv: the variants landing 90 % or more on each moving row, by folder."""
    counts = {}
    for folder, arc, line in re.findall(pattern, shown.text, re.MULTILINE):
        cells = read_csv(RESULTS / "variants" / folder / "variants.csv")
        landed = [sum(float(c["success_rate"]) >= 0.9 for c in cells if c["row"] == row) for row in MOVING_ROWS]
        assert [int(arc), int(line)] == landed, folder
        counts[folder] = landed
    return counts


def check_08_auto_lead(shown: Shown) -> None:
    """Section 4y: the moving cells with each lead and the lags ``auto`` identified are the shipped csvs'; ``auto``
    lands at least as many cells and random Crazyflies as either fixed lead; flown here, it leads a slow point mass
    by more than a fast one."""
    paper = "paper-moving-slow-trackers-fast-vertical"
    counts = {}
    for lead, count, total in re.findall(
        r"^lead (.+?): (\d+) of (\d+) moving cells at 90 % or more", shown.text, re.MULTILINE
    ):
        folder = {"0.5 s (trained)": paper, "0.3 s": f"{paper}-lead-0.3", "auto": f"{paper}-lead-auto"}[lead]
        moving = [c for c in transfer_csv(folder) if c["row"] in MOVING_ROWS]
        assert int(count) == sum(float(c["success_rate"]) >= 0.9 for c in moving) and int(total) == len(moving) == 24
        counts[lead] = int(count)
    assert len(counts) == 3 and counts["auto"] >= max(counts.values()), counts
    auto = [c for c in transfer_csv(f"{paper}-lead-auto") if c["row"] in MOVING_ROWS]
    table = re.findall(r"^\| ([^|]+) \| (\S+) / (\S+) \| (\S+) / (\S+) \| (\S+) / (\S+) \|$", shown.text, re.MULTILINE)
    lags = {column.strip(): (float(arc), float(line)) for column, arc, line, *_ in table}
    assert len(lags) == 12, lags
    for c in auto:
        assert close(lags[c["column"]][MOVING_ROWS.index(c["row"])], float(c["identified_lag_s"]), 0.0051), c
    assert max(lags["PyFlyt Crazyflie 0.22"]) > 0.7 > 0.45 > max(lags["point mass"]), lags
    for kind in ("PyBullet", "PyFlyt"):
        landed = shown_variant_counts(shown, rf"^random {kind} Crazyflies, (\S+): (\d+) / (\d+) of 40")
        auto = landed.pop(next(f for f in landed if f.endswith("lead-auto")))
        if kind == "PyBullet":  # the fast trackers: auto lands at least as many variants as either fixed lead
            assert landed and all(sum(auto) >= sum(other) for other in landed.values()), (auto, landed)
        else:  # PyFlyt's slow loops: within 2 variants a row of the trained lead, the one PyFlyt wants
            [trained] = landed.values()
            assert all(a >= t - 2 for a, t in zip(auto, trained, strict=True)), (auto, trained)
    # Seeds 1 and 2 of the recipe flown with auto: their counts, the three seeds' ranges and their random-draw counts
    # are the csvs'.
    for seed in ("1", "2"):
        shown_fine_tune_counts(shown, f"{paper}-seed{seed}-lead-auto")
    pattern = r"^seed (\d) with auto: ten Crazyflie-like columns (\S+)-(\S+) %; arc / line: "
    pattern += r"PyFlyt Crazyflie (\S+) / (\S+) %, PyFlyt Crazyflie 0.22 (\S+) / (\S+) %$"
    seeds = re.findall(pattern, shown.text, re.MULTILINE)
    assert [seed for seed, *_ in seeds] == ["0", "1", "2"], seeds
    for seed, *numbers in seeds:
        low, high, old_arc, old_line, new_arc, new_line = map(float, numbers)
        folder = f"{paper}{'' if seed == '0' else f'-seed{seed}'}-lead-auto"
        moving = [c for c in transfer_csv(folder) if c["row"] in MOVING_ROWS]
        ten = [100 * float(c["success_rate"]) for c in moving if not c["column"].startswith("PyFlyt")]
        assert close(low, min(ten), 0.051) and close(high, max(ten), 0.051), seed
        pyflyt = {"PyFlyt Crazyflie": (old_arc, old_line), "PyFlyt Crazyflie 0.22": (new_arc, new_line)}
        for column, shown_rates in pyflyt.items():
            rates = [100 * float(c["success_rate"]) for c in moving if c["column"] == column]
            assert all(close(a, b, 0.051) for a, b in zip(shown_rates, rates, strict=True)), (seed, column)
        assert low >= 90.0, (seed, low)  # the issue's moving target, in every Crazyflie-like column
    draws = [(seed, kind, suffix) for seed in "12" for kind, suffix in (("PyBullet", ""), ("PyFlyt", "-pyflyt-moving"))]
    for seed, kind, suffix in draws:
        pattern = rf"^seed {seed} with auto, 40 random {kind} draws: (\d+) / (\d+) variants"
        [(arc, line)] = re.findall(pattern, shown.text, re.M)
        cells = read_csv(RESULTS / "variants" / f"{paper}-seed{seed}{suffix}-lead-auto" / "variants.csv")
        landed = [sum(float(c["success_rate"]) >= 0.9 for c in cells if c["row"] == row) for row in MOVING_ROWS]
        assert [int(arc), int(line)] == landed, (seed, kind)
    pattern = r"^seed (\d) through the filter's pad-frame settings \(the file's lead, 30 s\): "
    pattern += r"(\d+) of (\d+) moving cells at 90 % or more, (\S+)-(\S+) %$"
    filtered = shown.numbers(pattern)
    assert [seed for seed, *_ in filtered] == [1, 2], filtered
    for seed, count, total, low, high in filtered:
        rates = [float(c["success_rate"]) for c in transfer_csv(f"{paper}-seed{int(seed)}-wide-climb-filter-30s")]
        assert total == len(rates) == 24 and count == sum(r >= 0.9 for r in rates), seed
        assert close(low, 100 * min(rates), 0.051) and close(high, 100 * max(rates), 0.051), seed
    pattern = r"^point mass with a (\S+) s velocity loop, line at 0.5 m/s, lead (\S+): (\d+) of \d+ .*flown (\S+) s$"
    found = re.findall(pattern, shown.text, re.MULTILINE)
    live = {(float(tau), lead): (int(landed), float(flown)) for tau, lead, landed, flown in found}
    assert len(live) == 6, live
    assert live[0.142, "auto"][1] < 0.25 < 0.4 < live[0.8, "auto"][1], live
    assert live[0.8, "auto"][0] >= live[0.8, "0.3"][0], live


def check_08_rotorpy_variants(shown: Shown) -> None:
    """Section 4za: the moving fine-tune's counts on the 40 random Crazyflies of each simulator are the shipped csvs';
    RotorPy's steady sink with a mass its controller does not know, worked by hand: g (1.2 - 1) / k_v."""
    pattern = r"^40 random (?:PyBullet|PyFlyt|RotorPy) Crazyflies, (\S+): (\d+) / (\d+) of 40"
    landed = shown_variant_counts(shown, pattern)
    assert len(landed) == 3 and "paper-moving-slow-trackers-fast-vertical-rotorpy-moving-lead-auto" in landed, landed
    assert "asked to hover: sinks at 0.196 m/s" in shown.text


def check_08_vertical_bias(shown: Shown) -> None:
    """Section 4zb: the RotorPy draw's counts without and with the vertical bias cancelled are the shipped csvs'; the
    light variants land more episodes with it; flown here, the light drone lands with it and hovers without."""
    landed = shown_variant_counts(shown, r"^RotorPy, (\S+): (\d+) / (\d+) of 40")
    assert len(landed) == 2 and any(folder.endswith("-vertical-bias") for folder in landed), landed
    light_lines = r"^    the 6 lighter than 0.92 x, \S+ 0.2-0.5 m/s: (\S+) %"
    light = [float(p) for p in re.findall(light_lines, shown.text, re.MULTILINE)]
    assert len(light) == 4 and light[2] > light[0] and light[3] > light[1], light
    flown = re.findall(r"floor, vertical bias (left|cancelled): (\d+) of (\d+) landed", shown.text)
    assert [m[0] for m in flown] == ["left", "cancelled"], flown
    assert int(flown[0][1]) == 0 and int(flown[1][1]) == int(flown[1][2]) >= 1, flown


def check_08_stiff_loops(shown: Shown) -> None:
    """Section 4zc: the stiff RotorPy draw's counts for the moving fine-tune and its continuation on the stiff corner
    are the shipped csvs', and the continuation lands more of them; flown here, more on the point mass's corner."""
    landed = shown_variant_counts(shown, r"^stiff RotorPy, (\S+): (\d+) / (\d+) of 16")
    before, after = (
        landed[f"{name}-rotorpy-stiff"]
        for name in ("paper-moving-slow-trackers-fast-vertical", "paper-moving-stiff-loops")
    )
    assert after[0] > before[0] and after[1] > before[1], landed
    flown = dict(
        re.findall(
            r"^(\S+) on the point mass, 0.06 s loop, 0.15 s attitude, 80 ms, line: (\d+) of \d+", shown.text, re.M
        )
    )
    assert int(flown["paper-moving-stiff-loops"]) > int(flown["paper-moving-slow-trackers-fast-vertical"]), flown


def check_08_two_corners(shown: Shown) -> None:
    """Section 4zd: the two-corner policy's stiff RotorPy counts are its shipped csv's and within one variant of the
    stiff-loops policy's; the slow cells printed are the shipped matrices', and it lands PyFlyt 0.22's line more than
    the stiff-loops policy; the counts printed for seeds 0 and 1 are their shipped matrices'."""
    landed = shown_variant_counts(shown, r"^stiff RotorPy, (\S+): (\d+) / (\d+) of 16")
    stiff, both = landed["paper-moving-stiff-loops-rotorpy-stiff"], landed["paper-moving-two-corners-rotorpy-stiff"]
    assert all(b >= s - 1 for s, b in zip(stiff, both, strict=True)), landed
    printed = dict(re.findall(r"^(paper-moving-\S+): PyFlyt Crazyflie 0.22, line ([\d.]+) %", shown.text, re.M))
    for name in ("paper-moving-stiff-loops", "paper-moving-two-corners"):
        cells = read_csv(RESULTS / "transfer" / name / "transfer.csv")
        line = next(c for c in cells if (c["row"], c["column"]) == ("line 0.2-0.5 m/s", "PyFlyt Crazyflie 0.22"))
        assert float(printed[name]) == pytest.approx(100 * float(line["success_rate"]), abs=0.05), printed
    assert float(printed["paper-moving-two-corners"]) > float(printed["paper-moving-stiff-loops"]), printed
    pattern = (
        r"^(paper-moving-two-corners(?:-seed1)?): moving cells at 90 % or more (\d+) of 24, static cells at 95 % or "
        r"more (\d+) of 24; worst moving cell ([\d.]+) %"
    )
    seeds = re.findall(pattern, shown.text, re.M)
    assert [name for name, *_ in seeds] == ["paper-moving-two-corners", "paper-moving-two-corners-seed1"], seeds
    for name, moving, static, worst in seeds:
        cells = read_csv(RESULTS / "transfer" / name / "transfer.csv")
        rates = {
            row: [float(c["success_rate"]) for c in cells if c["row"] in row]
            for row in (MOVING_ROWS, ("floor", "UR10"))
        }
        assert int(moving) == sum(r >= 0.9 for r in rates[MOVING_ROWS]), name
        assert int(static) == sum(r >= 0.95 for r in rates["floor", "UR10"]), name
        assert float(worst) == pytest.approx(100 * min(rates[MOVING_ROWS]), abs=0.05), name


def check_08_two_corners_random(shown: Shown) -> None:
    """Section 4ze: the 40-variant counts printed for the two-corner policy (its seed 1, and in RotorPy its flight with
    the vertical bias cancelled) are the shipped csvs'; each kind of drone printed is counted from the csv's drawn
    values again here, and the kinds make up the whole draw; each seed lands more RotorPy drones than the fine-tune."""
    pattern = r"^random (?:PyFlyt|RotorPy) draw, (\S+): (\d+) / (\d+) of 40"
    landed = shown_variant_counts(shown, pattern)
    two_corners = {
        f"paper-moving-two-corners-{draw}"
        for draw in (
            "pyflyt-moving-lead-auto",
            "rotorpy-moving-lead-auto",
            "seed1-rotorpy-moving-lead-auto",
            "seed1-pyflyt-moving-lead-auto",
            "rotorpy-moving-lead-auto-vertical-bias",
        )
    }
    assert two_corners <= set(landed), landed

    def light(c: dict) -> bool:
        return float(c["mass_scale"]) < 0.92

    def stiff(c: dict) -> bool:
        return float(c["outer_gain_scale"]) > 1.15

    kinds = {  # the notebook's split, restated from the csv's own columns
        "0.21.0 order": lambda c: c["controller"] == "pyflyt 0.21.0",
        "0.22 order": lambda c: c["controller"] == "pyflyt 0.22",
        "lighter than 0.92 x": light,
        "stiff (velocity gain over x1.15)": lambda c: not light(c) and stiff(c),
        "the others": lambda c: not light(c) and not stiff(c),
    }
    block = r"^random \w+ draw, {}: .*\n((?:    .*\n)+)"
    for folder in two_corners:
        cells = read_csv(RESULTS / "variants" / folder / "variants.csv")
        printed = re.search(block.format(re.escape(folder)), shown.text, re.M)
        assert printed, folder
        found = re.findall(r"^    (.+), (\d+) drones: (\d+) / (\d+) at 90 % or more", printed.group(1), re.M)
        assert sum(int(n) for _, n, _, _ in found) == 40, found
        for kind, drones, arc, line in found:
            mine = [c for c in cells if kinds[kind](c)]
            counts = [sum(float(c["success_rate"]) >= 0.9 for c in mine if c["row"] == row) for row in MOVING_ROWS]
            assert (int(drones), [int(arc), int(line)]) == (len(mine) // 2, counts), (folder, kind)
    before = landed["paper-moving-slow-trackers-fast-vertical-rotorpy-moving-lead-auto"]
    for seed in ("", "-seed1"):  # the section's claim: each seed lands more RotorPy drones than the fine-tune
        after = landed[f"paper-moving-two-corners{seed}-rotorpy-moving-lead-auto"]
        assert all(a > b for a, b in zip(after, before, strict=True)), landed


def check_08_auto_trained(shown: Shown) -> None:
    """Section 4z: the policy trained with the lead set in flight flies it by itself (its file's share); the counts it
    prints are the shipped csvs'; flown here, its own lead leads a slow point mass by more than a fast one."""
    paper = "paper-moving-slow-trackers-fast-vertical"
    assert re.search(rf"^{paper}-auto-lead: its file carries pad_frame_lead_share 0.6: it flies auto", shown.text, re.M)
    pattern = r"^\| (0.5 s|auto) \| auto \| (\d+) of 24 \| [^|]+ \| [^|]+ \| (\d+) of 24 \|$"
    found = {trained: (int(moving), int(static)) for trained, moving, static in re.findall(pattern, shown.text, re.M)}
    folders = {"0.5 s": (f"{paper}-lead-auto", paper), "auto": (f"{paper}-auto-lead", f"{paper}-auto-lead")}
    assert set(found) == set(folders), found
    for trained, (moving_folder, static_folder) in folders.items():
        moving = [c for c in transfer_csv(moving_folder) if c["row"] in MOVING_ROWS]
        static = [c for c in transfer_csv(static_folder) if c["row"] in ("floor", "UR10")]
        counts = (
            sum(float(c["success_rate"]) >= 0.9 for c in moving),
            sum(float(c["success_rate"]) >= 0.95 for c in static),
        )
        assert found[trained] == counts, (trained, found[trained], counts)
    pattern = r"^40 random PyBullet draws, trained with (0.5 s|auto), flown with auto: (\d+) / (\d+) variants"
    printed = re.findall(pattern, shown.text, re.M)
    assert sorted(trained for trained, _, _ in printed) == ["0.5 s", "auto"], printed
    for trained, arc, line in printed:
        cells = read_csv(RESULTS / "variants" / folders[trained][0] / "variants.csv")
        landed = [sum(float(c["success_rate"]) >= 0.9 for c in cells if c["row"] == row) for row in MOVING_ROWS]
        assert [int(arc), int(line)] == landed, trained
    pattern = r"^trained with auto, its own lead, on the point mass with a (\S+) s loop .*: (\d+) of \d+ landed, lead "
    pattern += r"flown (\S+) s$"
    live = {float(tau): (int(landed), float(flown)) for tau, landed, flown in re.findall(pattern, shown.text, re.M)}
    assert set(live) == {0.142, 0.8} and live[0.142][1] < 0.25 < 0.4 < live[0.8][1], live


def shown_fine_tune_counts(shown: Shown, name: str) -> float:
    """Check the line a notebook prints for a moving fine-tune's matrix (its static cells at 95 %, moving cells at 90 %,
    worst cells and largest moving error) against its csv; returns the worst static cell (%)."""
    cells = transfer_csv(name)
    static = [c for c in cells if c["row"] in ("floor", "UR10")]
    moving = [c for c in cells if c["row"].startswith(("arc", "line"))]
    pattern = (
        rf"^{name}: static cells at 95 % or more (\d+) of (\d+), worst (\S+) %; moving cells at 90 % or more "
        r"(\d+) of (\d+), worst (\S+) % \(.+\); largest moving landing error (\S+) cm$"
    )
    [(static_95, n_static, static_worst, moving_90, n_moving, moving_worst, widest)] = shown.numbers(pattern)
    assert n_static == len(static) == 24 and n_moving == len(moving) == 24, name
    assert static_95 == sum(float(c["success_rate"]) >= 0.95 for c in static), name
    assert moving_90 == sum(float(c["success_rate"]) >= 0.9 for c in moving), name
    assert close(static_worst, 100 * min(float(c["success_rate"]) for c in static), 0.051), name
    assert close(moving_worst, 100 * min(float(c["success_rate"]) for c in moving), 0.051), name
    assert close(widest, max(float(c["landing_error_cm"]) for c in moving), 0.0051), name
    return static_worst


def transfer_csv(name: str) -> list[dict[str, str]]:
    """The cells of the shipped matrix ``data/results/transfer/NAME``."""
    return read_csv(RESULTS / "transfer" / name / "transfer.csv")


def shown_matrix_and_pyflyt_flight(shown: Shown, policy: str) -> list[float]:
    """Checks the lines a notebook prints for ``policy``'s shipped twelve-column matrix (its worst cell and largest
    landing error are the csv's) and for its live floor flight in PyFlyt 0.22 (at least half of the episodes land: 18
    and 20 of the first 20 in tests/test_transfer.py); returns the matrix's PyFlyt 0.22 success rates."""
    matrix = read_csv(RESULTS / "transfer" / policy / "transfer.csv")
    assert len(matrix) == 24 and len({c["column"] for c in matrix}) == 12
    [(worst,)] = shown.numbers(rf"^{policy} worst cell: (\S+) % \(.+\)$")
    assert close(worst, 100 * min(float(c["success_rate"]) for c in matrix), 0.051)
    [(widest,)] = shown.numbers(rf"^{policy} largest landing error: (\S+) cm$")
    assert close(widest, max(float(c["landing_error_cm"]) for c in matrix), 0.0051)
    [(landed, flown)] = shown.numbers(rf"^flown here: {policy} alone in PyFlyt 0.22, floor: (\d+) of (\d+)")
    assert flown >= 2 and landed >= 0.5 * flown
    return [float(c["success_rate"]) for c in matrix if c["column"] == "PyFlyt Crazyflie 0.22"]


def check_09(shown: Shown) -> None:
    # A drone sinking straight down onto a 15-degree pad: its in-plane offset, worked by hand in the cell.
    [(error, expected)] = shown.numbers(r"landing error (\S+) cm \(landed_height x tan 15 deg = (\S+) cm\)")
    assert close(error, expected, 0.001) and close(expected, 1.25 * math.tan(math.radians(15.0)), 0.001)
    assert "landed [True, True]" in shown.text
    # The full-budget tables are shown, each with the command that flew it.
    shown_tables = "\n".join(shown.markdown)
    for stem in ("inclined", "fast"):
        assert f"**{stem}**" in shown_tables
    assert "static-floor tilt 15 deg" in shown_tables

    def tilted(stem: str, controller: str, n: int) -> dict[str, float]:
        """Success % by platform of one controller and swarm size in the shipped table ``stem``."""
        section = shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0]
        return {
            row["platform"]: first_number(row["success % [95 % CI]"])
            for row in markdown_rows(section)
            if row["controller"] == controller and row["N"] == str(n)
        }

    steep = "static-floor tilt 15 deg"
    # The quick preset's policy lands at 15 degrees on both simulators, where v0.2's quick-cpu loses the point mass.
    assert tilted("inclined_quick_cpu_smooth", "centralised", 2)[steep] >= 95.0
    assert tilted("crazyflie_firmware_inclined_quick_cpu_smooth", "centralised", 2)[steep] >= 95.0
    assert tilted("inclined", "centralised", 2)[steep] < 90.0
    # The shared policy alone, pads 0.35 m apart: >= 90 % at every tilt and size on the point mass and up to N = 8 in
    # PyBullet; at N = 16 on the 15-degree plate PyBullet's drones touch the plate with their rims (docs/scaling.md),
    # and the safety filter lands that cell.
    for stem, sizes in (
        ("inclined_shared_paired_spacing_35cm", (2, 4, 8, 16)),
        ("crazyflie_firmware_inclined_shared_paired_spacing_35cm", (2, 8)),
    ):
        for n in sizes:
            cells = tilted(stem, "shared", n)
            assert len(cells) == 4 and min(cells.values()) >= 90.0, (stem, n, cells)
    rim = tilted("crazyflie_firmware_inclined_shared_paired_spacing_35cm", "shared", 16)
    guarded = tilted("crazyflie_firmware_inclined_shared_paired_filter_spacing_35cm", "shared-filter", 16)
    assert rim[steep] < 80.0 <= min(rim[p] for p in rim if p != steep) and guarded[steep] >= 90.0, (rim, guarded)
    # The steeper approach cone (shared-quick-cone2) lands every size and tilt of the 0.35 m layout alone, >= 90 % in
    # PyBullet (N = 16 at 15 degrees, where shared-quick-paired touches the plate) and >= 95 % on the point mass.
    assert "**shared-quick-cone2, pads 0.35 m apart, 15 degrees**" in shown_tables  # the live cell, on this budget
    for stem, sizes, floor in (
        ("crazyflie_firmware_inclined_cone2_spacing_35cm", (2, 8, 16), 90.0),
        ("inclined_cone2_spacing_35cm", (2, 4, 8, 16), 95.0),
    ):
        for n in sizes:
            cells = tilted(stem, "shared", n)
            assert len(cells) == 4 and min(cells.values()) >= floor, (stem, n, cells)
    assert tilted("crazyflie_firmware_inclined_cone2_spacing_35cm", "shared", 16)[steep] > rim[steep]
    # On the 0.25 m grid the two land the same share of 300 8-drone swarms through the firmware tracker (each inside
    # the other's interval), as do the recipe's other two seeds; the figure's printed lines read those tables.
    n8 = {}
    for name, stem in (
        ("shared-quick-paired", "crazyflie_firmware_paired_n8_300"),
        ("shared-quick-cone2", "crazyflie_firmware_cone2_n8_300"),
        ("shared-quick-cone2-seed1", "crazyflie_firmware_cone2_seed1_n8_300"),
        ("shared-quick-cone2-seed2", "crazyflie_firmware_cone2_seed2_n8_300"),
        ("shared-quick-slow-trackers", "crazyflie_firmware_slow_trackers_n8_300"),
        ("shared-quick-slow-trackers-default-family", "crazyflie_firmware_slow_trackers_default_family_n8_300"),
        ("shared-quick-thin-cushion", "crazyflie_firmware_thin_cushion_n8_300"),
        ("shared-quick-slow-trackers-thin-cushion", "crazyflie_firmware_slow_trackers_thin_cushion_n8_300"),
        ("shared-quick-larger-swarms", "crazyflie_firmware_larger_swarms_n8_300"),
    ):
        [row] = markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
        assert row["N"] == "8" and row["trials"] == "300", (stem, row)
        success, low, high = (float(x) for x in re.findall(r"[\d.]+", row["success % [95 % CI]"]))
        assert success >= 85.0, (stem, row)
        [(printed,)] = shown.numbers(rf"PyBullet firmware, N = 8, 300 trials, {name}: (\S+) %")
        assert printed == success, (name, printed, success)
        n8[name] = (success, low, high)
    paired, cone = n8["shared-quick-paired"], n8["shared-quick-cone2"]
    assert paired[1] <= cone[0] <= paired[2] and cone[1] <= paired[0] <= cone[2], n8
    # Smooth commands for slower trackers: more 8-drone swarms land through the firmware tracker than with
    # shared-quick-cone2, the two intervals apart, and alone the policy collides in no trial at any N on the point mass.
    assert "**shared-quick-slow-trackers, pads 0.25 m apart**" in shown_tables  # the live cell, on this budget
    assert n8["shared-quick-slow-trackers"][1] > cone[2] and n8["shared-quick-slow-trackers"][0] >= 95.0, n8
    alone = [
        row
        for row in markdown_rows(shown_tables.split("**scaling_slow_trackers**", 1)[1].split("**", 1)[0])
        if row["controller"] == "shared"
    ]
    assert [row["N"] for row in alone] == ["2", "4", "8", "16"]
    assert all(first_number(row["collisions % [95 % CI]"]) == 0.0 for row in alone), alone
    # Stage 10, back on the default family, lands the point mass's 8-drone swarms alone again (>= 95 %), without a
    # collision, where stage 9 touched down too fast in 7.5 % of them.
    home = {
        row["N"]: row
        for row in markdown_rows(shown_tables.split("**scaling_slow_trackers_default_family**", 1)[1].split("**", 1)[0])
        if row["controller"] == "shared"
    }
    assert first_number(home["8"]["success % [95 % CI]"]) >= 95.0 > first_number(alone[2]["success % [95 % CI]"])
    assert all(first_number(row["collisions % [95 % CI]"]) == 0.0 for row in home.values()), home
    # Stage 12 on the thin cushion lands the 16-drone swarms (never trained on) alone, >= 95 % on the point mass where
    # stage 10 lands under 90 %, and >= 95 % of 300 firmware swarms of 8; the live cell on this budget is shown.
    # So do stage 13 on the slow trackers with the thin cushion and stage 14 on swarms of 4 and 8.
    for name, stem in (
        ("shared-quick-thin-cushion", "scaling_thin_cushion"),
        ("shared-quick-slow-trackers-thin-cushion", "scaling_slow_trackers_thin_cushion"),
        ("shared-quick-larger-swarms", "scaling_larger_swarms"),
    ):
        assert f"**{name} alone, pads 0.25 m apart**" in shown_tables
        thin = {
            row["N"]: row
            for row in markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
            if row["controller"] == "shared"
        }
        thin16, home16 = (first_number(rows["16"]["success % [95 % CI]"]) for rows in (thin, home))
        assert thin16 >= 95.0 > 90.0 > home16, (name, thin16, home16)
        assert all(first_number(row["collisions % [95 % CI]"]) == 0.0 for row in thin.values()), thin
        assert n8[name][0] >= 95.0, n8
    [(on_pads, safe)] = re.findall(
        r"16-drone example lab, point mass, shared-quick-larger-swarms: (\d+) of 16 on their pads, closest two drones "
        r"\S+ m, safe (\w+)",
        shown.text,
    )
    assert int(on_pads) >= 15 and safe == "True", (on_pads, safe)
    # A UR10 swing at 1.0 m/s: the shipped point-mass table meets the issue's 80 % aim through the filter only.
    fast = {
        row["controller"]: first_number(row["success % [95 % CI]"])
        for row in markdown_rows(shown_tables.split("**fast_moving_smooth_filter**", 1)[1].split("**", 1)[0])
        if row["platform"] == "moving-arc-1"
    }
    assert fast["centralised-filter"] >= 80.0 > fast["centralised"], fast
    assert "| centralised-filter | moving-arc-1 | 2 |" in shown_tables  # the live cell, on this budget
    assert "**crazyflie_firmware_fast_moving_smooth_filter**" in shown_tables
    # With the pad lead, the firmware tracker keeps up at 0.75 m/s, where the filter without it lands under half.
    led, unled = (
        {
            row["platform"]: first_number(row["success % [95 % CI]"])
            for row in markdown_rows(
                shown_tables.split(f"**crazyflie_firmware_fast_moving_smooth_filter_{s}**", 1)[1].split("**", 1)[0]
            )
            if row["controller"] == "centralised-filter"
        }
        for s in ("pad_lead", "sink_limit")
    )
    assert led["moving-arc-0.75"] >= 90.0 and unled["moving-arc-0.75"] < 50.0, (led, unled)
    assert led["moving-arc-1"] > unled["moving-arc-1"], (led, unled)
    # With the latency compensation as well, the firmware tracker lands the 1.0 m/s arc at the issue's 80 % aim.
    compensated = {
        row["platform"]: first_number(row["success % [95 % CI]"])
        for row in markdown_rows(
            shown_tables.split("**crazyflie_firmware_fast_moving_smooth_filter_latency**", 1)[1].split("**", 1)[0]
        )
        if row["controller"] == "centralised-filter"
    }
    assert compensated["moving-arc-1"] >= 80.0 > led["moving-arc-1"], (compensated, led)
    # Commands relative to the pad, alone (moving-slow-trackers): far above the world-frame policy alone at every speed
    # on both simulators, under the 80 % aim at 1.0 m/s.
    for stem, before in (
        ("fast_moving_slow_trackers", "fast_moving_smooth_filter"),
        ("crazyflie_firmware_fast_moving_slow_trackers", "crazyflie_firmware_fast_moving_smooth_filter"),
    ):
        rows = markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
        pad_frame = {row["platform"]: first_number(row["success % [95 % CI]"]) for row in rows}
        alone = {
            row["platform"]: first_number(row["success % [95 % CI]"])
            for row in markdown_rows(shown_tables.split(f"**{before}**", 1)[1].split("**", 1)[0])
            if row["controller"] == "centralised"
        }
        assert set(pad_frame) == set(alone) == {"moving-arc-0.5", "moving-arc-0.75", "moving-arc-1"}, stem
        assert all(pad_frame[p] > alone[p] for p in alone) and pad_frame["moving-arc-1"] < 80.0, (pad_frame, alone)

    def rates_at_1_m_s(stem: str) -> dict[str, float]:
        """Success % per controller on the 1.0 m/s arc of the shown table ``stem``."""
        return {
            row["controller"]: first_number(row["success % [95 % CI]"])
            for row in markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
            if row["platform"] == "moving-arc-1"
        }

    # ... and through the filter with the velocity step that follows the tracker: the 80 % aim at 1.0 m/s on the point
    # mass, not through the firmware tracker, where the filtered flights crash more than the policy alone.
    point_mass, firmware = (
        rates_at_1_m_s(stem)
        for stem in (
            "fast_moving_slow_trackers_tracker_step_filter",
            "crazyflie_firmware_fast_moving_slow_trackers_tracker_step_filter",
        )
    )
    assert point_mass["centralised-filter"] >= 80.0 > point_mass["centralised"], point_mass
    assert firmware["centralised-filter"] < firmware["centralised"] < 80.0, firmware
    # Through the filter's pad-frame settings (the climb and the 6 cm cone tip as well) the firmware tracker's crashes
    # at 1.0 m/s give way, and with the latency compensation identified in flight it meets the 80 % aim there too.
    wide = {
        stem: rates_at_1_m_s(stem)
        for stem in (
            "fast_moving_slow_trackers_wide_climb_filter",
            "crazyflie_firmware_fast_moving_slow_trackers_wide_climb_filter",
            "fast_moving_slow_trackers_wide_climb_filter_identified_lag",
            "crazyflie_firmware_fast_moving_slow_trackers_wide_climb_filter_identified_lag",
        )
    }
    pm_wide, fw_wide, pm_identified, fw_identified = (cells["centralised-filter"] for cells in wide.values())
    assert fw_wide > firmware["centralised"] > firmware["centralised-filter"], (fw_wide, firmware)
    assert fw_identified >= 80.0 and pm_wide >= 80.0 and pm_identified >= 80.0, wide
    # The late-command fine-tunes (both networks) flown with a 0.3 s lead (trained with 0.5 s): the 80 % aim at 1.0 m/s
    # alone on both simulators, nearer the pad centre than the fine-tune before alone at every speed.
    for stem, before in (
        ("fast_moving_slow_trackers_fast_vertical_lead_0.3", "fast_moving_slow_trackers"),
        (
            "crazyflie_firmware_fast_moving_slow_trackers_fast_vertical_lead_0.3",
            "crazyflie_firmware_fast_moving_slow_trackers",
        ),
        ("fast_paper_moving_slow_trackers_fast_vertical_lead_0.3", "fast_moving_slow_trackers"),
        (
            "crazyflie_firmware_fast_paper_moving_slow_trackers_fast_vertical_lead_0.3",
            "crazyflie_firmware_fast_moving_slow_trackers",
        ),
    ):
        led, earlier = (
            {
                row["platform"]: (
                    first_number(row["success % [95 % CI]"]),
                    first_number(row["landing error cm [95 % CI]"]),
                )
                for row in markdown_rows(shown_tables.split(f"**{name}**", 1)[1].split("**", 1)[0])
                if row["controller"] == "centralised"
            }
            for name in (stem, before)
        )
        assert "--pad-frame-lead 0.3" in shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0], stem
        assert led["moving-arc-1"][0] >= 80.0 > earlier["moving-arc-1"][0], (led, earlier)
        assert all(led[p][1] < earlier[p][1] for p in earlier), (led, earlier)
    # With the lead set in flight (auto) the paper's fine-tune keeps the 80 % aim at 1.0 m/s on both simulators, all
    # three seeds of its recipe.
    for stem in (
        f"{prefix}fast_paper_moving_slow_trackers_fast_vertical{seed}_lead_auto"
        for seed in ("", "_seed1", "_seed2")
        for prefix in ("", "crazyflie_firmware_")
    ):
        table = shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0]
        assert "--pad-frame-lead auto" in table, stem
        alone = {row["platform"]: row for row in markdown_rows(table) if row["controller"] == "centralised"}
        assert first_number(alone["moving-arc-1"]["success % [95 % CI]"]) >= 80.0, stem
    assert "**crazyflie_firmware_filter**" in shown_tables
    # The tables of the filter as it is now, on both simulators, with the landing error under the paper's 2.26 cm.
    stems = ("scaling_filter_guard", "crazyflie_firmware_filter_guard")
    for stem in (*stems, "scaling_filter_sink_limit", "crazyflie_firmware_filter_sink_limit"):
        table = shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0]
        errors = [
            first_number(row["landing error cm [95 % CI]"])
            for row in markdown_rows(table)
            if row["controller"] == "shared-filter"
        ]
        assert errors and max(errors) <= 2.26, (stem, errors)
    # The held-out tracker (gym-pybullet-drones' published PID, no tilt limit): two drones through the filter land as
    # through the firmware tracker; the N = 8 swarm does not (docs/scaling.md says why).
    for stem in ("crazyflie_held_out_filter", "crazyflie_held_out_filter_velocity_step"):
        table = shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0]
        assert table.startswith("\n\ncrazyflie (held-out tracker), "), stem
        pairs = [r for r in markdown_rows(table) if r["controller"] == "shared-filter" and r["N"] == "2"]
        assert len(pairs) == 1 and first_number(pairs[0]["success % [95 % CI]"]) >= 95.0, (stem, pairs)
    # The safety filter's head-on pair: each closes at gamma/2 (d - d_s) = 2 (0.5 - 0.19) m/s at most, and the
    # pair flown with velocity = command stays at the 0.19 m safety distance (collision: 0.15 m).
    [(limit,)] = shown.numbers(r"each may close at most gamma/2 \(d - d_s\) = (\S+) m/s")
    assert close(limit, 0.62, 0.001)
    [(closest,)] = shown.numbers(r"closest approach (\S+) m")
    assert closest >= 0.185
    # Pairing starts with pads: the straight paths of 8 random starts cross far less often, and the shipped
    # shared-quick-paired table shows the policy alone at the N = 8 target with the pairing, and colliding without it.
    [(fixed_crossings, paired_crossings)] = shown.numbers(
        r"mean crossings per swarm of 8 over 1000 draws: fixed (\S+), shortest (\S+)"
    )
    assert fixed_crossings > 5 * paired_crossings
    for label in ("shared-quick-drone-ends", "shared-quick-paired"):
        for pairing in ("fixed", "shortest"):
            assert f"**{label}, {pairing} pairing**" in shown_tables
    paired_table, fixed_table = (
        {
            (row["controller"], row["N"]): row
            for row in markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
        }
        for stem in ("scaling_paired", "scaling_paired_fixed_pairs")
    )
    alone, unpaired = paired_table[("shared", "8")], fixed_table[("shared", "8")]
    assert first_number(alone["success % [95 % CI]"]) >= 95.0 > first_number(unpaired["success % [95 % CI]"])
    assert first_number(alone["landing error cm [95 % CI]"]) <= 2.26
    assert first_number(unpaired["collisions % [95 % CI]"]) > 10 * first_number(alone["collisions % [95 % CI]"])
    for stem in ("crazyflie_firmware_paired", "crazyflie_pid_paired", "crazyflie_held_out_paired"):
        assert f"**{stem}**" in shown_tables
    # Pad spacing: the same policy alone, pads 0.35 m apart, meets the swarm targets the 0.25 m grid misses alone.
    assert "**pads 0.25 m apart**" in shown_tables and "**pads 0.35 m apart**" in shown_tables
    wide_point_mass, wide_pybullet = (
        {
            row["N"]: row
            for row in markdown_rows(shown_tables.split(f"**{stem}**", 1)[1].split("**", 1)[0])
            if row["controller"] == "shared"
        }
        for stem in ("scaling_paired_spacing_35cm", "crazyflie_firmware_paired_spacing_35cm")
    )
    assert first_number(wide_point_mass["8"]["success % [95 % CI]"]) >= 95.0
    assert first_number(wide_point_mass["16"]["success % [95 % CI]"]) >= 90.0
    assert all(first_number(wide_point_mass[n]["collisions % [95 % CI]"]) <= 1.0 for n in ("8", "16"))
    assert first_number(wide_pybullet["8"]["success % [95 % CI]"]) >= 90.0
    assert first_number(paired_table[("shared", "16")]["success % [95 % CI]"]) < 90.0  # the 0.25 m grid, alone
    for stem in ("scaling_paired_filter_spacing_35cm", "crazyflie_firmware_paired_filter_spacing_35cm"):
        assert f"**{stem}**" in shown_tables
    # Touchdown speeds: 40 ms of latency pushes lone drones of the shipped policy over the 0.5 m/s limit, which the
    # filter with settled_sink_limit 0.4 keeps them under.
    over = {
        (label, flown): (count, total)
        for label, flown, count, total in re.findall(
            r"^(nominal|latency 0.04 s), (alone|filter, settled_sink_limit 0.4): median \S+ m/s, largest \S+ m/s, "
            r"above 0.5 m/s: (\d+) of (\d+)$",
            shown.text,
            re.MULTILINE,
        )
    }
    assert len(over) == 4, over
    assert int(over[("latency 0.04 s", "alone")][0]) >= 0.2 * int(over[("latency 0.04 s", "alone")][1]), over
    assert over[("latency 0.04 s", "filter, settled_sink_limit 0.4")][0] == "0", over
    # The lab loop pairs the drones with pads at take-off: the 8-drone rehearsal swaps some pads and lands every drone
    # on the one it was given, within the pad radius by the simulator's truth.
    [line] = re.findall(r"Pads paired with the drones by the shortest paths: (.*)\.", shown.text)
    assert line.count(" -> ") == 8 and line.count("(as configured)") < 8, line
    [(landed, gap)] = shown.numbers(
        r"on their paired pads: (\d+) of 8 \(simulator truth: largest distance from the pad centre (\S+) cm\)"
    )
    assert landed == 8 and gap < 10.0
    # The two engines of the point-mass swarm fly the same random actions to the same bits, and the benchmark's
    # latest figures are shown beside the live timing.
    assert "swarms x 16 drones, 7 steps: the same bits on both engines: True" in shown.text
    assert re.search(r"bench_pointmass_2026-\d\d-\d\d(-[a-z]+)?\.txt:\n", shown.text)
    assert "Target: >= 5 at both sizes." in shown.text
    # The 16-drone PyBullet step: timed live against the bare loop (it cannot cost less than the loop it runs), and
    # the latest benchmark's 16-drone rows as the file has them.
    [(step_us, ratio)] = shown.numbers(
        r"^16 drones, PID, bare physics, timed here: step (\S+) us, (\S+) x the bare loop"
    )
    assert step_us > 0 and ratio > 1.0
    latest = max((ROOT / "benchmarks" / "results").glob("bench_crazyflie_2*.txt"))
    rows = [line for line in latest.read_text().splitlines() if line.startswith("    16 ") and " numba " in line]
    assert len(rows) == 4 and f"{latest.name}:\n" in shown.text and all(row in shown.text for row in rows)


VALUE_CHECKS: dict[str, Callable[[Shown], None]] = {
    "00_overview.ipynb": check_00,
    "01_mdp_and_pointmass.ipynb": check_01,
    "02_crazyflie_pybullet.ipynb": check_02,
    "03_training_ppo.ipynb": check_03,
    "04_static_platform.ipynb": check_04,
    "05_moving_platform.ipynb": check_05,
    "06_baselines.ipynb": check_06,
    "08_transfer.ipynb": check_08,
    "09_scaling.ipynb": check_09,
}
"""Values each notebook must show, against data it did not compute (notebook 07 checks only EXPECTED_TEXT)."""


def test_every_notebook_is_listed_here():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(EXPECTED_TEXT)
    assert set(VALUE_CHECKS) <= set(EXPECTED_TEXT)


@pytest.mark.parametrize("name", sorted(EXPECTED_TEXT))
def test_notebook_is_committed_without_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)
    # nbformat 4.5 cells carry ids (a missing one is a warning now, an error in future nbformat versions).
    raw = json.loads((NOTEBOOKS / name).read_text())
    assert all("id" in cell for cell in raw["cells"]), f"{name}: a cell without an id"


@pytest.mark.slow
@pytest.mark.notebooks
@pytest.mark.parametrize("name", sorted(EXPECTED_TEXT))
def test_notebook_runs_with_the_small_budget(name, executed_notebook):
    nb = nbformat.read(executed_notebook(name), as_version=4)  # run once per session (conftest.executed_notebook)
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    for expected in EXPECTED_TEXT[name]:
        assert expected in text, f"{name} did not print {expected!r}"
    if name in VALUE_CHECKS:
        VALUE_CHECKS[name](Shown.of(nb))
