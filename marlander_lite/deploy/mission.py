"""The deployment loop: pre-flight check, take-off, the policy at a fixed rate, landing, all logged.

One :class:`Mission` runs the same code on hardware and in rehearsal; only its four partners
change: a pose source, a :class:`marlander_lite.deploy.link.CrazyflieLink` (real radios or
virtual Crazyflies), a clock (wall time, or the simulated world which advances physics while the
loop "sleeps") and a flight log. Every tick (``1 / rates.loop_hz`` s):

1. read the frames that arrived, update the estimates, forward each new drone pose to its
   Crazyflie (``send_extpose``);
2. depending on the mode: pre-flight check -> take-off -> policy (every ``ticks_per_action``-th
   tick a new action, its velocity setpoints through the safety filter of the config's
   ``safety_filter`` section; the setpoint is re-sent every tick, keeping the firmware's
   watchdog fed) -> landing -> done, with the rules of :mod:`marlander_lite.deploy.safety`
   deciding fly / hover / land;
3. a drone that touches its own pad (within ``touchdown_height`` of its goal, within the pad
   radius, slow) gets its motors stopped; a landing drone gets them stopped when it rests;
4. one log record; then sleep until the next tick. The work of each tick is timed
   (``compute_ms``) against the period.

The mode (:class:`~marlander_lite.deploy.modes.MissionMode`) and each drone's phase
(:class:`~marlander_lite.deploy.modes.DronePhase`) change only as their tables in
:mod:`marlander_lite.deploy.modes` allow (``docs/lab_guide.md`` shows them); everything else the
mission remembers is in the named pieces of :mod:`marlander_lite.deploy.mission_state`.
Mission times (event times, log ``t``) are seconds since :meth:`Mission.run` started.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from marlander_lite.deploy.config import LabConfig
from marlander_lite.deploy.estimation import EstimatorConfig, SwarmEstimate, SwarmEstimator
from marlander_lite.deploy.flight_log import FlightLogWriter, jsonable, rounded, tick_record
from marlander_lite.deploy.interrupts import handle_signals
from marlander_lite.deploy.landing import LandingControl
from marlander_lite.deploy.mission_state import Landings, Milestones, PolicyOutput, PoseStream, Requests, TickBook
from marlander_lite.deploy.modes import (
    FINISHED,
    FLYING,
    MODE_TRANSITIONS,
    PHASE_TRANSITIONS,
    UNDER_POLICY,
    DronePhase,
    MissionMode,
    check_change,
)
from marlander_lite.deploy.pose_sources import Clock, PoseFrame, PoseSource
from marlander_lite.deploy.results import MissionResult
from marlander_lite.deploy.runner import InvalidAction, Policy, PolicyRunner, describe_filtering
from marlander_lite.deploy.safety import Event, EventKind, SafetyMonitor
from marlander_lite.rotations import tilt_deg

LATENCY_LOG_STEP = 0.05
"""s: a ``tracker_lag`` event is logged each time the identified latency compensation has moved this far from the one
last logged (the filter's ``identified_lag_share``), and so for the pad-frame lead set from it (``limits.pad_frame_lead:
auto``): the log shows what the flight identified, not every step."""
STEP_LOG_STEP = 0.1
"""m/s: so for the velocity step that the identified lag scales (the filter's ``low_velocity_step_lag``)."""


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
        estimator: settings of the velocity estimation (default: :class:`EstimatorConfig`'s).
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
        # partners and the parts built from the config (fixed for the flight)
        self.lab, self.source, self.link, self.clock, self.log = lab, source, link, clock, log
        self.hooks = list(hooks)
        contract = getattr(policy, "contract", None)
        self.task = lab.task_config(**lab.policy_options(contract.interface_options() if contract is not None else {}))
        sf = lab.safety_filter
        self.runner = PolicyRunner(policy, self.task, lab.limits.max_speed, sf.filter_config() if sf.enabled else None)
        self.estimator = SwarmEstimator(lab, estimator, landed_height=self.task.landed_height)
        self.safety = SafetyMonitor(lab)
        self.min_preflight_s = min_preflight_s
        self.names = lab.drone_names
        # the state, tick by tick
        n = lab.num_drones
        self.mode = MissionMode.PREFLIGHT
        self.phase = [DronePhase.IDLE] * n
        """Each drone's phase (changed only through :meth:`_set_phase`)."""
        self.tick, self.t = 0, 0.0
        """Index of the next tick to run, and the mission time of the latest one (s)."""
        self.events: list[Event] = []
        self.times = Milestones()
        self.stream = PoseStream.empty(n)
        self.output = PolicyOutput(velocity=np.zeros((n, 3)))
        self.landings = Landings(pad_radius=np.array([p.radius for p in lab.drone_pads()]))
        self.requests = Requests()
        self.book = TickBook()
        self.logged_latency = self.runner.latency_compensation
        """The filter's latency compensation (s) the last ``tracker_lag`` event reported (the setting at first)."""
        self.logged_step = self.runner.velocity_step
        """The filter's velocity step (m/s) the last ``tracker_lag`` event reported (the setting at first)."""
        self.logged_lead = self.runner.pad_frame_lead
        """The pad-frame lead (s) the last ``tracker_lag`` event reported (the policy's or the config's at first)."""

    # ------------------------------------------------------------------ read-only views
    @property
    def n(self) -> int:
        """Number of drones."""
        return len(self.names)

    @property
    def period(self) -> float:
        """Loop period (s)."""
        return 1.0 / self.lab.rates.loop_hz

    @property
    def armed(self) -> bool:
        """The pre-flight check passed and the drones were told to take off."""
        return self.times.takeoff is not None

    @property
    def policy_start(self) -> float | None:
        """Mission time the policy took over (s); None before."""
        return self.times.policy

    @property
    def interrupted_by(self) -> str | None:
        """The signal that ended the flight early (``"SIGINT"`` for Ctrl-C, ``"SIGTERM"``, ``"SIGHUP"``), or None."""
        return self.requests.interrupted_by

    # ------------------------------------------------------------------ public controls
    def request_land(self, reason: str = "emergency key") -> None:
        """Land every drone at the next tick (thread-safe: a key watcher may call it)."""
        self.requests.land.append(reason)

    def request_kill(self, reason: str = "emergency stop") -> None:
        """Stop every motor at the next tick."""
        self.requests.kill = reason

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
        self.times.start = next_tick = self.clock.now()
        with handle_signals(self.requests.on_signal):
            try:
                while self.mode != MissionMode.DONE:
                    try:
                        self._tick()
                    except KeyboardInterrupt:  # raised by code the tick called: treated like SIGINT
                        self.requests.on_signal("SIGINT")
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
            self.requests.on_signal("SIGINT")
        return next_tick

    def _settle_interrupted_tick(self) -> bool:
        """After a ``KeyboardInterrupt`` escaped a tick: whether that tick counts as done.

        A tick is done once its record is in the log (the writer's ``last_tick``), however far its
        bookkeeping got; then the counters are set as the tick would have set them (assignments,
        so doing it twice is harmless). A tick cut short before its record keeps its index and its
        events, and is redone: the log never holds a tick twice, and never skips one.
        """
        book = self.book
        k, book.open = book.open, None
        if k is None:
            return True  # the interrupt came after the tick finished
        if self.log is None or getattr(self.log, "last_tick", None) == k:
            self.tick, book.events_logged = k + 1, book.events_marked
            return True
        return False

    def result(self) -> MissionResult:
        ms = np.array(self.book.loop_ms) if self.book.loop_ms else np.zeros(1)
        landings = self.landings
        return MissionResult(
            armed=self.armed,
            phases=[p.value for p in self.phase],
            on_pad=[bool(v) for v in landings.on_pad],
            landing_error=[float(v) for v in landings.error],
            landing_time=[float(v) for v in landings.time],
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
        now, book = self.clock.now(), self.book
        k = book.open = self.tick
        self.t = now - self.times.start
        book.commands = [{"kind": "none"} for _ in range(self.n)]
        self.output.obs = self.output.action = None
        for hook in self.hooks:
            hook(self, self.t)
        frames = self.source.read(now)
        est = self.sense(frames, now)
        self._forward_poses()
        self.decide(est)
        compute_ms = (time.perf_counter() - start) * 1000.0
        book.events_marked = len(self.events)  # this record holds the events since the last record
        if self.log is not None:
            record = tick_record(
                tick=k,
                t=self.t,
                mode=self.mode.value,
                phase=[p.value for p in self.phase],
                frames=frames,
                ages=self.estimator.ages(now),
                est=est,
                obs=self.output.obs,
                action=self.output.action,
                commands=book.commands,
                events=[e.to_dict() for e in self.events[book.events_logged : book.events_marked]],
                compute_ms=compute_ms,
            )
            self.log.write(record)
        self.tick, book.events_logged = k + 1, book.events_marked
        book.loop_ms.append((time.perf_counter() - start) * 1000.0)
        book.open = None

    def sense(self, frames: list[PoseFrame], now: float) -> SwarmEstimate:
        """Feed the frames to the estimator; log rejected poses once per bad spell."""
        stream = self.stream
        for body, reason in self.estimator.ingest(frames):
            if body not in stream.rejected:
                stream.rejected.add(body)
                self.event("invalid_pose", f"{body}: {reason}", self._drone_index(body))
        tracks = self.estimator.tracks
        stream.rejected = {b for b in stream.rejected if tracks.invalid[tracks.index[b]]}
        stream.last = self.estimator.estimate(now)
        return stream.last

    def _drone_index(self, body: str) -> int | None:
        return self.names.index(body) if body in self.names else None

    def _forward_poses(self) -> None:
        tracks, stream = self.estimator.tracks, self.stream
        for i, name in enumerate(self.names):
            k = tracks.index[name]
            if tracks.t_last[k] > stream.forwarded[i] and self.phase[i] != DronePhase.LOST:
                self.link.send_pose(i, tracks.pose[k])
                stream.forwarded[i] = tracks.t_last[k]
                stream.streaming_since[i] = min(stream.streaming_since[i], self.t)

    # ------------------------------------------------------------------ modes
    def _enter(self, mode: MissionMode) -> None:
        """Change the mission's mode, as :data:`~marlander_lite.deploy.modes.MODE_TRANSITIONS` allows."""
        self.mode = check_change(MODE_TRANSITIONS, self.mode, mode, "mission mode")

    def _set_phase(self, i: int, phase: DronePhase) -> None:
        """Change drone ``i``'s phase, as :data:`~marlander_lite.deploy.modes.PHASE_TRANSITIONS` allows."""
        self.phase[i] = check_change(PHASE_TRANSITIONS, self.phase[i], phase, f"phase of {self.names[i]}")

    def decide(self, est: SwarmEstimate) -> None:
        """The mode machine for one tick (safety, policy, commands)."""
        self._check_links()
        self._check_tumbles(est)
        self._check_requests(est)
        if self.mode == MissionMode.PREFLIGHT:
            self._preflight(est)
        elif self.mode == MissionMode.TAKEOFF:
            self._takeoff(est)
        elif self.mode in (MissionMode.POLICY, MissionMode.LANDING):
            self._fly(est)
        if self.mode != MissionMode.PREFLIGHT and all(p in FINISHED for p in self.phase):
            self._enter(MissionMode.DONE)

    def _preflight(self, est: SwarmEstimate) -> None:
        lost = [self.link.lost(i) for i in range(self.n)]
        problems = self.safety.arming_problems(est, lost)
        streamed = self.t - self.stream.streaming_since.max()  # every drone's Kalman filter has had poses this long
        if not problems and streamed >= self.min_preflight_s:
            self.times.takeoff = self.t
            self.event("armed", "pre-flight check passed: taking off")
            height, duration = self.lab.limits.takeoff_height, self.lab.limits.takeoff_duration
            for i in range(self.n):
                self.link.takeoff(i, height, duration)
                self._set_phase(i, DronePhase.TAKEOFF)
                self.book.commands[i] = {"kind": "takeoff", "height": height, "duration": duration}
            self._enter(MissionMode.TAKEOFF)
        elif self.t > self.lab.safety.arming_timeout_s:
            self.event("arming_failed", "not cleared to take off: " + "; ".join(problems or ["timeout"]))
            self._enter(MissionMode.DONE)

    def _takeoff(self, est: SwarmEstimate) -> None:
        flying = np.array([p == DronePhase.TAKEOFF for p in self.phase])
        verdict = self.safety.flight(self.t, est, flying, action_ok=True)
        self._add(verdict.events)
        if verdict.action == "land":
            self._land_all(est, None)
            return
        limits, elapsed = self.lab.limits, self.t - self.times.takeoff
        fresh = est.drone_age <= self.lab.safety.stale_hover_s
        reached = flying & fresh & (np.abs(est.pos[:, 2] - limits.takeoff_height) < 0.1)
        if elapsed >= limits.takeoff_duration and reached[flying].all():
            self._enter(MissionMode.POLICY)
            self.times.policy, self.times.policy_tick = self.t, self.tick
            for i in np.flatnonzero(flying):
                self._set_phase(i, DronePhase.POLICY)
            self.event("policy_start", "every drone at take-off height: the policy takes over")
            self._fly(est)
        elif elapsed > limits.takeoff_duration + 3.0:
            self._land_all(est, "take-off did not reach its height in time")

    def _fly(self, est: SwarmEstimate) -> None:
        flying = np.array([p in UNDER_POLICY for p in self.phase])
        if flying.any() and self.mode == MissionMode.POLICY:
            due = (self.tick - self.times.policy_tick) % self.lab.rates.ticks_per_action == 0
            if due or DronePhase.HOVER in self.phase:  # after a hover, act on fresh data at once, not a stale command
                self._run_policy(est)
            verdict = self.safety.flight(self.t, est, flying, self.output.valid)
            self._add(verdict.events)
            if verdict.action == "land":
                self._land_all(est, None)
            elif self.t - self.times.policy > self.lab.limits.max_flight_s:
                self.event("flight_timeout", f"{self.lab.limits.max_flight_s} s under the policy: landing")
                self._land_all(est, None)
            else:
                self._touchdowns(est, flying)
                hover = verdict.action == "hover"
                under = flying & np.array([p in UNDER_POLICY for p in self.phase])
                # guarded every tick, not only when the policy acts: the drone moves on between two actions
                velocity = self.output.velocity
                send = np.zeros_like(velocity) if hover else self._guard_fence(est, velocity, under)
                for i in np.flatnonzero(under):
                    v = send[i]
                    self.link.send_velocity(i, v)
                    self.runner.previous_command[i] = v
                    self._set_phase(i, DronePhase.HOVER if hover else DronePhase.POLICY)
                    self.book.commands[i] = {"kind": "hover" if hover else "velocity", "v": rounded(v)}
                    if not hover:
                        self.output.annotate(i, self.book.commands[i])
        self._landings(est)

    def _run_policy(self, est: SwarmEstimate) -> None:
        ok = not est.invalid.any() and (est.age <= self.lab.safety.stale_hover_s).all()
        if not ok:
            return  # the safety rules hover; the policy waits for fresh data
        out = self.output
        out.obs = self.runner.observe(est)
        latency, step, lead = self.runner.latency_compensation, self.runner.velocity_step, self.runner.pad_frame_lead
        if (
            abs(latency - self.logged_latency) >= LATENCY_LOG_STEP
            or abs(step - self.logged_step) >= STEP_LOG_STEP
            or abs(lead - self.logged_lead) >= LATENCY_LOG_STEP
        ):
            assert self.runner.tracker_lag is not None  # all three change only as the lag is identified
            lag = float(self.runner.tracker_lag.time_constant()[0])
            message = f"velocity tracker lag identified: {lag:.2f} s; latency compensation {latency:.2f} s"
            if step != self.logged_step:
                message += f"; velocity step {step:.2f} m/s"
            if lead != self.logged_lead:
                message += f"; pad-frame lead {lead:.2f} s"
            self.event("tracker_lag", message)
            self.logged_latency, self.logged_step, self.logged_lead = latency, step, lead
        try:
            out.action, velocity = self.runner.act(out.obs, est.goal, self.runner.carried_pad_velocity(est))
            out.unfiltered = velocity
            out.velocity = velocity if self.runner.safety_filter is None else self._filter(est, velocity)
            out.velocity = self.runner.cancel_vertical_bias(out.velocity)  # limits.vertical_bias; else unchanged
            if not out.valid:
                self.event("recovered", "the policy returns valid actions again")
            out.valid = True
        except InvalidAction as error:
            if out.valid:
                self.event("invalid_action", f"{error}: hovering")
            out.valid = False

    def _filter(self, est: SwarmEstimate, velocity: np.ndarray) -> np.ndarray:
        """The policy's ``velocity`` ``(N, 3)`` m/s through the safety filter; drones not under the policy (landed,
        landing, down) stay where they are. A ``safety_filter`` event marks each drone the filter starts to act on
        (once per spell, :data:`~marlander_lite.deploy.mission_state.FILTER_SPELL_GAP_S`, not every step)."""
        settled = np.array([p not in UNDER_POLICY for p in self.phase])
        filtered, changed = self.runner.filter_velocity(velocity, est, settled)
        changed &= ~settled  # a drone not under the policy is sent nothing: nothing of it was filtered
        for i in self.output.starts(changed, self.t):
            self.event("safety_filter", describe_filtering(self.names, i, est, velocity[i], filtered[i]), i)
        self.output.filtered = changed
        return filtered

    def _guard_fence(self, est: SwarmEstimate, velocity: np.ndarray, under: np.ndarray) -> np.ndarray:
        """The setpoints ``velocity`` ``(N, 3)`` m/s through the fence guard, every tick: no drone is sent towards a
        wall or the ceiling faster than it can stop from before the soft fence (eq. 2 does not tell the policy where
        the walls are). A ``fence_guard`` event marks each drone under the policy (``under`` ``(N,)``) it starts to
        slow down (once per spell)."""
        guarded, changed = self.safety.keep_inside(velocity, est.pos, est.vel)
        changed &= under
        for i in self.output.guard_starts(changed, self.t):
            pos, before, after = np.round(est.pos[i], 2).tolist(), np.round(velocity[i], 3), np.round(guarded[i], 3)
            message = f"{self.names[i]} at {pos} nears the soft fence: {before.tolist()} -> {after.tolist()} m/s"
            self.event("fence_guard", message, i)
        self.output.guarded = changed
        return guarded

    # ------------------------------------------------------------------ lost links and requests
    def _check_links(self) -> None:
        for i in range(self.n):
            reason = self.link.lost(i)
            if reason and self.phase[i] != DronePhase.LOST:  # lost is final: each loss is handled once
                was = self.phase[i]
                self._set_phase(i, DronePhase.LOST)
                self.event("link_lost", f"{self.names[i]}: radio link lost ({reason}) while {was}", i)
                if self.mode in (MissionMode.TAKEOFF, MissionMode.POLICY) and self.stream.last is not None:
                    self._land_all(self.stream.last, "a link was lost: landing every other drone")

    def _check_tumbles(self, est: SwarmEstimate) -> None:
        """Stop the motors of a drone that has tumbled (:meth:`SafetyMonitor.tumbled`); before the policy's end every
        other drone lands, as after a lost link."""
        flying = np.array([p in FLYING for p in self.phase])
        for i in self.safety.tumbled(self.t, est, flying):
            tilt = float(tilt_deg(est.quat[i]))
            self.event("tumbled", f"{self.names[i]} tilted {tilt:.0f} degrees: it cannot be flown, motors off", i)
            self._motors_off(i)
            if self.mode in (MissionMode.TAKEOFF, MissionMode.POLICY):
                self._land_all(est, "a drone tumbled: landing every other drone")

    def _check_requests(self, est: SwarmEstimate) -> None:
        requests = self.requests
        if requests.kill:
            self.event("emergency", f"{requests.kill}: every motor off")
            for i in range(self.n):
                if self.phase[i] != DronePhase.LOST:
                    self._motors_off(i)
            requests.kill = None
            self._enter(MissionMode.DONE)
        elif requests.land:
            self.event("interrupt", f"{' and '.join(requests.take_land_reasons())}: landing every drone")
            if self.mode == MissionMode.PREFLIGHT:
                self._enter(MissionMode.DONE)
            else:
                self._land_all(est, None)

    def _add(self, events: list[Event]) -> None:
        for e in events:
            e.t = round(self.t, 6)
            self.events.append(e)
