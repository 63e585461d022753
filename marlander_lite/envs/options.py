"""The options of every environment face, as one frozen dataclass per simulator.

:class:`EnvOptions` holds what every simulator's envs take (the swarm size, the platform, the task
constants, the sensing model); each simulator extends it with its own fields and says how to build
its :class:`~marlander_lite.episodes.Simulator` (:class:`~marlander_lite.pointmass.envs.PointMassOptions`,
:class:`~marlander_lite.crazyflie.envs.CrazyflieOptions`). The three faces (gymnasium, stable-baselines3,
PettingZoo) take such an object, or its fields as keywords, which they turn into one with
:meth:`EnvOptions.from_keywords`; both spellings build the same env::

    make_vec_env("pointmass", num_envs=256, seed=0, num_drones=2, platform="moving-arc")
    make_vec_env("pointmass", num_envs=256, seed=0, options=PointMassOptions(num_drones=2, platform="moving-arc"))

The fields keep what was given (a platform name, a dict of task changes) so that the object prints
and compares as written; the ``*_config`` properties resolve them, and an object is only made when
they resolve, so a bad option fails where it was given, with its own message.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import numpy as np
from gymnasium import spaces

from marlander_lite.platforms import PLATFORM_KINDS, PlatformConfig, PlatformKind
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import ACT_PER_DRONE, TaskConfig, compiled_kernels, observation_limits

if TYPE_CHECKING:
    from marlander_lite.episodes import Simulator

SensingName = Literal["perfect", "vicon", "noisy", "robust"]
"""Named sensing models: none, the lab's motion capture (:meth:`SensingConfig.vicon`), the training aid
(:meth:`SensingConfig.noisy`)."""

OptionsT = TypeVar("OptionsT", bound="EnvOptions")
ConfigT = TypeVar("ConfigT")


def _is_count(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer) and value >= 1


def check_num_envs(num_envs: object) -> None:
    """Raise a ``ValueError`` unless ``num_envs`` is an integer >= 1."""
    if not _is_count(num_envs):
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}.")


def reject_unknown(names: Iterable[str], config_type: type, where: str, also: tuple[str, ...] = ()) -> None:
    """Raise a ``TypeError`` if a name in ``names`` is not a field of the dataclass ``config_type``.

    The dataclass would raise too, but with the first unknown name only and without the allowed ones,
    which this message lists (with ``also``: keywords a face takes besides the fields).
    """
    allowed = [f.name for f in dataclasses.fields(config_type)]
    unknown = sorted(set(names) - set(allowed))
    if unknown:
        raise TypeError(f"{where} got unknown option(s) {unknown}; allowed options: {', '.join([*allowed, *also])}.")


def config_from_mapping(config_type: type[ConfigT], values: Mapping[str, Any], where: str) -> ConfigT:
    """``config_type(**values)`` for a dataclass, naming the allowed fields if one in ``values`` is unknown."""
    reject_unknown(values, config_type, where)
    return config_type(**values)


def check_bounded_fields(
    config: object, bounds: Iterable[tuple[str, float, float, bool]], optional: tuple[str, ...] = ()
) -> None:
    """Every ``(name, low, high, open_low)`` field of ``config`` a finite number in ``[low, high]`` (``(low, high]``
    when ``open_low``), or None for the ``optional`` ones. Raises ``ValueError`` naming the field and its interval."""
    owner = type(config).__name__
    for name, low, high, open_low in bounds:
        value = getattr(config, name)
        if value is None and name in optional:
            continue
        finite = isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(value)
        inside = finite and (low < value if open_low else low <= value) and value <= high
        if not inside:
            bracket = "(" if open_low else "["
            raise ValueError(f"{owner}.{name} must be a number in {bracket}{low:g}, {high:g}], got {value!r}.")


def build_config(config_type: type[ConfigT], value: ConfigT | Mapping[str, Any] | None, where: str) -> ConfigT:
    """An option that takes a config dataclass: one, a mapping of its fields, or None for its defaults."""
    if value is None or isinstance(value, config_type):
        return value or config_type()
    if not isinstance(value, Mapping):
        raise TypeError(
            f"{where} must be a {config_type.__name__}, a mapping of its fields or None, got {type(value).__name__}."
        )
    return config_from_mapping(config_type, value, where)


@dataclass(frozen=True)
class EnvOptions:
    """What every env of every simulator takes: N drones, a platform, the MDP constants, the sensing model.

    A simulator's own options subclass this, add their fields and implement :meth:`make_simulator`.
    """

    num_drones: int = 2
    """Drones per swarm, N >= 1 (the paper flies 2)."""
    platform: PlatformKind | PlatformConfig = "static-floor"
    """One of ``PLATFORM_KINDS`` (floor, held still by the UR10, moved along a line or an arc), or a full
    :class:`~marlander_lite.platforms.PlatformConfig`."""
    platform_speed: float | tuple[float, float] | None = None
    """Tool speed of a moving platform (m/s; default 0.35), or a ``(low, high)`` range drawn per episode.
    Only next to a platform name: a :class:`PlatformConfig` carries its own speed."""
    task: TaskConfig | Mapping[str, Any] | None = None
    """A :class:`~marlander_lite.task.TaskConfig` (eq. 2-6 constants), or a mapping of its fields to change in
    the default one (``{"episode_seconds": 5}``); ``num_drones`` above wins over the task's own."""
    sensing: SensingConfig | SensingName | None = None
    """A :class:`~marlander_lite.sensing.SensingConfig`, a :data:`SensingName`, or ``None`` (``"perfect"``)."""

    def __post_init__(self) -> None:
        # Resolve everything once now: a bad option fails here, where it was given.
        _ = (self.task_config, self.platform_config, self.sensing_config)

    @property
    def task_config(self) -> TaskConfig:
        """The MDP's constants with ``num_drones`` drones."""
        n, task = self.num_drones, self.task
        if not _is_count(n):
            raise ValueError(f"num_drones must be an integer >= 1, got {n!r}.")
        if task is None:
            return TaskConfig(num_drones=int(n))
        if isinstance(task, TaskConfig):
            return task if task.num_drones == n else task.replace(num_drones=int(n))
        if isinstance(task, Mapping):
            return TaskConfig().replace(**{"num_drones": int(n), **task})
        raise TypeError(f"task must be a TaskConfig or a mapping of its fields, got {type(task).__name__}.")

    @property
    def platform_config(self) -> PlatformConfig:
        """The platform's motion and geometry."""
        if isinstance(self.platform, PlatformConfig):
            if self.platform_speed is not None:
                raise ValueError("Give platform_speed inside the PlatformConfig, not next to it.")
            return self.platform
        if isinstance(self.platform, str):
            if self.platform not in PLATFORM_KINDS:
                raise ValueError(f"Unknown platform {self.platform!r}; allowed: {', '.join(PLATFORM_KINDS)}.")
            return PlatformConfig(kind=self.platform, speed=self.platform_speed)
        raise TypeError(f"platform must be a name in {PLATFORM_KINDS} or a PlatformConfig, got {self.platform!r}.")

    @property
    def sensing_config(self) -> SensingConfig:
        """The noise and latency of the observation."""
        sensing = self.sensing
        if isinstance(sensing, SensingConfig):
            return sensing
        if sensing is None or sensing == "perfect":
            return SensingConfig()
        if sensing == "vicon":
            return SensingConfig.vicon()
        if sensing == "noisy":
            return SensingConfig.noisy()
        if sensing == "robust":
            return SensingConfig.robust()
        raise ValueError(
            f"sensing must be a SensingConfig, 'vicon', 'noisy', 'robust', 'perfect' or None, got {sensing!r}."
        )

    def make_simulator(self, num_envs: int = 1) -> Simulator:
        """A simulator of ``num_envs`` swarms with these options; each simulator's options implement it."""
        raise NotImplementedError(
            f"{type(self).__name__} holds the common options only; use a simulator's options, such as PointMassOptions."
        )

    def build(self, num_envs: int = 1) -> tuple[Simulator, SensingConfig]:
        """``(simulator, sensing)``: what :class:`~marlander_lite.episodes.LandingEpisodes` and every face need."""
        check_num_envs(num_envs)
        return self.make_simulator(int(num_envs)), self.sensing_config

    @classmethod
    def from_keywords(
        cls: type[OptionsT],
        keywords: Mapping[str, Any],
        options: EnvOptions | None = None,
        where: str | None = None,
        face_keywords: tuple[str, ...] = (),
    ) -> OptionsT:
        """The options a face was called with: ``options``, with the fields named in ``keywords`` changed.

        Args:
            keywords: option fields by name, e.g. ``{"num_drones": 3}``.
            options: an options object of this class (or common :class:`EnvOptions`, whose fields carry over);
                ``None`` starts from the defaults.
            where: the face, for error messages (default: the class name).
            face_keywords: keywords the face itself takes, listed as allowed in the error message.

        Raises:
            TypeError: a keyword is not a field of ``cls``; the message lists the allowed ones.
        """
        where = where or cls.__name__
        reject_unknown(keywords, cls, where, face_keywords)
        if options is None:
            return cls(**keywords)
        if not isinstance(options, cls):
            if not (isinstance(options, EnvOptions) and issubclass(cls, type(options))):
                raise TypeError(f"{where} takes {cls.__name__} options, got {type(options).__name__}.")
            common = {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}
            return cls(**{**common, **keywords})
        return dataclasses.replace(options, **keywords) if keywords else options


