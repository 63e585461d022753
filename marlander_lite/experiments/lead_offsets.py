"""Where a pad-frame policy's drones touch down on a moving pad: their offset along the pad's velocity.

A pad-frame command is ``v_pad + T_lead a_pad + a v_max`` (``TaskConfig.command_frame`` ``"pad"``, ``pad_frame_lead``
``T_lead``). A velocity tracker with time constant ``T`` follows a command that changes at ``a`` m/s^2 about ``T a``
behind it, so it keeps up with a pad that speeds up, brakes or turns when ``T_lead`` is about ``T``: led further,
its drone runs ahead of the pad and touches down ahead of its centre; led less, behind it.
:func:`touchdown_offsets` measures that offset in one cell of the transfer matrix (``benchmarks/pad_frame_lead.py``
sweeps the lead; docs/transfer.md, "Where a pad-frame drone touches down").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlander_lite.episodes import StepOutcome
from marlander_lite.experiments.transfer import Column, Row, build_episodes, cell_actor, find_column, fly_episodes
from marlander_lite.pad_frame_lead import PadFrameLead
from marlander_lite.policy_file import load_policy


@dataclass(frozen=True)
class TouchdownOffsets:
    """Each drone's first touchdown on a moving pad in ``episodes`` episodes, relative to its pad centre."""

    episodes: int
    successes: int
    """Episodes in which every drone landed."""
    along: np.ndarray
    """``(k,)`` offsets along the pad's horizontal velocity at touchdown (m); positive: ahead of the pad."""
    across: np.ndarray
    """``(k,)`` offsets across it (m), positive to the left of the pad's motion."""
    leads: np.ndarray
    """``(k,)`` the lead (s) the touchdown's last command was flown with: the one given, or ``"auto"``'s identified."""


def touchdown_offsets(
    policy_path: str,
    column: str | Column,
    platform: str,
    speed: float,
    lead: PadFrameLead | None,
    episodes: int,
    seed: int = 0,
) -> TouchdownOffsets:
    """Fly ``episodes`` episodes of ``policy_path`` in the transfer matrix's ``column`` (its name, or any
    :class:`Column`) on a ``platform`` (``moving-linear`` or ``moving-arc``) at tool ``speed`` (m/s), Vicon sensing,
    with its commands led by ``lead`` (s; None: the lead the policy was trained with; ``"auto"``: set in flight,
    :mod:`marlander_lite.pad_frame_lead`).
    Touchdowns while the pad is at rest (turning back) have no along-track direction and are left out."""
    if platform not in ("moving-linear", "moving-arc"):
        raise ValueError(f"platform must be moving-linear or moving-arc, got {platform!r}: a pad at rest has no track.")
    policy = load_policy(policy_path)
    row = Row(f"{platform} {speed:g} m/s", platform, (speed, speed))
    column = column if isinstance(column, Column) else find_column(column)
    world = build_episodes(policy, column, row, "vicon", pad_frame_lead=lead)
    along: list[float] = []
    across: list[float] = []
    leads: list[float] = []
    touched = np.zeros(world.task.num_drones, dtype=bool)  # this episode's drones already down
    flown_lead = world.pad_frame_leads()  # the lead of the step just flown: read before each step

    def watch(outcome: StepOutcome) -> None:
        nonlocal flown_lead
        contact = (outcome.landed_now[0] | outcome.crashed[0]) & ~touched
        s = world.sim.state()
        for i in np.flatnonzero(contact):
            offset, velocity = (s.pos[0, i] - s.pad_pos[0, i])[:2], s.pad_vel[0, i, :2]
            speed_now = float(np.linalg.norm(velocity))
            if speed_now > 1e-3:
                along.append(float(offset @ velocity) / speed_now)
                across.append(float(velocity[0] * offset[1] - velocity[1] * offset[0]) / speed_now)
                leads.append(float(flown_lead[0]))
        touched[:] = False if outcome.done[0] else touched | contact
        flown_lead = world.pad_frame_leads()

    successes = fly_episodes(world, cell_actor(policy, world, None), row.name, episodes, seed, watch)
    return TouchdownOffsets(episodes, successes, np.array(along), np.array(across), np.array(leads))
