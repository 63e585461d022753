"""The transfer targets checked on a matrix: hand-built cells, a shipped matrix read from its CSV, the command line."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import pytest

from marlander_lite.cli import main
from marlander_lite.experiments import targets
from marlander_lite.experiments.transfer import CellResult, read_results

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "data" / "results" / "transfer" / "paper-moving-slow-trackers-fast-vertical-seed2-lead-auto"


def cell(row: str, column: str, **values: float) -> CellResult:
    """A cell that meets every target unless ``values`` say otherwise."""
    good = {
        "episodes": 200, "successes": 200, "success_rate": 1.0, "wilson_low": 0.98, "wilson_high": 1.0,
        "landing_error_cm": 1.0, "landing_time_s": 5.0, "collision_rate": 0.0, "touchdown_speed": 0.1,
        "command_near_pad_p95": 0.4, "tilt_limit_fraction": 0.01, "approach_height": 1.0, "wall_s": 1.0,
    }  # fmt: skip
    return CellResult(row=row, column=column, **{**good, **values})


def by_target(checks: list[targets.TargetCheck]) -> dict[str, targets.TargetCheck]:
    return {c.target: c for c in checks}


def test_the_bounds_are_the_papers_and_the_issues() -> None:
    """MARLander's 2.26 cm (Table I) and 3.93 cm (Table II); the issue's 90 / 95 %, 0.3 m/s, 1.5 m/s and 0.3 m."""
    paper = targets.PAPER_AND_MOVING_TARGETS
    assert (paper.static_error_cm, paper.moving_error_cm) == (2.26, 3.93)
    assert (paper.static_success, paper.static_wilson_low, paper.moving_success) == (0.95, 0.90, 0.90)
    quick = targets.QUICK_CPU_TARGETS
    assert (quick.static_success, quick.static_error_cm, quick.moving_success) == (0.90, 2.26, None)
    assert (paper.touchdown_speed, paper.command_near_pad, paper.approach_height) == (0.3, 1.5, 0.3)
    assert targets.TARGETS["paper"] is targets.TARGETS["moving"] is paper


def test_the_worst_cell_decides_and_every_miss_is_counted_with_its_column() -> None:
    cells = [
        cell("floor", "point mass", success_rate=0.96),
        cell("UR10", "point mass", success_rate=0.94, landing_error_cm=2.3),
        cell("floor", "PyFlyt Crazyflie", success_rate=0.93),
        cell("UR10", "PyFlyt Crazyflie"),
        cell("line 0.2-0.5 m/s", "point mass", success_rate=0.70, landing_error_cm=math.nan),
        cell("line 0.2-0.5 m/s", "PyFlyt Crazyflie", success_rate=0.91, landing_error_cm=3.9),
    ]
    checks = by_target(targets.check_targets(cells, targets.PAPER_AND_MOVING_TARGETS))
    success = checks["success, static rows"]
    assert (success.met, success.misses, success.cells) == (False, 2, 4)
    assert success.worst == 0.93 and success.where == "floor, PyFlyt Crazyflie"
    assert success.missed_columns == ("point mass", "PyFlyt Crazyflie")  # the matrix's order
    error = checks["landing error, static rows"]
    assert (error.met, error.misses, error.worst, error.where) == (False, 1, 2.3, "UR10, point mass")
    # No landing, no landing error: that cell misses and is shown first, whatever the others measured.
    moving_error = checks["landing error, moving rows"]
    assert moving_error.misses == 1 and math.isnan(moving_error.worst) and moving_error.where.endswith("point mass")
    assert checks["success, moving rows"].missed_columns == ("point mass",)
    # Only the given columns are judged.
    pyflyt = by_target(targets.check_targets(cells, targets.PAPER_AND_MOVING_TARGETS, ["PyFlyt Crazyflie"]))
    assert pyflyt["success, moving rows"].met and pyflyt["success, static rows"].worst == 0.93


def test_flight_targets_are_judged_on_the_firmware_columns_only() -> None:
    """A point-mass or PID cell that touches down fast does not count against the flight a Crazyflie follows; the
    same on a perturbed firmware column does."""
    fast = {"touchdown_speed": 0.9, "tilt_limit_fraction": 0.2, "approach_height": 0.1, "command_near_pad_p95": 2.0}
    cells = [
        cell("floor", "point mass", **fast),
        cell("floor", "PyBullet PID", **fast),
        cell("floor", "PyBullet firmware"),
    ]
    flight = [
        c for c in targets.check_targets(cells, targets.QUICK_CPU_TARGETS) if c.target.endswith("firmware columns")
    ]
    assert len(flight) == 4 and all(c.met and c.cells == 1 for c in flight)
    cells.append(cell("floor", "firmware latency 60 ms", touchdown_speed=0.31))
    checks = by_target(targets.check_targets(cells, targets.QUICK_CPU_TARGETS))
    touchdown = checks["touchdown speed, firmware columns"]
    assert not touchdown.met and touchdown.where == "floor, firmware latency 60 ms" and touchdown.cells == 2
    assert "firmware combined" in targets.FIRMWARE_COLUMNS and "held-out DSL PID" not in targets.FIRMWARE_COLUMNS


def test_rows_not_flown_are_not_judged_and_the_quick_preset_asks_nothing_of_moving_pads() -> None:
    static_only = [cell("floor", "point mass"), cell("UR10", "point mass")]
    checks = by_target(targets.check_targets(static_only, targets.PAPER_AND_MOVING_TARGETS))
    assert checks["success, moving rows"].met is None and checks["success, moving rows"].cells == 0
    assert "not flown" in targets.format_targets(static_only, targets.PAPER_AND_MOVING_TARGETS)
    quick = targets.check_targets(static_only, targets.QUICK_CPU_TARGETS)
    assert not any("moving" in c.target or "Wilson" in c.target for c in quick)


def test_a_shipped_matrix_checked_as_its_csv_says() -> None:
    """Seed 2 of the paper's network's moving fine-tune: the worst moving cell of every column, read straight from its
    CSV, is the PyFlyt 0.21.0-order line; over the issue's seven columns every target is met."""
    rows = list(csv.DictReader((SHIPPED / "transfer.csv").open()))
    moving = [r for r in rows if r["row"] in targets.MOVING_ROWS]
    worst = min(moving, key=lambda r: float(r["success_rate"]))
    below = [r for r in moving if float(r["success_rate"]) < 0.90]
    checks = by_target(targets.check_targets(read_results(SHIPPED / "transfer.json"), targets.PAPER_AND_MOVING_TARGETS))
    success = checks["success, moving rows"]
    assert success.worst == pytest.approx(float(worst["success_rate"]))
    assert success.where == f"{worst['row']}, {worst['column']}" and success.misses == len(below)
    assert success.cells == len(moving) == 24
    issue = targets.check_targets(
        read_results(SHIPPED / "transfer.json"), targets.PAPER_AND_MOVING_TARGETS, targets.ISSUE_COLUMNS
    )
    assert all(c.met for c in issue), [c for c in issue if not c.met]
    table = targets.format_targets(read_results(SHIPPED / "transfer.json"), targets.PAPER_AND_MOVING_TARGETS)
    assert "the issue's columns (7)" in table and "every column flown (12)" in table


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"static_success": 1.5}, "static_success is a share from 0 to 1"),
        ({"static_error_cm": 0.0}, "static_error_cm must be > 0"),
        ({"moving_error_cm": None}, "both moving_success and moving_error_cm"),
    ],
)
def test_bad_targets_are_refused(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(targets.PAPER_AND_MOVING_TARGETS, **changes)


def test_an_unknown_column_is_refused_with_the_matrix_columns() -> None:
    with pytest.raises(ValueError, match=r"No cells for column\(s\) \['PyBullet warp'\]; the matrix has: point mass"):
        targets.check_targets([cell("floor", "point mass")], targets.QUICK_CPU_TARGETS, ["PyBullet warp"])


@pytest.mark.slow
def test_transfer_command_prints_the_check_after_the_matrix(tmp_path, capsys) -> None:
    args = [
        "transfer", "data/policies/quick-cpu-slow-trackers-fast-vertical-20m.safetensors", "--episodes", "1",
        "--rows", "floor", "--columns", "point mass,PyBullet firmware", "--workers", "1", "--targets", "quick-cpu",
        "--out", str(tmp_path / "t"),
    ]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "| target (quick-cpu) | required | the issue's columns (2) | every column flown (2) |" in printed
    assert "| touchdown speed, firmware columns | <= 0.30 m/s |" in printed


def test_targets_and_random_crazyflies_are_not_asked_for_together(tmp_path, capsys) -> None:
    args = ["transfer", "data/policies/quick-cpu.safetensors", "--variants", "2", "--targets", "paper"]
    with pytest.raises(SystemExit):
        main([*args, "--out", str(tmp_path / "v")])
    assert "--targets checks the columns' matrix, not random Crazyflies" in capsys.readouterr().err
    assert not (tmp_path / "v").exists()
    with pytest.raises(SystemExit):
        main(["transfer", "data/policies/quick-cpu.safetensors", "--targets", "fast"])
    assert "invalid choice: 'fast' (choose from 'quick-cpu', 'paper', 'moving')" in capsys.readouterr().err
