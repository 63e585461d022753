"""The cflib path: real cflib packets, decoded with the layouts in cflib's own source, carry our commands.

The packets are built by cflib (``Commander``, ``HighLevelCommander``, ``Localization``/``Extpos``,
``Param``) through :class:`CrazyflieLink`, ``Swarm`` and ``SyncCrazyflie``; only the Crazyflie
object is a double. Each test decodes the recorded bytes with the ``struct`` format string read
out of the cflib method that built them, and cflib's own port/channel/type constants.
"""

import inspect
import re
import struct

import numpy as np
import pytest
from cflib.crazyflie import commander as cf_commander
from cflib.crazyflie.commander import Commander
from cflib.crazyflie.high_level_commander import HighLevelCommander
from cflib.crazyflie.localization import Localization
from cflib.crtp.crtpstack import CRTPPort

from marlander_lite.deploy.config import CrazyflieParamsConfig
from marlander_lite.deploy.link import CrazyflieLink, LinkError
from marlander_lite.deploy.rehearsal import virtual_firmware as vf
from marlander_lite.deploy.rehearsal.virtual_crazyflie import VirtualCfFactory
from marlander_lite.deploy.rehearsal.virtual_firmware import VirtualFirmware

URIS = ["radio://0/80/2M/E7E7E7E701", "radio://0/80/2M/E7E7E7E702"]


def cflib_format(method) -> str:
    """The (single) ``struct.pack`` format string in a cflib method's source."""
    formats = set(re.findall(r"struct\.pack\(\s*'(<[^']+)'", inspect.getsource(method)))
    assert len(formats) == 1, formats
    return formats.pop()


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def swarm():
    clock = Clock()
    firmwares = {uri: VirtualFirmware(f"cf{i + 1}", clock) for i, uri in enumerate(URIS)}
    factory = VirtualCfFactory(firmwares)
    link = CrazyflieLink(URIS, CrazyflieParamsConfig(ext_quat_std_dev=0.01), factory=factory)
    link.open()
    yield link, firmwares, factory, clock
    link.close()


def last(factory: VirtualCfFactory, uri: str, count: int = 1) -> list[tuple[int, int, bytes]]:
    return list(factory.crazyflies[uri].sent)[-count:]


def test_parameters_are_set_and_confirmed_through_the_param_toc(swarm):
    link, firmwares, factory, _ = swarm
    for fw in firmwares.values():
        assert fw.params["stabilizer.estimator"] == 2
        assert fw.params["stabilizer.controller"] == 1
        assert fw.params["locSrv.extQuatStdDev"] == pytest.approx(0.01)
        assert fw.params["kalman.resetEstimation"] == 0  # reset: written 1, then 0
        assert fw.counts["param_write"] == 5
    cf = factory.crazyflies[URIS[0]]
    assert cf.param.get_value("stabilizer.estimator") == "2"  # cflib's own view, from the firmware's echo
    assert link.cfs[1] is factory.crazyflies[URIS[1]]


def test_extpose_packets_carry_the_mocap_pose(swarm):
    link, firmwares, factory, _ = swarm
    pose = np.array([0.5, -1.25, 0.75, 0.0, 0.0, 0.38268343, 0.92387953])  # x y z, qx qy qz qw
    link.send_pose(0, pose)
    [(port, channel, data)] = last(factory, URIS[0])
    assert (port, channel) == (CRTPPort.LOCALIZATION, Localization.GENERIC_CH)
    kind, *values = struct.unpack(cflib_format(Localization.send_extpose), data)
    assert kind == Localization.EXT_POSE
    np.testing.assert_allclose(values, pose, rtol=1e-6)
    np.testing.assert_allclose(firmwares[URIS[0]].est_pos, pose[:3], rtol=1e-6)


