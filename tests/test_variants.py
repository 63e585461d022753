"""Random Crazyflies (``marlander transfer POLICY --variants N``): the draw, the simulators it builds, the command.

The draw is checked against its ranges and its seed; the simulators against what each drawn value must do to the
drone (its tilt clamp reached and not exceeded, the level-flight acceleration bound ``g tan(tilt)``, the mass the
tracker does not know about); the command end to end on a tiny budget.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pybullet as p
import pytest

from marlander_lite.cli import main
from marlander_lite.crazyflie.control import PIDGains
from marlander_lite.crazyflie.envs import CrazyflieOptions
from marlander_lite.crazyflie.firmware import FirmwareGains
from marlander_lite.experiments import transfer
from marlander_lite.experiments.metrics import wilson_interval
from marlander_lite.experiments.variants import (
    PYFLYT_ORDERS,
    RANGE_BOUNDS,
    Variant,
    VariantRanges,
    draw_variants,
    format_summary,
    read_variants,
    summarize,
)
from marlander_lite.task import TaskConfig

POLICY = "data/policies/quick-cpu.safetensors"
G = 9.81


def test_the_draw_is_seeded_stays_in_its_ranges_and_a_longer_draw_extends_a_shorter_one() -> None:
    ranges = VariantRanges()
    drawn = draw_variants(200, seed=3)
    assert drawn == draw_variants(200, seed=3)
    assert drawn != draw_variants(200, seed=4)
    assert drawn[:10] == draw_variants(10, seed=3)
    for name in RANGE_BOUNDS:
        values = np.array([getattr(v, name) for v in drawn])
        low, high = getattr(ranges, name)
        assert values.min() >= low - 1e-4 and values.max() <= high + 1e-4
        assert values.max() - values.min() > 0.8 * (high - low)  # the whole range is drawn from
    firmware = sum(v.controller == "firmware" for v in drawn)
    aero = sum(v.physics == "aero" for v in drawn)
    assert 70 <= firmware <= 130 and 70 <= aero <= 130  # half each, within 3 binomial standard deviations
    assert {v.name for v in drawn} == {f"variant {k:03d}" for k in range(200)}


def test_shares_and_fixed_ranges_choose_what_is_drawn() -> None:
    only_firmware = VariantRanges(firmware_share=1.0, aero_share=0.0, latency_s=(0.05, 0.05))
    drawn = draw_variants(20, 0, only_firmware)
    assert {v.controller for v in drawn} == {"firmware"} and {v.physics for v in drawn} == {"bare"}
    assert {v.latency_s for v in drawn} == {0.05}
    assert {v.controller for v in draw_variants(20, 0, VariantRanges(firmware_share=0.0))} == {"pid"}


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"latency_s": [-0.01, 0.05]}, "a latency cannot be negative"),
        ({"mass_scale": [1.2, 0.9]}, "empty range"),
        ({"tilt_limit_deg": [15, 95]}, "allowed interval [5.0, 80.0]"),
        ({"inner_gain_scale": [0.7, float("nan")]}, "finite"),
        ({"outer_gain_scale": [0.7]}, "(low, high) pair"),
        ({"firmware_share": 1.5}, "probability from 0 to 1"),
        ({"gain_scale": [0.5, 1.0]}, "Unknown VariantRanges field(s) ['gain_scale']"),
    ],
)
def test_bad_ranges_are_refused_with_what_is_allowed(values: dict, message: str) -> None:
    with pytest.raises(ValueError) as error:
        VariantRanges.from_mapping(values)
    assert message in str(error.value)


@pytest.mark.parametrize(("count", "seed"), [(0, 0), (1001, 0), (2.5, 0), (5, -1)])
def test_a_bad_count_or_seed_is_refused(count, seed) -> None:
    with pytest.raises(ValueError, match="--variant"):
        draw_variants(count, seed)


def _variant(controller: str, tilt: float, mass: float = 1.0, inner: float = 1.0) -> Variant:
    return Variant("variant 000", controller, "bare", mass, 0.0, 1.0, inner, tilt)


def _build(variant: Variant, policy_hz: float):
    options = dict(variant.column().options, num_drones=1, task=dict(policy_hz=policy_hz))
    simulator, _ = CrazyflieOptions.from_keywords(options).build(1)
    return simulator


@pytest.mark.parametrize("controller", ["firmware", "pid"])
def test_a_variant_builds_the_drone_and_tracker_it_drew(controller: str) -> None:
    variant = Variant("variant 000", controller, "aero", 1.12, 0.05, 0.8, 1.3, 27.0)
    sim = _build(variant, 48.0)
    try:
        assert sim.controller_kind == controller
        assert sim.body_params.mass == pytest.approx(1.12 * sim.params.mass)  # the tracker is not told
        assert (sim.perturbation.latency_s, sim.perturbation.gain_scale) == (0.05, 0.8)
        assert sim.physics.ground_effect  # "aero"
        gains = sim.controller.gains
        if controller == "firmware":
            default = FirmwareGains()
            assert gains.tilt_limit_deg == 27.0
            assert gains.rate_p == (1.3 * default.rate_p[0], 1.3 * default.rate_p[1], default.rate_p[2])
            assert gains.attitude_p[:2] == (1.3 * default.attitude_p[0],) * 2
        else:
            default = PIDGains()
            assert gains.max_tilt_deg == 27.0
            assert gains.att_d == (1.3 * default.att_d[0], 1.3 * default.att_d[1], default.att_d[2])
    finally:
        sim.close()


def _peak_tilt_and_acceleration(variant: Variant) -> tuple[float, float]:
    """A 3 m/s level reversal along x, sampled at every firmware tick: the largest tilt (deg) and horizontal
    acceleration (m/s^2)."""
    hz = 240.0
    sim = _build(variant, hz)
    try:
        sim.place(0, np.array([[0.0, 0.0, 2.0]]))
        tilts, velocities = [], []
        for command in [(3.0, 0.0, 0.0)] * 240 + [(-3.0, 0.0, 0.0)] * 240:
            sim.step(np.array(command)[None, None])
            roll, pitch = p.getEulerFromQuaternion(sim.quat[0, 0].tolist())[:2]
            tilts.append(math.degrees(math.acos(math.cos(roll) * math.cos(pitch))))
            velocities.append(sim.vel[0, 0, :2].copy())
        accel = np.linalg.norm(np.diff(np.array(velocities), axis=0), axis=1) * hz
        return max(tilts), float(accel.max())
    finally:
        sim.close()


@pytest.mark.parametrize("tilt", [15.0, 35.0])
def test_a_firmware_variant_reaches_its_drawn_tilt_clamp_and_no_more(tilt: float) -> None:
    """The firmware clamps the roll and pitch setpoints: along one axis the tilt reaches the drawn clamp, the attitude
    loop overshoots it by under a tenth (measured: 2.5 deg at 35), and the level-flight acceleration is bounded by
    ``g tan(tilt)`` (as for the default 20 deg, tests/test_crazyflie_firmware.py)."""
    peak, accel = _peak_tilt_and_acceleration(_variant("firmware", tilt))
    assert tilt - 1.0 < peak < 1.1 * tilt
    bound = G * math.tan(math.radians(tilt))
    assert 0.9 * bound < accel < 1.25 * bound


def test_softer_inner_loops_answer_a_reversal_more_slowly() -> None:
    """Scaling the attitude and rate gains changes how fast the drone tilts: with x0.7 the first 0.1 s of a reversal
    reaches less tilt than with x1.4."""

    def tilt_after(inner: float, seconds: float = 0.1) -> float:
        sim = _build(_variant("firmware", 20.0, inner=inner), 240.0)
        try:
            sim.place(0, np.array([[0.0, 0.0, 2.0]]))
            for _ in range(int(seconds * 240)):
                sim.step(np.array([[[2.0, 0.0, 0.0]]]))
            roll, pitch = p.getEulerFromQuaternion(sim.quat[0, 0].tolist())[:2]
            return math.degrees(math.acos(math.cos(roll) * math.cos(pitch)))
        finally:
            sim.close()

    assert tilt_after(0.7) < tilt_after(1.4) - 1.0


def test_firmware_gains_need_the_firmware_tracker() -> None:
    with pytest.raises(ValueError, match="controller='firmware'"):
        CrazyflieOptions(controller="pid", firmware_gains=FirmwareGains())
    with pytest.raises(TypeError, match="FirmwareGains"):
        CrazyflieOptions(controller="firmware", firmware_gains={"tilt_limit_deg": 30})
    assert CrazyflieOptions(controller="firmware", task=TaskConfig(num_drones=1)).firmware_gains is None


def test_pyflyt_variants_draw_the_same_values_and_give_them_to_pyflyts_drone() -> None:
    crazyflies, pyflyts = draw_variants(40, 5), draw_variants(40, 5, simulator="pyflyt")
    for mine, theirs in zip(crazyflies, pyflyts, strict=True):  # the same numbers, only the tracker differs
        assert (theirs.simulator, theirs.physics) == ("pyflyt", mine.physics)
        assert [getattr(theirs, name) for name in RANGE_BOUNDS] == [getattr(mine, name) for name in RANGE_BOUNDS]
        assert theirs.controller in PYFLYT_ORDERS and mine.simulator == "crazyflie"
    assert 8 <= sum(v.controller == "pyflyt 0.21.0" for v in pyflyts) <= 32  # half, within 3 standard deviations
    column = pyflyts[0].column()
    assert column.simulator == "pyflyt" and column.options["read_state"] == PYFLYT_ORDERS[pyflyts[0].controller]
    tuning = column.options["tuning"]
    assert tuning["latency_s"] == pyflyts[0].latency_s and tuning["tilt_limit_deg"] == pyflyts[0].tilt_limit_deg
    assert tuning["body_drag"] == (pyflyts[0].physics == "aero")
    late = draw_variants(10, 0, VariantRanges(late_read_share=1.0), simulator="pyflyt")
    assert {v.controller for v in late} == {"pyflyt 0.21.0"}
    with pytest.raises(ValueError, match="--variant-simulator must be one of crazyflie, pyflyt, rotorpy"):
        draw_variants(3, 0, simulator="gazebo")


def test_rotorpy_variants_draw_the_same_values_and_give_them_to_rotorpys_drone() -> None:
    """The same numbers as the PyBullet draw; RotorPy has one controller and no tilt clamp, so neither is flown."""
    crazyflies, rotorpys = draw_variants(40, 5), draw_variants(40, 5, simulator="rotorpy")
    for mine, theirs in zip(crazyflies, rotorpys, strict=True):
        assert (theirs.simulator, theirs.controller, theirs.physics) == ("rotorpy", "rotorpy", mine.physics)
        assert [getattr(theirs, name) for name in RANGE_BOUNDS] == [getattr(mine, name) for name in RANGE_BOUNDS]
    column = rotorpys[0].column()
    assert column.simulator == "rotorpy" and column.options["aero"] == (rotorpys[0].physics == "aero")
    drawn = {name: getattr(rotorpys[0], name) for name in ("mass_scale", "latency_s")}
    drawn |= {"outer_gain_scale": rotorpys[0].outer_gain_scale, "inner_gain_scale": rotorpys[0].inner_gain_scale}
    assert column.options["tuning"] == drawn
    assert rotorpys[0].describe().endswith("no tilt clamp") and "tilt" not in str(column.options)


@pytest.mark.parametrize(
    ("simulator", "module", "name"), [("pyflyt", "PyFlyt", "PyFlyt"), ("rotorpy", "rotorpy", "RotorPy")]
)
def test_the_command_flies_random_crazyflies_in_another_simulator(simulator, module, name, tmp_path, capsys) -> None:
    pytest.importorskip(module)
    out = tmp_path / "v"
    args = ["transfer", POLICY, "--variants", "2", "--episodes", "1", "--rows", "floor", "--workers", "1"]
    assert main([*args, "--variant-simulator", simulator, "--out", str(out)]) == 0
    assert f"in {simulator}" in capsys.readouterr().out
    lines = list(csv.DictReader((out / "variants.csv").open()))
    assert [line["simulator"] for line in lines] == [simulator, simulator]
    variants, cells = read_variants(out / "variants.json")
    assert variants == draw_variants(2, 0, simulator=simulator) and len(cells) == 2
    assert f"random Crazyflies in {name}" in (out / "variants.md").read_text()


def _cell(column: str, row: str, successes: int, episodes: int = 20, error: float = 1.0) -> transfer.CellResult:
    low, high = wilson_interval(successes, episodes)
    return transfer.CellResult(
        row, column, episodes, successes, successes / episodes, low, high, error, 5.0, 0.0, 0.2, 0.4, 0.01, 0.9, 1.0
    )


def test_the_summary_counts_variants_at_90_percent_and_pools_episodes_worked_by_hand() -> None:
    cells = [_cell("variant 000", "floor", 20), _cell("variant 001", "floor", 18), _cell("variant 002", "floor", 11)]
    (s,) = summarize(cells)
    assert (s.variants, s.landed_variants) == (3, 2)  # 100 % and 90 % count, 55 % does not
    assert s.median_success == pytest.approx(0.9) and s.worst_success == pytest.approx(0.55)
    assert s.worst_variant == "variant 002"
    assert s.pooled_success == pytest.approx(49 / 60)
    assert (s.pooled_low, s.pooled_high) == pytest.approx(wilson_interval(49, 60))
    drawn = draw_variants(3, 0)
    assert f"variant 002: {drawn[2].describe()}" in format_summary(cells, drawn)


def test_the_command_flies_random_crazyflies_and_writes_them_with_their_results(tmp_path, capsys) -> None:
    out = tmp_path / "v"
    args = ["transfer", POLICY, "--variants", "2", "--episodes", "2", "--rows", "floor,UR10", "--workers", "1"]
    assert main([*args, "--variant-seed", "7", "--out", str(out)]) == 0
    assert "variants at 90 % or more" in capsys.readouterr().out
    lines = list(csv.DictReader((out / "variants.csv").open()))
    assert len(lines) == 4 and {line["row"] for line in lines} == {"floor", "UR10"}
    drawn = draw_variants(2, 7)
    variants, cells = read_variants(out / "variants.json")
    assert variants == drawn
    for line, cell in zip(lines, cells, strict=True):
        variant = next(v for v in drawn if v.name == line["variant"])
        assert line["controller"] == variant.controller and float(line["tilt_limit_deg"]) == variant.tilt_limit_deg
        assert cell.successes + sum(getattr(cell, name) for name in transfer.FAILURES) == cell.episodes == 2
    data = json.loads((out / "variants.json").read_text())
    assert data["variant_seed"] == 7 and data["ranges"]["latency_s"] == [0.0, 0.08] and len(data["policy_sha256"]) == 64
    assert "variant 001" in (out / "variants.md").read_text()
    with pytest.raises(SystemExit):  # the files are kept unless --force
        main([*args, "--variant-seed", "7", "--out", str(out)])
    assert "already exist" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--variants", "0"], "--variants must be an integer from 1 to 1000"),
        (["--variants", "3", "--columns", "point mass"], "leave --columns out"),
        (["--variant-seed", "2"], "need --variants N"),
        (["--variant-simulator", "pyflyt"], "need --variants N"),
        (["--variants", "3", "--variant-ranges", '{"latency_s": [0.1, 0.0]}'], "empty range"),
        (["--variants", "3", "--variant-ranges", "[1, 2]"], "JSON object"),
    ],
)
def test_the_command_refuses_bad_variant_options(extra: list[str], message: str, tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["transfer", POLICY, "--episodes", "1", "--out", str(tmp_path / "v"), *extra])
    assert exit_info.value.code != 0
    assert message in capsys.readouterr().err
