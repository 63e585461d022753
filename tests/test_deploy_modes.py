"""The mission's mode and phase tables: the lab guide shows them as they are, and the loop keeps to them.

The tables in ``docs/lab_guide.md`` are read back and compared with ``deploy/modes.py`` row by row,
words included; the rehearsals' flight logs are checked against the tables (every change of mode
or phase between two logged ticks is one the table allows); and changes outside the tables raise.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pytest

from marlander_lite.deploy.config import EXAMPLE_CONFIG, SimulationConfig, load_lab_config
from marlander_lite.deploy.flight_log import read_flight_log
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.modes import (
    MODE_TRANSITIONS,
    PHASE_TRANSITIONS,
    DronePhase,
    IllegalTransition,
    MissionMode,
    check_change,
)
from marlander_lite.deploy.rehearsal import FAULT_KINDS, FaultSpec, rehearse

LAB_GUIDE = Path(__file__).parents[1] / "docs" / "lab_guide.md"


def doc_table(heading: str) -> list[tuple[str, str, str]]:
    """Rows ``(from, to, when)`` of the first Markdown table after ``heading`` in the lab guide."""
    lines = LAB_GUIDE.read_text().splitlines()
    start = lines.index(heading)
    rows, in_table = [], False
    for line in lines[start + 1 :]:
        if line.startswith("|"):
            in_table = True
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows.append(tuple(cells))
        elif in_table:
            break
    assert rows[1] == ("---", "---", "---"), rows[:2]
    return [(a.strip("`"), b.strip("`"), when) for a, b, when in rows[2:]]


def code_table(table: dict) -> list[tuple[str, str, str]]:
    """The same rows from a transition table; a final state is ``(state, "none", "final")``."""
    rows = []
    for state, changes in table.items():
        rows += [(state.value, new.value, when) for new, when in changes.items()] or [(state.value, "none", "final")]
    return rows


@pytest.mark.parametrize(
    ("heading", "table"),
    [("### Mission modes", MODE_TRANSITIONS), ("### Drone phases", PHASE_TRANSITIONS)],
)
def test_the_lab_guide_shows_the_transition_tables_of_the_code(heading, table):
    assert doc_table(heading) == code_table(table)


def test_every_mode_and_phase_is_in_its_table():
    assert list(MODE_TRANSITIONS) == list(MissionMode)
    assert list(PHASE_TRANSITIONS) == list(DronePhase)
    assert MODE_TRANSITIONS[MissionMode.DONE] == {} and PHASE_TRANSITIONS[DronePhase.LOST] == {}
    # every mode but preflight is reachable, and from every mode but done the mission can end
    reached = {new for changes in MODE_TRANSITIONS.values() for new in changes}
    assert reached == set(MissionMode) - {MissionMode.PREFLIGHT}
    assert all(MissionMode.DONE in c for m, c in MODE_TRANSITIONS.items() if m != MissionMode.DONE)


def test_a_change_outside_the_table_raises():
    assert check_change(MODE_TRANSITIONS, MissionMode.TAKEOFF, MissionMode.POLICY, "mode") is MissionMode.POLICY
    assert check_change(PHASE_TRANSITIONS, DronePhase.HOVER, DronePhase.HOVER, "phase") is DronePhase.HOVER  # staying
    with pytest.raises(IllegalTransition, match=r"preflight -> policy .*from preflight: takeoff, done"):
        check_change(MODE_TRANSITIONS, MissionMode.PREFLIGHT, MissionMode.POLICY, "mission mode")
    with pytest.raises(IllegalTransition, match=r"lost -> takeoff .*nothing \(it is final\)"):
        check_change(PHASE_TRANSITIONS, DronePhase.LOST, DronePhase.TAKEOFF, "phase of cf1")


def test_modes_and_phases_read_and_log_as_their_names():
    assert MissionMode.POLICY == "policy" and f"{DronePhase.HOVER}" == "hover" and str(MissionMode.DONE) == "done"


@pytest.fixture(scope="module")
def lab():
    base = load_lab_config(EXAMPLE_CONFIG)
    return base.replace(simulation=SimulationConfig(simulator="pointmass", max_time_s=30.0))


@pytest.mark.parametrize("fault", [None, *FAULT_KINDS])
def test_rehearsed_flights_change_only_as_the_tables_allow(fault, lab, p_controller_policy, tmp_path):
    """Every change between consecutive ticks of the flight log is a row of its table; the flight ends in done."""
    path = tmp_path / "log.jsonl"
    rehearse(lab, p_controller_policy, fault=None if fault is None else FaultSpec(fault), log_path=path)
    ticks = read_flight_log(path).ticks
    modes = [MissionMode(t["mode"]) for t in ticks]
    phases = np.array([[DronePhase(p) for p in t["phase"]] for t in ticks])
    seen = set()
    for a, b in itertools.pairwise(modes):
        if a != b:
            assert b in MODE_TRANSITIONS[a], (a, b)
            seen.add((a, b))
    for column in phases.T:
        for a, b in itertools.pairwise(column):
            if a != b:
                assert b in PHASE_TRANSITIONS[a], (a, b)
    assert modes[0] == MissionMode.PREFLIGHT and modes[-1] == MissionMode.DONE
    assert (MissionMode.PREFLIGHT, MissionMode.TAKEOFF) in seen  # the flight took off: the test saw changes


class _FakeLink:
    def lost(self, i: int) -> str | None:
        return None


def test_the_mission_refuses_an_illegal_change(lab):
    mission = Mission(lab, policy=_ZeroPolicy(), source=None, link=_FakeLink(), clock=None)
    with pytest.raises(IllegalTransition, match="mission mode: preflight -> landing"):
        mission._enter(MissionMode.LANDING)
    with pytest.raises(IllegalTransition, match="phase of cf1: idle -> policy"):
        mission._set_phase(0, DronePhase.POLICY)
    mission._set_phase(1, DronePhase.LOST)
    with pytest.raises(IllegalTransition, match="phase of cf2: lost -> down"):
        mission._set_phase(1, DronePhase.DOWN)
    assert mission.mode == MissionMode.PREFLIGHT and mission.phase == ["idle", "lost"]


class _ZeroPolicy:
    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(6)


def test_lab_guide_event_names_exist():
    """Every event a table names (in backticks, snake_case) is an event the loop can log."""
    from typing import get_args

    from marlander_lite.deploy.safety import EventKind

    kinds = set(get_args(EventKind))
    texts = [when for t in (MODE_TRANSITIONS, PHASE_TRANSITIONS) for c in t.values() for when in c.values()]
    named = {w for text in texts for w in re.findall(r"`([a-z]+(?:_[a-z]+)*)`", text)}
    not_events = {"k", "min_preflight_s", "takeoff_duration"}  # a key and two settings
    assert named - not_events <= kinds, named - not_events - kinds
    assert {"armed", "policy_start", "link_lost", "interrupt", "emergency", "touchdown", "handover"} <= named
