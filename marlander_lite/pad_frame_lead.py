"""The lead of a pad-frame command: fixed, or set in flight from the velocity tracker it identifies.

Not in the paper. A pad-frame command carries its pad's velocity led by ``T_lead`` times its acceleration,
``v_pad + T_lead a_pad`` (``TaskConfig.command_frame`` ``"pad"``, ``pad_frame_lead``). A velocity tracker with time
constant ``T`` follows a command that changes at ``a`` m/s^2 about ``T a`` behind it, so the lead that keeps its drone
over a pad that brakes, reverses or turns grows with ``T``: led further, the drone touches down ahead of the pad
centre; led less, behind it (:mod:`marlander_lite.experiments.lead_offsets`; docs/transfer.md, "Where a pad-frame
drone touches down"). A lab seldom knows its tracker's time constant, and a policy is flown on trackers it was not
trained with, so one lead in the policy file cannot suit them all: the paper's network's moving fine-tune, trained
with 0.5 s, lands PyFlyt's slow Crazyflie best with 0.5 s and every faster tracker best with 0.15-0.3 s.

With ``TaskConfig.pad_frame_lead_share`` ``s`` > 0 the loop identifies its velocity tracker in flight, as the safety
filter's ``identified_lag_share`` does (:class:`~marlander_lite.swarm.tracker_lag.TrackerLag`: the first-order lag
``T`` that best explains the velocities that followed the commands sent), and leads each command by
``min(s T, MAX_PAD_FRAME_LEAD)``. Until the identification rests on :data:`WARMUP_SAMPLES` samples it leads by
``pad_frame_lead``, the policy file's (the identification starts from the prior ``pad_frame_lead / s``).
``marlander transfer --pad-frame-lead auto``, the lab config's ``limits.pad_frame_lead: auto`` and the other flight
settings select :data:`AUTO_LEAD_SHARE`. A policy trained with a share (``marlander train --task.pad-frame-lead-share
0.6``) carries it in its file, and every loop flies it so unless a lead is given (``PolicyContract.interface_options``;
:func:`describe_policy_lead`, :func:`flies_policy_lead`).

The identified ``T`` includes the attitude loop, the tilt limit and the sensing and command delays, so it is longer
than the velocity loop's own time constant: flying the moving fine-tune on the UR10's moving rows, 0.27-0.28 s on the
point mass (its loop: 0.14 s), 0.40 s through PyBullet's firmware tracker (0.20 s), 0.41 s on the held-out DSL PID and
0.82-0.96 s in PyFlyt (0.77 s; docs/transfer.md, "A lead the flight identifies").
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from marlander_lite.swarm.tracker_lag import TIME_CONSTANT_RANGE, TrackerLag
from marlander_lite.task import MAX_PAD_FRAME_LEAD, TaskConfig

AUTO = "auto"
"""The flight setting that leads pad-frame commands by :data:`AUTO_LEAD_SHARE` of the identified tracker lag."""
AUTO_LEAD_SHARE = 0.6
"""``s`` of ``auto``: 0.6 times the identified lag led by 0.16-0.34 s on the ten Crazyflie-like columns of the transfer
matrix, where fixed leads of 0.15-0.3 s land best, and by 0.49-0.58 s in PyFlyt, where 0.5 s lands best
(``benchmarks/pad_frame_lead.py``; docs/transfer.md, "A lead the flight identifies")."""

WARMUP_SAMPLES = 24
"""Samples (airborne drone-steps) the identification must rest on before it sets the lead: a second of one drone's
flight, half a second of two. The first commands after a hover meet the tracker's delays (radio, motion capture, a
setpoint mode switch) before any response, which a first-order fit of a few samples reads as the slowest tracker:
rehearsed through the firmware tracker, the first three samples gave 2.0 s, 1.74 s and 0.95 s where the flight then
settled at 0.45-0.5 s."""

PadFrameLead = float | Literal["auto"]
"""A flight setting for a pad-frame policy's lead: seconds (0 to :data:`~marlander_lite.task.MAX_PAD_FRAME_LEAD`), or
``"auto"``, the lead set in flight from the identified tracker."""


def lead_changes(lead: PadFrameLead) -> dict[str, float]:
    """The ``TaskConfig`` changes that fly a pad-frame policy with ``lead``: ``{"pad_frame_lead": lead,
    "pad_frame_lead_share": 0}`` for seconds, ``{"pad_frame_lead_share": AUTO_LEAD_SHARE}`` for ``"auto"`` (the file's
    ``pad_frame_lead`` then leads until the tracker is identified). Raises ``ValueError`` on anything else."""
    if lead == AUTO:
        return {"pad_frame_lead_share": AUTO_LEAD_SHARE}
    if isinstance(lead, bool) or not isinstance(lead, int | float) or not 0.0 <= lead <= MAX_PAD_FRAME_LEAD:
        raise ValueError(
            f"A pad-frame lead is a number of seconds from 0 to {MAX_PAD_FRAME_LEAD:g}, or 'auto' (set in flight "
            f"from the identified velocity tracker); got {lead!r}."
        )
    return {"pad_frame_lead": float(lead), "pad_frame_lead_share": 0.0}


def lead_argument(text: str) -> PadFrameLead:
    """The type of a command line's ``--pad-frame-lead``: ``"auto"`` or seconds; anything else gives an
    ``argparse.ArgumentTypeError`` saying what is allowed."""
    if text.strip().lower() == AUTO:
        return AUTO
    try:
        lead = float(text)
        lead_changes(lead)  # the range check and its message
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a pad-frame lead: give seconds from 0 to {MAX_PAD_FRAME_LEAD:g}, or 'auto'"
        ) from None
    return lead


def describe_lead(lead: PadFrameLead) -> str:
    """How a table or log names a lead: ``"0.3 s"`` or ``"auto (0.6 x the identified tracker lag)"``."""
    if lead == AUTO:
        return f"auto ({AUTO_LEAD_SHARE:g} x the identified tracker lag)"
    return f"{lead:g} s"


def describe_policy_lead(options: Mapping[str, Any]) -> str:
    """How a table names the lead a policy file flies with unless told otherwise, from its ``interface_options()``:
    ``"0.5 s"``, or ``"auto (0.6 x the identified tracker lag)"`` for a file trained with the lead set in flight."""
    share = float(options.get("pad_frame_lead_share", 0.0))
    if share == AUTO_LEAD_SHARE:
        return describe_lead(AUTO)
    if share > 0:
        return f"{share:g} x the identified tracker lag"
    return describe_lead(float(options.get("pad_frame_lead", 0.0)))


def flies_policy_lead(options: Mapping[str, Any], lead: PadFrameLead | None) -> bool:
    """Whether flying with the setting ``lead`` (None: the file's) keeps the lead of the policy file whose
    ``interface_options()`` are ``options``: ``auto`` on a file trained with it, its own seconds on one trained with a
    fixed lead."""
    if lead is None:
        return True
    flown = {**options, **lead_changes(lead)}
    return all(
        float(flown.get(name, 0.0)) == float(options.get(name, 0.0))
        for name in ("pad_frame_lead", "pad_frame_lead_share")
    )


def lead_prior(cfg: TaskConfig) -> float:
    """``T0`` (s): the tracker time constant the identification starts from, ``pad_frame_lead / share`` kept within
    :data:`~marlander_lite.swarm.tracker_lag.TIME_CONSTANT_RANGE`, so that the first commands keep the file's lead."""
    low, high = TIME_CONSTANT_RANGE
    return float(np.clip(cfg.pad_frame_lead / cfg.pad_frame_lead_share, low, high))


def lead_tracker(cfg: TaskConfig) -> TrackerLag | None:
    """A new :class:`TrackerLag` for the task's identified lead; None unless ``pad_frame_lead_share`` > 0."""
    if cfg.pad_frame_lead_share <= 0:
        return None
    return TrackerLag(lead_prior(cfg), cfg.dt)


def flight_leads(cfg: TaskConfig, tracker: TrackerLag | None) -> np.ndarray:
    """The lead of every env's next pad-frame command ``(E,)`` s (``(1,)`` before the first identification):
    ``pad_frame_lead`` without identification and until the identification rests on :data:`WARMUP_SAMPLES` samples,
    then ``min(share T, MAX_PAD_FRAME_LEAD)``."""
    if tracker is None:
        return np.array([cfg.pad_frame_lead])
    identified = np.minimum(cfg.pad_frame_lead_share * tracker.time_constant(), MAX_PAD_FRAME_LEAD)
    return np.where(tracker.samples() >= WARMUP_SAMPLES, identified, cfg.pad_frame_lead)
