"""The fault campaign (``benchmarks/fault_campaign.py``) in CI: every fault, every platform, 3 seeds, all zero.

It rehearses each documented fault and a SIGTERM on the floor, the UR10 and the moving arc at the
fastest speed the lab config allows (PyBullet physics, simulated flights cut to 12 s), and checks
that nothing that must never happen did: no fly-away, no fence exit, every drone down, every fault
injected, every tick logged exactly once. One test per platform. With 5 seeds they took 46 s (floor), 46 s (UR10) and
99 s (moving arc) of CI's time on the 2-core development machine under ``pytest -n 2`` (2026-12-01), the campaign's
share of a CI that ran over its 20 minutes; 3 seeds since. The benchmark itself runs 20 (``--seeds 20``).
"""

import dataclasses
import importlib.util
import signal
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

CAMPAIGN = Path(__file__).parents[1] / "benchmarks" / "fault_campaign.py"


@pytest.fixture(scope="module")
def fault_campaign():
    spec = importlib.util.spec_from_file_location("fault_campaign", CAMPAIGN)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


PLATFORM_NAMES = ("floor", "UR10", "moving arc")  # one test each, so that pytest -n spreads them over the workers


def test_the_campaign_tests_cover_every_platform(fault_campaign):
    assert set(PLATFORM_NAMES) == set(fault_campaign.PLATFORMS)


@pytest.mark.parametrize("name", PLATFORM_NAMES)
def test_campaign_totals_are_all_zero(fault_campaign, name):
    before = signal.getsignal(signal.SIGTERM)
    # Each platform draws its faults from (seed, platform name) alone, so one platform at a time flies the same
    # rehearsals as the whole campaign.
    campaign = fault_campaign.run_campaign(range(3), platforms={name: fault_campaign.PLATFORMS[name]})
    assert campaign.totals["rehearsals"] == 3 * len(fault_campaign.CASES)
    assert campaign.ok, campaign.report()
    assert signal.getsignal(signal.SIGTERM) is before  # the SIGTERM cases left no handler behind


def test_the_campaign_flies_at_the_largest_allowed_speed(fault_campaign):
    from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config

    lab = fault_campaign.campaign_lab("static-floor", 12.0)
    speed = lab.limits.max_speed
    assert speed >= load_lab_config(EXAMPLE_CONFIG).limits.max_speed
    with pytest.raises(ValueError):
        lab.replace(limits=dataclasses.replace(lab.limits, max_speed=speed + 0.02))


def test_a_drone_whose_moving_plate_leaves_it_during_a_landing_lands_on_the_floor(fault_campaign, tmp_path):
    """Moving arc, seed 17, ``nan-pose`` on cf2 (the campaign's draw; found on 2026-11-26): held over its moving pad
    by the approach guard, cf2 is still flying at the 12 s limit, and the land of every drone sends it down vertically
    onto the plate's height while the UR10 carries the plate on. It used to end that land beside the plate at 0.75 m
    and stop its motors there, dropping it; now the landing notices what is under it and lands it on the floor."""
    from marlander_lite.deploy.rehearsal import FaultSpec, rehearse
    from marlander_lite.policy_file import load_policy

    lab = fault_campaign.campaign_lab("moving-arc", 12.0)
    policy = load_policy(fault_campaign.POLICIES["moving"], lab.task_config(True))
    fault = FaultSpec("nan-pose", start_s=0.2786, drone=1)
    result = rehearse(lab, policy, simulator="crazyflie", fault=fault, seed=17, log_path=tmp_path / "log.jsonl")
    replanned = [e for e in result.mission.events if e.kind == "land_replanned"]
    assert len(replanned) == 1 and replanned[0].drone == 1, result.summary()
    # Simulator truth: both drones down with their motors off, cf2 at rest on the floor.
    assert result.safe and not result.motors_on.any(), result.summary()
    assert result.final_positions[1, 2] < 0.1 and result.final_speeds[1] < fault_campaign.DOWN_SPEED


def test_a_drone_knocked_over_by_a_falling_lost_drone_stops_its_motors(fault_campaign, tmp_path):
    """Moving arc, seed 6, ``link-loss`` on cf1 at 0.55 s, the moving-pad settings with the latency compensation (the
    campaign's draw; found on 2026-11-26): cf2 lands under the lost cf1, whose firmware stops its motors 2 s later;
    cf1 falls onto cf2 and knocks it over. With its motors still on, cf2's own thrust drove it along the floor to
    2.85 m beyond the hard fence. Now the tumble rule stops its motors: nothing leaves the fence."""
    from marlander_lite.deploy.rehearsal import FaultSpec, rehearse
    from marlander_lite.policy_file import load_policy

    lab = fault_campaign.campaign_lab("moving-arc", 12.0)
    settings = {"cone_radius": 0.04, "reaction_time": 0.35, "pad_lead": 0.2, "latency_compensation": 0.12}
    lab = lab.replace(safety_filter=lab.safety_filter.with_settings(settings))
    policy = load_policy(fault_campaign.POLICIES["moving"], lab.task_config(True))
    fault = FaultSpec("link-loss", start_s=0.5505, drone=0)
    log_path = tmp_path / "log.jsonl"
    result = rehearse(lab, policy, simulator="crazyflie", fault=fault, seed=6, log_path=log_path)
    tumbled = [e for e in result.mission.events if e.kind == "tumbled"]
    assert len(tumbled) == 1 and tumbled[0].drone == 1, result.summary()
    campaign = fault_campaign.Campaign()
    campaign.add("moving arc seed 6 link-loss", result, log_path)
    assert campaign.ok, campaign.report()
    assert (result.fence_excess == 0).all() and not result.motors_on.any(), result.summary()
