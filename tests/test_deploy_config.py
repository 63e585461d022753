"""Lab config: the example loads, and every kind of mistake is refused with a message saying what is allowed."""

import copy
import dataclasses
import time

import pytest
import yaml

from marlander_lite.deploy.config import (
    EXAMPLE_CONFIG,
    SIMULATOR_KINDS,
    ConfigError,
    LabConfig,
    SimulationConfig,
    load_lab_config,
)


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
        (lambda d: d["limits"].update(max_sped=1.0), r"^limits.max_sped: unknown key; allowed: max_speed, "),
        (lambda d: d.update(extra_section={}), r"^extra_section: unknown key; allowed: drones, pads"),
        (lambda d: d["drones"][1].pop("pad"), r"^drones\[1\].pad: required but missing"),
        (lambda d: d["drones"][1].update(pad="pad9"), r"drone 'cf2' names pad 'pad9'.*allowed: pad1, pad2"),
        (lambda d: d["drones"][1].update(pad="pad1"), r"drones 'cf1' and 'cf2' share pad 'pad1'"),
        (lambda d: d["drones"][1].update(name="cf1"), "rigid-body names must be unique"),
        (
            lambda d: d["rates"].update(loop_hz=500),
            r"^rates.loop_hz: Input should be less than or equal to 250 \(got 500\)",
        ),
        (lambda d: d["rates"].update(policy_hz=0.5), r"^rates.policy_hz: Input should be greater than or equal to 1"),
        (lambda d: d["rates"].update(loop_hz=50), "whole multiple of rates.policy_hz"),
        (
            lambda d: d["mocap"].update(kind="kinect"),
            r"^mocap.kind: Input should be 'vicon', 'optitrack', 'qualisys', 'vrpn' or 'mock' \(got 'kinect'\)",
        ),
        (lambda d: d["mocap"].update(hostname=""), "mocap.hostname is required"),
        (lambda d: d["mocap"].update(kind="mock"), "needs options.rigid_bodies"),
        (
            lambda d: d["limits"].update(max_speed="fast"),
            r"^limits.max_speed: Input should be a valid number \(got 'fast'\)",
        ),
        (lambda d: d["limits"].update(max_speed=5.0), r"^limits.max_speed: Input should be less than or equal to 3"),
        (lambda d: d["geofence"].update(x=[2.0, -2.0]), "low < high"),
        (lambda d: d["geofence"].update(z=[0.0]), r"^geofence.z\[1\]: required but missing"),
        (lambda d: d["limits"].update(takeoff_height=2.5), "above the soft geofence ceiling"),
        (lambda d: d["safety"].update(stale_land_s=0.05), "stale_hover_s < stale_land_s"),
        (lambda d: d["crazyflie"].update(estimator=1), "only Kalman fuses external poses"),
        (
            lambda d: d["safety_filter"].update(min_dist=0.2),
            r"^safety_filter.min_dist: unknown key; allowed: enabled, ",
        ),
        (
            lambda d: d["safety_filter"].update(min_distance=0.3),
            r"safety_filter.min_distance is 0.3 m but pads 'pad1' and 'pad2' .* are 0.250 m apart",
        ),
        (
            lambda d: d["simulation"].update(platform="moving-circle"),
            r"^simulation.platform: Input should be 'static-floor', 'static-elevated'",
        ),
        (lambda d: d["simulation"].update(start_positions=[[0, 0]]), "one \\(x, y\\) per drone"),
        (
            lambda d: d["simulation"].update(inclination_deg=90),
            r"^simulation.inclination_deg: Input should be less than 90",
        ),
        (lambda d: d["safety"].update(max_pad_tilt_deg=0), r"^safety.max_pad_tilt_deg: Input should be greater than 0"),
        # strict types: no text for numbers, no 0/1 for booleans, no number for a name
        (lambda d: d["limits"].update(max_speed="0.5"), r"^limits.max_speed: Input should be a valid number"),
        (lambda d: d["crazyflie"].update(arm=1), r"^crazyflie.arm: Input should be a valid boolean"),
        (lambda d: d["limits"].update(max_speed=float("nan")), r"^limits.max_speed: Input should be a finite number"),
        (lambda d: d.update(limits=None), r"^limits: must be a mapping of keys to values, got None"),
        # defect 10: names and URIs
        (lambda d: d["drones"][0].update(name=""), r"^drones\[0\].name: must be a name of 1-64 letters"),
        (lambda d: d["drones"][0].update(uri=""), r"^drones\[0\].uri: must be a cflib URI such as radio://"),
        (lambda d: d["drones"][0].update(uri="hello"), r"^drones\[0\].uri: must be a cflib URI .* got 'hello'"),
        (lambda d: d["drones"][0].update(uri="radio://0/126/2M/E7E7E7E701"), r"^drones\[0\].uri: must be a cflib"),
        (lambda d: d["pads"].update({"": {"body": "plate"}}), r"^pads\[''\] \(a key\): must be a name"),
        (lambda d: d["pads"]["pad1"].update(body=" "), r"^pads.pad1.body: must be a name"),
        # defect 10: mixed-type unknown keys are reported, not a TypeError
        (
            lambda d: d["limits"].update({3: 1, "x": 2}),
            r"^limits\[3\]: Keys should be strings \(got 3\); limits.x: unknown key",
        ),
        (lambda d: d.update({None: 1, 2.5: 2}), r"Keys should be strings"),
        # defect 10: a take-off height that arming always refuses (not 0.3 m above the floor, so above the pads)
        (
            lambda d: d["limits"].update(takeoff_height=0.25),
            r"takeoff_height 0.25 m is less than 0.3 m above the floor",
        ),
        # defect 2: the geofence margin must hold the stopping distance at max_speed
        (
            lambda d: d["limits"].update(max_speed=2.0),
            r"geofence.margin 0.6 m is too narrow to brake in at limits.max_speed 2.0 m/s: a Crazyflie needs 1.82 m "
            r".* lower limits.max_speed to 1.00 m/s or less, or widen the gap: geofence.margin >= 1.82 m",
        ),
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
    with pytest.raises(ConfigError, match=r"lab.yaml: mocap: required but missing"):
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
    assert fence.bounds(soft=True) == ((-1.4, -1.4, 0.0), (1.4, 1.4, 1.9))
    assert lab.mocap.connect_cfg() == {"hostname": "192.168.1.100"}


