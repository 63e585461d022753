"""A model of the Crazyflie firmware's side of the radio: decodes CRTP packets, flies a simulated drone.

cflib builds every packet the deployment sends (``Commander``, ``HighLevelCommander``,
``Localization``/``Extpos``, ``Param``); :class:`VirtualFirmware` receives those packets, decodes
them with the firmware's packet layouts (ports and channels from ``cflib.crtp.crtpstack.CRTPPort``,
type codes from cflib's modules, ``struct`` layouts of the firmware's packed C structs) and turns
them into what the drone would do: a velocity for the simulator, or motors off.

What is modelled (and what is not):

* **Low-level setpoints** (port ``COMMANDER_GENERIC``): ``velocity_world`` is tracked as given
  (the firmware does not clamp it); ``stop`` cuts the motors; the legacy RPYT packet with zero
  thrust (sent by cflib's ``close_link``) cuts the motors too.
* **Commander watchdog**: no low-level setpoint for 0.5 s -> level out and hold (velocity 0);
  for 2 s -> motors off and *locked* until a reboot (``COMMANDER_WDT_TIMEOUT_STABILIZE/SHUTDOWN``).
* **Priorities**: while low-level setpoints are active, high-level commands are ignored;
  ``notify_setpoint_stop`` hands control back to the high-level commander.
* **High-level commander**: ``takeoff``, ``land`` (smooth minimum-jerk path from the current
  estimate to the target height over the duration, then hold), ``stop`` (motors off).
* **Estimator**: with ``stabilizer.estimator == 2`` (Kalman) every ``ext_pose`` resets the
  position estimate, which is then dead-reckoned with the true velocity (a perfect IMU: an
  optimistic stand-in for the Kalman filter). With another estimator external poses are ignored
  and take-off is refused. The firmware never notices that external poses stopped coming.
* **Supervisor**: arming requests (a firmware built with ``requires_arming``, like the Crazyflie
  2.1 Brushless, refuses to take off unarmed) and the emergency stop (motors off, locked).
* **Parameters** (port ``PARAM``): the TOC (v2) of a few real parameters, reads, writes (the
  reply echoes the write, as the firmware does) and set-by-name.
* Not modelled: attitude control and yaw (the simulator does that), logging, memories.
"""

from __future__ import annotations

import math
import struct
import threading
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from cflib.crazyflie import commander as cf_commander
from cflib.crazyflie import param as cf_param
from cflib.crazyflie import supervisor as cf_supervisor
from cflib.crazyflie import toc as cf_toc
from cflib.crazyflie.high_level_commander import HighLevelCommander
from cflib.crazyflie.localization import Localization
from cflib.crazyflie.param import ParamTocElement
from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

# Packed C structs of the firmware's CRTP handlers (little endian, no padding).
VELOCITY_WORLD = struct.Struct("<Bffff")  # type, vx, vy, vz (m/s), yawrate (deg/s)
STOP = struct.Struct("<B")  # type
NOTIFY_SETPOINT_STOP = struct.Struct("<BI")  # meta type, remain_valid_ms
RPYT_LEGACY = struct.Struct("<fffH")  # roll, -pitch (deg), yawrate (deg/s), thrust
HL_TAKEOFF_LAND_2 = struct.Struct("<BBff?f")  # command, group mask, height (m), yaw (rad), use current yaw, duration
HL_STOP = struct.Struct("<BB")  # command, group mask
EXT_POSE = struct.Struct("<Bfffffff")  # type, x, y, z (m), qx, qy, qz, qw
EXT_POS = struct.Struct("<fff")  # x, y, z (m)

WATCHDOG_HOLD_S = 0.5
"""No setpoint for this long: level out and hold (firmware COMMANDER_WDT_TIMEOUT_STABILIZE)."""
WATCHDOG_OFF_S = 2.0
"""No setpoint for this long: motors off, locked (firmware COMMANDER_WDT_TIMEOUT_SHUTDOWN)."""
PROTOCOL_VERSION = 12
"""CRTP protocol version the virtual firmware reports (recent firmware: the supervisor port exists)."""

# (name, TOC type code, default) of the parameters the virtual firmware has.
PARAMETERS: tuple[tuple[str, int, float], ...] = (
    ("stabilizer.estimator", 0x08, 1),  # uint8: 1 complementary, 2 Kalman
    ("stabilizer.controller", 0x08, 0),  # uint8: 0 auto (PID), 1 PID, 2 Mellinger, ...
    ("locSrv.extQuatStdDev", 0x06, 4.5e-3),  # float (rad)
    ("locSrv.extPosStdDev", 0x06, 0.01),  # float (m)
    ("kalman.resetEstimation", 0x08, 0),  # uint8: write 1 to reset the Kalman filter
)

