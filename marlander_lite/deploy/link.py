"""The radio side of the deployment: a cflib ``Swarm`` of Crazyflies, one method per thing we send.

:class:`CrazyflieLink` opens every URI with cflib's ``Swarm`` (``SyncCrazyflie`` per drone, in
parallel), sets and *confirms* the firmware parameters (``stabilizer.estimator = 2`` (Kalman),
``stabilizer.controller = 1`` (PID), ``locSrv.extQuatStdDev``, then resets the Kalman filter),
arms the drones if the config asks (``supervisor.send_arming_request``), and afterwards sends,
per drone:

* ``extpos.send_extpose(x, y, z, qx, qy, qz, qw)``: the mocap pose (scalar-last quaternion);
* ``commander.send_velocity_world_setpoint(vx, vy, vz, 0)``: the (already clamped) velocity;
* ``high_level_commander.takeoff(h, T, yaw=0)`` before the policy starts;
* ``commander.send_notify_setpoint_stop()`` then ``high_level_commander.land(h, T, yaw=0)`` to land;
* ``commander.send_stop_setpoint()`` and ``high_level_commander.stop()``: motors off.

A lost radio link is reported by cflib's ``connection_lost`` callback; :meth:`lost` tells the
loop. The same class drives the simulated Crazyflies: pass ``factory=world.factory``
(:class:`marlander_lite.deploy.rehearsal.virtual_crazyflie.VirtualCfFactory`), the ``factory`` argument
``Swarm`` provides for test doubles.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.deploy.config import CrazyflieParamsConfig

TOC_CACHE = Path.home() / ".cache" / "marlander_lite" / "crazyflie_toc"
"""Where cflib caches the Crazyflies' parameter/log tables between connections."""
_drivers_ready = False


class LinkError(RuntimeError):
    """A Crazyflie could not be reached or configured."""


class CrazyflieLink:
    """A swarm of Crazyflies through cflib.

    Args:
        uris: one cflib URI per drone, in the lab config's drone order.
        params: firmware parameters to set after connecting.
        factory: ``Swarm``'s factory; None means real radios (``CachedCfFactory``).
    """

    def __init__(self, uris: list[str], params: CrazyflieParamsConfig | None = None, factory: Any = None) -> None:
        self.uris = list(uris)
        self.params = params or CrazyflieParamsConfig()
        self.factory = factory
        self.swarm: Any = None
        self.cfs: list[Any] = []
        """The cflib ``Crazyflie`` of each drone (or its double), in drone order."""
        self._lost: list[str | None] = [None] * len(self.uris)

    # ------------------------------------------------------------------ connect
    def open(self) -> None:
        """Connect every Crazyflie and set its parameters; raises :class:`LinkError` naming what failed."""
        from cflib.crazyflie.swarm import CachedCfFactory, Swarm

        factory = self.factory
        if factory is None:
            _init_drivers()
            factory = CachedCfFactory(rw_cache=str(TOC_CACHE))
        self.swarm = Swarm(self.uris, factory=factory)
        try:
            self.swarm.open_links()
        except Exception as error:
            raise LinkError(f"Could not connect to the Crazyflies {self.uris}: {_cause(error)}") from None
        scfs: list[Any] = []
        self.swarm.sequential(scfs.append)  # public API; URI order
        self.cfs = [scf.cf for scf in scfs]
        for i, cf in enumerate(self.cfs):
            cf.connection_lost.add_callback(lambda uri, message, i=i: self._on_lost(i, message))
        try:
            self.swarm.parallel_safe(self._configure)
        except Exception as error:
            self.close()
            raise LinkError(f"Could not set the Crazyflie parameters: {_cause(error)}") from None

    def _configure(self, scf: Any) -> None:
        for name, value in self.params.as_params().items():
            self._set_param(scf.cf, name, value)
        self._set_param(scf.cf, "kalman.resetEstimation", 1)
        self._set_param(scf.cf, "kalman.resetEstimation", 0)
        if self.params.arm:
            scf.cf.supervisor.send_arming_request(True)

    def _set_param(self, cf: Any, name: str, value: float) -> None:
        """``param.set_value`` and wait until the Crazyflie reports the new value."""
        done = threading.Event()

        def confirm(_name: str, reported: str) -> None:
            if math.isclose(float(reported), float(value), rel_tol=1e-6, abs_tol=1e-9):
                done.set()

        group, short = name.split(".")
        cf.param.add_update_callback(group=group, name=short, cb=confirm)
        try:
            cf.param.set_value(name, value)
            if not done.wait(self.params.param_timeout_s):
                wait = self.params.param_timeout_s
                raise LinkError(f"{cf.link_uri}: {name} = {value} was not confirmed within {wait} s.")
        except KeyError:
            raise LinkError(f"{cf.link_uri}: the firmware has no parameter {name!r}.") from None
        finally:
            cf.param.remove_update_callback(group=group, name=short, cb=confirm)

    def _on_lost(self, i: int, message: str) -> None:
        self._lost[i] = message or "link lost"

    # ------------------------------------------------------------------ state
    def lost(self, i: int) -> str | None:
        """Why drone ``i``'s link was lost, or None while it is up."""
        return self._lost[i]

    # ------------------------------------------------------------------ per-tick commands
    def send_pose(self, i: int, pose: np.ndarray) -> None:
        """Forward a mocap pose ``[x, y, z, qx, qy, qz, qw]`` (m, scalar-last) to drone ``i``'s estimator."""
        x, y, z, qx, qy, qz, qw = (float(v) for v in pose)
        self.cfs[i].extpos.send_extpose(x, y, z, qx, qy, qz, qw)

    def send_velocity(self, i: int, velocity: np.ndarray) -> None:
        """Velocity setpoint (m/s, world frame, yaw rate 0) for drone ``i``; clamp it before calling."""
        vx, vy, vz = (float(v) for v in velocity)
        self.cfs[i].commander.send_velocity_world_setpoint(vx, vy, vz, 0.0)

    def takeoff(self, i: int, height: float, duration: float) -> None:
        """High-level take-off to ``height`` (m, world z) in ``duration`` s, facing yaw 0 as in training."""
        self.cfs[i].high_level_commander.takeoff(float(height), float(duration), yaw=0.0)

    def land(self, i: int, height: float, duration: float) -> None:
        """Hand control back to the high-level commander and land to ``height`` (m) in ``duration`` s."""
        cf = self.cfs[i]
        cf.commander.send_notify_setpoint_stop()
        cf.high_level_commander.land(float(height), float(duration), yaw=0.0)

    def stop_motors(self, i: int) -> None:
        """Motors off now (a stop setpoint, and a high-level stop for a drone the planner flies)."""
        cf = self.cfs[i]
        cf.commander.send_stop_setpoint()
        cf.high_level_commander.stop()

    def close(self) -> None:
        """Close every link (cflib then sends zero thrust: call it only with every drone down)."""
        if self.swarm is not None:
            self.swarm.close_links()
            self.swarm = None


def _init_drivers() -> None:
    global _drivers_ready
    if not _drivers_ready:  # init_drivers appends to cflib's driver list on every call
        import cflib.crtp

        cflib.crtp.init_drivers()
        _drivers_ready = True


def _cause(error: BaseException) -> str:
    """The message of the innermost exception (``Swarm.parallel_safe`` wraps the thread's error)."""
    while error.__cause__ is not None:
        error = error.__cause__
    first_line = str(error).strip().splitlines()[0] if str(error).strip() else ""  # cflib appends tracebacks
    return f"{type(error).__name__}: {first_line}"