# ---------------------------------------------------------------------------- defect 10: the YAML loader


def write(tmp_path, text: str):
    path = tmp_path / "lab.yaml"
    path.write_text(text)
    return path


def test_duplicate_keys_are_refused_not_silently_overwritten(tmp_path):
    text = EXAMPLE_CONFIG.read_text().replace("  max_speed: 1.0", "  max_speed: 0.3\n  max_speed: 3.0")
    with pytest.raises(ConfigError, match=r"line \d+: key 'max_speed' repeats the one on line \d+"):
        load_lab_config(write(tmp_path, text))
    with pytest.raises(ConfigError, match=r"key 'drones' repeats"):
        load_lab_config(write(tmp_path, EXAMPLE_CONFIG.read_text() + "drones: []\n"))


def test_a_yaml_bomb_fails_fast_with_a_config_error(tmp_path):
    lines = ["a0: &a0 [radio://0/80/2M/E7E7E7E701, x]"]
    lines += [f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]" for i in range(1, 12)]
    bomb = "\n".join(lines) + "\ndrones: [*a11, *a11, *a11]\npads: {}\nmocap: {kind: vicon, hostname: h}\n"
    start = time.perf_counter()
    with pytest.raises(ConfigError, match=r"more than 16 YAML aliases"):
        load_lab_config(write(tmp_path, bomb))
    assert time.perf_counter() - start < 1.0