def test_velocity_setpoint_packets_carry_the_commanded_velocity(swarm):
    link, firmwares, factory, _ = swarm
    link.send_pose(1, np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]))
    velocity = np.array([0.3, -0.45, 0.12])
    link.send_velocity(1, velocity)
    [(port, channel, data)] = last(factory, URIS[1])
    assert (port, channel) == (CRTPPort.COMMANDER_GENERIC, cf_commander.SET_SETPOINT_CHANNEL)
    kind, vx, vy, vz, yawrate = struct.unpack(cflib_format(Commander.send_velocity_world_setpoint), data)
    assert kind == cf_commander.TYPE_VELOCITY_WORLD  # not the legacy type: protocol version > 8
    np.testing.assert_allclose([vx, vy, vz], velocity, rtol=1e-6)
    assert yawrate == 0.0
    np.testing.assert_allclose(firmwares[URIS[1]].velocity_setpoint, velocity, rtol=1e-6)
    assert firmwares[URIS[1]].mode == "low"


def test_landing_sends_notify_stop_then_a_high_level_land(swarm):
    link, firmwares, factory, _ = swarm
    link.send_pose(0, np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]))
    link.send_velocity(0, np.zeros(3))
    link.land(0, height=0.02, duration=2.5)
    (p1, c1, notify), (p2, _, land) = last(factory, URIS[0], 2)
    assert (p1, c1) == (CRTPPort.COMMANDER_GENERIC, cf_commander.META_COMMAND_CHANNEL)
    assert struct.unpack(cflib_format(Commander.send_notify_setpoint_stop), notify) == (
        cf_commander.TYPE_META_COMMAND_NOTIFY_SETPOINT_STOP,
        0,
    )
    assert p2 == CRTPPort.SETPOINT_HL
    command, group, height, yaw, use_current_yaw, duration = struct.unpack(cflib_format(HighLevelCommander.land), land)
    assert (command, group, yaw, use_current_yaw) == (HighLevelCommander.COMMAND_LAND_2, 0, 0.0, False)
    assert (height, duration) == pytest.approx((0.02, 2.5))
    fw = firmwares[URIS[0]]
    assert fw.mode == "high" and fw.plan.kind == "land" and fw.plan.end[2] == pytest.approx(0.02)


def test_takeoff_and_motor_stop_packets(swarm):
    link, firmwares, factory, clock = swarm
    link.send_pose(0, np.array([1.0, 2.0, 0.0125, 0.0, 0.0, 0.0, 1.0]))
    link.takeoff(0, height=1.0, duration=2.0)
    [(port, _, data)] = last(factory, URIS[0])
    assert port == CRTPPort.SETPOINT_HL
    command, _, height, _, _, duration = struct.unpack(cflib_format(HighLevelCommander.takeoff), data)
    assert command == HighLevelCommander.COMMAND_TAKEOFF_2 and (height, duration) == (1.0, 2.0)
    fw = firmwares[URIS[0]]
    clock.t = 1.0  # halfway: the minimum-jerk reference is at half height, moving up fastest
    velocity, motors_on = fw.output(clock.t, np.zeros(3))
    assert motors_on and velocity[2] > 0.5
    link.stop_motors(0)
    (_, _, stop), (hl_port, _, hl_stop) = last(factory, URIS[0], 2)
    assert struct.unpack(cflib_format(Commander.send_stop_setpoint), stop) == (cf_commander.TYPE_STOP,)
    assert hl_port == CRTPPort.SETPOINT_HL
    assert struct.unpack(cflib_format(HighLevelCommander.stop), hl_stop) == (HighLevelCommander.COMMAND_STOP, 0)
    assert fw.output(clock.t, np.zeros(3)) == (pytest.approx(np.zeros(3)), False)


def test_the_virtual_firmware_uses_cflib_layouts():
    assert vf.VELOCITY_WORLD.format == cflib_format(Commander.send_velocity_world_setpoint)
    assert vf.NOTIFY_SETPOINT_STOP.format == cflib_format(Commander.send_notify_setpoint_stop)
    assert vf.HL_TAKEOFF_LAND_2.format == cflib_format(HighLevelCommander.land)
    assert vf.HL_STOP.format == cflib_format(HighLevelCommander.stop)
    assert vf.EXT_POSE.format == cflib_format(Localization.send_extpose)
    assert vf.RPYT_LEGACY.format == cflib_format(Commander.send_setpoint)


