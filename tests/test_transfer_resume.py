"""An interrupted ``marlander transfer`` resumes from the cells it finished (experiments.cell_journal)."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time

import pytest

from marlander_lite.cli import main
from marlander_lite.experiments import transfer
from marlander_lite.experiments.cell_journal import CellJournal, matrix_fingerprint
from marlander_lite.experiments.variants import read_variants

POLICY = "data/policies/quick-cpu.safetensors"
ARGS = ["transfer", POLICY, "--episodes", "2", "--columns", "point mass", "--rows", "floor,UR10,arc 0.2-0.5 m/s"]


def _interrupt_after(monkeypatch: pytest.MonkeyPatch, cells: int) -> list[tuple[str, str]]:
    """Make ``fly_cell`` raise KeyboardInterrupt (Ctrl-C) once ``cells`` cells are flown; returns the cells flown."""
    real, flown = transfer.fly_cell, []

    def fly(policy, column, row, *rest):
        if len(flown) == cells:
            raise KeyboardInterrupt
        flown.append((row, column if isinstance(column, str) else column.name))
        return real(policy, column, row, *rest)

    monkeypatch.setattr(transfer, "fly_cell", fly)
    return flown


def _without_wall(cells: list[transfer.CellResult]) -> list[transfer.CellResult]:
    return [dataclasses.replace(c, wall_s=0.0) for c in cells]


def test_an_interrupted_matrix_resumes_and_equals_one_flown_without_a_stop(tmp_path, monkeypatch, capsys) -> None:
    whole, resumed = tmp_path / "whole", tmp_path / "resumed"
    assert main([*ARGS, "--workers", "1", "--out", str(whole)]) == 0
    flown = _interrupt_after(monkeypatch, 2)
    capsys.readouterr()
    assert main([*ARGS, "--workers", "1", "--out", str(resumed)]) == 130  # Ctrl-C
    assert f"the 2 finished cells are kept in {resumed / 'transfer.partial.jsonl'}" in capsys.readouterr().err
    journal = resumed / "transfer.partial.jsonl"
    assert not (resumed / "transfer.json").exists()
    assert len(journal.read_text().splitlines()) == 1 + 2  # the matrix line and the two finished cells
    monkeypatch.undo()
    flown_again = _interrupt_after(monkeypatch, 10)
    capsys.readouterr()
    assert main([*ARGS, "--workers", "1", "--out", str(resumed)]) == 0
    assert "Resuming: 2 of 3 cells read back" in capsys.readouterr().out
    assert flown == [("floor", "point mass"), ("UR10", "point mass")]
    assert flown_again == [("arc 0.2-0.5 m/s", "point mass")]  # only the missing cell
    assert not journal.exists()  # its cells are in transfer.json now
    assert _without_wall(transfer.read_results(resumed / "transfer.json")) == _without_wall(
        transfer.read_results(whole / "transfer.json")
    )


def test_the_parallel_path_records_every_cell_as_it_finishes(tmp_path) -> None:
    config = transfer.TransferConfig(POLICY, episodes=1, columns=("point mass",), rows=("floor", "UR10"), workers=2)
    journal = CellJournal(tmp_path / "j.jsonl", matrix_fingerprint(config, "0" * 64))
    cells = transfer.transfer_matrix(config, journal=journal)
    assert [(c.row, c.column) for c in cells] == [("floor", "point mass"), ("UR10", "point mass")]
    lines = (tmp_path / "j.jsonl").read_text().splitlines()
    assert sorted(json.loads(line)["cell"]["row"] for line in lines[1:]) == ["UR10", "floor"]
    again = CellJournal(tmp_path / "j.jsonl", matrix_fingerprint(config, "0" * 64))
    assert again.done == {(c.row, c.column): c for c in cells} and again.earlier_wall_s > 0


def test_a_journal_of_another_matrix_is_refused_and_force_flies_afresh(tmp_path, monkeypatch, capsys) -> None:
    out = tmp_path / "t"
    _interrupt_after(monkeypatch, 1)
    assert main([*ARGS, "--workers", "1", "--out", str(out)]) == 130
    monkeypatch.undo()
    other = [a if a != "2" else "3" for a in ARGS]  # three episodes a cell, not two
    with pytest.raises(SystemExit):
        main([*other, "--workers", "1", "--out", str(out)])
    error = capsys.readouterr().err
    assert "holds the finished cells of another matrix (it differs in: episodes)" in error and "--force" in error
    assert (out / "transfer.partial.jsonl").exists()  # kept: refusing loses nothing
    flown = _interrupt_after(monkeypatch, 10)
    assert main([*other, "--workers", "1", "--out", str(out), "--force"]) == 0
    assert len(flown) == 3 and transfer.read_results(out / "transfer.json")[0].episodes == 3


def test_a_line_cut_short_by_the_kill_is_flown_again_and_a_damaged_one_refused(tmp_path) -> None:
    config = transfer.TransferConfig(POLICY, episodes=1, columns=("point mass",), rows=("floor", "UR10"), workers=1)
    fingerprint = matrix_fingerprint(config, "0" * 64)
    path = tmp_path / "j.jsonl"
    transfer.transfer_matrix(config, journal=CellJournal(path, fingerprint))
    whole = path.read_text()
    path.write_text(whole[: whole.rindex("\n", 0, -1) + 20])  # the last cell's line cut off mid-write
    cut = CellJournal(path, fingerprint)
    assert list(cut.done) == [("floor", "point mass")]
    assert path.read_text().count("\n") == 2  # the cut line dropped, so the next cell starts its own line
    lines = whole.splitlines()
    path.write_text("\n".join([lines[0], lines[1][:30], lines[2]]) + "\n")
    with pytest.raises(ValueError, match=r"j.jsonl, line 2, is damaged .* add --force"):
        CellJournal(path, fingerprint)
    path.write_text("not a journal\n")
    with pytest.raises(ValueError, match="is not a transfer journal"):
        CellJournal(path, fingerprint)
    path.write_text('{"matrix": ')  # killed before the first line was whole: started afresh
    assert CellJournal(path, fingerprint).done == {} and json.loads(path.read_text())["matrix"] == fingerprint


def test_random_crazyflies_resume_too_and_a_new_draw_is_another_matrix(tmp_path, monkeypatch, capsys) -> None:
    out = tmp_path / "v"
    args = ["transfer", POLICY, "--variants", "2", "--episodes", "1", "--rows", "floor", "--workers", "1"]
    _interrupt_after(monkeypatch, 1)
    assert main([*args, "--out", str(out)]) == 130
    assert (out / "variants.partial.jsonl").exists()
    monkeypatch.undo()
    with pytest.raises(SystemExit):
        main([*args, "--variant-seed", "1", "--out", str(out)])
    assert "differs in: columns" in capsys.readouterr().err
    flown = _interrupt_after(monkeypatch, 10)
    assert main([*args, "--out", str(out)]) == 0
    assert flown == [("floor", "variant 001")]
    _, cells = read_variants(out / "variants.json")
    assert [c.column for c in cells] == ["variant 000", "variant 001"]
    assert not (out / "variants.partial.jsonl").exists()


def test_a_matrix_killed_by_sigterm_resumes_from_its_journal(tmp_path) -> None:
    """A real kill, not a simulated one: the process is terminated as soon as its first cell is on disk."""
    out = tmp_path / "t"
    args = [*ARGS[:-2], "--columns", "PyBullet firmware", "--rows", "floor,UR10", "--workers", "1", "--out", str(out)]
    command = [sys.executable, "-m", "marlander_lite.cli", *args]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = out / "transfer.partial.jsonl"
    deadline = time.monotonic() + 300
    while process.poll() is None and time.monotonic() < deadline:
        if journal.exists() and journal.read_text().count("\n") >= 2:
            process.send_signal(signal.SIGTERM)
            break
        time.sleep(0.02)
    process.wait(timeout=60)
    assert process.returncode == -signal.SIGTERM, "the matrix finished before it could be killed"
    assert not (out / "transfer.json").exists()
    kept = CellJournal(journal, json.loads(journal.read_text().splitlines()[0])["matrix"]).done
    assert list(kept) == [("floor", "PyBullet firmware")]
    assert main(args) == 0
    cells = transfer.read_results(out / "transfer.json")
    assert [(c.row, c.column) for c in cells] == [("floor", "PyBullet firmware"), ("UR10", "PyBullet firmware")]
    assert cells[0] == kept[("floor", "PyBullet firmware")]  # read back, not flown again
    assert _without_wall([cells[1]]) == _without_wall(
        [transfer.fly_cell(POLICY, "PyBullet firmware", "UR10", 2, 0, "vicon")]
    )