def test_deep_nesting_and_huge_files_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="nested deeper than 16 levels"):
        load_lab_config(write(tmp_path, "drones: " + "[" * 3000 + "]" * 3000 + "\n"))
    with pytest.raises(ConfigError, match="nested deeper than 16 levels"):
        load_lab_config(write(tmp_path, "".join(f"{'  ' * i}k{i}:\n" for i in range(40))))
    with pytest.raises(ConfigError, match=r"has 65537 bytes; a lab config has at most 65536"):
        load_lab_config(write(tmp_path, "#" * 70_000))
    with pytest.raises(ConfigError, match="not UTF-8"):
        (tmp_path / "lab.yaml").write_bytes(b"drones: \xff\xfe\n")
        load_lab_config(tmp_path / "lab.yaml")
    with pytest.raises(ConfigError, match="the config is empty"):
        load_lab_config(write(tmp_path, "# nothing\n"))


def test_a_few_aliases_still_work(tmp_path):
    text = EXAMPLE_CONFIG.read_text().replace("radius: 0.1", "radius: *r").replace("radius: *r", "radius: &r 0.12", 1)
    lab = load_lab_config(write(tmp_path, text))
    assert lab.pads["pad2"].radius == lab.pads["pad1"].radius == 0.12


def test_every_error_is_one_line(tmp_path):
    for text in (
        "\x1fdrones: []\n",  # a control character: found by the property test
        "drones: [\n",
        "drones: 3\n",
        "limits: {max_speed: fast}\n",
        ": : :\n",
        "!!python/object:os.system x\n",
    ):
        with pytest.raises(ConfigError) as error:
            load_lab_config(write(tmp_path, text))
        assert "\n" not in str(error.value) and str(error.value)


def test_accepted_uris_and_names():
    lab = load_lab_config(EXAMPLE_CONFIG)
    for uri in (
        "radio://0/80/2M/E7E7E7E7E7",
        "radio://*/125/250K",
        "radio://1/0/1M/e7e7e7e7e7",
        "usb://0",
        "debug://0/1",
    ):
        drone = dataclasses.replace(lab.drones[0], uri=uri)
        assert LabConfig.from_dict(dataclasses.asdict(lab.replace(drones=(drone, lab.drones[1])))).drones[0].uri == uri


def test_replace_validates_like_a_file():
    lab = load_lab_config(EXAMPLE_CONFIG)
    too_slow = dataclasses.replace(lab.limits, takeoff_duration=20.0)  # a bare section is not validated ...
    with pytest.raises(ConfigError, match=r"^limits.takeoff_duration: Input should be less than or equal to 10"):
        lab.replace(limits=too_slow)  # ... the lab config it goes into is
    assert lab.replace() == lab


def test_the_old_simulator_name_still_loads_with_a_warning_naming_the_new_one(tmp_path, example):
    """``simulator: pybullet`` (the name before the registry) loads as ``crazyflie``; the user is told to update."""
    assert load_lab_config(EXAMPLE_CONFIG).simulation.simulator == "crazyflie"
    old = tmp_path / "lab.yaml"
    old.write_text(EXAMPLE_CONFIG.read_text().replace("simulator: crazyflie", "simulator: pybullet"))
    assert "simulator: pybullet" in old.read_text()
    with pytest.warns(
        FutureWarning, match=r"lab\.yaml: simulation\.simulator: 'pybullet' .* write 'crazyflie'"
    ) as seen:
        lab = load_lab_config(old)
    assert len(seen) == 1 and lab.simulation.simulator == "crazyflie"
    assert lab == load_lab_config(EXAMPLE_CONFIG)  # nothing else changes
    with pytest.warns(FutureWarning, match="write 'crazyflie'"):
        assert SimulationConfig(simulator="pybullet").simulator == "crazyflie"
    example["simulation"]["simulator"] = "bullet"
    allowed = r"simulation.simulator: Input should be 'pointmass', 'crazyflie', 'rotorpy' or 'pyflyt'"
    with pytest.raises(ConfigError, match=allowed):
        LabConfig.from_dict(example)


def test_the_simulators_a_lab_can_rehearse_with_are_the_registered_ones():
    from marlander_lite.simulators import SIMULATORS

    assert SIMULATOR_KINDS == SIMULATORS == ("pointmass", "crazyflie", "rotorpy", "pyflyt")
