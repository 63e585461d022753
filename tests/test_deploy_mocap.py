"""motioncapture's ``mock`` backend feeding the deployment loop, and connections that time out."""

import time

import numpy as np
import pytest

from marlander_lite.deploy.config import EXAMPLE_CONFIG, MocapConfig, load_lab_config
from marlander_lite.deploy.link import CrazyflieLink
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.pose_sources import MotionCaptureSource, RealClock
from marlander_lite.deploy.rehearsal.virtual_crazyflie import VirtualCfFactory
from marlander_lite.deploy.rehearsal.virtual_firmware import VirtualFirmware
from marlander_lite.policy_file import PolicyContract, load_policy, save_policy

# Bodies as motioncapture's mock takes them: name(x, y, z, qw, qx, qy, qz). The plate is turned
# 90 degrees about z, so its pads' offsets (-0.125, 0, 0.0025) and (0.125, 0, 0.0025) point along -y and +y.
S = float(np.sqrt(0.5))
MOCK_BODIES = f"cf1(-0.6,0.5,0.0125,1,0,0,0);cf2(0.6,0.5,0.0125,1,0,0,0);plate(0.2,-0.4,0.3,{S},0,0,{S})"
EXPECTED_PADS = np.array([[0.2, -0.525, 0.3025], [0.2, -0.275, 0.3025]])  # rotated offsets, by hand


def mock_lab():
    lab = load_lab_config(EXAMPLE_CONFIG)
    mocap = MocapConfig(kind="mock", options={"rigid_bodies": MOCK_BODIES, "frequency": "100"})
    return lab.replace(mocap=mocap)


def test_mock_frames_arrive_in_our_quaternion_order():
    lab = mock_lab()
    source = MotionCaptureSource("mock", lab.mocap.connect_cfg(), timeout_s=20.0)
    try:
        deadline, frames = time.monotonic() + 10.0, []
        while len(frames) < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
            frames += source.read(time.monotonic())
    finally:
        source.close()
    assert len(frames) >= 5
    assert np.all(np.diff([f.t for f in frames]) > 0)
    plate = frames[-1].bodies["plate"]
    np.testing.assert_allclose(plate, [0.2, -0.4, 0.3, 0.0, 0.0, S, S], atol=1e-6)  # x y z, qx qy qz qw
    np.testing.assert_allclose(frames[-1].bodies["cf2"], [0.6, 0.5, 0.0125, 0, 0, 0, 1], atol=1e-6)


def test_mock_backend_feeds_the_loop_to_take_off(tmp_path):
    """The mission on wall time: mock poses -> estimates and eq. 2 -> arming -> cflib take-off packets."""
    lab = mock_lab()
    task = lab.task_config()
    contract = PolicyContract(
        num_drones=2, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(), normalize_observations=False
    )
    zeros = {"actor.0.weight": np.zeros((6, 26)), "actor.0.bias": np.zeros(6)}
    path = save_policy(tmp_path / "p.safetensors", contract, zeros)
    firmwares = {d.uri: VirtualFirmware(d.name, time.monotonic) for d in lab.drones}
    link = CrazyflieLink([d.uri for d in lab.drones], lab.crazyflie, factory=VirtualCfFactory(firmwares))
    link.open()
    source = MotionCaptureSource("mock", lab.mocap.connect_cfg(), timeout_s=20.0)

    def stop_after_takeoff(mission: Mission, t: float) -> None:
        if mission.mode == "takeoff":
            mission.request_kill("test over")
        elif t > 8.0:
            mission.request_land("test timeout")

    mission = Mission(
        lab, load_policy(path, task), source, link, RealClock(), hooks=[stop_after_takeoff], min_preflight_s=0.3
    )
    try:
        result = mission.run()
    finally:
        source.close()
        link.close()
    assert result.armed, [e.message for e in result.events]
    kinds = [e.kind for e in result.events if e.kind != "loop_overrun"]  # a loaded CI host may stall the loop
    assert kinds == ["armed", "emergency"], [e.message for e in result.events]
    est = mission.stream.last
    np.testing.assert_allclose(est.pos, [[-0.6, 0.5, 0.0125], [0.6, 0.5, 0.0125]], atol=1e-6)
    np.testing.assert_allclose(est.pad_pos, EXPECTED_PADS, atol=1e-6)
    np.testing.assert_allclose(est.vel, 0.0, atol=1e-9)
    obs = mission.runner.observe(est)
    goals = EXPECTED_PADS + np.array([0.0, 0.0, task.landed_height])
    rel = np.array([[-0.6, 0.5, 0.0125], [0.6, 0.5, 0.0125]]) - goals
    np.testing.assert_allclose(obs[:, 0:3], rel, atol=1e-6)
    np.testing.assert_allclose(obs[:, 3:7], [[0, 0, 0, 1]] * 2, atol=1e-6)
    for i, fw in enumerate(firmwares.values()):
        assert fw.counts["takeoff"] == 1 and fw.counts["ext_pose"] >= 5  # 0.3 s of poses at 48 Hz, some ticks lost
        np.testing.assert_allclose(fw.est_pos, est.pos[i], atol=1e-6)
        assert fw.mode == "off"  # stopped by the kill request


def test_connecting_to_a_silent_server_times_out():
    start = time.monotonic()
    with pytest.raises(TimeoutError, match="No answer from the 'vicon' motion-capture server"):
        MotionCaptureSource("vicon", {"hostname": "127.0.0.1"}, timeout_s=1.0)
    assert time.monotonic() - start < 10.0


def test_connection_errors_are_reported():
    with pytest.raises(ConnectionError, match="Unknown motion capture type"):
        MotionCaptureSource("kinect", {}, timeout_s=20.0)


def test_the_mocap_worker_survives_the_signals_that_land_the_drones():
    """Ctrl-C in the terminal, a dropped SSH session (SIGHUP) and ``timeout`` signal the whole foreground
    process group; the worker must keep streaming poses while the loop lands the drones."""
    import os

    lab = mock_lab()
    source = MotionCaptureSource("mock", lab.mocap.connect_cfg(), timeout_s=20.0)
    try:
        worker = source._proc.pid
        assert os.getpgid(worker) != os.getpgid(0) and os.getsid(worker) != os.getsid(0)  # not in our group
        deadline, frames = time.monotonic() + 10.0, []
        while len(frames) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
            frames += source.read(time.monotonic())
    finally:
        source.close()
    assert len(frames) >= 3
