"""marlander_lite: the MARLander swarm-landing paper as a small, readable library.

Importing the package registers the gymnasium ids of every simulator in
:mod:`marlander_lite.simulators` (``marlander_lite/PointMassLanding-v0`` and
``marlander_lite/CrazyflieLanding-v0``).

Importing it also imports gymnasium, pettingzoo and Stable-Baselines3 (torch): about 2 s. The
``marlander`` command imports it before :func:`marlander_lite.cli.main` can catch anything, so a
Ctrl-C in those 2 s is handled here: when the program is the ``marlander`` command
(:func:`_started_as_command`), it ends with one line ``Interrupted.`` and exit status 130, like a
Ctrl-C anywhere else in the command; in any other program the ``KeyboardInterrupt`` goes on as usual.
"""

import itertools
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


try:
    from marlander_lite.envs.options import EnvOptions
    from marlander_lite.make import ENV_IDS, SIMULATORS, make_parallel_env, make_vec_env
    from marlander_lite.platforms import PLATFORM_KINDS, PlatformConfig
    from marlander_lite.sensing import SensingConfig
    from marlander_lite.simulators import SimulatorEntry, register_simulator, simulator_entry
    from marlander_lite.task import TaskConfig
except KeyboardInterrupt:
    if not _started_as_command():
        raise
    print("Interrupted.", file=sys.stderr)
    raise SystemExit(130) from None

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
