"""Lab config: the example loads, and every kind of mistake is refused with a message saying what is allowed."""

import copy

import pytest
import yaml

from marlander_lite.deploy.config import EXAMPLE_CONFIG, ConfigError, LabConfig, load_lab_config


@pytest.fixture
def example() -> dict:
    return yaml.safe_load(EXAMPLE_CONFIG.read_text())


def test_example_config_loads_with_its_values(example):
    lab = load_lab_config(EXAMPLE_CONFIG)
    assert lab.drone_names == ["cf1", "cf2"]
    assert lab.pad_bodies == ["plate"]
    assert lab.pads["pad2"].offset == (0.125, 0.0, 0.0025)
    assert lab.rates.ticks_per_action == 2
    assert lab.geofence.x == (-2.0, 2.0)
    task = lab.task_config()
    assert (task.num_drones, task.max_speed, task.policy_hz) == (2, 3.0, 24.0)
    assert lab.crazyflie.as_params() == {
        "stabilizer.estimator": 2,
        "stabilizer.controller": 1,
        "locSrv.extQuatStdDev": 0.008,
    }
    assert LabConfig.from_dict(example) == lab


def broken(example: dict, change) -> dict:
    data = copy.deepcopy(example)
    change(data)
    return data


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["limits"].update(max_sped=1.0), r"unknown key\(s\) \['max_sped'\]; allowed: max_speed, "),
        (lambda d: d.update(extra_section={}), r"unknown key\(s\) \['extra_section'\]; allowed: drones, pads"),
        (lambda d: d["drones"][1].pop("pad"), r"drones\[1\]: missing key\(s\) \['pad'\]; required: name, uri, pad"),
        (lambda d: d["drones"][1].update(pad="pad9"), r"drone 'cf2' names pad 'pad9'.*allowed: pad1, pad2"),
        (lambda d: d["drones"][1].update(pad="pad1"), r"drones 'cf1' and 'cf2' share pad 'pad1'"),
        (lambda d: d["drones"][1].update(name="cf1"), "rigid-body names must be unique"),
        (lambda d: d["rates"].update(loop_hz=500), r"loop_hz must be in \[policy_hz, 250\]"),
        (lambda d: d["rates"].update(policy_hz=0.5), r"policy_hz must be in \[1, 100\] Hz"),
        (lambda d: d["rates"].update(loop_hz=50), "whole multiple of rates.policy_hz"),
        (lambda d: d["mocap"].update(kind="kinect"), "allowed: vicon, optitrack, qualisys, vrpn, mock"),
        (lambda d: d["mocap"].update(hostname=""), "mocap.hostname is required"),
        (lambda d: d["mocap"].update(kind="mock"), "needs options.rigid_bodies"),
        (lambda d: d["limits"].update(max_speed="fast"), "limits.max_speed must be a finite number"),
        (lambda d: d["limits"].update(max_speed=5.0), r"max_speed must be in \(0, 3\] m/s"),
        (lambda d: d["geofence"].update(x=[2.0, -2.0]), "low < high"),
        (lambda d: d["geofence"].update(z=[0.0]), "geofence.z must be a list of 2 values"),
        (lambda d: d["limits"].update(takeoff_height=2.5), "above the soft geofence ceiling"),
        (lambda d: d["safety"].update(stale_land_s=0.05), "stale_hover_s < stale_land_s"),
        (lambda d: d["crazyflie"].update(estimator=1), "only Kalman fuses external poses"),
        (lambda d: d["simulation"].update(platform="moving-circle"), "allowed: static-floor, static-elevated"),
        (lambda d: d["simulation"].update(start_positions=[[0, 0]]), "one \\(x, y\\) per drone"),
    ],
)
def test_mistakes_are_refused_with_what_is_allowed(example, change, message):
    with pytest.raises(ConfigError, match=message):
        LabConfig.from_dict(broken(example, change))


def test_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "lab.yaml"
    bad.write_text("drones: [\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_lab_config(bad)
    bad.write_text("drones: []\npads: {}\n")
    with pytest.raises(ConfigError, match=r"lab.yaml: config: missing key\(s\) \['mocap'\]"):
        load_lab_config(bad)
    bad.write_text("drones: []\npads: {}\nmocap: {kind: vicon, hostname: vicon.local}\n")
    with pytest.raises(ConfigError, match=r"lab.yaml: config: drones: list at least one drone"):
        load_lab_config(bad)
    with pytest.raises(FileNotFoundError, match=r"example_lab\.yaml"):
        load_lab_config(tmp_path / "missing.yaml")


def test_geofence_soft_box_and_mock_cfg():
    lab = load_lab_config(EXAMPLE_CONFIG)
    fence = lab.geofence
    assert fence.contains((1.9, 0.0, 1.0)) and not fence.contains((1.9, 0.0, 1.0), soft=True)
    assert not fence.contains((float("nan"), 0.0, 1.0))
    assert fence.bounds(soft=True) == ((-1.7, -1.7, 0.0), (1.7, 1.7, 2.2))
    assert lab.mocap.connect_cfg() == {"hostname": "192.168.1.100"}
