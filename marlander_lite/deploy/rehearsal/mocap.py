"""The simulated motion-capture system: a simulated world sampled like Vicon, noisy, late, with faults.

:class:`SimulatedPoseSource` is a :class:`marlander_lite.deploy.pose_sources.PoseSource`: the loop
reads it exactly as it reads :class:`~marlander_lite.deploy.pose_sources.MotionCaptureSource`. Each
call captures the world's true poses (:meth:`SimulatedWorld.true_poses`), adds Gaussian noise,
loses whole frames or single bodies at the configured rates, and delivers frames ``latency_s``
after capture, in order. :class:`MocapFaults` holds the faults of
:mod:`marlander_lite.deploy.rehearsal.faults` that act on the stream (dropout, latency spike,
occlusion, NaN pose). Poses are ``[x, y, z, qx, qy, qz, qw]`` (m, scalar-last quaternion).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.rotations import quat_normalize


class TruePoses(Protocol):
    """A simulated world as a pose source sees it."""

    time: float

    def true_poses(self) -> dict[str, np.ndarray]:
        """Rigid-body name -> true ``(7,)`` pose ``[x, y, z, qx, qy, qz, qw]`` now."""


@dataclass
class MocapFaults:
    """Faults a :class:`SimulatedPoseSource` applies while they last (times on the world's clock, s)."""

    dropout_until: float = -np.inf
    """No frame at all arrives for frames captured before this time."""
    extra_latency_s: float = 0.0
    """Added delay for frames captured before ``latency_until``."""
    latency_until: float = -np.inf
    occluded_until: dict[str, float] = field(default_factory=dict)
    """Body -> time until which it is missing from every frame."""
    nan_until: dict[str, float] = field(default_factory=dict)
    """Body -> time until which its pose is NaN."""


class SimulatedPoseSource:
    """Samples a simulated world like a motion-capture system: one frame per call, noisy and late.

    Args:
        world: anything with ``time`` and ``true_poses()`` (:class:`.world.SimulatedWorld`).
        pos_noise_std: Gaussian position noise (m).
        quat_noise_std: Gaussian noise per quaternion component before renormalising.
        latency_s: delay from capture to arrival (s); frames arrive at the first read at or after it.
        drop_rate: probability that a whole frame is lost.
        occlusion_rate: probability that a body is missing from a frame.
        seed: seed of the noise.
    """

    def __init__(
        self,
        world: TruePoses,
        pos_noise_std: float = 0.001,
        quat_noise_std: float = 0.002,
        latency_s: float = 0.01,
        drop_rate: float = 0.0,
        occlusion_rate: float = 0.0,
        seed: int | None = 0,
    ) -> None:
        self.world = world
        self.pos_noise_std, self.quat_noise_std = pos_noise_std, quat_noise_std
        self.latency_s, self.drop_rate, self.occlusion_rate = latency_s, drop_rate, occlusion_rate
        self.rng = np.random.default_rng(seed)
        self.faults = MocapFaults()
        self._queue: collections.deque[tuple[float, dict[str, np.ndarray]]] = collections.deque()
        self._last_arrival = -np.inf

    def _capture(self, t: float) -> dict[str, np.ndarray] | None:
        f = self.faults
        if t < f.dropout_until or (self.drop_rate and self.rng.random() < self.drop_rate):
            return None
        bodies = {}
        for name, pose in self.world.true_poses().items():
            if f.occluded_until.get(name, -np.inf) > t:
                continue
            if self.occlusion_rate and self.rng.random() < self.occlusion_rate:
                continue
            noisy = np.array(pose, dtype=float)
            noisy[:3] += self.rng.normal(0.0, self.pos_noise_std, 3) if self.pos_noise_std else 0.0
            if self.quat_noise_std:
                noisy[3:] = quat_normalize(noisy[3:] + self.rng.normal(0.0, self.quat_noise_std, 4))
            if f.nan_until.get(name, -np.inf) > t:
                noisy[:] = np.nan
            bodies[name] = noisy
        return bodies

    def read(self, now: float) -> list[PoseFrame]:
        t = self.world.time
        bodies = self._capture(t)
        if bodies is not None:
            extra = self.faults.extra_latency_s if t < self.faults.latency_until else 0.0
            self._queue.append((t + self.latency_s + extra, bodies))
        frames = []
        while self._queue and self._queue[0][0] <= now + 1e-9:
            arrival, bodies = self._queue.popleft()
            # Frames arrive in order: one stuck behind a late one reaches the host with it.
            self._last_arrival = max(arrival, self._last_arrival)
            frames.append(PoseFrame(t=self._last_arrival, bodies=bodies))
        return frames

    def close(self) -> None:
        self._queue.clear()