Mode = Literal["off", "low", "high", "locked"]


class FirmwareModelError(RuntimeError):
    """The rehearsal asked the virtual firmware for something a real Crazyflie would not do safely."""


@dataclass
class _Plan:
    """A high-level-commander path from ``start`` to ``end`` over ``duration`` s, beginning at ``t0``."""

    start: np.ndarray
    end: np.ndarray
    t0: float
    duration: float
    kind: str

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) of the minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5``."""
        s = min(max((t - self.t0) / self.duration, 0.0), 1.0)
        shape = 10 * s**3 - 15 * s**4 + 6 * s**5
        rate = (30 * s**2 - 60 * s**3 + 30 * s**4) / self.duration
        delta = self.end - self.start
        return self.start + shape * delta, rate * delta


class VirtualFirmware:
    """The firmware of one simulated Crazyflie, driven by the CRTP packets cflib builds.

    Args:
        name: for messages.
        clock: the simulated time (s).
        position_gain: gain of the high-level position tracking (1/s).
        max_hl_speed: speed cap of high-level manoeuvres (m/s).
        requires_arming: the motors stay off until an arming request arrives (Crazyflie 2.1 Brushless).
    """

    def __init__(
        self,
        name: str,
        clock: Callable[[], float],
        position_gain: float = 2.5,
        max_hl_speed: float = 1.5,
        requires_arming: bool = False,
    ) -> None:
        self.name, self.clock = name, clock
        self.armed = not requires_arming
        self.position_gain, self.max_hl_speed = position_gain, max_hl_speed
        self.params: dict[str, float] = {param: default for param, _, default in PARAMETERS}
        self._toc = [ParamTocElement(i, self._toc_bytes(i)) for i in range(len(PARAMETERS))]
        self.mode: Mode = "off"
        self.velocity_setpoint = np.zeros(3)
        """Last low-level velocity setpoint (m/s, world frame)."""
        self.t_setpoint = -math.inf
        self.plan: _Plan | None = None
        self.est_pos: np.ndarray | None = None
        """Position estimate at ``t_est`` (m); None until an external pose arrives."""
        self.t_est = -math.inf
        self.counts: Counter[str] = Counter()
        """Decoded packets by kind."""
        self.events: list[tuple[float, str, str]] = []
        """(time, kind, message) of everything notable the firmware did."""
        self._watchdog_state = ""
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ packets in
    def receive(self, pk: CRTPPacket) -> list[CRTPPacket]:
        """Decode one packet from the host; returns the firmware's reply packets."""
        with self._lock:
            data = bytes(pk.data)
            now = self.clock()
            if pk.port == CRTPPort.COMMANDER_GENERIC:
                self._commander_generic(pk.channel, data, now)
            elif pk.port == CRTPPort.COMMANDER:
                self._rpyt(data, now)
            elif pk.port == CRTPPort.SETPOINT_HL:
                self._high_level(data, now)
            elif pk.port == CRTPPort.LOCALIZATION:
                self._localization(pk.channel, data, now)
            elif pk.port == CRTPPort.PARAM:
                return self._param(pk.channel, data)
            elif pk.port == CRTPPort.SUPERVISOR and pk.channel == cf_supervisor.SUPERVISOR_CH_COMMAND:
                self._supervisor(data, now)
            else:
                self._event(now, "unsupported", f"packet on port {pk.port} channel {pk.channel} ignored")
            return []

    def _event(self, t: float, kind: str, message: str) -> None:
        self.events.append((t, kind, message))

    def _commander_generic(self, channel: int, data: bytes, now: float) -> None:
        notify = cf_commander.TYPE_META_COMMAND_NOTIFY_SETPOINT_STOP
        if channel == cf_commander.META_COMMAND_CHANNEL and data[0] == notify:
            NOTIFY_SETPOINT_STOP.unpack(data)
            self.counts["notify_setpoint_stop"] += 1
            if self.mode == "low":
                self.mode, self.plan, self._watchdog_state = "high", None, ""
                self.t_setpoint = now  # the high-level commander owns the watchdog from here
            return
        kind = data[0]
        if self.mode == "locked":
            self._event(now, "locked", "setpoint ignored: motors locked until a reboot")
            return
        if kind == cf_commander.TYPE_VELOCITY_WORLD:
            _, vx, vy, vz, _yawrate = VELOCITY_WORLD.unpack(data)
            self.counts["velocity_world"] += 1
            if self.mode == "off" and (self.est_pos is None or not self.armed):
                why = "not armed" if not self.armed else "no position estimate to take off with"
                self._event(now, "refused", f"velocity setpoint refused: {why}")
                return
            self.velocity_setpoint = np.array([vx, vy, vz])
            self.mode, self.plan = "low", None  # low-level setpoints take priority over the planner
            self.t_setpoint, self._watchdog_state = now, ""
        elif kind == cf_commander.TYPE_STOP:
            STOP.unpack(data)
            self.counts["stop"] += 1
            self._motors_off(now, "stop setpoint")
        else:
            self._event(now, "unsupported", f"setpoint type {kind} is not modelled")

    def _rpyt(self, data: bytes, now: float) -> None:
        _roll, _pitch, _yawrate, thrust = RPYT_LEGACY.unpack(data)
        self.counts["rpyt"] += 1
        if thrust != 0:
            raise FirmwareModelError(f"{self.name}: attitude/thrust setpoints are not modelled (thrust={thrust}).")
        if self.mode != "locked":
            self._motors_off(now, "zero-thrust setpoint")

    def _high_level(self, data: bytes, now: float) -> None:
        command = data[0]
        hlc = HighLevelCommander
        if command == hlc.COMMAND_STOP:
            HL_STOP.unpack(data)
            self.counts["hl_stop"] += 1
            if self.mode != "locked":
                self._motors_off(now, "high-level stop")
            return
        if command not in (hlc.COMMAND_TAKEOFF_2, hlc.COMMAND_LAND_2):
            self._event(now, "unsupported", f"high-level command {command} is not modelled")
            return
        _, _group, height, _yaw, _use_current_yaw, duration = HL_TAKEOFF_LAND_2.unpack(data)
        kind = "takeoff" if command == hlc.COMMAND_TAKEOFF_2 else "land"
        self.counts[kind] += 1
        if self.mode in ("low", "locked"):
            why = "low-level setpoints have priority (send notify_setpoint_stop first)"
            why = why if self.mode == "low" else "motors locked"
            self._event(now, "ignored", f"{kind} ignored: {why}")
            return
        if self.est_pos is None or not self.armed:
            why = "not armed" if not self.armed else "no position estimate (is the Kalman estimator on?)"
            self._event(now, "refused", f"{kind} refused: {why}")
            return
        start = self.estimate(now, np.zeros(3))
        if self.plan is not None:  # continue smoothly from the current reference
            start = self.plan.reference(now)[0]
        end = np.array([start[0], start[1], height])
        self.plan = _Plan(start, end, now, max(float(duration), 0.1), kind)
        self.mode = "high"
        self._event(now, kind, f"{kind} to z={height:.2f} m in {duration:.1f} s")

    def _supervisor(self, data: bytes, now: float) -> None:
        if data[0] == cf_supervisor.CMD_ARM_SYSTEM:
            self.armed = bool(data[1])
            self.counts["arming_request"] += 1
        elif data[0] == cf_supervisor.CMD_EMERGENCY_STOP:
            self.counts["emergency_stop"] += 1
            self._motors_off(now, "emergency stop")
            self.mode = "locked"
        else:
            self._event(now, "unsupported", f"supervisor command {data[0]} is not modelled")

    def _localization(self, channel: int, data: bytes, now: float) -> None:
        if channel == Localization.GENERIC_CH and data[0] == Localization.EXT_POSE:
            _, x, y, z, _qx, _qy, _qz, _qw = EXT_POSE.unpack(data)
            self.counts["ext_pose"] += 1
        elif channel == Localization.POSITION_CH:
            x, y, z = EXT_POS.unpack(data)
            self.counts["ext_pos"] += 1
        else:
            self._event(now, "unsupported", f"localization packet type {data[0]} is not modelled")
            return
        if self.params["stabilizer.estimator"] == 2:
            self.est_pos, self.t_est = np.array([x, y, z]), now
        else:
            self.counts["ext_pose_ignored"] += 1

    def _motors_off(self, now: float, why: str) -> None:
        if self.mode not in ("off", "locked"):
            self._event(now, "motors_off", why)
        self.mode, self.plan = "off", None

    # ------------------------------------------------------------------ parameters
    @staticmethod
    def _toc_bytes(ident: int) -> bytes:
        name, type_code, _ = PARAMETERS[ident]
        group, short = name.split(".")
        return bytes([type_code]) + group.encode() + b"\0" + short.encode() + b"\0"

    def _param(self, channel: int, data: bytes) -> list[CRTPPacket]:
        def reply(chan: int, payload: bytes) -> list[CRTPPacket]:
            pk = CRTPPacket()
            pk.set_header(CRTPPort.PARAM, chan)
            pk.data = payload
            return [pk]

        if channel == cf_param.TOC_CHANNEL:
            if data[0] == cf_toc.CMD_TOC_INFO_V2:
                crc = zlib.crc32(b"".join(self._toc_bytes(i) for i in range(len(PARAMETERS))))
                return reply(channel, bytes([data[0]]) + struct.pack("<HI", len(PARAMETERS), crc))
            if data[0] == cf_toc.CMD_TOC_ITEM_V2:
                ident = data[1] | data[2] << 8
                return reply(channel, data[:3] + self._toc_bytes(ident))
            raise FirmwareModelError(f"TOC command {data[0]} (v1 protocol) is not modelled.")
        if channel == cf_param.READ_CHANNEL:
            (ident,) = struct.unpack("<H", data[:2])
            element = self._toc[ident]
            value = struct.pack(element.pytype, self.params[self._name(element)])
            return reply(channel, data[:2] + b"\0" + value)
        if channel == cf_param.WRITE_CHANNEL:
            (ident,) = struct.unpack("<H", data[:2])
            element = self._toc[ident]
            (value,) = struct.unpack(element.pytype, data[2:])
            self._set(self._name(element), value)
            return reply(channel, data)  # the firmware answers a write with the new value
        if channel == cf_param.MISC_CHANNEL and data[0] == cf_param.MISC_SETBYNAME:
            group, short, rest = data[1:].split(b"\0", 2)
            pytype = ParamTocElement.types[rest[0]][1]
            (value,) = struct.unpack(pytype, rest[1:])
            self._set(f"{group.decode()}.{short.decode()}", value)
            return []
        raise FirmwareModelError(f"param channel {channel} command {data[:1].hex()} is not modelled.")

    @staticmethod
    def _name(element: ParamTocElement) -> str:
        return f"{element.group}.{element.name}"

    def _set(self, name: str, value: float) -> None:
        if name not in self.params:
            raise FirmwareModelError(f"{self.name}: no parameter {name!r}; known: {sorted(self.params)}.")
        self.params[name] = value
        self.counts["param_write"] += 1
        if name == "kalman.resetEstimation" and value:
            self.est_pos, self.t_est = None, -math.inf

    # ------------------------------------------------------------------ what the drone does
    def estimate(self, now: float, true_vel: np.ndarray) -> np.ndarray:
        """The firmware's position estimate (m): last external pose, dead-reckoned with the true velocity."""
        if self.est_pos is None:
            return np.full(3, np.nan)
        return self.est_pos + true_vel * (now - self.t_est)

    def output(self, now: float, true_vel: np.ndarray) -> tuple[np.ndarray, bool]:
        """``(velocity command (3,) m/s, motors on)`` at time ``now``; the simulator tracks the velocity."""
        with self._lock:
            if self.mode in ("off", "locked"):
                return np.zeros(3), False
            if self.plan is None:  # low-level control, or nothing after notify_setpoint_stop: the watchdog runs
                silence = now - self.t_setpoint
                if silence > WATCHDOG_OFF_S:
                    self._event(now, "watchdog", f"no setpoint for {silence:.2f} s: motors off, locked")
                    self.mode = "locked"
                    return np.zeros(3), False
                if self.mode == "low" and silence <= WATCHDOG_HOLD_S:
                    return self.velocity_setpoint.copy(), True
                if self._watchdog_state != "hold":
                    self._event(now, "watchdog", f"no setpoint for {silence:.2f} s: level out and hold")
                    self._watchdog_state = "hold"
                return np.zeros(3), True
            p_ref, v_ref = self.plan.reference(now)
            command = v_ref + self.position_gain * (p_ref - self.estimate(now, true_vel))
            speed = float(np.linalg.norm(command))
            if speed > self.max_hl_speed:
                command *= self.max_hl_speed / speed
            return command, True

    @property
    def plan_done(self) -> bool:
        """Whether a high-level manoeuvre is running and has reached its end time."""
        return self.plan is not None and self.clock() >= self.plan.t0 + self.plan.duration
