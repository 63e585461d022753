"""A drone's last ``H`` observation frames, newest first: ``TaskConfig.observation_history`` (beyond the paper).

The simulators' episodes (:class:`marlander_lite.episodes.LandingEpisodes`) and the deployment loop
(:class:`marlander_lite.deploy.runner.PolicyRunner`) both stack frames with :class:`ObservationHistory`, so a
policy reads its history the same way in training, in every simulator and on the drones. The newest frame comes
first: the indices of one frame (``task.EQ2_POSITION``, ``task.PLATFORM_VELOCITY``) keep pointing at the current
observation, and code that reads only the present (the APF baseline, the safety filter) needs no change.
"""

from __future__ import annotations

import numpy as np


class ObservationHistory:
    """The latest ``history`` frames of every drone, ``(..., frame)`` in, ``(..., history * frame)`` out.

    Args:
        history: ``H >= 1`` frames kept; with 1 the frames pass through unchanged.
        shape: the leading shape of a batch of frames: ``(num_envs, N)`` in the simulators, ``(N,)`` in the
            deployment loop.
        frame: numbers per frame (``TaskConfig.frame_per_drone``).
    """

    def __init__(self, history: int, shape: tuple[int, ...], frame: int) -> None:
        if history < 1:
            raise ValueError(f"history must be >= 1 frame, got {history}.")
        self.history, self.frame = int(history), int(frame)
        self.stacked = np.zeros((*shape, self.history * self.frame))
        """``(*shape, H * frame)``: slot 0 (the first ``frame`` numbers) is the newest frame."""

    def reset(self, frames: np.ndarray, ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Fill every slot of the batch entries ``ids`` with ``frames`` (their first frame after a reset) and return
        their stacked observations ``(len(ids), ..., H * frame)``."""
        if self.history == 1:
            return frames
        self.stacked[ids] = np.tile(frames, self.history)
        return self.stacked[ids].copy()

    def push(self, frames: np.ndarray) -> np.ndarray:
        """Add the newest frames of the whole batch ``(*shape, frame)`` and drop the oldest; returns the stack."""
        if self.history == 1:
            return frames
        f = self.frame
        self.stacked[..., f:] = self.stacked[..., :-f].copy()
        self.stacked[..., :f] = frames
        return self.stacked.copy()

    def replace_newest(self, frames: np.ndarray) -> np.ndarray:
        """Put ``frames`` in the newest slot of the whole batch (the same instant observed again; the older slots
        stay) and return the stack."""
        if self.history == 1:
            return frames
        self.stacked[..., : self.frame] = frames
        return self.stacked.copy()
