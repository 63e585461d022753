"""Training presets: every hyperparameter of a PPO run in one typed dataclass.

``PRESETS`` maps a name to a :class:`TrainConfig`; ``marlander train --preset NAME`` uses it and
saves the resolved config beside the run. The paper (Sec. III-F) trained PPO for 20 M steps on
36 cores + 1 GPU and publishes neither its PPO hyperparameters nor its reward constants; the
values below are ours and each preset's docstring says why.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

from marlander_lite.make import SIMULATORS
from marlander_lite.platforms import PLATFORM_KINDS
from marlander_lite.pointmass.family import DynamicsFamily

Activation = Literal["relu", "tanh"]
Schedule = Literal["constant", "linear"]


@dataclass(frozen=True)
class TrainConfig:
    """A complete PPO training run."""

    simulator: str = "pointmass"
    """Which simulator to train in: a registered name (``pointmass``, ``crazyflie``, ``rotorpy``, ``pyflyt``)."""
    num_drones: int = 2
    """Drones per swarm (the policy is centralised over them, as in the paper)."""
    platform: str = "static-floor"
    """Platform motion during training (see ``marlander_lite.platforms``)."""
    platform_speed: float | tuple[float, float] | None = None
    """Tool speed of a moving platform (m/s); a (low, high) pair draws it per episode."""
    platform_height: tuple[float, float] | None = None
    """Plate top height range for UR10-held kinds (m); None keeps 0.5-1.0; (0.005, 1.0) covers the floor too."""
    sensing: str = "perfect"
    """``perfect``, ``vicon`` (motion-capture noise and latency on observations), ``noisy`` (vicon with far more
    attitude and body-rate noise, a training aid; :meth:`~marlander_lite.sensing.SensingConfig.noisy`) or ``robust``
    (noisy with the delay drawn per episode within 0-40 ms; :meth:`~marlander_lite.sensing.SensingConfig.robust`)."""
    task: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`~marlander_lite.task.TaskConfig` fields."""
    dynamics: dict[str, Any] = field(default_factory=dict)
    """Point-mass only: fields of :class:`~marlander_lite.pointmass.simulator.PointMassParams` (e.g. ``family``, the
    ranges of :class:`~marlander_lite.pointmass.family.DynamicsFamily` each drone draws its dynamics from)."""
    total_steps: int = 3_000_000
    """Environment steps (one step = one action for the whole swarm)."""
    num_envs: int = 256
    """Swarms simulated in parallel."""
    n_steps: int = 64
    """Steps per env per rollout; the rollout holds num_envs * n_steps samples."""
    batch_size: int = 4096
    """Minibatch size of the PPO update."""
    n_epochs: int = 5
    """Passes over each rollout."""
    learning_rate: float = 3e-4
    """Adam step size (at the start, when the schedule is linear)."""
    lr_schedule: Schedule = "constant"
    """``constant`` or ``linear`` decay to zero."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clip_range: float = 0.2
    """PPO ratio clipping."""
    ent_coef: float = 0.0
    """Entropy bonus."""
    vf_coef: float = 0.5
    """Value-loss weight."""
    max_grad_norm: float = 0.5
    """Gradient clipping."""
    target_kl: float | None = None
    """Stop an update's epochs early beyond this KL (None: never)."""
    log_std_init: float = -2.0
    """Initial log standard deviation of the Gaussian actions: exp(-2) = 0.14 of max_speed (0.4 m/s). SB3's default
    (0, i.e. 3 m/s) makes a soft touchdown under 0.5 m/s a rare accident and stalls learning."""
    reset_log_std: bool = False
    """When fine-tuning (``init_from``), set the loaded policy's log standard deviation back to ``log_std_init``."""
    net_arch: tuple[int, ...] = (128, 128)
    """Hidden layers of the actor (the policy network of the paper's Fig. 3)."""
    critic_arch: tuple[int, ...] | None = None
    """Hidden layers of the separate critic; None: the same as the actor. The paper describes only the policy."""
    activation: Activation = "relu"
    """Hidden activation (the paper: ReLU)."""
    normalize_observations: bool = True
    """Standardise observations with running statistics (SB3 VecNormalize); exported with the policy."""
    normalize_rewards: bool = True
    """Scale rewards by a running estimate of the return's spread."""
    obs_norm_epsilon: float = 0.01
    """Floor added to each observation variance before standardising. An input that never varied in training
    (yaw is always 0 in the point-mass) would otherwise be divided by ~1e-4 when it does vary (PyBullet, the lab)."""
    seed: int = 0
    """Seeds the environments, the network initialisation and the sampling."""
    init_from: str | None = None
    """A run directory to continue from (fine-tuning): its model and normaliser are loaded. Or a centralised
    policy file (``.safetensors``): its actor and observation statistics are loaded, the critic starts afresh
    (:mod:`~marlander_lite.training.warm_start`)."""
    critic_warmup_steps: int = 0
    """Fine-tuning aid: train only the critic for this many steps first (the actor is frozen). For ``init_from`` a
    policy file, which holds no critic."""
    torch_threads: int = 2
    """CPU threads for torch."""
    checkpoint_every: int = 1_000_000
    """Save a checkpoint every this many steps (0: only at the end)."""
    smoothness_temporal: float = 0.0
    """Training aid, not in the paper: lambda_T of the CAPS regulariser (:mod:`~marlander_lite.training.smoothness`),
    weight of the change of the policy's mean action between consecutive steps. 0: off."""
    smoothness_spatial: float = 0.0
    """Training aid, not in the paper: lambda_S of the CAPS regulariser, weight of the change of the mean action
    under observation noise of ``smoothness_noise``. 0: off."""
    smoothness_noise: float = 0.05
    """Standard deviation of that noise, in units of the normalised observation."""
    smoothness_batch_size: int | None = None
    """Consecutive pairs per CAPS gradient; None: ``batch_size``. A smaller sample keeps the regulariser cheap for the
    paper's 512-wide network: its ``paper`` run trained at 1,500-2,000 steps/s with 8192 pairs, 3,000 with 1024."""
    family_opening: float = 0.0
    """Training aid, not in the paper: the fraction of ``total_steps`` over which ``dynamics["family"]`` opens from its
    overlap with the default family to its own ranges (:mod:`~marlander_lite.training.family_curriculum`). 0: the
    whole family from the first step."""
    family_opening_gate: float = 0.0
    """Begin that opening only once the recent training success rate (SB3's last 100 episodes) reaches this, so the
    policy first learns to land where landing is easy. 0: from the first step."""

    def __post_init__(self) -> None:
        problems = []
        if self.simulator not in SIMULATORS:
            problems.append(f"simulator must be one of {SIMULATORS}, got {self.simulator!r}")
        if self.platform not in PLATFORM_KINDS:
            problems.append(f"platform must be one of {PLATFORM_KINDS}, got {self.platform!r}")
        if self.sensing not in ("perfect", "vicon", "noisy", "robust"):
            problems.append(f"sensing must be 'perfect', 'vicon', 'noisy' or 'robust', got {self.sensing!r}")
        if self.activation not in get_args(Activation):
            problems.append(f"activation must be one of {get_args(Activation)}, got {self.activation!r}")
        if self.lr_schedule not in get_args(Schedule):
            problems.append(f"lr_schedule must be one of {get_args(Schedule)}, got {self.lr_schedule!r}")
        if not isinstance(self.critic_warmup_steps, int) or self.critic_warmup_steps < 0:
            problems.append(f"critic_warmup_steps must be an integer >= 0, got {self.critic_warmup_steps!r}")
        for name in ("total_steps", "num_envs", "n_steps", "batch_size", "n_epochs", "num_drones", "torch_threads"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                problems.append(f"{name} must be an integer >= 1, got {getattr(self, name)!r}")
        if self.dynamics and self.simulator != "pointmass":
            problems.append("dynamics options apply to the point-mass simulator only")
        if not 0 < self.gamma <= 1 or not 0 < self.gae_lambda <= 1:
            problems.append("gamma and gae_lambda must be in (0, 1]")
        if self.learning_rate <= 0:
            problems.append(f"learning_rate must be > 0, got {self.learning_rate}")
        pairs = self.smoothness_batch_size
        if pairs is not None and not (isinstance(pairs, int) and pairs >= 1):
            problems.append(f"smoothness_batch_size must be an integer >= 1 or None, got {pairs!r}")
        for name in ("smoothness_temporal", "smoothness_spatial", "smoothness_noise"):
            if not getattr(self, name) >= 0:
                problems.append(f"{name} must be >= 0 (0 switches it off), got {getattr(self, name)!r}")
        if not 0 <= self.family_opening <= 1:
            problems.append(f"family_opening must be a fraction of total_steps in [0, 1], got {self.family_opening!r}")
        elif not 0 <= self.family_opening_gate <= 1:
            problems.append(f"family_opening_gate must be a success rate in [0, 1], got {self.family_opening_gate!r}")
        elif self.family_opening > 0 and not self.dynamics.get("family"):
            problems.append(
                "family_opening needs a dynamics family to open (point mass, dynamics={'family': ...}); "
                "without one set family_opening to 0"
            )
        if problems:
            raise ValueError("Invalid training config: " + "; ".join(problems) + ".")

    def replace(self, **changes: Any) -> TrainConfig:
        """A copy with some fields changed; unknown names raise with the list of fields."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(f"Unknown training option(s) {unknown}; allowed: {sorted(known)}.")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_dict` (JSON turns tuples into lists)."""
        values = dict(values)
        values["net_arch"] = tuple(values.get("net_arch", ()))
        if values.get("critic_arch") is not None:
            values["critic_arch"] = tuple(values["critic_arch"])
        if isinstance(values.get("platform_height"), list):
            values["platform_height"] = tuple(values["platform_height"])
        if isinstance(values.get("platform_speed"), list):
            values["platform_speed"] = tuple(values["platform_speed"])
        return cls().replace(**values)


PAPER_NET = (512, 512, 256, 128)
"""The paper's Fig. 3 network: fully connected ReLU layers 512, 512, 256, 128 (Source: Aschu et al.,
MARLander, Sec. III-D; docs/references.md)."""

TRAINING_AIDS = {
    "spawn_near_pad_fraction": 0.25,
    "landing_tolerance": 0.03,
    "training_touchdown_speed": 0.3,
    "approach_cone_penalty": 1.0,
    "command_speed_penalty": 0.5,
    "command_error_penalty": 0.2,
}
"""Training aids (not in the paper; :class:`~marlander_lite.task.TaskConfig` documents each): a quarter of the
episodes start near the pads; a landing counts only within 3 cm of the pad centre and below 0.3 m/s; drones lose
reward for flying below their approach cone, for commanding speeds they cannot brake from before the pad, and for
commands far from their velocity. Evaluation switches every aid off (``training_aids.TRAINING_AIDS_OFF``). The
smoothness aid ``action_change_penalty`` is not used: it penalises the exploration noise itself, and neither 8 M-step
run with it learnt to land."""

ROBUST_DYNAMICS: dict[str, Any] = {"family": DynamicsFamily().to_dict()}
"""Each drone draws its velocity-tracker dynamics at every reset from the default
:class:`~marlander_lite.pointmass.family.DynamicsFamily` (tilt limit 15-35 degrees, latency 0-60 ms, mass +-15 %,
...), so that the policy flies in a way every member follows: PyBullet with either tracker, and real Crazyflies."""


def slow_tracker_family(tau_max: float) -> dict[str, Any]:
    """The dynamics family widened to trackers as slow as PyFlyt's (identified: horizontal tau 0.76 s, tilt limit
    12.7 degrees, sink 9.62 m/s^2; docs/transfer.md, "PyFlyt"): horizontal tau 0.08 s to ``tau_max`` (s), tilt limit
    12-35 degrees, sink up to 9.6 m/s^2; the rest as :class:`DynamicsFamily`'s defaults. The slow-tracker chains of
    the quick preset's policy and of the shared policy used the same ranges."""
    family = dataclasses.replace(
        DynamicsFamily(),
        velocity_time_constant=(0.08, tau_max),
        max_tilt_deg=(12.0, 35.0),
        max_sink_acceleration=(3.0, 9.6),
    )
    return {"family": family.to_dict()}


THIN_CUSHION = (0.0, 0.1)
"""A ground cushion of at most 0.1 g (the default family's: up to 0.5 g, 0.25 g on average). With the thick one,
policies let the ground effect brake their touchdowns, and touched down above 0.5 m/s where there is none (the
nominal point mass, docs/scaling.md "A thin ground cushion"); with it they brake themselves."""
THIN_CUSHION_DYNAMICS: dict[str, Any] = {
    "family": dataclasses.replace(DynamicsFamily(), ground_cushion=THIN_CUSHION).to_dict()
}
"""The default family with the thin ground cushion (the shared policy's stage 12)."""

_QUICK = TrainConfig(
    total_steps=8_000_000, sensing="noisy", task=dict(TRAINING_AIDS), dynamics=ROBUST_DYNAMICS, torch_threads=1
)
_FINETUNE = _QUICK.replace(
    simulator="crazyflie",
    sensing="vicon",
    dynamics={},
    total_steps=3_000_000,
    num_envs=32,
    n_steps=128,
    batch_size=1024,
    learning_rate=1e-4,
    log_std_init=-2.5,
    reset_log_std=True,
    platform="static-elevated",
    platform_height=(0.005, 1.0),
    task={"spawn_near_pad_fraction": 0.25, "landing_tolerance": 0.05},
    torch_threads=1,
    checkpoint_every=500_000,
)
MOVING_LANDING_TOLERANCE = 0.07
"""The ``moving`` preset's landing aid (m): a touchdown counts within 7 cm of a moving pad's centre, not 3 cm. With
the static presets' 3 cm, almost every touchdown on a pad moving at 0.2-0.5 m/s (4-5 cm off) was a crash in training,
and the policy landed 35-57 % of moving trials (``moving-robust``); with 7 cm and 16 M steps, 90-95.5 % on the point
mass and through the firmware tracker (``moving-robust-16m``, docs/transfer.md)."""
_ALL_HEIGHTS = {"platform": "static-elevated", "platform_height": (0.005, 1.0)}
"""Static plates from the floor (5 mm) up to the UR10's 1 m, drawn per episode. ``quick-cpu`` does not use it: its
seed 0 trained this way (``quick-cpu-all-heights``) lands 91.5-99 % in every static column of the transfer matrix,
but over seeds 0-4 the recipe is far less steady than the floor pad alone (worst seed 13 % on the point-mass floor,
46 % through the firmware tracker; floor only: 93.5 % and 94 %; docs/transfer.md)."""
SMOOTH_COMMANDS = {"smoothness_temporal": 1.0, "smoothness_spatial": 1.0}
"""The CAPS smoothness aid (:mod:`~marlander_lite.training.smoothness`) of the ``moving`` preset. Trained 16 M steps
without it, robust policies learn a period-3 command cycle near the pad and touch down too fast on trackers that
answer at once or 60 ms late (``moving-robust-16m``: 24.5-28 % on static pads with 60 ms latency, 79-81 % on the point
mass); with it (``moving-smooth-16m``, one seed) 98-99.5 % there and >= 78.5 % in every cell of the transfer matrix
(docs/transfer.md). The 8 M-step ``quick-cpu`` stays without it: after 8 M steps it lands less with it. The 1-drone
``single-agent`` preset uses it: with it, 8 M steps (``single-agent-smooth-8m``) land 99 % on static pads in PyBullet
with our PID, where 3 M steps without it landed 85-90 % (docs/reproduction.md)."""
_MOVING_PLATFORMS = {"platform": "moving-arc", "platform_speed": (0.0, 0.6), "platform_height": (0.005, 1.0)}
STEEP_APPROACH_CONE = {"approach_cone_slope": 2.0}
"""The approach-cone aid asking for 2 m of height per metre from the pad instead of 1 (``quick-cpu-smooth``): a drone
then centres over its pad before its last tens of centimetres of descent. With slope 1, ``quick-cpu-smooth`` was
still 10 cm off its pad centre 1 s before touching down in RotorPy and landed 2.17-2.62 cm from it; with slope 2
(seeds 0 and 1) 97-100 % in all ten columns of the transfer matrix at 0.67-2.04 cm, RotorPy included
(docs/transfer.md). Slope 3 (one seed) landed 1.87 cm from the centre in RotorPy's UR10 row, against 1.57 cm."""
_QUICK_SMOOTH = _QUICK.replace(
    task={**TRAINING_AIDS, **STEEP_APPROACH_CONE},
    total_steps=12_000_000,
    critic_arch=(64, 64),
    learning_rate=5e-4,
    lr_schedule="linear",
    smoothness_batch_size=1024,
    torch_threads=2,
    **_ALL_HEIGHTS,
    **SMOOTH_COMMANDS,
)
"""``quick-cpu-smooth``: ``quick-cpu`` on plates of every height with smooth commands, the recipe of
``quick-cpu-smooth-16m`` (95-100 % in every static column at 0.65-2.05 cm over three seeds) made cheaper so that it
trains within 10 minutes on 2 cores:

* 12 M steps instead of 16 M, with the step size decaying linearly from 5e-4 to zero. At a constant 3e-4, 12 M steps
  landed 2.6 cm from the pad centre on the point-mass UR10 plate; decaying from 3e-4 they landed 30 % of episodes.
* a 64-64 critic: the update is bound by its matrix products, and the 128-128 critic made half of the PPO loss's.
* 1024 consecutive pairs per CAPS gradient instead of the whole 4096-sample minibatch (at 4096 the aid doubled the
  cost of an update), and both cores for PyTorch's update (a sweep then trains one seed at a time by default).

* the steeper approach cone (:data:`STEEP_APPROACH_CONE`, since 2026-11-27; shipped as ``quick-cpu-smooth-cone2-bench``,
  the preset exactly, trained alone in 9.1 min, and ``quick-cpu-smooth-cone2`` / ``-seed1`` with one thread each).

Seed 0 of the version before the steeper cone (``quick-cpu-smooth``), trained alone in 8.2 min on the 2-core
development VM, and its seed 1 land 95.5-100 % in every static column of the transfer matrix at 0.74-2.17 cm but 2.17 /
2.62 cm in RotorPy; the 14 M-step version before it (a 128-128 critic, constant 3e-4, ``quick-cpu-smooth-14m``) took
11.9 min (docs/transfer.md)."""

TRACKER_INTEGRATOR = (0.0, 0.8)
"""Integral action of the family's horizontal velocity loop (``DynamicsFamily.velocity_integral_gain``, 1/s) in
``quick-cpu-slow-trackers``: PyFlyt's PID has 0.375, the Crazyflie firmware's 0.04. PyFlyt's integrator cost the
preset's first version (without it) 1.3 cm of landing error there (``benchmarks/pyflyt_tracker_parts.py``); trained
with 0-0.5 a one-thread run landed 2.19-2.37 cm from the centre there, with 0-0.8 1.86-2.05 cm (docs/transfer.md)."""

SLOW_TRACKERS_FIRST_VERSION: dict[str, Any] = {
    "family": {**slow_tracker_family(1.2)["family"], "ground_cushion": list(THIN_CUSHION)}
}
"""The dynamics of ``quick-cpu-slow-trackers``' first version (shipped as ``quick-cpu-slow-trackers`` and
``-seed1``, trained with ``family_opening=0.3``): the slow-tracker family with the thin cushion, no integrator."""

SLOW_TRACKERS_STEPS = 20_000_000
"""Training steps of ``quick-cpu-slow-trackers`` (12 M until 2026-11-30, ``quick-cpu-smooth``'s): with 12 M steps the
preset's three seeds landed 2.41-3.18 cm from the pad centre in PyFlyt 0.22, with 20 M steps 1.79-2.10 cm
(docs/transfer.md, "Twenty million steps")."""

QUICK_SLOW_TRACKERS_20M = _QUICK_SMOOTH.replace(
    dynamics={"family": {**SLOW_TRACKERS_FIRST_VERSION["family"], "velocity_integral_gain": list(TRACKER_INTEGRATOR)}},
    total_steps=SLOW_TRACKERS_STEPS,
    family_opening=0.15,
    family_opening_gate=0.05,
)
"""``quick-cpu-slow-trackers`` until 2026-12-01 (shipped as ``quick-cpu-slow-trackers-20m``, ``-seed1``, ``-seed2``;
the ``paper-slow-trackers`` and ``moving-slow-trackers`` runs were trained on it): ``quick-cpu-smooth`` on a family
that reaches PyFlyt's slow loop, so that the quick policy lands alone in simulators whose tracker answers in up to a
second, PyFlyt's included:

* the family of :func:`slow_tracker_family` with horizontal tau up to 1.2 s (PyFlyt's fit: 0.76 s), and the thin
  ground cushion (:data:`THIN_CUSHION`). With the default family's cushion this family from scratch never learnt to
  land in 12 M steps (touchdowns at 0.8 m/s, or hovering; docs/transfer.md).
* velocity loops with integral action (:data:`TRACKER_INTEGRATOR`, since 2026-11-29 late): a PID tracker's
  integrator carries the approach's error on after the drone has braked. Seed 0 of the preset with it lands 99.5 %
  / 99.5 % in PyFlyt 0.22 (seeds 1 and 2: 96.0 / 98.0 and 95.5 / 98.0 %), where the first version (without it,
  opening over 30 %) landed 88.5 / 90.5 %; 2.41-3.18 cm from the pad centre there over the three seeds, 0.70-2.57 cm
  in the other columns but PyFlyt's 0.21.0 order.
* the family opens over 15 % of the run's steps (``family_opening``,
  :mod:`~marlander_lite.training.family_curriculum`; 30 % in the first version), once 5 % of the recent training
  episodes land (``family_opening_gate``). On the whole family from the first step, seed 0 learnt to land after 9 M
  steps and seeds 1 and 2 never did; opening from the first step over half the run, seeds 1 and 2 learnt and seed 0
  did not; over 30 % of it, neither seed 1 nor 2. Gated, seed 0 opened at 6.2 M steps: over half the run it was 97 %
  open at the end and landed 82-83 % in PyFlyt 0.22 (200 episodes a row), over 30 % 88.5-90.5 %, over 15 %
  88.5-90.0 % (without the integrator).

* 20 M steps (:data:`SLOW_TRACKERS_STEPS`, since 2026-11-30; 12 M before): three seeds land 91.0-100 % in every cell
  of the twelve-column transfer matrix, within 2.26 cm in all columns but PyFlyt's 0.21.0 order (0.59-2.10 cm; PyFlyt
  0.22 1.79-2.10 cm), where the 12 M-step seeds landed 2.41-3.18 cm from the centre in PyFlyt 0.22.

Everything else is ``quick-cpu-smooth``'s: two threads, the same network and aids. Alone on the 2-core VM the preset
trained in 6.78 min (2026-11-30), its 12 M-step version in 3.93 min, its first version in 4.24 min and
``quick-cpu-smooth`` in 3.79 min (2026-11-29), one run each (``benchmarks/results/bench_quick_cpu_*``)."""

LATE_COMMANDS_FAST_VERTICAL = {
    "latency_s": [0.0, 0.08],
    "vertical_time_constant": [0.04, 0.2],
    "ground_cushion": [0.0, 0.02],
}
"""What ``quick-cpu-slow-trackers`` changes in its family since 2026-12-01: command latency up to 80 ms (60 ms
before), a vertical loop no slower than 0.2 s (0.3 s before) and a ground cushion of at most 0.02 g (0.1 g before).
PyFlyt's vertical loop answers a -0.6 m/s step with -0.36 m/s after one policy step; with commands 40-80 ms late, the
20 M-step version's last-centimetre pulses became touchdowns above 0.5 m/s and it landed in 16 of 40 random PyFlyt
Crazyflies (docs/transfer.md, "Random PyFlyt Crazyflies: late commands on a fast vertical loop")."""

_QUICK_SLOW_TRACKERS = QUICK_SLOW_TRACKERS_20M.replace(
    dynamics={"family": {**QUICK_SLOW_TRACKERS_20M.dynamics["family"], **LATE_COMMANDS_FAST_VERTICAL}}
)
"""``quick-cpu-slow-trackers``: the 20 M-step version (:data:`QUICK_SLOW_TRACKERS_20M`: ``quick-cpu-smooth`` on a
family of trackers up to 1.2 s slow with integral action, opening over 15 % of the run) on a family whose commands
arrive up to 80 ms late on a fast vertical loop with almost no ground cushion (:data:`LATE_COMMANDS_FAST_VERTICAL`).
Its three seeds (``quick-cpu-slow-trackers-fast-vertical-20m``, ``-seed1``, ``-seed2``; the family opened at 3.2-3.8 M
steps) land in 29-31 / 31-32 of 40 random PyFlyt Crazyflies (floor / UR10), every one PyFlyt 0.22 steps among them,
where seeds 0 and 1 of the 20 M-step version landed in 13-16 / 15-19; 94.0-100 % in every cell of the twelve-column
transfer matrix, at 0.50-1.94 cm in eleven columns and 3.58-4.09 cm in PyFlyt's 0.21.0 order (docs/transfer.md, "The
quickstart's preset on late commands"). Alone on the 2-core VM it trained in 9.43 min on 2026-12-01, a day on which
the VM ran the first 1 M steps at 41 k steps/s against 52 k on 2026-11-30 (``benchmarks/results/bench_quick_cpu_*``).
It is what ``marlander quickstart`` trains."""

PAPER_SLOW_TRACKERS_20M = QUICK_SLOW_TRACKERS_20M.replace(net_arch=PAPER_NET)
"""``paper-slow-trackers`` until 2026-12-01 (shipped as ``paper-slow-trackers``, ``-seed1``, ``-seed2``): the paper's
network (:data:`PAPER_NET`, 512-512-256-128) trained by :data:`QUICK_SLOW_TRACKERS_20M`, with nothing else changed
(the 64-64 critic included). Its seed 0 (2026-11-30, 51.5 min on 2 cores; the family opened at 7.0 M steps, the small
network's at 4.4 M) lands alone 96.0-99.5 % in every cell of the twelve-column transfer matrix, Wilson lower bounds
92.3 % and above, at 0.70-1.55 cm in eleven columns (PyFlyt 0.22: 1.42 / 1.41 cm) and 3.61 / 3.45 cm in PyFlyt's
0.21.0 order; its seed 1 (73.1 min beside evaluations) 96.5-99.5 %, lower bounds 92.9 % and above, at 0.74-1.57 cm in
those eleven columns; its seed 2 (84.5 min beside other work) 94.5-100 %, lower bounds 90.4 % and above, 95 % or more
in all cells but PyFlyt's 0.21.0-order floor (94.5 %), at 0.71-1.72 cm in those eleven columns.
``paper-robust-smooth`` (the ``paper`` preset's recipe, fine-tuned with smooth commands) lands 0-2 % alone in PyFlyt,
and an 8 M-step fine-tune of it on this family landed nobody (touchdowns at 0.6-1 m/s; docs/transfer.md)."""

_PAPER_SLOW_TRACKERS = _QUICK_SLOW_TRACKERS.replace(net_arch=PAPER_NET)
"""``paper-slow-trackers``: the paper's network (:data:`PAPER_NET`, 512-512-256-128) trained by the quickstart's
preset (``quick-cpu-slow-trackers``: the 20 M-step recipe on commands up to 80 ms late to fast vertical loops,
:data:`LATE_COMMANDS_FAST_VERTICAL`), with nothing else changed (the 64-64 critic included). Its seed 0
(``paper-slow-trackers-fast-vertical``, 2026-12-01, 58.4 min alone on 2 cores; the family opened at 6.1 M steps) lands
alone 95.0-99.5 % in every static cell of the twelve-column transfer matrix, Wilson lower bounds 91.0 % and above, at
0.88-1.50 cm in eleven columns and 3.38 / 3.28 cm in PyFlyt's 0.21.0 order, and in 31 / 30 of 40 random PyFlyt
Crazyflies (floor / UR10), every PyFlyt 0.22 one among them, where the version before
(:data:`PAPER_SLOW_TRACKERS_20M`) landed in 21 / 25 (docs/transfer.md, "The paper's network on late commands")."""

PAD_FRAME_LEAD = 0.5
"""``TaskConfig.pad_frame_lead`` of ``moving-slow-trackers`` (s). Trained with a 0.3 s lead, the fine-tune landed 90 /
86 % on PyFlyt 0.22's moving arc / line; with 0.5 s 98 / 92 %, and 100 / 98 % through the firmware tracker, where a
fine-tune trained without a lead and flown with 0.6 s fell to 94 / 92 % (50 episodes a cell; docs/transfer.md)."""

MOVING_SLOW_TRACKERS_20M = QUICK_SLOW_TRACKERS_20M.replace(
    task={**QUICK_SLOW_TRACKERS_20M.task, "command_frame": "pad", "pad_frame_lead": PAD_FRAME_LEAD},
    total_steps=6_000_000,
    **_MOVING_PLATFORMS,
)
"""``moving-slow-trackers`` until 2026-12-01: the fine-tune below on :data:`QUICK_SLOW_TRACKERS_20M`'s family, which the
shipped ``moving-slow-trackers``, ``-seed1`` and ``paper-moving-slow-trackers`` runs continue from the 20 M-step runs
and the paper's network."""

_MOVING_SLOW_TRACKERS = MOVING_SLOW_TRACKERS_20M.replace(
    dynamics={"family": {**MOVING_SLOW_TRACKERS_20M.dynamics["family"], **LATE_COMMANDS_FAST_VERTICAL}}
)
"""``moving-slow-trackers``: a ``quick-cpu-slow-trackers`` run (``--init-from``) fine-tuned 6 M steps on moving pads
(UR10 arcs at 0-0.6 m/s, plates from the floor to 1 m) with commands relative to the pad
(``TaskConfig.command_frame`` ``"pad"``, led by :data:`PAD_FRAME_LEAD`): the loop carries each pad's velocity, so the
policy keeps the static task it learnt and learns only what a pad's turns ask of a lagging tracker. Trained from
scratch on moving pads in this frame (20 M steps, arcs or arcs and lines) it landed less and less precisely than the
static policy flown in it, untrained (docs/transfer.md, "Commands relative to the pad"). Its family is the quickstart
preset's since 2026-12-01 (:data:`LATE_COMMANDS_FAST_VERTICAL`), so that it continues a run of that preset on the
family the run learnt; the runs shipped before continue the 20 M-step runs on theirs
(:data:`MOVING_SLOW_TRACKERS_20M`). Its two seeds from the preset's seeds 0 and 1
(``moving-slow-trackers-fast-vertical``, ``-seed1``) land alone 94.5-100 % on static pads in all twelve columns, where
both fine-tunes before landed 89.0 % on the held-out tracker's UR10, and 90 % or more in 21 / 20 of the 24 moving cells
(before: 20 / 19); on the moving rows of 40 random PyFlyt Crazyflies they land in 30 / 24 and 27 / 7 (arc / line)
where the fine-tune before landed in 22 / 4, touching down too fast (docs/transfer.md, "The moving fine-tune on late
commands")."""

STIFF_LATE_CORNER = {
    "velocity_time_constant": [0.04, 0.12],
    "attitude_time_constant": [0.08, 0.25],
    "latency_s": [0.03, 0.08],
    "max_tilt_deg": [25.0, 50.0],
}
"""The corner of the family that ``moving-stiff-loops`` draws for :data:`STIFF_LATE_SHARE` of its drones
(``PointMassParams.corner``): a velocity loop stiffer than the family's stiffest, over an attitude loop up to 0.25 s
slow, commands 30-80 ms late and tilt clamps to 50 degrees, as RotorPy's ``cmd_vel`` loop with its gain at x1.15-1.5 and
no clamp (docs/transfer.md, "The stiff, late loop"). Uniform draws from the family give it to about 0.1 % of drones."""

STIFF_LATE_SHARE = 0.3
"""Share of ``moving-stiff-loops``' drones drawn from :data:`STIFF_LATE_CORNER` at each reset."""

_MOVING_STIFF_LOOPS = _MOVING_SLOW_TRACKERS.replace(
    dynamics={**_MOVING_SLOW_TRACKERS.dynamics, "corner": STIFF_LATE_CORNER, "corner_fraction": STIFF_LATE_SHARE}
)
"""``moving-stiff-loops``: a ``moving-slow-trackers`` run (``--init-from``) continued 6 M steps on the same family and
moving pads, with :data:`STIFF_LATE_SHARE` of the drones drawn from :data:`STIFF_LATE_CORNER`. From the paper's
network's moving fine-tune (``paper-moving-stiff-loops``, 2026-12-02) it lands 15 / 14 of 16 random stiff RotorPy
Crazyflies (arc / line) where its source landed 4 / 4, and PyFlyt 0.22's line 83.0 % where its source landed 90.0 %:
for stiff trackers, not the default (docs/transfer.md, "The stiff, late loop")."""

SLOW_LATE_CORNER = {
    "velocity_time_constant": [0.6, 1.2],
    "vertical_time_constant": [0.04, 0.08],
    "latency_s": [0.03, 0.08],
    "velocity_integral_gain": [0.2, 0.6],
}
"""The slow corner ``moving-two-corners`` draws as well: a horizontal loop of 0.6-1.2 s with integral action over a fast
vertical one, commands 30-80 ms late, as PyFlyt's Crazyflie (identified: 0.76 s, 0.375 /s integral, 0.05 s vertical;
docs/transfer.md, "PyFlyt")."""

TWO_CORNER_SHARES = [0.2, 0.2]
"""Shares of ``moving-two-corners``' drones drawn from :data:`STIFF_LATE_CORNER` and :data:`SLOW_LATE_CORNER`."""

_MOVING_TWO_CORNERS = _MOVING_SLOW_TRACKERS.replace(
    total_steps=5_000_000,
    dynamics={
        **_MOVING_SLOW_TRACKERS.dynamics,
        "corner": [STIFF_LATE_CORNER, SLOW_LATE_CORNER],
        "corner_fraction": TWO_CORNER_SHARES,
    },
)
"""``moving-two-corners``: a ``moving-stiff-loops`` run (``--init-from``) continued 5 M steps with 20 % of the drones
on the stiff, late corner and 20 % on the slow one. From ``paper-moving-stiff-loops``: ``paper-moving-two-corners``
(2026-12-02), which kept the stiff RotorPy Crazyflies (14 / 13 of 16, arc / line), landed PyFlyt 0.22's line 90.5 %
where the stiff-loops policy landed 83.0 %, and lands 23 of the 24 moving cells of its matrix at 90 % or more
(docs/transfer.md, "Two corners, shipped"), and 35 / 32 of the 40 random RotorPy Crazyflies (the moving fine-tune:
18 / 12). With ``--seed 1`` (``paper-moving-two-corners-seed1``): 21 of 24 moving cells, 34 / 29 of the 40."""

PRESETS: dict[str, TrainConfig] = {
    "quick-cpu": _QUICK,
    "quick-cpu-smooth": _QUICK_SMOOTH,
    "quick-cpu-slow-trackers": _QUICK_SLOW_TRACKERS,
    "paper": _QUICK.replace(
        torch_threads=2,
        total_steps=20_000_000,
        net_arch=PAPER_NET,
        critic_arch=(256, 256),
        num_envs=512,
        batch_size=8192,
        n_epochs=4,
        lr_schedule="linear",
        checkpoint_every=2_000_000,
    ),
    "paper-slow-trackers": _PAPER_SLOW_TRACKERS,
    "crazyflie-finetune": _FINETUNE,
    "moving": _QUICK.replace(
        total_steps=16_000_000,
        task={**TRAINING_AIDS, "landing_tolerance": MOVING_LANDING_TOLERANCE, "observe_platform_velocity": True},
        **_MOVING_PLATFORMS,
        **SMOOTH_COMMANDS,
    ),
    "moving-slow-trackers": _MOVING_SLOW_TRACKERS,
    "moving-stiff-loops": _MOVING_STIFF_LOOPS,
    "moving-two-corners": _MOVING_TWO_CORNERS,
    "moving-crazyflie-finetune": _FINETUNE.replace(
        task={**_FINETUNE.task, "observe_platform_velocity": True}, **_MOVING_PLATFORMS
    ),
    "single-agent": _QUICK.replace(num_drones=1, total_steps=8_000_000, **_ALL_HEIGHTS, **SMOOTH_COMMANDS),
}
"""Named presets; see :func:`describe_presets`."""

FINETUNE_PRESETS = (
    "crazyflie-finetune",
    "moving-crazyflie-finetune",
    "moving-slow-trackers",
    "moving-stiff-loops",
    "moving-two-corners",
)
"""Presets that continue a trained run (``--init-from RUN``) rather than start from scratch."""

PRESET_NOTES: dict[str, str] = {
    "quick-cpu": "2 drones, floor pad, point mass with a dynamics family, 128-128 ReLU, 8 M steps: minutes on 2 cores.",
    "quick-cpu-smooth": "quick-cpu on plates of every height with smooth commands and a steeper approach cone, 12 M "
    "steps, 2 threads: lands in every static column of the transfer matrix but PyFlyt's, RotorPy included; 4-13 min on "
    "2 cores.",
    "quick-cpu-slow-trackers": "quick-cpu-smooth on a dynamics family that opens to trackers as slow as PyFlyt's "
    "(tau up to 1.2 s, with integral action) and commands up to 80 ms late to fast, uncushioned vertical loops, 20 M "
    "steps: lands alone in every column of the transfer matrix and in random PyFlyt Crazyflies; 7-10 min on 2 cores "
    "(the quickstart's).",
    "paper": "the paper's 512-512-256-128 ReLU policy, 20 M steps, point mass (about 45 min on 2 cores).",
    "paper-slow-trackers": "the paper's 512-512-256-128 policy on the quick-cpu-slow-trackers recipe (late commands, "
    "fast vertical loops), 20 M steps: lands alone in every column of the transfer matrix and in random PyFlyt "
    "Crazyflies; about 1 h on 2 cores.",
    "crazyflie-finetune": "continue a quick-cpu/paper run in the PyBullet Crazyflie swarm, 3 M steps (~30 min).",
    "moving": "beyond the paper: observes the platform velocity; UR10 arcs at 0-0.6 m/s, floor to 1 m, smooth "
    "commands, 16 M steps.",
    "moving-slow-trackers": "beyond the paper: continue a quick-cpu-slow-trackers run (--init-from) 6 M steps on "
    "moving pads, on the same family, with commands relative to the pad, which the loop carries (led by 0.5 s of its "
    "acceleration).",
    "moving-stiff-loops": "beyond the paper: continue a moving-slow-trackers run (--init-from) 6 M steps with 30 % of "
    "the drones on stiff, late velocity loops over slow attitude loops (RotorPy's at high gain); lands those, less on "
    "slow ones.",
    "moving-two-corners": "beyond the paper: continue a moving-stiff-loops run (--init-from) 5 M steps with 20 % of "
    "the drones on the stiff, late corner and 20 % on a slow one (PyFlyt's loop); lands both kinds of tracker.",
    "moving-crazyflie-finetune": "continue a 'moving' run in the PyBullet Crazyflie swarm, 3 M steps (~30 min).",
    "single-agent": "one drone (MorphoLander-style: applied per drone with APF repulsion), smooth commands, 8 M steps.",
}


def get_preset(name: str) -> TrainConfig:
    """The preset called ``name``; an unknown name raises with the list of presets."""
    if name not in PRESETS:
        raise ValueError(f"Unknown preset {name!r}; available presets: {', '.join(PRESETS)}.")
    return PRESETS[name]


def describe_presets() -> str:
    """One line per preset, for ``marlander train --list``."""
    return "\n".join(f"{name:<26} {PRESET_NOTES.get(name, '')}" for name in PRESETS)
