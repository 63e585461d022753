"""Both simulators we did not write, hosted in the point mass's world (``pointmass/hosted.py``): touchdowns.

A drone sinking straight down onto its own pad lands when slow and crashes when fast, judged by the MDP from the
impact velocity the hosted step hands over, as in the point mass.
"""

from __future__ import annotations

import numpy as np
import pytest

from marlander_lite.episodes import LandingEpisodes
from marlander_lite.simulators import simulator_entry
from marlander_lite.task import CONTACT_OWN_PAD

HOSTED = [
    # name, its package, how far off the pad centre a slow straight descent may end (m): RotorPy's drone holds its
    # position; PyFlyt's drifts under 2 % motor noise, as nothing in its velocity loop holds a position.
    ("rotorpy", "rotorpy", 0.01),
    ("pyflyt", "PyFlyt", 0.1),
]


@pytest.mark.parametrize(("name", "package", "error_bound"), HOSTED)
@pytest.mark.parametrize(("sink", "lands"), [(0.2, True), (1.5, False)])
def test_a_touchdown_on_the_own_pad_lands_when_slow_and_crashes_when_fast(name, package, error_bound, sink, lands):
    pytest.importorskip(package)
    sim, _ = simulator_entry(name).options_class()(num_drones=1, platform="static-elevated").build(1)
    episodes = LandingEpisodes(sim, seed=1)
    episodes.reset()
    goal = sim.state().pad_pos[0, 0]
    sim.place(0, (goal + np.array([0.0, 0.0, 0.3]))[None])
    for _ in range(72):  # over the pad centre, sinking straight down
        command = np.array([0.0, 0.0, -sink]) / episodes.task.max_speed
        outcome = episodes.step(command[None, None])
        if outcome.done[0]:
            break
    assert outcome.done[0]
    assert bool(outcome.success[0]) is lands
    assert bool(outcome.crashed[0, 0]) is not lands
    if lands:
        assert outcome.landing_error[0, 0] < error_bound
        assert sim.landed[0, 0] and np.abs(sim.vel[0, 0]).max() == 0.0  # held on its pad
    else:
        assert outcome.rel_speed[0, 0] > episodes.task.touchdown_speed_max
        assert sim.contact[0, 0] == CONTACT_OWN_PAD
    sim.close()
