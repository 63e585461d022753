"""``pad_assignment: shortest`` in the lab: the drones' pads handed out again at take-off by the shortest pairing.

Checked against pairings worked out by hand or by trying every permutation, against motioncapture's own mock
backend (real poses in, the rotated plate's pads out), and in rehearsals judged by the simulator's ground truth.
"""

import dataclasses
import itertools
import re
import struct
import time

import numpy as np
import pytest
from cflib.crtp.crtpstack import CRTPPort

from marlander_lite.cli import main
from marlander_lite.deploy.config import EXAMPLE_CONFIG, MocapConfig, SimulationConfig, load_lab_config
from marlander_lite.deploy.flight_log import read_flight_log
from marlander_lite.deploy.link import CrazyflieLink
from marlander_lite.deploy.pairing import PairingError, pair_drones_with_pads, pairing_line, resting_positions
from marlander_lite.deploy.pose_sources import MotionCaptureSource, PoseFrame, RealClock
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.rehearsal.faults import FAULT_KINDS, FaultSpec
from marlander_lite.deploy.rehearsal.virtual_crazyflie import VirtualCfFactory
from marlander_lite.deploy.rehearsal.virtual_firmware import VirtualFirmware
from marlander_lite.deploy.rehearsal.world import SimulatedWorld, make_simulator
from marlander_lite.deploy.schema import ConfigError

S = float(np.sqrt(0.5))
# cf1 rests north of the plate, cf2 south; the plate is turned 90 degrees about z, so pad1 (offset -0.125 m in x)
# lies at y = -0.525 and pad2 at y = -0.275 (as in test_deploy_mocap.py). The config's pairs cross; the
# shortest pairing sends cf1 to pad2 and cf2 to pad1: squared distances 0.775^2 + 0.975^2 = 1.55 m^2 against
# 1.025^2 + 1.225^2 = 2.55 m^2 for the config's pairs.
MOCK_BODIES = f"cf1(0.2,0.5,0.0125,1,0,0,0);cf2(0.2,-1.5,0.0125,1,0,0,0);plate(0.2,-0.4,0.3,{S},0,0,{S})"


@pytest.fixture(scope="module")
def lab():
    return load_lab_config(EXAMPLE_CONFIG).replace(
        pad_assignment="shortest", simulation=SimulationConfig(simulator="pointmass", max_time_s=30.0)
    )


def test_motioncapture_mock_poses_pair_the_drones_as_worked_by_hand(lab):
    lab = lab.replace(mocap=MocapConfig(kind="mock", options={"rigid_bodies": MOCK_BODIES, "frequency": "100"}))
    source = MotionCaptureSource("mock", lab.mocap.connect_cfg(), timeout_s=20.0)
    try:
        drones, pads = resting_positions(lab, source, RealClock(), wait_s=10.0)
    finally:
        source.close()
    np.testing.assert_allclose(drones, [[0.2, 0.5, 0.0125], [0.2, -1.5, 0.0125]], atol=1e-6)
    np.testing.assert_allclose(pads, [[0.2, -0.525, 0.3025], [0.2, -0.275, 0.3025]], atol=1e-6)
    paired = pair_drones_with_pads(lab, drones, pads)
    assert [d.pad for d in paired.drones] == ["pad2", "pad1"]
    assert [d.name for d in paired.drones] == ["cf1", "cf2"] and paired.drones[0].uri == lab.drones[0].uri
    assert (
        pairing_line(lab, ["pad2", "pad1"])
        == "Pads paired with the drones by the shortest paths: cf1 -> pad2, cf2 -> pad1."
    )


def brute_force_pads(starts: np.ndarray, pads: np.ndarray) -> tuple[int, ...]:
    """For each drone, the index of its pad under the pairing of least summed squared distance, seen from above."""
    n = len(starts)
    costs = {
        p: sum(float(((starts[i, :2] - pads[p[i], :2]) ** 2).sum()) for i in range(n))
        for p in itertools.permutations(range(n))
    }
    return min(costs, key=costs.get)


def test_eight_drones_get_the_pairing_that_trying_every_permutation_finds():
    lab8 = load_lab_config(EXAMPLE_CONFIG.parent / "example_lab_8.yaml")
    rng = np.random.default_rng(3)
    pads = np.array([[*p.offset[:2], 0.0] for p in lab8.drone_pads()])
    for _ in range(5):
        starts = np.column_stack((rng.uniform(-1.8, 1.8, (8, 2)), rng.uniform(0, 1.5, 8)))  # heights do not count
        paired = pair_drones_with_pads(lab8, starts, pads)
        expected = brute_force_pads(starts, pads)
        assert [d.pad for d in paired.drones] == [lab8.drones[k].pad for k in expected]


