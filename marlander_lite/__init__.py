"""marlander_lite: the MARLander swarm-landing paper as a small, readable library.

Importing the package registers the gymnasium ids of every simulator in
:mod:`marlander_lite.simulators` (``marlander_lite/PointMassLanding-v0`` and
``marlander_lite/CrazyflieLanding-v0``).

Importing it also imports gymnasium, pettingzoo and Stable-Baselines3 (torch): about 2 s. The
``marlander`` command imports it before :func:`marlander_lite.cli.main` can catch anything, so a
Ctrl-C in those 2 s is handled here: when the program is the ``marlander`` command
(:func:`_started_as_command`), a SIGINT handler set before any other import ends it with one line
``Interrupted.`` and exit status 130, like a Ctrl-C anywhere else in the command, until
:func:`marlander_lite.cli.main` puts Python's own handler back (:func:`restore_interrupt_handler`). In any
other program the ``KeyboardInterrupt`` goes on as usual.
"""

import itertools
import multiprocessing
import os
import signal
import sys
from pathlib import Path

COMMAND_NAME = "marlander"
"""The console command (``[project.scripts]``) whose start-up a Ctrl-C may end quietly."""


def _started_as_command() -> bool:
    """Whether this process is the ``marlander`` command (its script, or ``python -m marlander_lite.cli``)."""
    argv = getattr(sys, "argv", None) or [""]
    if Path(str(argv[0])).stem == COMMAND_NAME:  # .venv/bin/marlander, marlander.exe on Windows
        return True
    orig = list(getattr(sys, "orig_argv", ()))  # python -m marlander_lite.cli: argv[0] is "-m" while importing
    return any(a == "-m" and b == f"{__name__}.cli" for a, b in itertools.pairwise(orig))


def _interrupted_during_start_up(signum: int, frame: object) -> None:
    """SIGINT handler of the ``marlander`` command's start-up: one line and exit status 130, no traceback.

    It ends the process at once (``os._exit``) rather than raising ``SystemExit``: a signal handler runs wherever the
    interpreter happens to be, and inside a callback of the import machinery (the weakref callback of importlib's
    module locks) a raised ``SystemExit`` is printed as "Exception ignored" with its traceback and the start-up goes
    on. Until :func:`marlander_lite.cli.main` runs, the command has only imported modules: nothing to close or save.
    """
    sys.stderr.write("Interrupted.\n")
    sys.stderr.flush()
    os._exit(130)


def restore_interrupt_handler() -> None:
    """Put Python's own SIGINT handler (``KeyboardInterrupt``) back if the start-up handler is still set;
    :func:`marlander_lite.cli.main` calls it once its own ``except KeyboardInterrupt`` is in place."""
    if signal.getsignal(signal.SIGINT) is _interrupted_during_start_up:
        signal.signal(signal.SIGINT, signal.default_int_handler)


# Only in the command's own process (not in the worker processes it spawns, which never run cli.main) and only over
# Python's default handler: a shell starts background jobs with SIGINT ignored, and that stays.
if (
    _started_as_command()
    and multiprocessing.parent_process() is None
    and signal.getsignal(signal.SIGINT) is signal.default_int_handler
):
    signal.signal(signal.SIGINT, _interrupted_during_start_up)

from marlander_lite.envs.options import EnvOptions  # noqa: E402 (after the start-up handler, on purpose)
from marlander_lite.make import ENV_IDS, SIMULATORS, make_parallel_env, make_vec_env  # noqa: E402
from marlander_lite.platforms import PLATFORM_KINDS, PlatformConfig  # noqa: E402
from marlander_lite.sensing import SensingConfig  # noqa: E402
from marlander_lite.simulators import SimulatorEntry, register_simulator, simulator_entry  # noqa: E402
from marlander_lite.task import TaskConfig  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ENV_IDS",
    "PLATFORM_KINDS",
    "SIMULATORS",
    "EnvOptions",
    "PlatformConfig",
    "SensingConfig",
    "SimulatorEntry",
    "TaskConfig",
    "__version__",
    "make_parallel_env",
    "make_vec_env",
    "register_simulator",
    "simulator_entry",
]
