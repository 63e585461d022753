"""Print hashes of rollouts and of a short training run, to show a refactor changed no behaviour.

Run it before and after a change and compare the output line by line::

    python scripts/fingerprint.py > before.txt   # on the old code
    python scripts/fingerprint.py > after.txt    # on the new code
    diff before.txt after.txt                    # empty: rollouts and training are bit-identical

Each line hashes the raw bytes of observations, rewards and infos of a seeded rollout (point mass with
and without a dynamics family, PyBullet with the PID and the firmware tracker, a moving platform), an
evaluation of the shipped ``quick-cpu`` policy and the weights after a short seeded PPO run. Takes about a
minute on one core.
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite import make_vec_env
from marlander_lite.policy_file import load_policy
from marlander_lite.training.evaluation import evaluate_policy_file
from marlander_lite.training.presets import get_preset

ROOT = Path(__file__).resolve().parents[1]


def _digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, dtype=np.float64)).tobytes())
    return h.hexdigest()[:16]


def rollout(simulator: str, steps: int, num_envs: int, **options: Any) -> str:
    env = make_vec_env(simulator, num_envs=num_envs, seed=3, **options)
    rng = np.random.default_rng(7)
    h = hashlib.sha256()
    obs = env.reset()
    h.update(np.asarray(obs, np.float64).tobytes())
    for _ in range(steps):
        action = rng.uniform(-1, 1, (num_envs, env.action_space.shape[0])).astype(np.float32)
        obs, reward, done, infos = env.step(action)
        h.update(_digest(obs, reward, done).encode())
        for info in infos:
            for key in sorted(info):
                value = info[key]
                if isinstance(value, int | float | bool | np.number | np.ndarray):
                    h.update(key.encode() + _digest(value).encode())
    env.close()
    return h.hexdigest()[:16]


def short_training() -> str:
    from marlander_lite.training.train import train

    config = dataclasses.replace(get_preset("quick-cpu"), total_steps=16_384, num_envs=64, batch_size=1024)
    with tempfile.TemporaryDirectory() as tmp:
        files = train(config, Path(tmp) / "run")
        policy = load_policy(files.policy)
        rng = np.random.default_rng(0)
        obs = rng.normal(size=(32, policy.contract.num_drones * 13)).astype(np.float32)
        return _digest(policy.act(obs))


def main() -> int:
    family = get_preset("quick-cpu").dynamics
    lines = {
        "pointmass static": rollout("pointmass", 300, 16),
        "pointmass family+noisy": rollout(
            "pointmass", 300, 16, sensing="noisy", dynamics=family, task={"training_touchdown_speed": 0.3}
        ),
        "pointmass robust sensing": rollout("pointmass", 300, 16, sensing="robust", dynamics=family),
        "pointmass moving-arc": rollout("pointmass", 300, 8, platform="moving-arc", platform_speed=0.5),
        "pointmass 5 drones": rollout("pointmass", 200, 8, num_drones=5),
        "crazyflie pid": rollout("crazyflie", 60, 2),
        "crazyflie firmware elevated": rollout("crazyflie", 60, 2, controller="firmware", platform="static-elevated"),
    }
    summary = evaluate_policy_file(ROOT / "data/policies/quick-cpu.safetensors", episodes=64)
    lines["eval quick-cpu pointmass"] = _digest(summary.success_rate, summary.landing_error_mean_cm)
    lines["ppo 16k steps"] = short_training()
    for name, value in lines.items():
        print(f"{name:32s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