def test_drones_already_on_their_shortest_pairs_keep_their_pads(lab):
    pads = np.array([[-0.125, 0.0, 0.0], [0.125, 0.0, 0.0]])
    paired = pair_drones_with_pads(lab, np.array([[-1.0, 0.3, 0.0], [1.0, -0.3, 0.0]]), pads)
    assert paired == lab
    assert "cf1 -> pad1 (as configured)" in pairing_line(lab, ["pad1", "pad2"])


class ScriptedSource:
    """A pose source that only ever sees the bodies it is given."""

    def __init__(self, bodies: dict[str, list[float]]) -> None:
        self.bodies = {k: np.array(v, dtype=float) for k, v in bodies.items()}

    def read(self, now: float) -> list[PoseFrame]:
        return [PoseFrame(t=now, bodies=dict(self.bodies))]

    def close(self) -> None:
        pass


class SimClock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


def test_a_drone_the_motion_capture_never_sees_stops_the_pairing_and_names_it(lab):
    source = ScriptedSource({"cf1": [0.0, 0.5, 0.0, 0, 0, 0, 1], "plate": [0.0, 0.0, 0.0, 0, 0, 0, 1]})
    clock = SimClock()
    with pytest.raises(PairingError, match=r"no valid pose of cf2\. Nothing was armed.*pad_assignment: fixed"):
        resting_positions(lab, source, clock, wait_s=2.0)
    assert 2.0 <= clock.t < 2.1  # it waited as long as it was told, no longer


