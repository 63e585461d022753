"""State estimation from the pose stream: velocities, angular velocities, pad goals and data age.

The motion-capture system measures poses only; the policy's observation (eq. 2) also needs
each drone's velocity relative to its pad and its angular velocity (paper Sec. III-A: "the
control station ... estimates linear and angular velocity"). :class:`BodyTracks` estimates them
per rigid body by finite differences of consecutive poses, low-pass filtered with a time
constant ``tau``::

    v_raw = (p_k - p_{k-1}) / (t_k - t_{k-1}),     v_k = v_{k-1} + a (v_raw - v_{k-1}),   a = 1 - exp(-dt / tau)

and the same for the angular velocity from the quaternion change
(as :func:`marlander_lite.rotations.angular_velocity_from_quats`, world frame, rad/s). After a gap
longer than ``reset_gap_s`` the filter restarts from the raw difference. A pose that is not
finite, not a unit quaternion, or implies a jump faster than ``max_body_speed`` is rejected and
marks the body *invalid* until a good pose arrives; a jump that the next pose confirms (the two
agree with each other) is a real move, not a glitch, and the body is re-acquired there (after a
burst of late frames, say). Every body also reports its *age*: the
time since its last accepted pose, which the safety rules compare with their thresholds.

Pads are found from the body that carries them: pad top centre ``c = p + R(q) o`` for the
pad's offset ``o`` in the body frame, and its velocity ``v + omega x R(q) o`` (rigid body).
The pad's normal is the body's z axis, ``n = R(q) e_z``, and the goal point is ``c`` raised by
``TaskConfig.landed_height`` along it, exactly as in the simulators: straight up on a level plate, and on a
plate tilted by a manipulator (beyond the paper, ``platforms.PlateGeometry.inclination_deg``) along its
tilted normal. The body's frame must therefore have its z axis perpendicular to the pad (the pre-flight
check refuses a pad tilted more than ``safety.max_pad_tilt_deg``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from marlander_lite.deploy.config import LabConfig
from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.rotations import angular_velocity_from_quats, cross, rotate_vector


@dataclass(frozen=True)
class EstimatorConfig:
    """Filter constants of the finite-difference estimator."""

    tau: float = 0.03
    """Time constant of the velocity and angular-velocity low-pass filter (s)."""
    reset_gap_s: float = 0.3
    """After a gap longer than this the filter restarts from the raw difference (s)."""
    max_body_speed: float = 8.0
    """A pose implying a faster jump than this is rejected (m/s)."""
    max_abs_position: float = 100.0
    """A coordinate larger than this is out of range (m)."""

    def __post_init__(self) -> None:
        if not (self.tau >= 0 and self.reset_gap_s > 0 and self.max_body_speed > 0 and self.max_abs_position > 0):
            raise ValueError(f"EstimatorConfig values must be positive (tau may be 0), got {self!r}.")


class BodyTracks:
    """Pose, velocity and angular velocity of ``B`` named rigid bodies from their pose samples.

    Arrays are per body, in the order of ``names``; one frame updates every body it contains at
    once (vectorised: the cost hardly grows with the number of bodies).
    """

    def __init__(self, names: list[str], config: EstimatorConfig) -> None:
        self.names = list(names)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.config = config
        b = len(self.names)
        self.pose = np.full((b, 7), np.nan)
        """Last accepted pose per body ``[x, y, z, qx, qy, qz, qw]`` (m; unit quaternion)."""
        self.vel = np.zeros((b, 3))
        """Filtered velocity (m/s, world frame)."""
        self.ang_vel = np.zeros((b, 3))
        """Filtered angular velocity (rad/s, world frame)."""
        self.t_last = np.full(b, -np.inf)
        """Time of each body's last accepted pose (s); -inf before the first."""
        self.samples = np.zeros(b, dtype=np.int64)
        self.invalid = np.zeros(b, dtype=bool)
        """True while the latest pose of the body was rejected."""
        self.reason = [""] * b
        self._jump_pos = np.full((b, 3), np.nan)
        self._jump_t = np.full(b, -np.inf)

    def update(self, t: float, bodies: dict[str, np.ndarray]) -> list[tuple[str, str]]:
        """Feed one frame measured at ``t`` (s); returns ``(body, reason)`` for each rejected pose."""
        cfg = self.config
        names = [n for n in bodies if n in self.index]
        if not names:
            return []
        idx = np.array([self.index[n] for n in names])
        poses = np.array([bodies[n] for n in names], dtype=float)
        prev = self.pose[idx]
        pos, quat = poses[:, :3], poses[:, 3:]
        norm2 = (quat * quat).sum(axis=1)  # NaN compares False below: no warnings
        valid = np.isfinite(poses).all(axis=1) & (np.abs(pos).max(axis=1) <= cfg.max_abs_position)
        valid &= (norm2 > 0.81) & (norm2 < 1.21)  # |q| within 0.9 .. 1.1
        dt = t - self.t_last[idx]
        fresh = dt > 0.0  # a repeated or out-of-order frame carries nothing new
        seen = (self.samples[idx] > 0) & fresh
        step = pos - prev[:, :3]
        limit2 = (cfg.max_body_speed * dt) ** 2
        jump = seen & ((step * step).sum(axis=1) > limit2)
        if jump.any():  # a jump confirmed by the previous (rejected) pose is a real move: re-acquire the body
            gap = pos - self._jump_pos[idx]
            since = t - self._jump_t[idx]
            confirmed = jump & (since > 0) & ((gap * gap).sum(axis=1) <= (cfg.max_body_speed * since) ** 2)
            self._jump_pos[idx[jump]], self._jump_t[idx[jump]] = pos[jump], t
            jump &= ~confirmed
            seen &= ~confirmed
            self.samples[idx[confirmed]] = 0  # the filter restarts from the next difference
        bad = ~valid | jump
        rejected = self._reject(idx[bad], poses[bad], step[bad], dt[bad]) if bad.any() else []
        ok = ~bad & fresh
        if not ok.any():
            return rejected
        i, dt, seen, step = idx[ok], dt[ok], seen[ok], step[ok]
        quat = quat[ok] / np.sqrt(norm2[ok])[:, None]
        prev_q = prev[ok, 3:]
        quat[(quat * prev_q).sum(axis=1) < 0.0] *= -1.0  # q and -q are one attitude: keep the sign continuous
        if seen.any():
            s, dts = i[seen], dt[seen][:, None]
            raw_w = angular_velocity_from_quats(prev_q[seen], quat[seen], dts)
            raw_v = step[seen] / dts
            a = 1.0 - np.exp(-dts / cfg.tau) if cfg.tau > 0 else np.ones_like(dts)
            a[(self.samples[s] == 1) | (dts[:, 0] > cfg.reset_gap_s)] = 1.0  # (re)start from the raw difference
            self.vel[s] += a * (raw_v - self.vel[s])
            self.ang_vel[s] += a * (raw_w - self.ang_vel[s])
        self.pose[i, :3], self.pose[i, 3:] = pos[ok], quat
        self.t_last[i] = t
        self.samples[i] += 1
        self.invalid[i] = False
        return rejected

    def _reject(self, idx: np.ndarray, poses: np.ndarray, step: np.ndarray, dt: np.ndarray) -> list[tuple[str, str]]:
        """Mark rejected bodies invalid and say why, ``(body, reason)`` each."""
        rejected = []
        for i, pose, move, gap in zip(idx.tolist(), poses, step, dt, strict=True):
            norm = float(np.sqrt(pose[3:] @ pose[3:]))
            if not np.isfinite(pose).all():
                why = "non-finite pose"
            elif np.abs(pose[:3]).max() > self.config.max_abs_position or not 0.9 < norm < 1.1:
                why = f"out-of-range pose (|q| = {norm:.3f}, position {np.round(pose[:3], 3).tolist()})"
            else:
                speed = float(np.sqrt(move @ move)) / gap
                why = f"jump of {speed:.1f} m/s (limit {self.config.max_body_speed} m/s)"
            self.invalid[i], self.reason[i] = True, why
            rejected.append((self.names[i], why))
        return rejected

    def age(self, now: float) -> np.ndarray:
        """Seconds since each body's last accepted pose ``(B,)`` (inf before the first)."""
        return now - self.t_last


