"""Signals during a flight: SIGTERM and SIGHUP land every drone like Ctrl-C does; Ctrl-C never logs a tick twice.

The signal tests run ``marlander deploy --sim`` in a real child process (the example lab config,
PyBullet physics) with a policy file that hovers in place, wait in the flight log until the policy
flies, send the signal, and check what a lab needs: every drone landed (in the log and in the
summary), the exit status, no temporary folder left behind.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from marlander_lite.deploy.config import EXAMPLE_CONFIG, LabConfig, SimulationConfig, load_lab_config
from marlander_lite.deploy.flight_log import FlightLogWriter, read_flight_log
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.policy_file import PolicyContract, load_policy, save_policy

POLICY = Path(__file__).parents[1] / "data" / "policies" / "crazyflie-finetune.safetensors"


@pytest.fixture(scope="module")
def hover_policy(tmp_path_factory) -> Path:
    """A policy file that always answers 0 (hover): the drones stay up until something lands them."""
    contract = PolicyContract(
        num_drones=2, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(), normalize_observations=False
    )
    path = tmp_path_factory.mktemp("policy") / "hover.safetensors"
    return save_policy(path, contract, {"actor.0.weight": np.zeros((6, 26)), "actor.0.bias": np.zeros(6)})


@pytest.fixture(scope="module")
def lab() -> LabConfig:
    return load_lab_config(EXAMPLE_CONFIG).replace(simulation=SimulationConfig(simulator="pointmass", max_time_s=30.0))


def _policy_ticks(path: Path) -> int:
    """How many complete tick records with the policy flying the log holds so far."""
    if not path.exists():
        return 0
    lines = path.read_text().splitlines()[:-1]  # the last line may be half written
    return sum('"mode":"policy"' in line for line in lines)


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_a_signal_during_the_flight_lands_every_drone(signame, hover_policy, tmp_path):
    log = tmp_path / "flight.jsonl"
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = {**os.environ, "TMPDIR": str(temp)}
    cmd = [sys.executable, "-m", "marlander_lite.cli", "deploy", "--sim", "--config", str(EXAMPLE_CONFIG)]
    cmd += ["--policy", str(hover_policy), "--log", str(log)]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 60.0
        while _policy_ticks(log) < 10:  # take-off done, the policy flies
            assert child.poll() is None, child.communicate()
            assert time.monotonic() < deadline, "the policy never took over"
            time.sleep(0.02)
        child.send_signal(getattr(signal, signame))
        out, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 128 + getattr(signal, signame), (out, err)  # the shell's convention
    assert f"ended by {signame}" in err and "Flight log:" in out, (out, err)
    flight = read_flight_log(log)
    assert flight.summary is not None and flight.summary["interrupted_by"] == signame
    assert flight.summary["phases"] == ["down", "down"]  # the loop's account ...
    interrupts = [e for e in flight.events if e["kind"] == "interrupt"]
    assert len(interrupts) == 1 and signame in interrupts[0]["message"]
    landed = {e["drone"] for e in flight.events if e["kind"] in ("motors_off", "touchdown")}
    assert landed == {0, 1}, flight.events  # ... every drone came down and rests
    last = flight.ticks[-1]
    assert last["phase"] == ["down", "down"] and max(last["est"]["pos"][i][2] for i in range(2)) < 0.05
    ticks = [t["tick"] for t in flight.ticks]
    assert ticks == list(range(len(ticks)))
    assert "safe=True" in out
    assert list(temp.iterdir()) == []  # the virtual Crazyflies' TOC folders were removed


def test_handlers_are_restored_after_the_flight(lab, hover_policy):
    """In process: a SIGTERM sent during the flight lands the drones; the handler in place before comes back."""
    seen = []
    previous = signal.signal(signal.SIGTERM, lambda *a: seen.append("outer"))

    def term_at_250(mission, t):  # well after take-off
        if mission.tick == 250:
            os.kill(os.getpid(), signal.SIGTERM)

    try:
        result = rehearse(lab, load_policy(hover_policy, lab.task_config()), hooks=[term_at_250])
        assert result.mission.interrupted_by == "SIGTERM" and result.safe and result.at_rest.all(), result.summary()
        assert [e.kind for e in result.mission.events].count("interrupt") == 1
        assert seen == []  # the flight's handler took it
        os.kill(os.getpid(), signal.SIGTERM)
        assert seen == ["outer"]  # the handler from before the flight is back
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_terminate_as_interrupt_raises_and_restores():
    from marlander_lite.deploy.interrupts import handle_signals, terminate_as_interrupt

    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), terminate_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)
    assert signal.getsignal(signal.SIGTERM) is before
    calls = []
    with handle_signals(calls.append, ("SIGHUP",)) as installed:
        os.kill(os.getpid(), signal.SIGHUP)
    assert installed and calls == ["SIGHUP"]


class Interrupting(FlightLogWriter):
    """A flight log whose ``write`` raises Ctrl-C right after the record of tick ``k`` went out: the window in
    which the loop used to log a tick twice."""

    def __init__(self, path, header, k: int) -> None:
        self.k = k
        super().__init__(path, header)

    def write(self, record):
        super().write(record)
        if record.get("tick") == self.k:
            raise KeyboardInterrupt


class CtrlCAt:
    """A mission hook raising Ctrl-C once, at the start of tick ``k`` (before anything of the tick is done)."""

    def __init__(self, k: int) -> None:
        self.k, self.done = k, False

    def __call__(self, mission, t):
        if mission.tick == self.k and not self.done:
            self.done = True
            raise KeyboardInterrupt


def _check_ticks(path: Path, result) -> None:
    log = read_flight_log(path)
    ticks = [t["tick"] for t in log.ticks]
    assert ticks == list(range(result.mission.ticks)), ticks  # strictly increasing, no duplicate, no gap
    assert [(e["t"], e["kind"]) for e in log.events] == [(e.t, e.kind) for e in result.mission.events]
    assert [e.kind for e in result.mission.events].count("interrupt") == 1
    assert result.safe and result.at_rest.all(), result.summary()


@pytest.mark.parametrize("k", [0, 1, 30, 49, 50, 51, 120, 170, 171, 172, 173, 200, 260])
def test_ctrl_c_at_any_tick_logs_each_tick_once(k, lab, tmp_path, monkeypatch):
    """Ctrl-C right after tick k's record was written (pre-flight, take-off, policy, landing ticks)."""
    from marlander_lite.deploy.rehearsal import run as rehearsal

    policy = load_policy(POLICY, lab.task_config())
    monkeypatch.setattr(rehearsal, "FlightLogWriter", lambda path, header, overwrite: Interrupting(path, header, k))
    path = tmp_path / "log.jsonl"
    result = rehearse(lab, policy, log_path=path)
    _check_ticks(path, result)
    assert result.mission.interrupted_by == "SIGINT"


