"""The ``marlander`` command line.

Each subcommand lives in its own module exposing ``register(subparsers)``, which adds an
``argparse`` parser whose ``func`` default runs the command and returns an exit code.

User errors (a bad option, a missing or unreadable file, a file that would be overwritten)
end the command with one line ``marlander COMMAND: error: ...`` and exit status 2, before any
work starts; Ctrl-C ends it with status 130 and no traceback. This module also holds the small
argument helpers the command modules share (:func:`positive_int`, :func:`check_output_file`).
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from marlander_lite import restore_interrupt_handler

COMMAND_MODULES = (
    "marlander_lite.training.commands",
    "marlander_lite.training.sweep_command",
    "marlander_lite.experiments.commands",
    "marlander_lite.experiments.transfer_command",
    "marlander_lite.swarm.commands",
    "marlander_lite.deploy.commands",
)

USER_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,  # also ConfigError, PolicyFileError, JSON and Unicode decoding errors
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)
"""Exceptions that mean the user asked for something impossible: reported in one line."""

LIBRARY_ERRORS = {
    "marlander_lite.deploy.schema": "ConfigError",
    "marlander_lite.policy_file": "PolicyFileError",
    "marlander_lite.deploy.link": "LinkError",
    "marlander_lite.deploy.rehearsal.world": "SimulatorUnavailable",
}
"""The library's own error types (module -> class name), looked up only if their module was imported."""


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1 (argparse names the option in its message)."""
    return _integer(text, minimum=1, what="a positive integer (1, 2, ...)")


def non_negative_int(text: str) -> int:
    """An argparse type: an integer >= 0, e.g. a seed."""
    return _integer(text, minimum=0, what="a non-negative integer (0, 1, ...)")


def _integer(text: str, minimum: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = minimum - 1
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def check_output_file(
    path: Path,
    option: str,
    force: bool,
    *,
    reading: Iterable[Path] = (),
    suffixes: Sequence[str] | None = None,
) -> None:
    """Refuse to write ``path`` (given with ``option``) when that would lose or misplace data.

    A directory, a file the command reads (even with ``--force``), a missing or wrong suffix
    (when ``suffixes`` is given) and an existing file without ``force`` raise ``ValueError``.
    """
    if path.is_dir():
        raise ValueError(f"{option} {path} is a directory; give a file name.")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise ValueError(f"{option} {path}: the file name must end in {', '.join(suffixes)}.")
    target = path.resolve()
    if any(target == Path(source).resolve() for source in reading):
        raise ValueError(f"{option} {path} is a file this command reads; choose another file.")
    if path.exists() and not force:
        raise ValueError(f"{option} {path} already exists; pass --force to overwrite it, or choose another file.")


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (no usage block); its subcommand parsers are too.

    An unknown option is reported by the (sub)command it was given to, with the options it may have meant.
    """

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")

    def parse_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> argparse.Namespace:  # type: ignore[override]
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            command = _command_parser(self, parsed)
            command.error(unrecognized(extras, [s for a in command._actions for s in a.option_strings]))
        return parsed


def _command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The innermost (sub)command parser that ``args`` went through."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and getattr(args, action.dest, None) in action.choices:
            return _command_parser(action.choices[getattr(args, action.dest)], args)
    return parser


def unrecognized(extras: Sequence[str], options: Sequence[str]) -> str:
    """The error for words no option took: each unknown option with the ones it may have meant.

    A dotted option (``--task.KEY``) lists every key its group takes; others get the closest spellings.
    """
    notes = []
    for word in extras:
        name = word.split("=", 1)[0]
        if not name.startswith("--"):
            continue
        group = name.rpartition(".")[0]
        keys = [o.removeprefix(f"{group}.") for o in options if group and o.startswith(f"{group}.")]
        keys = [key for key in keys if not key.startswith("no-")]  # the negations of bool keys
        if keys:
            notes.append(f"{name}: the keys of {group}.KEY are {', '.join(keys)}")
            continue
        close = difflib.get_close_matches(name, options, n=2, cutoff=0.8)
        notes.append(f"{name}: did you mean {' or '.join(close)}?" if close else f"{name} is not an option here")
    return f"unrecognized arguments: {' '.join(extras)}" + "".join(f"; {note}" for note in notes)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="marlander",
        description="MARLander swarm landing: train, evaluate, plot, reproduce the paper, deploy.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name == name:  # that group of commands is not part of this install
                continue
            raise
        module.register(subparsers)
    return parser


def is_user_error(error: BaseException) -> bool:
    """Whether ``error`` is reported as one line rather than a traceback."""
    if isinstance(error, USER_ERRORS):
        return True
    for module_name, class_name in LIBRARY_ERRORS.items():
        error_type = getattr(sys.modules.get(module_name), class_name, None)
        if isinstance(error_type, type) and isinstance(error, error_type):
            return True
    return False


def one_line(error: BaseException) -> str:
    """The error's message on one line (several lines are joined with '; ')."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return "; ".join(lines) or type(error).__name__


def main(argv: Sequence[str] | None = None) -> int:
    command = "marlander"
    try:
        restore_interrupt_handler()  # from here on a Ctrl-C is a KeyboardInterrupt, caught below
        parser = build_parser()
        args = parser.parse_args(argv)
        command = f"marlander {args.command}"
        return int(args.func(args) or 0)
    except KeyboardInterrupt as error:  # Ctrl-C; training says where its checkpoint is
        print(str(error) or "Interrupted.", file=sys.stderr)
        return 130
    except Exception as error:
        if not is_user_error(error):
            raise
        print(f"{command}: error: {one_line(error)}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    sys.exit(main())