@dataclass
class SwarmEstimate:
    """What the loop knows at one instant. Arrays are per drone, in the config's drone order."""

    t: float
    """Time of this estimate (s)."""
    pos: np.ndarray
    """Drone positions ``(N, 3)`` m (NaN before the first pose)."""
    quat: np.ndarray
    """Drone attitudes ``(N, 4)`` ``(x, y, z, w)``."""
    vel: np.ndarray
    """Drone velocities ``(N, 3)`` m/s."""
    ang_vel: np.ndarray
    """Drone angular velocities ``(N, 3)`` rad/s, world frame."""
    pad_pos: np.ndarray
    """Each drone's pad top-face centre ``(N, 3)`` m."""
    pad_vel: np.ndarray
    """Each drone's pad velocity ``(N, 3)`` m/s."""
    goal: np.ndarray
    """Goal points ``(N, 3)`` m: pad centre raised by ``landed_height`` along the pad normal (as in the
    simulators)."""
    drone_age: np.ndarray
    """Seconds since each drone's last accepted pose ``(N,)`` (inf if never seen)."""
    pad_age: np.ndarray
    """Seconds since the last accepted pose of each drone's pad body ``(N,)``."""
    drone_invalid: np.ndarray
    """True where the drone's latest pose was rejected ``(N,)``."""
    pad_invalid: np.ndarray
    """True where the pad body's latest pose was rejected ``(N,)``."""
    pad_normal: np.ndarray = field(default=None)  # type: ignore[assignment]
    """Unit normal of each drone's pad ``(N, 3)``, world frame: its body's z axis (NaN until the body has been
    seen). Left out, ``+z`` for every pad: level pads."""

    def __post_init__(self) -> None:
        if self.pad_normal is None:
            self.pad_normal = np.tile([0.0, 0.0, 1.0], (len(self.pos), 1))

    @property
    def age(self) -> np.ndarray:
        """Age of the older of each drone's and its pad's data ``(N,)`` s."""
        return np.maximum(self.drone_age, self.pad_age)

    @property
    def invalid(self) -> np.ndarray:
        """Drone or pad pose rejected ``(N,)``."""
        return self.drone_invalid | self.pad_invalid


