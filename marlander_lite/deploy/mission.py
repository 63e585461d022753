"""The deployment loop: pre-flight check, take-off, the policy at a fixed rate, landing, all logged.

One :class:`Mission` runs the same code on hardware and in rehearsal; only its four partners
change: a pose source, a :class:`marlander_lite.deploy.link.CrazyflieLink` (real radios or
virtual Crazyflies), a clock (wall time, or the simulated world which advances physics while the
loop "sleeps") and a flight log. Every tick (``1 / rates.loop_hz`` s):

1. read the frames that arrived, update the estimates, forward each new drone pose to its
   Crazyflie (``send_extpose``);
2. depending on the mode: pre-flight check -> take-off -> policy (every ``ticks_per_action``-th
   tick a new action; the velocity setpoint is re-sent every tick, keeping the firmware's
   watchdog fed) -> landing -> done, with the rules of :mod:`marlander_lite.deploy.safety`
   deciding fly / hover / land;
3. a drone that touches its own pad (within ``touchdown_height`` of its goal, within the pad
   radius, slow) gets its motors stopped; a landing drone gets them stopped when it rests;
4. one log record; then sleep until the next tick. The work of each tick is timed
   (``compute_ms``) against the period.

Mission times (event times, log ``t``) are seconds since :meth:`Mission.run` started.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np

from marlander_lite.deploy.config import LabConfig
from marlander_lite.deploy.estimation import EstimatorConfig, SwarmEstimate, SwarmEstimator
from marlander_lite.deploy.flight_log import FlightLogWriter, jsonable, rounded, tick_record
from marlander_lite.deploy.interrupts import describe, handle_signals
from marlander_lite.deploy.landing import FLYING as FLYING  # re-exported: the phases in which motors run
from marlander_lite.deploy.landing import LandingControl
from marlander_lite.deploy.pose_sources import Clock, PoseFrame, PoseSource
from marlander_lite.deploy.results import MissionResult
from marlander_lite.deploy.runner import InvalidAction, Policy, PolicyRunner
from marlander_lite.deploy.safety import Event, EventKind, SafetyMonitor
from marlander_lite.task import OBS_PER_DRONE

Phase = Literal["idle", "takeoff", "policy", "hover", "landing", "down", "lost"]
Mode = Literal["preflight", "takeoff", "policy", "landing", "done"]


class Mission(LandingControl):
    """One flight of the swarm; see the module docstring.

    Args:
        lab: the lab config.
        policy: the policy (``load_lab_policy(path, lab)``).
        source: where poses come from.
        link: the Crazyflies (already opened).
        clock: the loop's clock.
        log: where each tick is recorded (optional).
        hooks: called as ``hook(mission, t)`` at the start of every tick (fault injection, UIs).
        min_preflight_s: stream poses to every drone at least this long before take-off (s), so
            that their Kalman filters settle.
    """

    def __init__(
        self,
        lab: LabConfig,
        policy: Policy,
        source: PoseSource,
        link: Any,
        clock: Clock,
        log: FlightLogWriter | None = None,
        hooks: Sequence[Callable[[Mission, float], None]] = (),
        estimator: EstimatorConfig | None = None,
        min_preflight_s: float = 1.0,
    ) -> None:
        self.lab, self.source, self.link, self.clock, self.log = lab, source, link, clock, log
        self.hooks = list(hooks)
        contract = getattr(policy, "contract", None)
        self.task = lab.task_config(contract is not None and contract.obs_per_drone > OBS_PER_DRONE)
        self.runner = PolicyRunner(policy, self.task, lab.limits.max_speed)
        self.estimator = SwarmEstimator(lab, estimator, landed_height=self.task.landed_height)
        self.safety = SafetyMonitor(lab)
        self.min_preflight_s = min_preflight_s
        n = lab.num_drones
        self.n, self.names = n, lab.drone_names
        self.period = 1.0 / lab.rates.loop_hz
        self.pad_radius = np.array([p.radius for p in lab.drone_pads()])
        self.mode: Mode = "preflight"
        self.phase: list[Phase] = ["idle"] * n
        self.armed = False
        self.tick = 0
        self.t = 0.0
        self.policy_start: float | None = None
        """Mission time the policy took over (s); None before."""
        self.velocity = np.zeros((n, 3))
        self.obs: np.ndarray | None = None
        self.action: np.ndarray | None = None
        self.events: list[Event] = []
        self.on_pad = np.zeros(n, dtype=bool)
        self.landing_error = np.full(n, np.nan)
        self.landing_time = np.full(n, np.nan)
        self.loop_ms: list[float] = []
        self.interrupted_by: str | None = None
        """The signal that ended the flight early (``"SIGINT"`` for Ctrl-C, ``"SIGTERM"``, ``"SIGHUP"``), or None."""
        self._signals = 0
        self._tick_open: int | None = None  # index of the tick being worked on
        self._events_logged = 0  # self.events[:_events_logged] are in tick records
        self._events_marked = 0  # ... and [:_events_marked] in the record being written
        self._cmd: list[dict[str, Any]] = []
        self._landing: dict[int, tuple[float, float, float]] = {}
        self._near_since = np.full(n, np.nan)
        self._handover = np.zeros(n, dtype=bool)
        self._forwarded = np.full(n, -math.inf)
        self._streaming_since = np.full(n, np.inf)  # mission time of each drone's first forwarded pose
        self._action_ok = True
        self._policy_tick0 = 0
        self._land_requests: list[str] = []  # appended from signal handlers and key threads, emptied by ticks
        self._kill_request: str | None = None
        self._invalid_bodies: set[str] = set()
        self._lost_seen = np.zeros(n, dtype=bool)
        self._last_est: SwarmEstimate | None = None

    # ------------------------------------------------------------------ public controls
    def request_land(self, reason: str = "emergency key") -> None:
        """Land every drone at the next tick (thread-safe: a key watcher may call it)."""
        self._land_requests.append(reason)  # a list: two requests in one tick (Ctrl-C and a time limit) both count

    def request_kill(self, reason: str = "emergency stop") -> None:
        """Stop every motor at the next tick."""
        self._kill_request = reason

    def event(self, kind: EventKind, message: str, drone: int | None = None) -> None:
        """Record an event at the current mission time."""
        self.events.append(Event(round(self.t, 6), kind, message, drone))

    # ------------------------------------------------------------------ the loop
    def run(self) -> MissionResult:
        """Fly until every drone is down, lost, or the pre-flight check gives up.

        While it runs (in the main thread), SIGINT, SIGTERM and SIGHUP land every drone at the next
        tick and a second one stops every motor (:mod:`marlander_lite.deploy.interrupts`); the
        previous signal handlers are restored when it returns.
        """
        self._t0 = self.clock.now()
        next_tick = self._t0
        with handle_signals(self._on_signal):
            try:
                while self.mode != "done":
                    try:
                        self._tick()
                    except KeyboardInterrupt:  # raised by code the tick called: treated like SIGINT
                        self._on_signal("SIGINT")
                        if not self._settle_interrupted_tick():
                            continue  # cut short before its record was written: redo it under the same index
                    next_tick = self._pace(next_tick)
            except Exception as error:
                self.event("error", f"{type(error).__name__}: {error}; landing every drone")
                self._fallback_landing()
                raise
            finally:
                result = self.result()
                if self.log is not None:
                    self.log.write({"type": "summary", **jsonable(result.to_dict())})
                    self.log.close()
        return result

    def _pace(self, next_tick: float) -> float:
        """Sleep until the next tick is due (or note that the loop fell behind); returns when it is due."""
        next_tick += self.period
        try:
            behind = self.clock.now() - next_tick
            if behind > self.period:
                self.event("loop_overrun", f"the loop fell {behind * 1000:.0f} ms behind; ticks skipped")
                next_tick = self.clock.now()
            self.clock.sleep_until(next_tick)
        except KeyboardInterrupt:
            self._on_signal("SIGINT")
        return next_tick

    def _on_signal(self, name: str) -> None:
        """Ctrl-C or a signal (``"SIGINT"``, ``"SIGTERM"``, ``"SIGHUP"``): the first lands every drone at the
        next tick, any later one stops every motor. Runs inside a signal handler: it only sets requests."""
        self._signals += 1
        if self.interrupted_by is None:
            self.interrupted_by = name
        if self._signals == 1:
            self.request_land(describe(name))
        else:
            self.request_kill(f"second interrupt ({describe(name)})")

    def _settle_interrupted_tick(self) -> bool:
        """After a ``KeyboardInterrupt`` escaped a tick: whether that tick counts as done.

        A tick is done once its record is in the log (the writer's ``last_tick``), however far its
        bookkeeping got; then the counters are set as the tick would have set them (assignments,
        so doing it twice is harmless). A tick cut short before its record keeps its index and its
        events, and is redone: the log never holds a tick twice, and never skips one.
        """
        k, self._tick_open = self._tick_open, None
        if k is None:
            return True  # the interrupt came after the tick finished
        if self.log is None or getattr(self.log, "last_tick", None) == k:
            self.tick, self._events_logged = k + 1, self._events_marked
            return True
        return False

    def result(self) -> MissionResult:
        ms = np.array(self.loop_ms) if self.loop_ms else np.zeros(1)
        return MissionResult(
            armed=self.armed,
            phases=list(self.phase),
            on_pad=[bool(v) for v in self.on_pad],
            landing_error=[float(v) for v in self.landing_error],
            landing_time=[float(v) for v in self.landing_time],
            ticks=self.tick,
            duration_s=self.t,
            loop_ms_median=float(np.median(ms)),
            loop_ms_p95=float(np.percentile(ms, 95)),
            loop_ms_max=float(ms.max()),
            overruns=int((ms > self.period * 1000).sum()),
            events=list(self.events),
            log_path=None if self.log is None else str(self.log.path),
            interrupted_by=self.interrupted_by,
        )

    def _tick(self) -> None:
        start = time.perf_counter()
        now = self.clock.now()
        k = self._tick_open = self.tick
        self.t = now - self._t0
        self._cmd = [{"kind": "none"} for _ in range(self.n)]
        self.obs = self.action = None
        for hook in self.hooks:
            hook(self, self.t)
        frames = self.source.read(now)
        est = self.sense(frames, now)
        self._forward_poses()
        self.decide(est)
        compute_ms = (time.perf_counter() - start) * 1000.0
        self._events_marked = len(self.events)  # this record holds the events since the last record
        if self.log is not None:
            record = tick_record(
                tick=k,
                t=self.t,
                mode=self.mode,
                phase=self.phase,
                frames=frames,
                ages=self.estimator.ages(now),
                est=est,
                obs=self.obs,
                action=self.action,
                commands=self._cmd,
                events=[e.to_dict() for e in self.events[self._events_logged : self._events_marked]],
                compute_ms=compute_ms,
            )
            self.log.write(record)
        self.tick, self._events_logged = k + 1, self._events_marked
        self.loop_ms.append((time.perf_counter() - start) * 1000.0)
        self._tick_open = None

    def sense(self, frames: list[PoseFrame], now: float) -> SwarmEstimate:
        """Feed the frames to the estimator; log rejected poses once per bad spell."""
        for body, reason in self.estimator.ingest(frames):
            if body not in self._invalid_bodies:
                self._invalid_bodies.add(body)
                self.event("invalid_pose", f"{body}: {reason}", self._drone_index(body))
        tracks = self.estimator.tracks
        self._invalid_bodies = {b for b in self._invalid_bodies if tracks.invalid[tracks.index[b]]}
        est = self.estimator.estimate(now)
        self._last_est = est
        return est

    def _drone_index(self, body: str) -> int | None:
        return self.names.index(body) if body in self.names else None

    def _forward_poses(self) -> None:
        tracks = self.estimator.tracks
        for i, name in enumerate(self.names):
            k = tracks.index[name]
            if tracks.t_last[k] > self._forwarded[i] and self.phase[i] != "lost":
                self.link.send_pose(i, tracks.pose[k])
                self._forwarded[i] = tracks.t_last[k]
                self._streaming_since[i] = min(self._streaming_since[i], self.t)

    def decide(self, est: SwarmEstimate) -> None:
        """The mode machine for one tick (safety, policy, commands)."""
        self._check_links()
        self._check_requests(est)
        if self.mode == "preflight":
            self._preflight(est)
        elif self.mode == "takeoff":
            self._takeoff(est)
        elif self.mode in ("policy", "landing"):
            self._fly(est)
        if self.mode != "preflight" and all(p in ("down", "lost") for p in self.phase):
            self.mode = "done"

    # ------------------------------------------------------------------ modes
    def _preflight(self, est: SwarmEstimate) -> None:
        lost = [self.link.lost(i) for i in range(self.n)]
        problems = self.safety.arming_problems(est, lost)
        streamed = self.t - self._streaming_since.max()  # every drone's Kalman filter has had poses this long
        if not problems and streamed >= self.min_preflight_s:
            self.armed = True
            self.event("armed", "pre-flight check passed: taking off")
            height, duration = self.lab.limits.takeoff_height, self.lab.limits.takeoff_duration
            for i in range(self.n):
                self.link.takeoff(i, height, duration)
                self.phase[i] = "takeoff"
                self._cmd[i] = {"kind": "takeoff", "height": height, "duration": duration}
            self.mode, self._takeoff_t = "takeoff", self.t
        elif self.t > self.lab.safety.arming_timeout_s:
            self.event("arming_failed", "not cleared to take off: " + "; ".join(problems or ["timeout"]))
            self.mode = "done"

    def _takeoff(self, est: SwarmEstimate) -> None:
        flying = np.array([p == "takeoff" for p in self.phase])
        verdict = self.safety.flight(self.t, est, flying, action_ok=True)
        self._add(verdict.events)
        if verdict.action == "land":
            self._land_all(est, None)
            return
        limits, elapsed = self.lab.limits, self.t - self._takeoff_t
        fresh = est.drone_age <= self.lab.safety.stale_hover_s
        reached = flying & fresh & (np.abs(est.pos[:, 2] - limits.takeoff_height) < 0.1)
        if elapsed >= limits.takeoff_duration and reached[flying].all():
            self.mode, self.policy_start, self._policy_tick0 = "policy", self.t, self.tick
            for i in np.flatnonzero(flying):
                self.phase[i] = "policy"
            self.event("policy_start", "every drone at take-off height: the policy takes over")
            self._fly(est)
        elif elapsed > limits.takeoff_duration + 3.0:
            self._land_all(est, "take-off did not reach its height in time")

    def _fly(self, est: SwarmEstimate) -> None:
        flying = np.array([p in ("policy", "hover") for p in self.phase])
        if flying.any() and self.mode == "policy":
            due = (self.tick - self._policy_tick0) % self.lab.rates.ticks_per_action == 0
            if due or "hover" in self.phase:  # after a hover, act on fresh data at once, not on a stale command
                self._run_policy(est)
            verdict = self.safety.flight(self.t, est, flying, self._action_ok)
            self._add(verdict.events)
            if verdict.action == "land":
                self._land_all(est, None)
            elif self.t - self.policy_start > self.lab.limits.max_flight_s:
                self.event("flight_timeout", f"{self.lab.limits.max_flight_s} s under the policy: landing")
                self._land_all(est, None)
            else:
                self._touchdowns(est, flying)
                hover = verdict.action == "hover"
                for i in np.flatnonzero(flying & np.array([p in ("policy", "hover") for p in self.phase])):
                    v = np.zeros(3) if hover else self.velocity[i]
                    self.link.send_velocity(i, v)
                    self.phase[i] = "hover" if hover else "policy"
                    self._cmd[i] = {"kind": "hover" if hover else "velocity", "v": rounded(v)}
        self._landings(est)

    def _run_policy(self, est: SwarmEstimate) -> None:
        ok = not est.invalid.any() and (est.age <= self.lab.safety.stale_hover_s).all()
        if not ok:
            return  # the safety rules hover; the policy waits for fresh data
        self.obs = self.runner.observe(est)
        try:
            self.action, self.velocity = self.runner.act(self.obs)
            if not self._action_ok:
                self.event("recovered", "the policy returns valid actions again")
            self._action_ok = True
        except InvalidAction as error:
            if self._action_ok:
                self.event("invalid_action", f"{error}: hovering")
            self._action_ok = False

    # ------------------------------------------------------------------ landing and requests
    def _check_links(self) -> None:
        for i in range(self.n):
            reason = self.link.lost(i)
            if reason and not self._lost_seen[i]:
                self._lost_seen[i] = True
                was = self.phase[i]
                self.phase[i] = "lost"
                self.event("link_lost", f"{self.names[i]}: radio link lost ({reason}) while {was}", i)
                if self.mode in ("takeoff", "policy") and self._last_est is not None:
                    self._land_all(self._last_est, "a link was lost: landing every other drone")

    def _check_requests(self, est: SwarmEstimate) -> None:
        if self._kill_request:
            self.event("emergency", f"{self._kill_request}: every motor off")
            for i in range(self.n):
                if self.phase[i] != "lost":
                    self.link.stop_motors(i)
                    self.phase[i], self._cmd[i] = "down", {"kind": "stop"}
            self._kill_request, self.mode = None, "done"
        elif self._land_requests:
            reasons = []
            while self._land_requests:
                reasons.append(self._land_requests.pop(0))
            self.event("interrupt", f"{' and '.join(reasons)}: landing every drone")
            if self.mode == "preflight":
                self.mode = "done"
            else:
                self._land_all(est, None)

    def _add(self, events: list[Event]) -> None:
        for e in events:
            e.t = round(self.t, 6)
            self.events.append(e)