@pytest.mark.parametrize("k", [0, 60, 150, 171])
def test_ctrl_c_at_the_start_of_a_tick_logs_each_tick_once(k, lab, tmp_path, monkeypatch):
    from marlander_lite.deploy.rehearsal import run as rehearsal

    policy = load_policy(POLICY, lab.task_config())
    original = rehearsal._FirmwareEvents

    def hooks(world):
        fw = original(world)
        ctrl_c = CtrlCAt(k)

        def both(mission, t):
            ctrl_c(mission, t)
            fw(mission, t)

        return both

    monkeypatch.setattr(rehearsal, "_FirmwareEvents", hooks)
    path = tmp_path / "log.jsonl"
    _check_ticks(path, rehearse(lab, policy, log_path=path))


def test_summary_records_no_interrupt_for_a_normal_flight(lab, tmp_path):
    path = tmp_path / "log.jsonl"
    result = rehearse(lab, POLICY, log_path=path)
    assert result.mission.interrupted_by is None and result.passed
    summary = json.loads(path.read_text().splitlines()[-1])
    assert summary["interrupted_by"] is None


def test_a_signal_in_the_same_tick_as_another_landing_request_is_logged(lab, hover_policy, tmp_path):
    """SIGTERM arriving in the tick the simulated time limit asks for a landing: both reasons in the event."""

    def both(mission, t):
        if mission.tick == 200:
            os.kill(os.getpid(), signal.SIGTERM)
            mission.request_land("simulated time limit")

    path = tmp_path / "log.jsonl"
    result = rehearse(lab, load_policy(hover_policy, lab.task_config()), log_path=path, hooks=[both])
    [interrupt] = [e for e in result.mission.events if e.kind == "interrupt"]
    assert "SIGTERM" in interrupt.message and "simulated time limit" in interrupt.message, interrupt.message
    assert result.mission.interrupted_by == "SIGTERM" and result.at_rest.all()


def test_a_signal_before_take_off_stops_cleanly(tmp_path, monkeypatch, hover_policy, capsys):
    """SIGTERM while the radios connect: nothing flies yet; the command unwinds (links and world closed)."""
    from marlander_lite.cli import main
    from marlander_lite.deploy.link import CrazyflieLink
    from marlander_lite.deploy.rehearsal import run as rehearsal

    opened = CrazyflieLink.open

    def open_then_term(self):
        opened(self)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)  # the handler raises here

    monkeypatch.setattr(rehearsal.CrazyflieLink, "open", open_then_term)
    config = tmp_path / "lab.yaml"
    config.write_text(EXAMPLE_CONFIG.read_text().replace("simulator: crazyflie", "simulator: pointmass"))
    before = signal.getsignal(signal.SIGTERM)
    args = ["deploy", "--sim", "--config", str(config), "--policy", str(hover_policy)]
    assert main([*args, "--log", str(tmp_path / "log.jsonl")]) == 128 + signal.SIGTERM
    assert "stopped by SIGTERM" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is before
