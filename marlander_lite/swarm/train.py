"""Train the shared policy: PPO with parameter sharing over a mixture of swarm sizes.

The PPO hyperparameters, network, training aids, noisy sensing and dynamics family are those of a
:class:`~marlander_lite.training.presets.TrainConfig` (the ``quick-cpu`` recipe, so that the policy
transfers the way the centralised one does); :class:`SharedTrainConfig` adds the swarm sizes and the
neighbours each drone senses. One SB3 timestep is one *drone* step here (an entry of
:class:`~marlander_lite.swarm.vec_env.SharedSwarmVecEnv`), not one swarm step.

A run directory holds ``config.json``, ``logs/progress.csv`` (SB3's columns plus ``rollout/landing_error_cm``),
``model.zip`` and ``vecnormalize.pkl`` (for continuing), and ``policy.safetensors`` (a shared policy file).
Interrupted runs are not resumable (unlike ``marlander train``): start again.

Command line::

    python -m marlander_lite.swarm.train --preset shared-quick --out data/runs/shared-quick
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.vec_env import VecNormalize

from marlander_lite.swarm import memory
from marlander_lite.swarm.policy import export_shared_policy
from marlander_lite.swarm.safety_filter import SafetyFilterConfig
from marlander_lite.swarm.vec_env import SharedSwarmVecEnv
from marlander_lite.task import TaskConfig
from marlander_lite.training.presets import (
    ROBUST_DYNAMICS,
    SMOOTH_COMMANDS,
    THIN_CUSHION_DYNAMICS,
    TRAINING_AIDS,
    TrainConfig,
    slow_tracker_family,
)
from marlander_lite.training.resume import make_logger
from marlander_lite.training.smoothness import regulariser_for
from marlander_lite.training.train import CheckpointEvery, LandingStatsCallback, RunFiles, _new_model, check_new_run


@dataclass(frozen=True)
class SharedTrainConfig(TrainConfig):
    """A :class:`TrainConfig` for a shared policy. ``num_drones`` and ``num_envs`` are not used: the batch is
    ``swarm_sizes`` x ``drones_per_size`` drones."""

    swarm_sizes: tuple[int, ...] = (1, 2, 3, 4)
    """Swarm sizes trained on together; each is one group of swarms in the VecEnv."""
    drones_per_size: int = 256
    """Drones simulated per swarm size: ``drones_per_size // N`` swarms of N drones (at least one)."""
    neighbours: int = 3
    """``k``: nearest neighbours in each drone's input."""
    neighbour_radius: float | None = None
    """Sensing range of the neighbour features (m); ``None``: the k nearest at any distance."""
    collision_credit: Literal["swarm", "involved"] = "swarm"
    """Training aid: ``"involved"`` charges eq. 6's penalty only to the drones in a collision (SharedSwarmVecEnv)."""
    separation_penalty: float = 0.0
    """Training aid: reward lost per step per metre a flying drone's nearest neighbour is inside separation_margin."""
    separation_margin: float = 0.22
    """Distance (m) below which the separation aid charges a flying drone; below the 0.25 m pad spacing."""
    shield: bool = False
    """Training aid: fly the commands through the safety filter (its defaults) while training (SharedSwarmVecEnv)."""
    shield_penalty: float = 0.0
    """Training aid: reward lost per step per m/s the shield changed a flying drone's command (needs ``shield``)."""
    drone_episode_ends: bool = False
    """Training aid: a crash, collision or exit ends only the episode of the drones in it (SharedSwarmVecEnv)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        problems = []
        if not self.swarm_sizes or any(
            isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 64 for n in self.swarm_sizes
        ):
            problems.append(f"swarm_sizes must be integers in [1, 64], got {self.swarm_sizes!r}")
        for name in ("drones_per_size", "neighbours"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                problems.append(f"{name} must be an integer >= 1, got {value!r}")
        if self.collision_credit not in ("swarm", "involved"):
            problems.append(f"collision_credit must be 'swarm' or 'involved', got {self.collision_credit!r}")
        if not (isinstance(self.separation_penalty, int | float) and 0 <= self.separation_penalty < float("inf")):
            problems.append(f"separation_penalty must be a finite number >= 0, got {self.separation_penalty!r}")
        if not (isinstance(self.separation_margin, int | float) and 0 < self.separation_margin < float("inf")):
            problems.append(f"separation_margin must be a finite distance > 0 m, got {self.separation_margin!r}")
        if not (isinstance(self.shield_penalty, int | float) and 0 <= self.shield_penalty < float("inf")):
            problems.append(f"shield_penalty must be a finite number >= 0, got {self.shield_penalty!r}")
        elif self.shield_penalty and not self.shield:
            problems.append("shield_penalty needs shield=True (the penalty is on the shield's corrections)")
        if self.drone_episode_ends and self.collision_credit != "involved":
            problems.append(
                "drone_episode_ends needs collision_credit='involved' (eq. 6 charged to the drones it stops)"
            )
        if self.simulator != "pointmass":
            problems.append("shared policies train on the point-mass simulator only")
        if problems:
            raise ValueError("Invalid shared training config: " + "; ".join(problems) + ".")

    @property
    def swarms_per_size(self) -> tuple[int, ...]:
        return tuple(max(1, self.drones_per_size // n) for n in self.swarm_sizes)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> SharedTrainConfig:
        values = dict(values)
        values["swarm_sizes"] = tuple(values.get("swarm_sizes", cls.swarm_sizes))
        return super().from_dict(values)  # type: ignore[return-value]

    def task_config(self) -> TaskConfig:
        """The task the policy learns (``num_drones`` of the largest swarm, for the record)."""
        return TaskConfig().replace(**{**self.task, "num_drones": max(self.swarm_sizes)})


SHARED_PRESETS: dict[str, SharedTrainConfig] = {
    "shared-quick": SharedTrainConfig(
        total_steps=16_000_000,
        sensing="noisy",
        # The quick-cpu training aids. Starts near the pads need drones closer than 0.5 m on a 0.25 m pad grid: at
        # 0.3 m one draw of 8 drones in 22 fits (an 8-drone reset failed 100 draws once), at 0.2 m two in 5.
        task={**TRAINING_AIDS, "spawn_separation": 0.2},
        dynamics=ROBUST_DYNAMICS,
        torch_threads=1,
        # Small swarms: one crash ends a swarm's episode for every drone in it, so in swarms of 6 or 8 most drones
        # are cut off before they reach their pad (episodes of 35 steps); with k = 3 neighbours a swarm of 4 already
        # fills every neighbour slot. 2-8 drones never learnt to touch down (data/runs/shared-quick-bigbatch, -2to8).
        swarm_sizes=(1, 2, 3, 4),
        drones_per_size=160,
        # PPO moves the policy a bounded step per rollout: ~640 drones x 32 steps keeps quick-cpu's ~20 k samples per
        # update, and so its number of updates (~780 in 16 M steps, not 196 with 1275 drones x 64 steps).
        n_steps=32,
        batch_size=5112,  # a quarter of the rollout, as quick-cpu's 4096 of 16 k
        checkpoint_every=4_000_000,
    ),
}
SHARED_PRESETS["shared-quick-continue"] = SHARED_PRESETS["shared-quick"].replace(
    # Stage 2 (``--init-from`` a shared-quick run): after stage 1 the policy landed a lone drone every time but
    # dived onto the plate (0.6-1.8 m/s) whenever it sensed a neighbour; every drone now has at least one.
    swarm_sizes=(2, 3, 4),
    drones_per_size=213,
    batch_size=5096,  # a quarter of 637 drones x 32 steps
)
SHARED_PRESETS["shared-quick-local"] = SHARED_PRESETS["shared-quick"].replace(
    # Stage 2 (``--init-from`` a shared-quick run). Flown with unlimited sensing, the stage-1 policy lands a lone
    # drone every time and almost never beside a sensed neighbour: it learnt to land mostly alone. Sensing only
    # neighbours within 0.2 m, between the collision distance (0.15 m) and the pad spacing (0.25 m), keeps drones
    # on neighbouring pads out of each other's input; the same weights then land 92 / 56 / 38 % at N = 2 / 4 / 8,
    # failing by collisions, which this stage teaches it to avoid, in swarms up to 8.
    neighbour_radius=0.2,
    swarm_sizes=(2, 4, 8),
    drones_per_size=213,
    batch_size=5056,  # a quarter of 632 drones x 32 steps
)
SHARED_PRESETS["shared-quick-shielded"] = SHARED_PRESETS["shared-quick-local"].replace(
    # Stage 3 (``--init-from`` a shared-quick-local run). Stage 2 left a policy that lands but collides (57.5 % of
    # 8-drone swarms). One collision ends the episode of every drone of the swarm, so avoidance is rarely practised
    # to the end; here the safety filter flies the commands in training (a shield), and every m/s it has to change
    # costs the drone, so the policy learns flight the filter leaves alone. The network alone is evaluated.
    shield=True,
    shield_penalty=1.0,
)
SHARED_PRESETS["shared-quick-drone-ends"] = SHARED_PRESETS["shared-quick-local"].replace(
    # Stage 3 (``--init-from`` a shared-quick-local run). One collision ends the episode of every drone of the swarm,
    # so in swarms of 8 the drones that had no part in it never practise the rest of the approach and the landing
    # beside the others. Here a crash, collision or exit ends the episode of the drones in it only (they take off
    # again from new starts), and eq. 6 is charged to them alone; the others fly on.
    drone_episode_ends=True,
    collision_credit="involved",
)
SHARED_PRESETS["shared-quick-paired"] = SHARED_PRESETS["shared-quick-drone-ends"].replace(
    # Stage 4 (``--init-from`` a shared-quick-drone-ends run). With the paper's fixed pairs the straight paths of
    # random starts cross in most swarms of 8 and the policy, sensing only within 0.2 m, collides there (51 % of
    # 8-drone trials); with the shortest pairing of starts to pads (CAPT's assignment) the same policy collides in
    # none of 200, and fails by touchdowns at 0.50-0.54 m/s instead, 4-5 % of its drones. Trained on with the pairing
    # alone it still did; a landing counted in training only below 0.2 m/s (0.3 before) cut them to about 1 %.
    task={
        **SHARED_PRESETS["shared-quick-drone-ends"].task,
        "pad_assignment": "shortest",
        "training_touchdown_speed": 0.2,
    },
)
SHARED_PRESETS["shared-quick-paired-soft"] = SHARED_PRESETS["shared-quick-paired"].replace(
    # Stage 5 (``--init-from`` a shared-quick-paired run). Stage 4 still touches down above 0.5 m/s with about 1 % of
    # its drones, which at N = 8 fails one swarm in ten; a landing counted in training only below 0.15 m/s.
    task={**SHARED_PRESETS["shared-quick-paired"].task, "training_touchdown_speed": 0.15},
)
SHARED_PRESETS["shared-quick-cone2"] = SHARED_PRESETS["shared-quick-paired-soft"].replace(
    # Stage 6 (``--init-from`` a shared-quick-paired run). Through PyBullet's trackers the drones that fail come down
    # beside their pads: on a plate tilted 15 degrees the rims of 16-drone swarms touch it 11-15 cm uphill of the pad.
    # An approach cone of 2 m of height per metre from the pad (1 before, as the quick preset's cone2) keeps them
    # higher until they are over it; a smaller step size falling to zero keeps the landing stage 5 learnt.
    learning_rate=1e-4,
    lr_schedule="linear",
    task={**SHARED_PRESETS["shared-quick-paired-soft"].task, "approach_cone_slope": 2.0},
)
SHARED_PRESETS["shared-quick-memory"] = SHARED_PRESETS["shared-quick-paired-soft"].replace(
    # Stage 6 (``--init-from`` a shared-quick-paired run; its network is widened, swarm/memory.py). Under 20-60 ms of
    # latency the shipped policy touches down too fast (docs/scaling.md, "Why the touchdowns are not soft"): from its
    # state alone it cannot tell a late tracker from a slow one. Each drone also reads the command it sent last.
    task={**SHARED_PRESETS["shared-quick-paired-soft"].task, "observe_previous_command": True},
)
"""Shared-policy presets. ``shared-quick``: the quick-cpu recipe (128-128 ReLU, training aids, noisy sensing,
dynamics family) on swarms of 1 to 4 drones, each drone sensing its 3 nearest neighbours, 16 M drone steps;
``shared-quick-continue`` trains such a run on for 16 M more steps on swarms of 2 to 4; ``shared-quick-local``
does so on swarms of 2, 4 and 8 with neighbours sensed within 0.2 m only (the shipped policy);
``shared-quick-shielded`` trains that one on with the safety filter as a shield and a penalty on its corrections;
``shared-quick-drone-ends`` trains it on with per-drone episode ends; ``shared-quick-paired`` trains that one on with
starts paired with pads by the shortest pairing and a stricter touchdown speed, ``shared-quick-paired-soft`` that one
with a stricter one still (the shipped ``shared-quick-paired`` policy); ``shared-quick-cone2`` continues that one with a
steeper approach cone (the shipped ``shared-quick-cone2`` policy); ``shared-quick-memory`` continues that one with
its previous command in each drone's input (:mod:`~marlander_lite.swarm.memory`; tried, not shipped).
``shared-quick-smooth``, ``shared-quick-slow-trackers`` and ``shared-quick-slow-trackers-settle`` (below) continue
``shared-quick-cone2`` with the smoothness aid and a family of slower trackers (the shipped
``shared-quick-slow-trackers`` policy); ``shared-quick-slow-trackers-default-family`` continues that one on the default
family (the shipped policy of that name). ``shared-quick-slow-trackers-explore`` continues
``shared-quick-slow-trackers`` with more exploration of the slow trackers; ``shared-quick-thin-cushion`` settles that
one on the default family with a thin ground cushion (the shipped policy of that name);
``shared-quick-slow-trackers-thin-cushion`` continues that one on the slow-tracker family with the thin cushion (the
shipped policy of that name); ``shared-quick-larger-swarms`` continues that one on swarms of 4 and 8 only (the shipped
policy of that name, which the example lab configs name). N = 16 is never seen in training."""


SHARED_PRESETS["shared-quick-smooth"] = SHARED_PRESETS["shared-quick-cone2"].replace(
    # Stage 7 (``--init-from`` a shared-quick-cone2 run). The shared recipe never trained with the CAPS smoothness
    # aid, and alone it touched down too fast in RotorPy (57.5 % on the floor); every centralised policy that lands
    # there had it. From stage 6, which lands, the aid no longer breaks the touchdown as it did from stage 2 (docs/
    # scaling.md). The family widens towards PyFlyt's slow tracker at the same time.
    total_steps=6_000_000,
    learning_rate=3e-4,
    dynamics=slow_tracker_family(0.8),
    smoothness_batch_size=1024,
    **SMOOTH_COMMANDS,
)
SHARED_PRESETS["shared-quick-slow-trackers"] = SHARED_PRESETS["shared-quick-smooth"].replace(
    # Stage 8 (``--init-from`` a shared-quick-smooth run). After 96 M steps the policy's action noise had shrunk to a
    # standard deviation of 0.006, and a stage that only widened the family (tau to 1.0 s) left PyFlyt 0.22 at 35 %;
    # with the noise set back to exp(-3) = 0.05 the same stage reached 80 % there. (exp(-2) landed 27 %.)
    dynamics=slow_tracker_family(1.0),
    reset_log_std=True,
    log_std_init=-3.0,
)
SHARED_PRESETS["shared-quick-slow-trackers-settle"] = SHARED_PRESETS["shared-quick-slow-trackers"].replace(
    # Stage 9 (``--init-from`` a shared-quick-slow-trackers run; the shipped ``shared-quick-slow-trackers`` policy):
    # the same family with a smaller step size and less noise (exp(-4) = 0.018). Widening on to 1.2 s instead cost
    # point-mass swarms of 16 a third of their landings (touchdowns too fast).
    learning_rate=1e-4,
    log_std_init=-4.0,
)
SHARED_PRESETS["shared-quick-slow-trackers-default-family"] = SHARED_PRESETS[
    "shared-quick-slow-trackers-settle"
].replace(
    # Stage 10 (``--init-from`` a shared-quick-slow-trackers run): back to the default family for 6 M more steps. On
    # the widened family the policy touched down a little too fast on the quick trackers (the nominal point mass:
    # 8-drone swarms 92.5 %, every failure a touchdown above 0.5 m/s); here it trains on them again.
    dynamics=ROBUST_DYNAMICS,
)
SHARED_PRESETS["shared-quick-slow-trackers-explore"] = SHARED_PRESETS["shared-quick-slow-trackers"].replace(
    # Stage 11 (``--init-from`` a shared-quick-slow-trackers run, stage 9): stage 8 again, twice as long. The noise is
    # set back to exp(-3) once more and the policy explores the slow trackers for 12 M steps: PyFlyt 0.22 from 83 to
    # 88 % on a first look, while point-mass swarms of 16 fell to 67 % (touchdowns too fast), which stage 12 mends.
    total_steps=12_000_000,
)
SHARED_PRESETS["shared-quick-thin-cushion"] = SHARED_PRESETS["shared-quick-slow-trackers-explore"].replace(
    # Stage 12 (``--init-from`` a shared-quick-slow-trackers-explore run; the shipped ``shared-quick-thin-cushion``
    # policy). Stage 10 settled on the default family, and its lone drones still touched down at up to 0.51 m/s on
    # the nominal point mass, which has no cushion: the family's cushion (0-0.5 g, 0.25 g on average) had braked them
    # in training. Settled on a family with at most 0.1 g, every point-mass swarm size landed 99.5-100 % of 200.
    total_steps=6_000_000,
    learning_rate=1e-4,
    log_std_init=-4.0,
    dynamics=THIN_CUSHION_DYNAMICS,
)
SHARED_PRESETS["shared-quick-slow-trackers-thin-cushion"] = SHARED_PRESETS["shared-quick-thin-cushion"].replace(
    # Stage 13 (``--init-from`` a shared-quick-thin-cushion run; the shipped policy of this name): the same settings on
    # the slow-tracker family with the thin cushion. Stage 12 on the default family landed PyFlyt 0.22 alone 90 / 85 %
    # (floor / UR10), by touchdowns too fast; here the slow trackers are back in the draws, and the cushion stays thin.
    dynamics={
        "family": {
            **slow_tracker_family(1.0)["family"],
            "ground_cushion": THIN_CUSHION_DYNAMICS["family"]["ground_cushion"],
        }
    },
)
SHARED_PRESETS["shared-quick-larger-swarms"] = SHARED_PRESETS["shared-quick-slow-trackers-thin-cushion"].replace(
    # Stage 14 (``--init-from`` a shared-quick-slow-trackers-thin-cushion run; the shipped policy of this name): the
    # same settings on swarms of 4 and 8 only. Stage 13 collided in a fifth of PyFlyt 0.22's 8-drone swarms; here
    # every drone trains with neighbours, half of them in swarms of 8. PyFlyt 0.22, 2-drone swarms: 94.0 / 97.0 ->
    # 99.5 / 98.5 % (floor / UR10); 8-drone swarms 70 -> 88 % of 50 on a first look.
    swarm_sizes=(4, 8),
)


def make_shared_env(config: SharedTrainConfig, seed: int | None = None) -> SharedSwarmVecEnv:
    """The training VecEnv of ``config`` (without normalisation)."""
    platform: Any = config.platform
    speed = config.platform_speed
    if config.platform_height is not None:
        from marlander_lite.platforms import PlatformConfig

        platform = PlatformConfig(kind=config.platform, speed=speed, elevated_height=config.platform_height)  # type: ignore[arg-type]
        speed = None
    return SharedSwarmVecEnv(
        config.swarm_sizes,
        config.swarms_per_size,
        config.neighbours,
        task=dict(config.task),
        platform=platform,
        platform_speed=speed,
        sensing=config.sensing,
        dynamics=dict(config.dynamics) if config.dynamics else None,
        seed=config.seed if seed is None else seed,
        neighbour_radius=config.neighbour_radius,
        collision_credit=config.collision_credit,
        separation_penalty=config.separation_penalty,
        separation_margin=config.separation_margin,
        shield=SafetyFilterConfig() if config.shield else None,
        shield_penalty=config.shield_penalty,
        drone_episode_ends=config.drone_episode_ends,
    )


def train_shared(config: SharedTrainConfig, out_dir: str | Path, *, preset: str | None = None) -> RunFiles:
    """Train a shared policy with PPO and write the run directory ``out_dir`` (refused if it holds a run)."""
    files = check_new_run(config, out_dir)
    widen = False
    if config.init_from:  # checked before anything is written, so that a corrected command can reuse out_dir
        source = RunFiles(Path(config.init_from))
        widen = memory.adds_previous_command(memory.source_task(source.root), config.task_config())
        missing = [path.name for path in (source.model, source.normalizer) if not path.is_file()]
        if missing:
            raise FileNotFoundError(
                f"--init-from {source.root} lacks {' and '.join(missing)}; give a finished shared run directory."
            )
    files.root.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {
        "preset": preset,
        "kind": "shared",
        "train": dataclasses.asdict(config),
        "task": vars(config.task_config()),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    files.config.write_text(json.dumps(record, indent=2))
    torch.set_num_threads(config.torch_threads)
    if config.init_from and not widen:  # continue a shared run: its model and its normaliser's statistics
        env = VecNormalize.load(str(RunFiles(Path(config.init_from)).normalizer), make_shared_env(config))
        env.training, env.norm_reward = True, config.normalize_rewards
        model = _new_model(config, env)
    else:
        env = VecNormalize(
            make_shared_env(config),
            norm_obs=config.normalize_observations,
            norm_reward=config.normalize_rewards,
            gamma=config.gamma,
            epsilon=config.obs_norm_epsilon,
        )
        model = _new_model(config.replace(init_from=None), env)
        if widen:  # the source run's weights and statistics, with the previous command as new inputs
            memory.widened_start(config.init_from, model, env)
            if config.reset_log_std:  # as a plain --init-from does
                with torch.no_grad():
                    model.policy.log_std.fill_(config.log_std_init)
    model.set_logger(make_logger(files.progress.parent, append=False))
    callbacks = CallbackList(
        [LandingStatsCallback(), CheckpointEvery(files.checkpoints, config.checkpoint_every), *regulariser_for(config)]
    )
    started = time.perf_counter()
    model.learn(config.total_steps, callback=callbacks, reset_num_timesteps=not config.init_from)
    seconds = time.perf_counter() - started
    model.save(files.model)
    env.save(str(files.normalizer))
    extra = {
        "preset": preset,
        "simulator": "pointmass",
        "steps": int(model.num_timesteps),
        "seed": config.seed,
        "swarm_sizes": list(config.swarm_sizes),
    }
    export_shared_policy(
        model,
        files.policy,
        config.task_config(),
        config.neighbours,
        env if config.normalize_observations else None,
        extra,
        neighbour_radius=config.neighbour_radius,
    )
    record["finished"] = {"seconds": round(seconds, 1), "steps": int(model.num_timesteps)}
    files.config.write_text(json.dumps(record, indent=2))
    env.close()
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``marlander swarm train`` (and ``python -m marlander_lite.swarm.train``)."""
    parser.add_argument("--preset", default="shared-quick", choices=sorted(SHARED_PRESETS))
    parser.add_argument("--out", required=True, help="new run directory")
    parser.add_argument("--steps", type=int, default=None, help="total drone steps (default: the preset's)")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--init-from", default=None, help="a finished shared run to continue training from")


def run(args: argparse.Namespace) -> RunFiles:
    """Train the preset with the given changes into a new run directory."""
    config = SHARED_PRESETS[args.preset]
    changes = {
        k: v
        for k, v in (("total_steps", args.steps), ("seed", args.seed), ("init_from", args.init_from))
        if v is not None
    }
    files = train_shared(config.replace(**changes), args.out, preset=args.preset)
    print(f"Trained {files.root}; policy: {files.policy}")
    return files


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Train a shared (decentralised, any-N) landing policy with PPO.")
    add_arguments(parser)
    run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
