"""The simulators marlander_lite knows, in one registry: name -> simulator class, env faces, options.

Everything that picks a simulator by name reads :data:`REGISTRY`: the gymnasium ids (registered by
:func:`register_simulator`), :func:`~marlander_lite.make.make_vec_env` and
:func:`~marlander_lite.make.make_parallel_env`, the experiments' trials
(:func:`~marlander_lite.experiments.protocol.make_episodes`) and the lab rehearsal's simulated world.
Each simulator has one name everywhere: ``"pointmass"``, ``"crazyflie"``, ``"rotorpy"`` or ``"pyflyt"`` (the
optional extras ``rotorpy`` and ``pyflyt``: two simulators this project did not write, for flying policies trained
here).

An entry names its classes as ``"module:attr"`` strings and imports them on first use, so that a
point-mass env never imports PyBullet::

    entry = simulator_entry("crazyflie")
    entry.env_id                       # "marlander_lite/CrazyflieLanding-v0"
    swarm = entry.swarm_class()        # CrazyflieSwarm; PyBullet is imported here, not before
    swarm(task_config, platform_config, 1)

## Adding a simulator

Write the simulator (a class with the :class:`~marlander_lite.episodes.Simulator` protocol, built as
``Swarm(task_config, platform_config, num_envs)``), its options (a frozen subclass of
:class:`~marlander_lite.envs.options.EnvOptions` that adds its own fields and implements
``make_simulator``) and its three faces, a few lines each (see :mod:`marlander_lite.pointmass.envs`).
Then add one entry, at the end of this module to make it built in, or from your own code::

    register_simulator(
        SimulatorEntry(
            name="mysim",
            env_id="marlander_lite/MySimLanding-v0",
            swarm="mypackage.simulator:MySwarm",
            gym_env="mypackage.envs:MySimLandingEnv",
            vec_env="mypackage.envs:MySimVecEnv",
            parallel_env="mypackage.envs:mysim_parallel_env",
            options="mypackage.envs:MySimOptions",
            description="What it simulates, in one line.",
        )
    )

Nothing else is edited: ``make_vec_env("mysim", ...)``, ``make_parallel_env("mysim", ...)``,
``gymnasium.make("marlander_lite/MySimLanding-v0", ...)``, the experiments and the rehearsal find it
here. Entries registered in this module are also in :data:`SIMULATORS` and :data:`SimulatorName`,
the names the command line offers.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from gymnasium.envs.registration import register as register_gym_env
from gymnasium.envs.registration import registry as gym_registry

if TYPE_CHECKING:
    from collections.abc import Callable

    import gymnasium
    from pettingzoo import ParallelEnv
    from stable_baselines3.common.vec_env import VecEnv

    from marlander_lite.envs.options import EnvOptions
    from marlander_lite.episodes import Simulator


def _load(path: str) -> Any:
    """The object ``attr`` of ``module`` for a ``"module:attr"`` path, importing the module."""
    module, attr = path.split(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class SimulatorEntry:
    """One simulator: its name, its gymnasium id, and where its classes live (``"module:attr"``).

    The faces are called the same way for every simulator, with ``fields`` the simulator's options as
    keywords and ``options`` an instance of its options class (either or both; keywords win):

    - ``gym_env(options=None, **fields)``: a ``gymnasium.Env`` class, the id's entry point;
    - ``vec_env(num_envs=..., seed=..., options=None, **fields)``: a stable-baselines3 ``VecEnv``;
    - ``parallel_env(options=None, **fields)``: a PettingZoo ``ParallelEnv``, one agent per drone;
    - ``swarm(task_config, platform_config, num_envs)``: the bare
      :class:`~marlander_lite.episodes.Simulator`, default physics, for code that needs no face.
    """

    name: str
    """The simulator's one name, used everywhere (``make_vec_env(name)``, configs, the command line)."""
    env_id: str
    """Versioned gymnasium id, ``"marlander_lite/<Name>Landing-v<N>"``."""
    swarm: str
    """The :class:`~marlander_lite.episodes.Simulator` class."""
    gym_env: str
    """The gymnasium env class."""
    vec_env: str
    """The stable-baselines3 ``VecEnv`` class or factory."""
    parallel_env: str
    """The PettingZoo ``ParallelEnv`` factory."""
    options: str
    """The simulator's frozen :class:`~marlander_lite.envs.options.EnvOptions` subclass."""
    description: str
    """One line: what the simulator is."""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"A simulator name must be a non-empty string such as 'pointmass', got {self.name!r}.")
        for field in ("swarm", "gym_env", "vec_env", "parallel_env", "options"):
            module, _, attr = getattr(self, field).partition(":")
            if not module or not attr.isidentifier():
                raise ValueError(f"{field} must be a 'module:attr' path, got {getattr(self, field)!r}.")

    def swarm_class(self) -> type[Simulator]:
        """The :class:`~marlander_lite.episodes.Simulator` class, imported now."""
        return _load(self.swarm)

    def gym_env_class(self) -> type[gymnasium.Env]:
        """The gymnasium env class, imported now."""
        return _load(self.gym_env)

    def vec_env_factory(self) -> Callable[..., VecEnv]:
        """The ``VecEnv`` factory, imported now."""
        return _load(self.vec_env)

    def parallel_env_factory(self) -> Callable[..., ParallelEnv]:
        """The PettingZoo factory, imported now."""
        return _load(self.parallel_env)

    def options_class(self) -> type[EnvOptions]:
        """The options class, imported now."""
        return _load(self.options)


