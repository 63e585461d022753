"""Signals during a flight: Ctrl-C, ``kill`` and a dropped SSH session all land the drones.

A program flying drones must not die in the air. Three signals can end a flight from outside:

* ``SIGINT``: Ctrl-C in the terminal;
* ``SIGTERM``: ``kill PID``, ``timeout``, systemd or a container stopping;
* ``SIGHUP``: the terminal or the SSH session carrying it closed.

Python's default turns ``SIGINT`` into a ``KeyboardInterrupt`` that can surface between any two
bytecodes (in the middle of writing a log line, say), and lets ``SIGTERM`` and ``SIGHUP`` kill
the process at once: no landing, no log summary, no clean-up. During a flight
:class:`marlander_lite.deploy.mission.Mission` therefore installs :func:`handle_signals`: the
handler only records the signal; the loop acts on it at the start of its next tick, the same way
for all three (first signal: land every drone; second: stop every motor). The previous handlers
come back when the flight ends.

Around the rest of a command (connecting, the rehearsal's settling, closing),
:func:`terminate_as_interrupt` makes ``SIGTERM`` and ``SIGHUP`` raise ``KeyboardInterrupt`` like
Ctrl-C does, so that ``finally`` blocks still close the radios and remove temporary folders.

Handlers can only be installed from the main thread; elsewhere both helpers do nothing (the
loop still treats a ``KeyboardInterrupt`` raised inside it like a ``SIGINT``).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

FLIGHT_SIGNALS: tuple[str, ...] = tuple(name for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
"""The signals that land the drones (SIGHUP does not exist on Windows)."""

REASONS = {
    "SIGINT": "Ctrl-C",
    "SIGTERM": "SIGTERM (the program was asked to stop)",
    "SIGHUP": "SIGHUP (the terminal or SSH session closed)",
}
"""How each signal is named in events and messages."""


def describe(name: str) -> str:
    """A human-readable reason for signal ``name`` (e.g. ``"SIGTERM"``)."""
    return REASONS.get(name, name)


def exit_code(name: str) -> int:
    """The shell's exit status of a program ended by signal ``name``: 128 + its number (SIGTERM: 143)."""
    return 128 + int(signal.Signals[name])


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def _installed(handler: Callable[[int, FrameType | None], Any], names: tuple[str, ...]) -> Iterator[bool]:
    """Install ``handler`` for ``names`` for the block, then put the previous handlers back."""
    if not _in_main_thread():
        yield False
        return
    previous: dict[signal.Signals, Any] = {}
    try:
        for name in names:
            number = signal.Signals[name]
            previous[number] = signal.signal(number, handler)
        yield True
    finally:
        for number, old in previous.items():
            signal.signal(number, old if old is not None else signal.SIG_DFL)


@contextlib.contextmanager
def handle_signals(callback: Callable[[str], None], names: tuple[str, ...] = FLIGHT_SIGNALS) -> Iterator[bool]:
    """Call ``callback(signal_name)`` instead of the usual action for ``names`` while the block runs.

    The callback runs in the main thread between two bytecodes, so it must only record what
    happened (set a flag); it must not raise. Yields whether the handlers were installed (False
    outside the main thread).
    """

    def handler(signum: int, frame: FrameType | None) -> None:
        callback(signal.Signals(signum).name)

    with _installed(handler, names) as installed:
        yield installed


@contextlib.contextmanager
def terminate_as_interrupt(names: tuple[str, ...] = ("SIGTERM", "SIGHUP")) -> Iterator[bool]:
    """Make ``names`` raise ``KeyboardInterrupt`` while the block runs, so that clean-up code runs."""
    names = tuple(n for n in names if n in FLIGHT_SIGNALS)

    def handler(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)

    with _installed(handler, names) as installed:
        yield installed
