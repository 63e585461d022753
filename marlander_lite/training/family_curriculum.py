"""Training aid, not in the paper: a dynamics family that opens while the policy learns (a curriculum).

Trained from the first step on a family that reaches PyFlyt's slow horizontal loop (time constants up to 1.2 s, tilt
limits from 12 degrees, a thin ground cushion), the ``quick-cpu-smooth`` recipe hovers for most of its 12 M steps: a
drone that answers a second late overshoots its pad, so landing is rare and hovering the safest return. Seed 0 began
to land after about 9 M steps, seeds 1 and 2 never did (docs/transfer.md, "One preset for slow trackers"). With the
default family's time constants the same recipe begins after about 4 M steps. So the family *opens*: it starts as the
overlap of the wanted ranges with the default :class:`~marlander_lite.pointmass.family.DynamicsFamily`'s, and every
bound moves linearly to the wanted one over ``TrainConfig.family_opening`` of the run's steps (curriculum learning
[Bengio2009], docs/references.md). A fixed schedule was not enough (over half the run, one seed of three still never
landed): the opening begins only once ``TrainConfig.family_opening_gate`` of the recent training episodes land.
Evaluation flies no family at all.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from marlander_lite.pointmass.family import DynamicsFamily


def opening_start(wanted: DynamicsFamily, default: DynamicsFamily | None = None) -> DynamicsFamily:
    """Where the opening family starts: each of ``wanted``'s ranges clipped to ``default``'s (the default family's).

    A range that does not overlap the default's keeps its own: there is nothing easier of it to start from.
    """
    default = DynamicsFamily() if default is None else default
    ranges = {}
    for field in dataclasses.fields(DynamicsFamily):
        (low, high), (d_low, d_high) = getattr(wanted, field.name), getattr(default, field.name)
        clipped = (max(low, d_low), min(high, d_high))
        ranges[field.name] = clipped if clipped[0] <= clipped[1] else (low, high)
    return DynamicsFamily(**ranges)


def family_at(start: DynamicsFamily, wanted: DynamicsFamily, progress: float) -> DynamicsFamily:
    """The family at ``progress`` in [0, 1] of the opening: every bound ``(1 - p) * start + p * wanted``."""
    p = min(max(float(progress), 0.0), 1.0)
    ranges = {}
    for field in dataclasses.fields(DynamicsFamily):
        (s_low, s_high), (w_low, w_high) = getattr(start, field.name), getattr(wanted, field.name)
        ranges[field.name] = ((1 - p) * s_low + p * w_low, (1 - p) * s_high + p * w_high)
    return DynamicsFamily(**ranges)


OPENED_AT_KEY = "train/family_opened_at"
"""The log key under which a gated opening records the step it began (a resumed run reads it back)."""


def opened_at_in_log(progress_csv: Path) -> int | None:
    """The step a gated opening began, from a run's ``progress.csv``; None when it has not begun."""
    if not progress_csv.is_file():
        return None
    with progress_csv.open(newline="") as handle:
        for row in csv.DictReader(handle):
            if row.get(OPENED_AT_KEY):
                return int(float(row[OPENED_AT_KEY]))
    return None


class OpeningFamily(BaseCallback):
    """Sets the point-mass simulator's family before every rollout: :func:`family_at` of the run's progress.

    The opening begins at ``opened_at`` steps of the model (the run's first step, or the step a resumed run's log
    shows it began), or, when that is None, at the first rollout whose recent training success rate (SB3's last 100
    episodes) has reached ``gate``; ``opening_steps`` environment steps then take the family from
    :func:`opening_start` to ``wanted``. The family of the first rollout is set here, before ``learn`` resets the
    environments.
    """

    def __init__(
        self,
        env: VecEnv,
        wanted: DynamicsFamily,
        opening_steps: int,
        opened_at: int | None,
        now: int,
        gate: float = 0.0,
    ) -> None:
        super().__init__()
        if opening_steps < 1:
            raise ValueError(f"opening_steps must be >= 1, got {opening_steps}.")
        self.simulator = env.unwrapped.simulator  # type: ignore[attr-defined]
        self.wanted, self.start = wanted, opening_start(wanted)
        self.opening_steps, self.opened_at, self.gate = opening_steps, opened_at, gate
        self._apply(now)

    def progress(self, steps: int) -> float:
        """Fraction of the opening done after the model's ``steps`` (clipped to [0, 1]; 0 before it begins)."""
        if self.opened_at is None:
            return 0.0
        return min(max((steps - self.opened_at) / self.opening_steps, 0.0), 1.0)

    def _apply(self, steps: int) -> None:
        self.simulator.set_family(family_at(self.start, self.wanted, self.progress(steps)))

    def _on_rollout_start(self) -> None:
        if self.opened_at is None:
            recent = self.model.ep_success_buffer
            if recent and sum(recent) / len(recent) >= self.gate:
                self.opened_at = self.num_timesteps
                self.logger.record(OPENED_AT_KEY, self.opened_at)
        self._apply(self.num_timesteps)

    def _on_step(self) -> bool:
        return True


def opening_for(config: Any, env: VecEnv, run_start: int, resumed_log: Path | None, now: int) -> list[BaseCallback]:
    """``[OpeningFamily]`` for a :class:`~marlander_lite.training.presets.TrainConfig` with ``family_opening`` > 0,
    else ``[]``. ``run_start``: the model's step count when the run began; ``resumed_log``: a resumed run's
    ``progress.csv`` (a gated opening may have begun before the interrupt)."""
    if config.family_opening <= 0:
        return []
    opening = max(1, round(config.family_opening * config.total_steps))
    wanted = DynamicsFamily.from_mapping(config.dynamics["family"])
    gate = config.family_opening_gate
    if gate == 0:
        opened_at: int | None = run_start
    else:
        opened_at = None if resumed_log is None else opened_at_in_log(resumed_log)
    return [OpeningFamily(env, wanted, opening, opened_at, now=now, gate=gate)]
