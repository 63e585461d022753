"""Stopping a training run cleanly on Ctrl-C (or SIGTERM) and resuming it later.

A long PPO run should not lose its work when someone presses Ctrl-C or a batch system sends
SIGTERM. :class:`StopOnSignal` turns the first such signal into a request; the
:class:`CheckpointOnStop` callback honours it at the next rollout boundary (the start of a
rollout, right after the previous PPO update), where the whole training state is small and
well defined, and saves it under ``RUN/resume/``::

    model.zip          the SB3 model: weights, Adam state, step counter, last observation
    vecnormalize.pkl   the observation and reward running statistics
    state.pkl          the step target, the python / numpy / torch random states, the reward
                       normaliser's running returns and, for the point-mass simulator, the whole
                       vectorised environment (it is plain numpy, so it pickles)

Restoring all of it makes a resumed point-mass run continue exactly as if it had never stopped.
For the PyBullet simulator the environments cannot be saved mid-episode: they restart (with a
fresh seed) when the run resumes. A second Ctrl-C while waiting for the boundary aborts at once.
"""

from __future__ import annotations

import pickle
import random
import shutil
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, KVWriter, Logger, TensorBoardOutputFormat
from stable_baselines3.common.vec_env import VecNormalize

RESUME_DIR = "resume"
"""Sub-folder of a run that holds the interrupt checkpoint."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

SNAPSHOT_SIMULATORS = ("pointmass",)
"""Simulators whose vectorised env is plain Python/numpy state, saved whole in the checkpoint."""


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on a signal after saving a checkpoint; the message says how to resume."""

    def __init__(self, run_dir: Path, steps: int) -> None:
        self.run_dir, self.steps = run_dir, steps
        super().__init__(
            f"Training interrupted at {steps:,} steps; checkpoint saved in {run_dir / RESUME_DIR}. "
            f"Resume with: marlander train --resume {run_dir}"
        )


class StopOnSignal:
    """Context manager: the first SIGINT/SIGTERM sets :attr:`requested`; a second one aborts.

    Handlers can only be installed from the main thread; elsewhere this does nothing.
    """

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:  # second signal: give up waiting for the rollout boundary
            raise KeyboardInterrupt
        self.requested = True
        print(
            f"\n{signal.Signals(signum).name}: saving a checkpoint at the end of this update "
            "(press Ctrl-C again to stop without saving).",
            file=sys.stderr,
            flush=True,
        )

    def __enter__(self) -> StopOnSignal:
        try:
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        except ValueError:  # not the main thread
            pass
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()


class CheckpointOnStop(BaseCallback):
    """When ``stop.requested``, save the resume checkpoint at the next rollout start and end learning."""

    def __init__(self, stop: StopOnSignal, folder: Path, simulator: str) -> None:
        super().__init__()
        self.stop, self.folder, self.simulator = stop, folder, simulator
        self.saved_at: int | None = None

    def _on_rollout_start(self) -> None:
        if self.stop.requested and self.saved_at is None:
            save_checkpoint(self.model, self.folder, self.simulator)
            self.saved_at = int(self.model.num_timesteps)

    def _on_step(self) -> bool:
        return self.saved_at is None


def save_checkpoint(model: PPO, folder: Path, simulator: str) -> None:
    """Write everything :func:`load_checkpoint` needs into ``folder`` (atomically: a temporary folder, renamed)."""
    normalizer = model.get_vec_normalize_env()
    if normalizer is None:
        raise ValueError("Resumable training needs the VecNormalize wrapper that marlander train uses.")
    state = {
        "num_timesteps": int(model.num_timesteps),
        "total_timesteps": int(model._total_timesteps),
        "python_random": random.getstate(),
        "numpy_random": np.random.get_state(),  # noqa: NPY002 - SB3 shuffles minibatches with it
        "torch_random": torch.get_rng_state(),
        "returns": normalizer.returns.copy(),
        # The point-mass VecEnv is plain numpy: pickling it keeps every episode in flight. PyBullet worlds
        # live in other processes (or behind client ids) and cannot be saved this way.
        "venv": pickle.dumps(normalizer.venv) if simulator in SNAPSHOT_SIMULATORS else None,
    }
    temporary = folder.with_name(folder.name + ".partial")
    shutil.rmtree(temporary, ignore_errors=True)
    temporary.mkdir(parents=True)
    model.save(temporary / "model.zip")
    normalizer.save(str(temporary / "vecnormalize.pkl"))
    with (temporary / "state.pkl").open("wb") as handle:
        pickle.dump(state, handle)
    shutil.rmtree(folder, ignore_errors=True)
    temporary.rename(folder)


def has_checkpoint(folder: Path) -> bool:
    return all((folder / name).is_file() for name in ("model.zip", "vecnormalize.pkl", "state.pkl"))


def load_checkpoint(folder: Path, fresh_env: Any, custom_objects: dict[str, Any], seed: int) -> tuple[PPO, int]:
    """The model saved by :func:`save_checkpoint`, wired to its restored environment, and the step target.

    ``fresh_env()`` builds the (unnormalised) training env, used when the saved state holds none.
    """
    with (folder / "state.pkl").open("rb") as handle:
        state = pickle.load(handle)  # our own file, written by save_checkpoint
    venv = pickle.loads(state["venv"]) if state["venv"] is not None else fresh_env()
    env = VecNormalize.load(str(folder / "vecnormalize.pkl"), venv)
    # force_reset=False keeps the saved last observation: the restored environments continue from it.
    model = PPO.load(folder / "model.zip", env=env, device="cpu", custom_objects=custom_objects, force_reset=False)
    if state["venv"] is not None:
        env.venv = pickle.loads(state["venv"])  # PPO.load re-seeded the first copy; take an untouched one
    else:
        # Episodes restart; a seed of their own so they are not the run's first episodes again.
        env.seed(int(np.random.SeedSequence([seed, state["num_timesteps"]]).generate_state(1)[0]))
        model._last_obs = None  # makes learn() reset the environments
    env.returns = state["returns"]
    random.setstate(state["python_random"])
    np.random.set_state(state["numpy_random"])  # noqa: NPY002
    torch.set_rng_state(state["torch_random"])
    return model, int(state["total_timesteps"])


class AppendingCSVOutputFormat(CSVOutputFormat):
    """SB3's CSV writer, continuing an existing ``progress.csv`` (its header kept) instead of truncating it."""

    def __init__(self, filename: str) -> None:  # not calling super().__init__: it opens the file with "w+"
        path = Path(filename)
        if not path.is_file():
            path.touch()
        self.file = path.open("r+")
        header = self.file.readline().rstrip("\n")
        self.keys: list[str] = header.split(",") if header else []
        self.separator, self.quotechar = ",", '"'
        self.file.seek(0, 2)  # write after the rows already there


def make_logger(folder: Path, append: bool) -> Logger:
    """CSV (``progress.csv``) and TensorBoard logging into ``folder``; ``append`` continues the CSV."""
    folder.mkdir(parents=True, exist_ok=True)
    csv_path = str(folder / "progress.csv")
    formats: list[KVWriter] = [
        AppendingCSVOutputFormat(csv_path) if append else CSVOutputFormat(csv_path),
        TensorBoardOutputFormat(str(folder)),
    ]
    return Logger(str(folder), formats)
