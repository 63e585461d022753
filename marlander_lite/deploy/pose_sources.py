"""Where poses come from: a motion-capture system (or, in a rehearsal, the simulated lab) behind one interface.

A :class:`PoseSource` hands the control loop every frame that arrived since it last asked:
``read(now) -> list[PoseFrame]``, oldest first, possibly empty. A frame maps rigid-body names to
poses ``[x, y, z, qx, qy, qz, qw]``: world frame, metres, quaternion **scalar-last** like the
rest of marlander_lite. motioncapture returns quaternions scalar-first (``.w .x .y .z``);
:func:`wxyz_to_xyzw` is the single place where that order is changed. A body the cameras do
not see this frame (occluded) is absent from the frame.

* :class:`MotionCaptureSource` wraps ``motioncapture`` (vicon, optitrack, qualisys, vrpn, mock).
* :class:`marlander_lite.deploy.rehearsal.mocap.SimulatedPoseSource` samples the simulated lab of a
  rehearsal with noise, latency, lost frames, occlusions and injected faults.
"""

from __future__ import annotations

import collections
import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

WORKER = Path(__file__).with_name("mocap_worker.py")


@dataclass
class PoseFrame:
    """One motion-capture frame."""

    t: float
    """When the frame reached the host (s, on the loop's clock)."""
    bodies: dict[str, np.ndarray]
    """Rigid-body name -> ``(7,)`` pose ``[x, y, z, qx, qy, qz, qw]`` (m, unit quaternion, world frame)."""


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """motioncapture's quaternion order ``(w, x, y, z)`` -> marlander_lite's ``(x, y, z, w)``, ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    return np.concatenate((q[..., 1:4], q[..., 0:1]), axis=-1)


class PoseSource(Protocol):
    """What the control loop needs from a source of poses."""

    def read(self, now: float) -> list[PoseFrame]:
        """Frames that arrived since the last call, oldest first (``now`` is the loop's clock, s)."""

    def close(self) -> None:
        """Stop receiving."""


class MotionCaptureSource:
    """A motion-capture system through ``motioncapture``, read by a child process.

    ``motioncapture.connect`` blocks while no server answers (vicon) and holds Python's GIL
    while it does, so a thread cannot time it out: the connection runs in
    ``mocap_worker.py``'s process, a reader thread here collects its frames, and a connection
    that does not answer within ``timeout_s`` is killed with a :class:`TimeoutError`. The child
    runs in its own session, so that the signals which make the loop land (Ctrl-C, SIGHUP, SIGTERM
    sent to the process group) do not also stop the poses the landing needs.
    Frame times are ``time.monotonic()`` at arrival; use :class:`RealClock` in the loop.

    Args:
        kind: ``vicon``, ``optitrack``, ``qualisys``, ``vrpn`` or ``mock``.
        cfg: ``motioncapture.connect``'s configuration, every value a string (e.g. ``hostname``).
        timeout_s: longest wait for the connection (s).
        max_buffer: frames kept when the loop falls behind (older ones are dropped).
    """

    def __init__(self, kind: str, cfg: dict[str, str], timeout_s: float = 5.0, max_buffer: int = 1000) -> None:
        self.kind = kind
        self._frames: collections.deque[PoseFrame] = collections.deque(maxlen=max_buffer)
        self._lock = threading.Lock()
        self._status: dict[str, str] = {}
        self._answered = threading.Event()
        self._connected = False
        self.error: str | None = None
        self._proc = subprocess.Popen(
            [sys.executable, "-u", str(WORKER), kind, json.dumps({k: str(v) for k, v in cfg.items()})],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            # Its own session: Ctrl-C, a closed terminal or SSH session (SIGHUP) and `timeout`'s SIGTERM reach
            # the whole foreground process group; the flight needs poses while it lands after one of those.
            # It ends when close() kills it, or on a broken pipe when this process is gone.
            start_new_session=True,
        )
        self._reader = threading.Thread(target=self._read_worker, name=f"mocap-{kind}", daemon=True)
        self._reader.start()
        answered = self._answered.wait(timeout_s)
        if not self._connected:
            self.close()
            if answered:
                raise ConnectionError(f"motioncapture could not connect to {kind!r} ({cfg}): {self.error}")
            raise TimeoutError(
                f"No answer from the {kind!r} motion-capture server ({cfg}) within {timeout_s} s. Is the server "
                "running and reachable, and is the hostname right?"
            )

    def _read_worker(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            msg = json.loads(line)
            if "status" in msg:
                self._connected = msg["status"] == "connected"
                self.error = None if self._connected else msg.get("message", "unknown error")
                self._answered.set()
                if not self._connected:
                    break
                continue
            bodies = {}
            for name, v in msg["b"].items():
                pose = np.empty(7)
                pose[:3] = v[:3]
                pose[3:] = wxyz_to_xyzw(np.asarray(v[3:7]))
                bodies[name] = pose
            with self._lock:
                self._frames.append(PoseFrame(t=float(msg["t"]), bodies=bodies))
        if not self._answered.is_set():  # the worker died without a word
            self.error = f"the worker process exited with code {self._proc.wait()}"
            self._answered.set()

    @property
    def alive(self) -> bool:
        """Whether the worker process is still running."""
        return self._proc.poll() is None

    def read(self, now: float) -> list[PoseFrame]:
        with self._lock:
            frames = list(self._frames)
            self._frames.clear()
        return frames

    def close(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait(timeout=5)
        if self._proc.stdout is not None:
            self._proc.stdout.close()


class Clock(Protocol):
    """Time for the loop: :class:`marlander_lite.deploy.pose_sources.RealClock` or a simulated world."""

    def now(self) -> float: ...

    def sleep_until(self, t: float) -> None: ...


class RealClock:
    """Wall-clock time for hardware: ``time.monotonic`` (the clock of motion-capture frames)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        """Sleep until ``t`` (s); returns at once if it has passed."""
        delay = t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