def drone_observation_space(task: TaskConfig) -> spaces.Box:
    """One drone's eq. 2 observation: ``(13,)`` float32, 3 more for each extra the task asks for (the platform
    velocity, the previous command, the platform acceleration: ``TaskConfig.observe_platform_velocity`` /
    ``observe_previous_command`` / ``observe_platform_acceleration``), times ``observation_history`` frames."""
    high = observation_limits(task.frame_per_drone, task.observation_history).astype(np.float32)
    return spaces.Box(-high, high, dtype=np.float32)


def drone_action_space() -> spaces.Box:
    """One drone's eq. 3 action: normalised velocity ``(3,)`` in ``[-1, 1]``."""
    return spaces.Box(-1.0, 1.0, shape=(ACT_PER_DRONE,), dtype=np.float32)


def centralised_observation_space(task: TaskConfig) -> spaces.Box:
    """The paper's flattened input: ``(13 N,)`` float32; with the extras and ``observation_history``
    ``(TaskConfig.obs_per_drone N,)``, each drone's part bounded as :func:`drone_observation_space`."""
    high = np.tile(drone_observation_space(task).high, task.num_drones)
    return spaces.Box(-high, high, dtype=np.float32)


def centralised_action_space(num_drones: int) -> spaces.Box:
    """The paper's output: 3 velocity components per drone, ``(3 N,)`` in ``[-1, 1]``."""
    return spaces.Box(-1.0, 1.0, shape=(ACT_PER_DRONE * num_drones,), dtype=np.float32)


def policy_input(obs: np.ndarray) -> np.ndarray:
    """``(num_envs, N, 13)`` observations as a float32 ``(num_envs, 13 N)`` array (row-major: one env per row)."""
    kernels = compiled_kernels()
    if kernels is not None and obs.ndim == 3 and obs.dtype == np.float64:  # the same numbers, transposed faster
        out = np.empty((obs.shape[0], obs.shape[1] * obs.shape[2]), dtype=np.float32)
        kernels.policy_rows(obs, out)
        return out
    return obs.astype(np.float32, order="K").reshape(obs.shape[0], -1)