def test_firmware_watchdog_priorities_and_estimator(swarm):
    link, firmwares, _, clock = swarm
    fw = firmwares[URIS[0]]
    link.send_pose(0, np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]))
    link.send_velocity(0, np.array([0.2, 0.0, 0.0]))
    link.cfs[0].high_level_commander.land(0.0, 2.0)  # no notify_setpoint_stop first
    assert fw.events[-1][1] == "ignored" and fw.mode == "low"
    clock.t = 0.4
    np.testing.assert_allclose(fw.output(0.4, np.zeros(3))[0], [0.2, 0.0, 0.0], rtol=1e-6)
    assert fw.output(0.6, np.zeros(3)) == (pytest.approx(np.zeros(3)), True)  # 0.5 s: level out and hold
    assert fw.output(2.1, np.zeros(3))[1] is False and fw.mode == "locked"  # 2 s: motors off
    clock.t = 2.2
    link.send_velocity(0, np.array([0.2, 0.0, 0.0]))
    assert fw.mode == "locked" and fw.events[-1][1] == "locked"
    kinds = [kind for _, kind, _ in fw.events]
    assert kinds.count("watchdog") == 2


def test_extpose_is_ignored_without_kalman_and_take_off_refused():
    clock = Clock()
    fw = VirtualFirmware("cf1", clock)
    link = CrazyflieLink(URIS[:1], factory=VirtualCfFactory({URIS[0]: fw}))
    link.params = CrazyflieParamsConfig(extra={"stabilizer.estimator": 1})  # overrides Kalman
    link.open()
    link.send_pose(0, np.array([0.0, 0.0, 0.0125, 0.0, 0.0, 0.0, 1.0]))
    link.takeoff(0, 1.0, 2.0)
    assert fw.counts["ext_pose_ignored"] == 1 and fw.est_pos is None
    assert fw.events[-1][1] == "refused" and fw.mode == "off"
    link.close()


def test_unknown_parameters_and_lost_links_are_reported():
    fw = VirtualFirmware("cf1", Clock())
    link = CrazyflieLink(URIS[:1], CrazyflieParamsConfig(extra={"ring.effect": 7}), VirtualCfFactory({URIS[0]: fw}))
    with pytest.raises(LinkError, match=r"no parameter 'ring\.effect'"):
        link.open()

    fw = VirtualFirmware("cf1", Clock())
    factory = VirtualCfFactory({URIS[0]: fw})
    link = CrazyflieLink(URIS[:1], factory=factory)
    link.open()
    assert link.lost(0) is None
    factory.crazyflies[URIS[0]].fail_link("too many packets lost")
    assert link.lost(0) == "too many packets lost"
    sent = len(factory.crazyflies[URIS[0]].sent)
    link.send_velocity(0, np.ones(3))  # dropped, as cflib drops packets to a dead link
    assert len(factory.crazyflies[URIS[0]].sent) == sent and fw.counts["velocity_world"] == 0
    link.close()


def test_closing_the_link_stops_the_motors_as_cflib_does(swarm):
    link, firmwares, _, _ = swarm
    link.send_pose(0, np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]))
    link.send_velocity(0, np.zeros(3))
    link.close()
    fw = firmwares[URIS[0]]
    assert fw.counts["rpyt"] == 1 and fw.mode == "off"


@pytest.mark.parametrize("arm", [False, True])
def test_drones_that_need_arming_take_off_only_when_armed(arm):
    from cflib.crazyflie import supervisor

    fw = VirtualFirmware("cf1", Clock(), requires_arming=True)
    factory = VirtualCfFactory({URIS[0]: fw})
    link = CrazyflieLink(URIS[:1], CrazyflieParamsConfig(arm=arm), factory)
    link.open()
    arming = [(c, d) for p, c, d in factory.crazyflies[URIS[0]].sent if p == CRTPPort.SUPERVISOR]
    assert arming == ([(supervisor.SUPERVISOR_CH_COMMAND, bytes([supervisor.CMD_ARM_SYSTEM, 1]))] if arm else [])
    link.send_pose(0, np.array([0.0, 0.0, 0.0125, 0.0, 0.0, 0.0, 1.0]))
    link.takeoff(0, 1.0, 2.0)
    assert fw.mode == ("high" if arm else "off")
    assert arm or fw.events[-1][2] == "takeoff refused: not armed"
    link.close()
