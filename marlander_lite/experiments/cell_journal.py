"""A journal of the finished cells of a transfer matrix, so that an interrupted matrix resumes where it stopped.

A full matrix of the paper's network takes about an hour on two cores and a 40-variant RotorPy draw longer; a
``marlander transfer`` killed near the end must not throw that away. While the cells are flown each finished one is
appended to ``<out>/transfer.partial.jsonl`` (``variants.partial.jsonl`` with ``--variants``) as one JSON line and
flushed to disk. Run the same command again and the cells already there are read back instead of flown. Every cell
is flown from its own seeds (:func:`~marlander_lite.experiments.transfer.fly_cell`), so a resumed matrix holds the
same cells as one flown without a stop.

The first line says which matrix the journal belongs to: the policy file's SHA-256, the settings that change what a
cell measures (:class:`~marlander_lite.experiments.transfer.TransferConfig` without ``workers``) and the columns flown
(the random Crazyflies of a ``--variants`` draw included). A journal of another matrix is refused, never mixed in. A
line cut short by the kill (the last one) is dropped and its cell flown again; a damaged line before it is refused
with the file's name. Once the finished ``transfer.*`` files are written the journal is removed.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from marlander_lite.experiments.transfer import CellResult, Column, TransferConfig

JOURNAL_VERSION = 1


def matrix_fingerprint(
    config: TransferConfig, policy_sha256: str, columns: Sequence[Column] | None = None
) -> dict[str, Any]:
    """What makes two runs the same matrix: policy hash, settings but ``workers``, columns (``None``: by name)."""
    settings = {k: v for k, v in asdict(config).items() if k != "workers"}
    flown = None if columns is None else [asdict(c) for c in columns]
    fingerprint = {"version": JOURNAL_VERSION, "policy_sha256": policy_sha256, "config": settings, "columns": flown}
    return json.loads(json.dumps(fingerprint))  # tuples as lists, as they read back


class CellJournal:
    """The finished cells of one matrix in a JSON-lines file; see the module docstring.

    ``path``: the journal file. ``fingerprint``: :func:`matrix_fingerprint` of the matrix about to be flown. An
    existing journal of the same matrix is read (:attr:`done`); of another matrix it raises ``ValueError`` unless
    ``discard`` (``--force``), which starts it afresh."""

    def __init__(self, path: str | Path, fingerprint: dict[str, Any], discard: bool = False) -> None:
        self.path = Path(path)
        self.fingerprint = fingerprint
        self.done: dict[tuple[str, str], CellResult] = {}
        """Finished cells by (row, column): read back from an earlier run, then each one :meth:`record` adds."""
        self.earlier_wall_s = 0.0
        """Seconds the earlier runs of this journal flew for, summed."""
        self._session = 0
        self._started = time.perf_counter()
        if self.path.exists() and not discard:
            self._read()
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._replace([json.dumps({"matrix": fingerprint})])

    def _replace(self, lines: list[str]) -> None:
        """Write the journal whole, through a temporary file: a kill leaves the old journal or the new one."""
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text("".join(line + "\n" for line in lines))
        os.replace(temporary, self.path)

    def _read(self) -> None:
        from marlander_lite.experiments.transfer import CellResult

        lines = self.path.read_text().split("\n")
        if lines.pop() != "":  # the last line has no newline: the run was killed while writing it; drop it
            self._replace(lines)
        if not lines:  # killed before the first line was whole
            self._replace([json.dumps({"matrix": self.fingerprint})])
            return
        try:
            header = json.loads(lines[0])["matrix"]
        except (ValueError, KeyError, TypeError):
            header = None
        if header is None:
            raise ValueError(
                f"{self.path} is not a transfer journal (its first line should name the matrix); move it away, or add "
                "--force to start the matrix afresh."
            )
        if header != self.fingerprint:
            differ = sorted(
                k
                for k in {**header.get("config", {}), **self.fingerprint["config"]}
                if header.get("config", {}).get(k) != self.fingerprint["config"].get(k)
            )
            differ += [k for k in ("version", "policy_sha256", "columns") if header.get(k) != self.fingerprint[k]]
            raise ValueError(
                f"{self.path} holds the finished cells of another matrix (it differs in: {', '.join(differ)}); run "
                "the same command as before to resume it, choose another --out, or add --force to discard them."
            )
        walls: dict[int, float] = {}
        for number, line in enumerate(lines[1:], start=2):
            try:
                entry = json.loads(line)
                cell = CellResult(**entry["cell"])
                session, wall = int(entry["session"]), float(entry["session_wall_s"])
            except (ValueError, KeyError, TypeError) as error:
                raise ValueError(
                    f"{self.path}, line {number}, is damaged ({error}); move the file away, or add --force to fly the "
                    "matrix afresh."
                ) from None
            self.done[(cell.row, cell.column)] = cell
            walls[session] = max(walls.get(session, 0.0), wall)
            self._session = max(self._session, session + 1)
        self.earlier_wall_s = sum(walls.values())

    def record(self, cell: CellResult) -> None:
        """Append one finished cell and flush it to disk before the next one is flown."""
        self.done[(cell.row, cell.column)] = cell
        entry = {"session": self._session, "session_wall_s": time.perf_counter() - self._started, "cell": asdict(cell)}
        with self.path.open("a") as f:
            f.write(json.dumps(entry) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def interrupted(self) -> KeyboardInterrupt:
        """The Ctrl-C to raise instead of a bare one: it says where the finished cells are and how to resume."""
        return KeyboardInterrupt(
            f"Interrupted; the {len(self.done)} finished cells are kept in {self.path}: run the same command again to "
            "fly only the others."
        )

    def remove(self) -> None:
        """Delete the journal (its cells are now in the finished files)."""
        self.path.unlink(missing_ok=True)