class SwarmEstimator:
    """Tracks every drone and pad body of a :class:`LabConfig` from :class:`PoseFrame` s."""

    def __init__(self, lab: LabConfig, config: EstimatorConfig | None = None, landed_height: float = 0.0125) -> None:
        self.config = config or EstimatorConfig(max_body_speed=lab.safety.max_body_speed)
        self.drones = lab.drone_names
        pads = lab.drone_pads()
        self.tracks = BodyTracks([*self.drones, *lab.pad_bodies], self.config)
        self._drone_idx = np.array([self.tracks.index[n] for n in self.drones])
        self._pad_idx = np.array([self.tracks.index[p.body] for p in pads])
        self.pad_offsets = np.array([p.offset for p in pads], dtype=float)
        self.landed_height = landed_height

    def ingest(self, frames: list[PoseFrame]) -> list[tuple[str, str]]:
        """Feed frames (oldest first); returns ``(body, reason)`` for every rejected pose."""
        rejected = []
        for frame in frames:
            rejected += self.tracks.update(frame.t, frame.bodies)
        return rejected

    def ages(self, now: float) -> dict[str, float]:
        """Age of every tracked body (s)."""
        return dict(zip(self.tracks.names, self.tracks.age(now).tolist(), strict=True))

    def estimate(self, now: float) -> SwarmEstimate:
        """Current estimate of every drone and pad."""
        tr, d, p = self.tracks, self._drone_idx, self._pad_idx
        body_pose = tr.pose[p]
        arm = rotate_vector(body_pose[:, 3:], self.pad_offsets)  # NaN until the body has been seen
        pad_pos = body_pose[:, :3] + arm
        normal = rotate_vector(body_pose[:, 3:], np.array([0.0, 0.0, 1.0]))
        age = tr.age(now)
        return SwarmEstimate(
            t=now,
            pos=tr.pose[d, :3],
            quat=tr.pose[d, 3:],
            vel=tr.vel[d],
            ang_vel=tr.ang_vel[d],
            pad_pos=pad_pos,
            pad_vel=tr.vel[p] + cross(tr.ang_vel[p], arm),
            goal=pad_pos + self.landed_height * normal,
            drone_age=age[d],
            pad_age=age[p],
            drone_invalid=tr.invalid[d],
            pad_invalid=tr.invalid[p],
            pad_normal=normal,
        )