REGISTRY: dict[str, SimulatorEntry] = {}
"""Every registered simulator by name, in registration order; fill it with :func:`register_simulator`."""


def register_simulator(entry: SimulatorEntry) -> SimulatorEntry:
    """Add ``entry`` to :data:`REGISTRY` and its id to gymnasium's registry; return it.

    Registering the same entry again does nothing (a module may be imported twice).

    Raises:
        ValueError: another entry has the same name or id, or gymnasium already knows the id
            with another entry point.
    """
    known = REGISTRY.get(entry.name)
    if known is not None and known != entry:
        raise ValueError(f"A simulator named {entry.name!r} is already registered: {known}.")
    for other in REGISTRY.values():
        if other.env_id == entry.env_id and other.name != entry.name:
            raise ValueError(f"The gymnasium id {entry.env_id!r} already belongs to simulator {other.name!r}.")
    spec = gym_registry.get(entry.env_id)
    if spec is None:
        register_gym_env(id=entry.env_id, entry_point=entry.gym_env)
    elif spec.entry_point != entry.gym_env:
        raise ValueError(f"gymnasium already registers {entry.env_id!r}, with entry point {spec.entry_point!r}.")
    REGISTRY[entry.name] = entry
    return entry


def simulator_entry(name: str) -> SimulatorEntry:
    """The registry entry of simulator ``name``.

    Raises:
        ValueError: ``name`` is not registered; the message lists the names that are.
    """
    if not isinstance(name, str) or name not in REGISTRY:
        raise ValueError(f"Unknown simulator {name!r}; allowed: {', '.join(REGISTRY)}.")
    return REGISTRY[name]


# ----------------------------------------------------------------------------- the built-in simulators

register_simulator(
    SimulatorEntry(
        name="pointmass",
        env_id="marlander_lite/PointMassLanding-v0",
        swarm="marlander_lite.pointmass.simulator:PointMassSwarm",
        gym_env="marlander_lite.pointmass.envs:PointMassLandingEnv",
        vec_env="marlander_lite.pointmass.envs:PointMassVecEnv",
        parallel_env="marlander_lite.pointmass.envs:pointmass_parallel_env",
        options="marlander_lite.pointmass.envs:PointMassOptions",
        description="Point masses with a fitted velocity-tracker lag, natively batched in numpy (fast, no PyBullet).",
    )
)
register_simulator(
    SimulatorEntry(
        name="crazyflie",
        env_id="marlander_lite/CrazyflieLanding-v0",
        swarm="marlander_lite.crazyflie.simulator:CrazyflieSwarm",
        gym_env="marlander_lite.crazyflie.envs:CrazyflieLandingEnv",
        vec_env="marlander_lite.crazyflie.envs:make_crazyflie_vec_env",
        parallel_env="marlander_lite.crazyflie.envs:crazyflie_parallel_env",
        options="marlander_lite.crazyflie.envs:CrazyflieOptions",
        description="PyBullet Crazyflie 2.x rigid bodies under a cascaded PID or the firmware tracker (Sec. III-F).",
    )
)

register_simulator(
    SimulatorEntry(
        name="rotorpy",
        env_id="marlander_lite/RotorPyLanding-v0",
        swarm="marlander_lite.rotorpy_sim.simulator:RotorPySwarm",
        gym_env="marlander_lite.rotorpy_sim.envs:RotorPyLandingEnv",
        vec_env="marlander_lite.rotorpy_sim.envs:RotorPyVecEnv",
        parallel_env="marlander_lite.rotorpy_sim.envs:rotorpy_parallel_env",
        options="marlander_lite.rotorpy_sim.envs:RotorPyOptions",
        description="RotorPy's Crazyflie under RotorPy's own velocity controller (a simulator we did not write).",
    )
)
register_simulator(
    SimulatorEntry(
        name="pyflyt",
        env_id="marlander_lite/PyFlytLanding-v0",
        swarm="marlander_lite.pyflyt_sim.simulator:PyFlytSwarm",
        gym_env="marlander_lite.pyflyt_sim.envs:PyFlytLandingEnv",
        vec_env="marlander_lite.pyflyt_sim.envs:PyFlytVecEnv",
        parallel_env="marlander_lite.pyflyt_sim.envs:pyflyt_parallel_env",
        options="marlander_lite.pyflyt_sim.envs:PyFlytOptions",
        description="PyFlyt's Crazyflie under PyFlyt's own cascaded PID (a second simulator we did not write).",
    )
)

SIMULATORS: tuple[str, ...] = tuple(REGISTRY)
"""The built-in simulators' names, ``("pointmass", "crazyflie", "rotorpy", "pyflyt")``: the choices the command line
offers. Simulators registered later are reachable by name everywhere too, but are not listed here."""

# A Literal made from the entries above, so that the names are written once; tools that read it at run
# time (argument parsers, config loaders) see the choices. Static type checkers see a plain str.
if TYPE_CHECKING:
    SimulatorName = str
else:
    SimulatorName = Literal[SIMULATORS]
"""A built-in simulator's name, as a ``Literal`` type."""
