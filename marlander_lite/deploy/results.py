"""What a flight reports: :class:`MissionResult` (the loop's own account; rehearsals add the simulator's truth)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from marlander_lite.deploy.safety import Event


@dataclass
class MissionResult:
    """How the flight went."""

    armed: bool
    """The pre-flight check passed and the drones took off."""
    phases: list[str]
    """Final phase per drone (``down``: motors off on a surface; ``lost``: link lost)."""
    on_pad: list[bool]
    """Drone touched down on its own pad under the policy."""
    landing_error: list[float]
    """Horizontal distance from the pad centre at touchdown (m); NaN if not on the pad."""
    landing_time: list[float]
    """Touchdown time since the policy started (s); NaN if not on the pad."""
    ticks: int
    duration_s: float
    loop_ms_median: float
    loop_ms_p95: float
    loop_ms_max: float
    overruns: int
    """Ticks whose work took longer than the loop period."""
    events: list[Event] = field(default_factory=list)
    log_path: str | None = None
    interrupted_by: str | None = None
    """The signal that ended the flight early: ``"SIGINT"`` (Ctrl-C), ``"SIGTERM"``, ``"SIGHUP"``; None otherwise."""

    @property
    def success(self) -> bool:
        """Every drone landed on its own pad."""
        return self.armed and all(self.on_pad)

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["success"] = self.success
        return out
