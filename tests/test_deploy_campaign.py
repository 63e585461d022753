"""The fault campaign (``benchmarks/fault_campaign.py``) in CI: every fault, every platform, 5 seeds, all zero.

It rehearses each documented fault and a SIGTERM on the floor, the UR10 and the moving arc at the
fastest speed the lab config allows (PyBullet physics, simulated flights cut to 12 s), and checks
that nothing that must never happen did: no fly-away, no fence exit, every drone down, every fault
injected, every tick logged exactly once. About 45 s on the 2-core development machine.
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


def test_campaign_totals_are_all_zero(fault_campaign):
    before = signal.getsignal(signal.SIGTERM)
    campaign = fault_campaign.run_campaign(range(5))
    cases, platforms = len(fault_campaign.CASES), len(fault_campaign.PLATFORMS)
    assert campaign.totals["rehearsals"] == 5 * cases * platforms
    assert campaign.ok, campaign.report()
    assert signal.getsignal(signal.SIGTERM) is before  # the SIGTERM cases left no handler behind


def test_the_campaign_flies_at_the_largest_allowed_speed(fault_campaign):
    from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config

    lab = fault_campaign.campaign_lab("static-floor", 12.0)
    speed = lab.limits.max_speed
    assert speed >= load_lab_config(EXAMPLE_CONFIG).limits.max_speed
    with pytest.raises(ValueError):
        lab.replace(limits=dataclasses.replace(lab.limits, max_speed=speed + 0.02))
