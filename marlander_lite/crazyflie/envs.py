"""The PyBullet simulator's options and three faces: gymnasium, a stable-baselines3 ``VecEnv``, PettingZoo."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, ClassVar, Literal, get_args

import numpy as np
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv, VecMonitor

from marlander_lite.crazyflie.batch import CrazyflieBatch
from marlander_lite.crazyflie.control import PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains
from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig, build_physics
from marlander_lite.crazyflie.perturb import Controller, Perturbation, build_perturbation, check_controller
from marlander_lite.crazyflie.simulator import CrazyflieSwarm
from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import EnvOptions, check_num_envs
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.pointmass.kernels import Engine, resolve_engine
from marlander_lite.sensing import SensingConfig

RenderMode = Literal["rgb_array", "human"]
RENDER_MODES: tuple[str, ...] = ("rgb_array", "human")
FRAME_SIZE = (480, 360)
"""Width and height (pixels) of ``rgb_array`` frames and recorded videos."""


@dataclass(frozen=True)
class CrazyflieOptions(EnvOptions):
    """The options of the PyBullet envs: the common :class:`~marlander_lite.envs.options.EnvOptions`, the
    physics, the drone, and the velocity tracker that flies it.

    ``gui``, ``render_mode`` and ``video_path`` are not options of the task but of one face (a window or a
    video of one world), so they are keywords of :class:`CrazyflieLandingEnv` (and ``gui`` of
    :func:`crazyflie_parallel_env`).
    """

    physics: PhysicsConfig | Mapping[str, Any] | str | None = None
    """A :class:`PhysicsConfig`, a preset name (``"aero"``, the default: ground effect, drag, downwash;
    ``"bare"``: rigid body and motors only), or a mapping of its fields (``{"control_hz": 30}``)."""
    drone: CF2XParams | None = None
    """The airframe (:class:`CF2XParams`); ``None``: the Crazyflie 2.x."""
    gains: PIDGains | None = None
    """Gains of the ``"pid"`` tracker (:class:`PIDGains`); ``None``: its defaults."""
    controller: Controller = "pid"
    """The velocity tracker: ``"pid"`` (our cascaded PID at 48 Hz, chasing ``p + u dt`` and ``u``) or
    ``"firmware"`` (the Crazyflie firmware's velocity PID, :mod:`marlander_lite.crazyflie.firmware`)."""
    engine: Engine = "auto"
    """Who runs the control ticks: ``"numpy"`` (the reference, Python floats), ``"numba"`` (compiled, the same results
    bit for bit, faster) or ``"auto"`` (numba when installed, unless ``MARLANDER_LITE_ENGINE=numpy``); see
    :mod:`marlander_lite.crazyflie.tick_kernels`."""
    perturbation: Perturbation | Mapping[str, Any] | None = None
    """How the drone differs from the one its tracker was tuned for (:class:`Perturbation` or a mapping of
    its fields, e.g. ``{"mass_scale": 1.15, "latency_s": 0.06}``); ``None``: not at all."""
    firmware_gains: FirmwareGains | None = None
    """Gains and limits of the ``"firmware"`` tracker (:class:`FirmwareGains`: its tilt clamp, attitude and rate
    loops); ``None``: the Crazyflie firmware's defaults. Only with ``controller="firmware"``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.drone is not None and not isinstance(self.drone, CF2XParams):
            raise TypeError(f"drone must be a CF2XParams, got {type(self.drone).__name__}.")
        if self.gains is not None and not isinstance(self.gains, PIDGains):
            raise TypeError(f"gains must be a PIDGains, got {type(self.gains).__name__}.")
        check_controller(self.controller)
        if self.firmware_gains is not None:
            if not isinstance(self.firmware_gains, FirmwareGains):
                raise TypeError(f"firmware_gains must be a FirmwareGains, got {type(self.firmware_gains).__name__}.")
            if self.controller != "firmware":
                raise ValueError(
                    f"firmware_gains set the 'firmware' tracker's gains, but controller={self.controller!r}; "
                    "give controller='firmware', or gains=PIDGains(...) for the 'pid' tracker."
                )
        resolve_engine(self.engine)
        _ = (self.physics_config, self.perturbation_config)

    @property
    def physics_config(self) -> PhysicsConfig:
        """``physics`` as a :class:`PhysicsConfig`."""
        return build_physics(self.physics)

    @property
    def perturbation_config(self) -> Perturbation:
        """``perturbation`` as a :class:`Perturbation`."""
        return build_perturbation(self.perturbation)

    def make_simulator(self, num_envs: int = 1, gui: bool = False) -> CrazyflieSwarm | CrazyflieBatch:
        """One PyBullet world (``num_envs=1``, optionally in a ``gui`` window), or a batch of them in this process."""
        if num_envs == 1:
            return CrazyflieSwarm(
                self.task_config,
                self.platform_config,
                1,
                self.physics_config,
                self.drone,
                self.gains,
                bool(gui),
                controller=self.controller,
                perturbation=self.perturbation_config,
                firmware_gains=self.firmware_gains,
                engine=self.engine,
            )
        if gui:
            raise ValueError("gui opens one PyBullet window: build one world (num_envs=1) to watch it.")
        return self.make_batch(num_envs)

    def make_batch(self, num_envs: int) -> CrazyflieBatch:
        """``num_envs`` PyBullet worlds in this process behind one batched simulator."""
        return CrazyflieBatch(
            self.task_config,
            self.platform_config,
            num_envs,
            self.physics_config,
            self.drone,
            self.gains,
            controller=self.controller,
            perturbation=self.perturbation_config,
            firmware_gains=self.firmware_gains,
            engine=self.engine,
        )


def build_simulator(**options: Any) -> tuple[CrazyflieSwarm | CrazyflieBatch, SensingConfig]:
    """``(simulator, sensing)`` of one world from :class:`CrazyflieOptions` fields given as keywords."""
    return CrazyflieOptions.from_keywords(options, where="crazyflie build_simulator").build()


class CrazyflieLandingEnv(SwarmLandingEnv):
    """``marlander_lite/CrazyflieLanding-v0``: land N PyBullet Crazyflies on their own pads.

    ## Description
    The MARLander task (Aschu et al., Sec. III) in the physics simulator the paper trained in
    (Sec. III-F, Fig. 4: PyBullet). N Crazyflie 2.x quadrotors start at random in a 4 x 4 x 4 m
    arena and must each land on their own pad of a plate that lies on the floor, is held up by
    a UR10 arm, or is moved by it. One centralised policy sees every drone and commands every
    drone's velocity. Each command becomes a target position ``p + u dt`` and velocity ``u`` for
    a cascaded PID (48 Hz) that drives the four motors of a rigid-body model (240 Hz), with
    ground effect, rotor drag and a bounded downwash model (see
    :class:`~marlander_lite.crazyflie.params.PhysicsConfig`).

    ## Action Space
    ``Box(-1, 1, (3N,), float32)``: for each drone in turn, a velocity command along world x, y, z
    as a fraction of ``max_speed`` (3 m/s) (eq. 3). Entries beyond [-1, 1] are clipped; NaN
    raises ``ValueError``.

    ## Observation Space
    ``Box((13N,), float32)``: for each drone in turn (eq. 2), its position relative to its goal
    point (pad centre raised by ``landed_height``) [m], its attitude quaternion (x, y, z, w), its
    velocity relative to the platform [m/s] and its angular velocity [rad/s], world frame.

    ## Rewards
    Eq. 4: ``R_t = sum_i [alpha (|p_{t-1}| - |p_t|) + beta |v_t| + c 1(lands now)] - alpha_c
    1(collision) + K 1(all landed now)``, with the constants of :class:`~marlander_lite.task.TaskConfig`.

    ## Starting State
    Platform placed uniformly where its whole path fits in the arena (on the floor, 0.5-1.0 m up
    on the UR10 column, random phase when moving); drones uniform in the arena, at least 0.3 m
    above the plate and 0.5 m apart, at rest and level, motors at hover speed.

    ## Episode End
    Terminated when every drone has landed (success: it touched its own pad, as reported by
    PyBullet's contact points, within the pad radius and slower than 0.5 m/s relative to it),
    or when a drone touches anything else or its pad too fast or off-centre (crash), two drones
    come closer than 0.15 m (collision), or a drone leaves the arena. Truncated after
    ``episode_seconds`` (10 s, 240 steps at 24 Hz). A landed drone is latched to its pad.

    ## Arguments
    ``gymnasium.make("marlander_lite/CrazyflieLanding-v0", gui=False, render_mode=None, video_path=None,
    **fields)`` with the fields of :class:`CrazyflieOptions` (``num_drones=2, platform="static-floor",
    platform_speed=None, task=None, sensing=None, physics=None, drone=None, gains=None, controller="pid",
    engine="auto", perturbation=None``), or ``options=CrazyflieOptions(...)``: ``platform`` is one of
    ``static-floor``, ``static-elevated``, ``moving-linear``, ``moving-arc``, ``moving-mixed`` (line or arc
    per episode); ``platform_speed`` the moving tool speed (m/s, default 0.35); ``task`` a :class:`TaskConfig`
    or dict of fields to change
    (``policy_hz`` sets the action rate); ``sensing`` a :class:`SensingConfig` or ``"vicon"``; ``physics`` a
    :class:`PhysicsConfig`, ``"aero"`` (default: ground effect, drag, downwash) or ``"bare"`` (rigid body
    and motors only), or a dict of its fields (e.g. ``{"control_hz": 30, "downwash": False}``); ``drone`` a
    :class:`CF2XParams`; ``gains`` a :class:`PIDGains`; ``controller`` the velocity tracker: ``"pid"``
    (default, our cascaded PID at 48 Hz, chasing ``p + u dt`` and ``u``) or ``"firmware"`` (the Crazyflie
    firmware's own velocity PID, which follows ``send_velocity_world_setpoint`` on hardware: 100 Hz velocity
    loop, attitude and rate loops at every physics step, tilt within 20 degrees; see
    :mod:`marlander_lite.crazyflie.firmware`); ``perturbation`` a
    :class:`~marlander_lite.crazyflie.perturb.Perturbation` or a dict of its fields (``{"mass_scale": 1.15,
    "latency_s": 0.06, "gain_scale": 0.7}``: a drone heavier than its tracker believes, commands that arrive
    late, softer or stiffer outer gains); ``engine`` who runs the control ticks (``"numpy"``: the Python reference,
    ``"numba"``: compiled, the same results bit for bit; ``"auto"``: numba when installed); ``gui`` opens a PyBullet
    window; ``render_mode="rgb_array"`` makes
    :meth:`render` return an image, ``"human"`` opens the window; ``video_path`` records every episode as an
    animated GIF ``<video_path stem>-<episode>.gif``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": list(RENDER_MODES), "render_fps": 24}

    def __init__(
        self,
        options: CrazyflieOptions | None = None,
        *,
        gui: bool = False,
        render_mode: RenderMode | None = None,
        video_path: str | os.PathLike | None = None,
        **fields: Any,
    ) -> None:
        face_keywords = ("gui", "render_mode", "video_path")
        options = CrazyflieOptions.from_keywords(fields, options, "CrazyflieLanding-v0", face_keywords)
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"Unknown render_mode {render_mode!r}; allowed: None, {', '.join(RENDER_MODES)}.")
        super().__init__(options.make_simulator(1, gui=gui or render_mode == "human"), options.sensing_config)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": self.task.policy_hz}
        self.video_path = None if video_path is None else Path(video_path)
        self._frames: list[np.ndarray] = []
        self._episode = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        out = super().reset(seed=seed, options=options)
        if self.video_path is not None:
            self._save_video()
            self._frames.append(self._frame())
        return out

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        out = super().step(action)
        if self.video_path is not None:
            self._frames.append(self._frame())
            if out[2] or out[3]:
                self._save_video()
        return out

    def render(self) -> np.ndarray | None:
        """An RGB frame ``(360, 480, 3)`` uint8 in ``"rgb_array"`` mode; the PyBullet window shows ``"human"``."""
        return self._frame() if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if self.video_path is not None:
            self._save_video()
        super().close()

    def _frame(self) -> np.ndarray:
        """A camera image of the arena, looking at the plate from 4 m away."""
        sim = self.simulator
        target = (sim.pad_pos[0, :, 0].mean(), sim.pad_pos[0, :, 1].mean(), 0.8)
        return sim.world.render(*FRAME_SIZE, target=target, distance=4.0)

    def _save_video(self) -> None:
        """Write the frames recorded so far as ``<stem>-<episode>.gif`` (Pillow), then start afresh."""
        if len(self._frames) < 2 or self.video_path is None:
            self._frames = []
            return
        from PIL import Image

        path = self.video_path.with_name(f"{self.video_path.stem}-{self._episode:03d}.gif")
        path.parent.mkdir(parents=True, exist_ok=True)
        images = [Image.fromarray(frame) for frame in self._frames]
        images[0].save(
            path, save_all=True, append_images=images[1:], duration=round(1000 / self.task.policy_hz), loop=0
        )
        self._frames = []
        self._episode += 1


def crazyflie_parallel_env(
    options: CrazyflieOptions | None = None, *, gui: bool = False, **fields: Any
) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the PyBullet swarm, one agent per drone; options as :class:`CrazyflieLandingEnv`
    (except ``render_mode`` and ``video_path``)."""
    options = CrazyflieOptions.from_keywords(fields, options, "crazyflie_parallel_env", ("gui",))
    return SwarmParallelEnv(options.make_simulator(1, gui=gui), options.sensing_config)


Vectorization = Literal["batched", "subprocess"]
VECTORIZATIONS: tuple[str, ...] = get_args(Vectorization)


def make_crazyflie_vec_env(
    num_envs: int = 1,
    seed: int | None = None,
    options: CrazyflieOptions | None = None,
    *,
    vectorization: Vectorization = "batched",
    start_method: str | None = None,
    **fields: Any,
) -> VecEnv:
    """``num_envs`` PyBullet swarms as one stable-baselines3 ``VecEnv``.

    ``vectorization="batched"`` (default) keeps every PyBullet world in this process and evaluates
    the MDP for all of them at once (:class:`~marlander_lite.crazyflie.batch.CrazyflieBatch` behind
    :class:`~marlander_lite.envs.vec_env.LandingVecEnv`, the point-mass VecEnv's code): on a
    2-core machine it is the fastest, since a subprocess's messaging costs as much as a two-drone
    step. ``"subprocess"`` runs one world per process (SB3 ``SubprocVecEnv`` + ``VecMonitor``), which
    scales on many cores; a script that uses it must guard its entry point with
    ``if __name__ == "__main__":``, as for any ``multiprocessing`` code (``start_method`` is passed on).

    Either way the same seed gives the same rollouts, finished envs are reset at once (SB3
    convention, ``infos[i]["terminal_observation"]``), and the last step's info carries
    ``is_success`` and ``episode``. Options are :class:`CrazyflieOptions` (an object, or its fields as
    keywords); ``gui``, ``render_mode`` and ``video_path`` are not taken (record a video with the single
    gymnasium env).
    """
    face_keywords = ("num_envs", "seed", "vectorization", "start_method")
    # Check the options here, in this process, so that a bad one fails with its own message.
    options = CrazyflieOptions.from_keywords(fields, options, "make_vec_env('crazyflie')", face_keywords)
    check_num_envs(num_envs)
    if vectorization not in VECTORIZATIONS:
        raise ValueError(f"Unknown vectorization {vectorization!r}; allowed: {', '.join(VECTORIZATIONS)}.")
    if vectorization == "batched":
        return LandingVecEnv(options.make_batch(int(num_envs)), options.sensing_config, seed)
    makers = [partial(CrazyflieLandingEnv, options) for _ in range(int(num_envs))]
    vec = SubprocVecEnv(makers, start_method=start_method)
    if seed is not None:
        vec.seed(seed)
    return VecMonitor(vec)