def test_wrong_shapes_and_unknown_assignments_are_refused(lab, tmp_path):
    with pytest.raises(ValueError, match=r"must be \(2, 3\) arrays"):
        pair_drones_with_pads(lab, np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        pair_drones_with_pads(lab, np.full((2, 3), np.nan), np.zeros((2, 3)))
    bad = tmp_path / "lab.yaml"
    bad.write_text(EXAMPLE_CONFIG.read_text().replace("pad_assignment: fixed ", "pad_assignment: nearest"))
    with pytest.raises(ConfigError, match=r"pad_assignment: Input should be 'fixed' or 'shortest'"):
        load_lab_config(bad)


def test_the_rehearsal_lands_each_drone_on_the_pad_the_pairing_gave_it(lab, p_controller_policy, tmp_path):
    """The config's pairs would cross (cf1 east of the plate, pad1 west); the pairing swaps them, and the drones,
    judged by the simulator's ground truth, rest on the swapped pads. The flight log records the pairing flown."""
    lab = lab.replace(simulation=dataclasses.replace(lab.simulation, start_positions=((1.0, 0.6), (-1.0, -0.6))))
    log_path = tmp_path / "paired.jsonl"
    result = rehearse(lab, p_controller_policy, log_path=log_path)
    assert result.pads == ["pad2", "pad1"]
    assert result.mission.success and result.safe, result.summary()
    offsets = {name: np.array(p.offset) for name, p in lab.pads.items()}
    plate_centre = result.pad_positions.mean(axis=0)
    for i, pad in enumerate(result.pads):  # the pad under each drone is the config's pad it was given
        np.testing.assert_allclose(result.pad_positions[i, :2] - plate_centre[:2], offsets[pad][:2], atol=1e-6)
    assert (np.linalg.norm(result.final_positions[:, :2] - result.pad_positions[:, :2], axis=1) < 0.05).all()
    assert result.final_positions[0, 0] > plate_centre[0] > result.final_positions[1, 0]  # cf1 east, cf2 west
    assert read_flight_log(log_path).header["pads"] == ["pad2", "pad1"]


def test_a_fault_on_a_paired_drone_strikes_that_drone(lab, p_controller_policy, tmp_path):
    """The world lists its drones in pad order after the swap; the fault still hits cf1, the drone it names."""
    lab = lab.replace(simulation=dataclasses.replace(lab.simulation, start_positions=((1.0, 0.6), (-1.0, -0.6))))
    log_path = tmp_path / "fault.jsonl"
    result = rehearse(lab, p_controller_policy, fault=FaultSpec("geofence-breach", drone=0), log_path=log_path)
    assert result.pads == ["pad2", "pad1"] and result.safe, result.summary()
    reach = np.array([[np.hypot(*t["est"]["pos"][i][:2]) for i in range(2)] for t in read_flight_log(log_path).ticks])
    soft_half = 2.0 - lab.geofence.margin
    ran = np.nanmax(reach, axis=0)
    assert ran[0] >= soft_half - 0.05 > ran[1], ran  # cf1 ran out to the soft fence, cf2 did not


def test_shortest_rehearsals_are_deterministic(lab, p_controller_policy):
    a, b = (rehearse(lab, p_controller_policy, seed=4) for _ in range(2))
    assert a.pads == b.pads
    np.testing.assert_array_equal(a.final_positions, b.final_positions)


def test_the_world_places_given_starts_in_drone_order(lab):
    starts = np.array([[1.0, 0.6, 0.0125], [-1.0, -0.6, 0.0125]])
    world = SimulatedWorld(lab, make_simulator(lab, "pointmass"), seed=0, starts=starts)
    try:
        np.testing.assert_allclose(world.drone_positions(), starts)
        assert world.index("cf2") == 1
    finally:
        world.close()


def test_the_command_line_rehearsal_prints_the_pairing(p_controller_policy, tmp_path, capsys):
    config = tmp_path / "lab.yaml"
    text = EXAMPLE_CONFIG.read_text().replace("simulator: crazyflie", "simulator: pointmass")
    config.write_text(text.replace("pad_assignment: fixed ", "pad_assignment: shortest"))
    args = ["deploy", "--sim", "--config", str(config), "--policy", str(p_controller_policy)]
    assert main([*args, "--log", str(tmp_path / "a.jsonl")]) == 0
    [line] = [x for x in capsys.readouterr().out.splitlines() if x.startswith("Pads paired")]
    assert re.fullmatch(r"Pads paired with the drones by the shortest paths: cf1 -> pad\d.*, cf2 -> pad\d.*\.", line)


def test_a_drone_missing_from_the_motion_capture_stops_the_flight_before_anything_is_armed(
    p_controller_policy, tmp_path, capsys, monkeypatch
):
    """The hardware path, with motioncapture's mock backend tracking cf1 and the plate but not cf2, and virtual
    Crazyflies behind cflib: the command stops with exit code 2 and no drone was sent a setpoint or a take-off."""
    config = tmp_path / "lab.yaml"
    mocap = (
        "mocap:\n  kind: mock\n  connect_timeout_s: 20.0\n"
        f'  options: {{rigid_bodies: "cf1(0.2,0.5,0.0125,1,0,0,0);plate(0.2,-0.4,0.3,{S},0,0,{S})", '
        'frequency: "100"}\n'
    )
    text = EXAMPLE_CONFIG.read_text()
    start, end = text.index("mocap:\n"), text.index("\ndrones:")
    config.write_text(text[:start] + mocap + text[end:].replace("pad_assignment: fixed ", "pad_assignment: shortest"))
    lab = load_lab_config(config)
    firmwares = {d.uri: VirtualFirmware(d.name, time.monotonic) for d in lab.drones}
    factory = VirtualCfFactory(firmwares)

    def virtual_link(uris, params, **_):
        return CrazyflieLink(uris, params, factory=factory)

    monkeypatch.setattr("marlander_lite.deploy.link.CrazyflieLink", virtual_link)
    code = main(
        [
            "deploy",
            "--config",
            str(config),
            "--policy",
            str(p_controller_policy),
            "--yes",
            "--log",
            str(tmp_path / "f.jsonl"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2, err
    assert "no valid pose of cf2. Nothing was armed." in err
    for cf in factory.crazyflies.values():  # no setpoint, no take-off; closing cflib's link sends zero thrust only
        assert not [p for p, _, _ in cf.sent if p in (CRTPPort.COMMANDER_GENERIC, CRTPPort.SETPOINT_HL)]
        legacy = [struct.unpack("<fffH", data) for p, _, data in cf.sent if p == CRTPPort.COMMANDER]
        assert all(thrust == 0 for *_, thrust in legacy), legacy
    assert not (tmp_path / "f.jsonl").exists()


@pytest.mark.parametrize("fault", FAULT_KINDS)
def test_every_fault_ends_safely_with_the_pads_swapped(fault, lab, p_controller_policy):
    """Each fault names drone 0 (cf1), which the pairing sends to pad2; the world lists cf2 first. The fault must hit
    cf1 and every drone must end at rest inside the fence, as in the faults of test_deploy_rehearsal.py."""
    lab = lab.replace(simulation=dataclasses.replace(lab.simulation, start_positions=((1.0, 0.6), (-1.0, -0.6))))
    result = rehearse(lab, p_controller_policy, fault=FaultSpec(fault))
    assert result.pads == ["pad2", "pad1"]
    assert result.safe and result.inside_fence.all() and result.at_rest.all(), result.summary()
    [injected] = [e for e in result.mission.events if e.kind == "fault_injected"]
    if fault in ("occlusion", "nan-pose", "link-loss", "geofence-breach"):  # faults of one drone name it
        assert "cf1" in injected.message and "cf2" not in injected.message, injected.message
    if fault == "link-loss":
        assert result.mission.phases[0] == "lost" and result.mission.phases[1] == "down"
        watchdog = [d for d, _, kind, _ in result.firmware_events if kind == "watchdog"]
        assert set(watchdog) == {"cf1"}, watchdog
        firmware = [e for e in result.mission.events if e.kind == "firmware"]  # logged against the drone they name
        assert firmware and all(e.drone == 0 and "cf1" in e.message for e in firmware), firmware
