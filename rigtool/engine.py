"""Runs a Plan against a RigSet: depth, ramp, settle, acquire, store, rest, with safe exits.

The engine is the single writer of a run. Every exit path (end, exception, Ctrl-C,
SIGTERM, SIGHUP, limit trip) sends the actuator to neutral, stops a captive run's carriage
(speed 0) and closes the run with a status; completed points are already committed, a point
in progress is discarded.
"""

from __future__ import annotations

import contextlib
import math
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType

import numpy as np

from rigtool.devices.base import FeedbackBlock
from rigtool.errors import (
    EXIT_COMPLETED,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_NOT_AT_NEUTRAL,
    DeviceError,
    SafetyTrip,
    StoreError,
)
from rigtool.plan import PlanStep, sensor_timing
from rigtool.progress import SilentReporter
from rigtool.protocol import Protocol
from rigtool.rig import RigSet, counter_delta
from rigtool.safety import BusVoltageMonitor, FollowMonitor, LimitMonitor
from rigtool.spool import SampleSpool
from rigtool.store import SAMPLE_COLUMNS, STAT_FIELDS, StepRecord, Store
from rigtool.units import FT_CHANNELS

CHUNK_S = 0.2  # acquisition block length: limit checks and Ctrl-C are seen this often
RAMP_DT_S = 0.05  # command update period while slewing
CATCH_UP_SLACK = 2.0  # sample periods a settled point's newest sample may fall short by
MAX_CATCH_UP_READS = 200  # CHUNK_S blocks read at most to catch a lagging reader up
LAG_WARN_S = 0.1  # a reader this far behind is named in a warning event (less is clock drift)
# After the final neutral, an actuator's speed feedback must fall within NEUTRAL_CONFIRM_S:
# to NEUTRAL_SPEED_RPM or below, or to NEUTRAL_FALL_FRAC of its first reading; else exit 3.
NEUTRAL_CONFIRM_S = 2.0
NEUTRAL_SPEED_RPM = 100.0
NEUTRAL_FALL_FRAC = 0.5
NEUTRAL_POLL_S = 0.02
NEUTRAL_FAILED = "THE NEUTRAL COMMAND FAILED"
CARRIAGE_NOT_STOPPED = "THE CARRIAGE MAY STILL BE MOVING: its stop command failed"
FOLD_SAMPLES = 1_000_000  # settle, rest and tare readings beyond this are summed as they come
FEEDBACK_FIELDS = ("speed_rpm", "current_a", "voltage_v")


def torque_channel(choice: str, thrust_channel: int) -> int:
    """Index of the torque channel a torque limit watches: `axis` is the torque about the
    thrust axis (tx for thrust on fx, ty for fy, tz for fz)."""
    if choice == "axis":
        return 3 + thrust_channel % 3
    return FT_CHANNELS.index(choice)


def decimated(block: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    """Each `k` consecutive samples of a block as one: their mean (the sequence number of the
    last); a block whose length is not a multiple of k keeps its whole groups only."""
    n = len(block["t_s"]) // k * k
    out = {name: v[:n].reshape(-1, k).mean(axis=1) for name, v in block.items() if name != "seq"}
    out["seq"] = block["seq"][k - 1:n:k]
    return out


def feedback_limits(fb: FeedbackBlock, power: bool) -> dict[str, np.ndarray | None]:
    """The limited quantities in a block of actuator feedback, one reading per frame; the
    power only when it is limited (`power`), so a run without that limit computes nothing."""
    power = (fb.voltage_v * fb.current_a
             if power and fb.voltage_v is not None and fb.current_a is not None else None)
    return {"current_a": fb.current_a, "speed_rpm": fb.speed_rpm, "bus_v": fb.voltage_v,
            "power_w": power, "temperature_c": fb.temperature_c}


class StopNow(BaseException):
    """Raised from a signal handler to stop immediately (second Ctrl-C, SIGTERM, SIGHUP);
    `by_operator` for the Ctrl-C, so the exit status says which stopped the run."""

    def __init__(self, message: str, by_operator: bool = False) -> None:
        super().__init__(message)
        self.by_operator = by_operator


class NeutralNotConfirmed(DeviceError):
    """A run failed and its final neutral command was not confirmed: the thruster may run."""

    exit_status = EXIT_NOT_AT_NEUTRAL


@dataclass
class Outcome:
    """How a run ended."""

    run_id: str
    status: str
    reason: str | None
    steps_done: int
    neutral_ok: bool = True  # False: the final neutral command could not be confirmed
    interrupted: bool = False  # the operator's Ctrl-C (SIGINT) stopped the run
    neutral_note: str = NEUTRAL_FAILED  # what went wrong with neutral, when not neutral_ok

    @property
    def exit_status(self) -> int:
        """The command's exit status for this ending (docs/cli.md): 3 the actuator may not be
        at neutral, whatever else stopped the run; 0 completed; 130 the operator's Ctrl-C; 1
        otherwise (a limit trip, a device fault, SIGTERM or SIGHUP)."""
        if not self.neutral_ok:
            return EXIT_NOT_AT_NEUTRAL
        if self.status == "completed":
            return EXIT_COMPLETED
        return EXIT_INTERRUPTED if self.interrupted else EXIT_FAILED


class _Signals:
    """First SIGINT asks for a stop after the current point; a second, or SIGTERM/SIGHUP, stops now."""

    def __init__(self, reporter) -> None:
        self.stop_requested = False
        self.closing = False  # while the run is being made safe, signals are only noted
        self.reporter = reporter
        self._old: dict[int, object] = {}

    def _on_int(self, signum: int, frame: FrameType | None) -> None:
        if self.closing:
            return
        if self.stop_requested:
            raise StopNow("second Ctrl-C: stopped at once", by_operator=True)
        self.stop_requested = True
        self.reporter.note("Ctrl-C: finishing the current point, then stopping "
                           "(Ctrl-C again to stop at once)")

    def _on_term(self, signum: int, frame: FrameType | None) -> None:
        if not self.closing:
            raise StopNow(f"stopped by {signal.Signals(signum).name}")

    def __enter__(self) -> _Signals:
        if threading.current_thread() is threading.main_thread():
            self._old[signal.SIGINT] = signal.signal(signal.SIGINT, self._on_int)
            for sig in (signal.SIGTERM, signal.SIGHUP):
                if signal.getsignal(sig) is not signal.SIG_IGN:  # e.g. nohup: keep ignoring
                    self._old[sig] = signal.signal(sig, self._on_term)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)


class Engine:
    """Executes plan steps on the devices and commits each finished point to the store."""

    def __init__(self, protocol: Protocol, plan: list[PlanStep], rig: RigSet, store: Store,
                 run_id: str, reporter=None, confirm: Callable[[str], bool] | None = None) -> None:
        """`confirm` asks the operator a yes/no question (None: nobody to ask, so pauses abort)."""
        self.protocol = protocol
        self.plan = plan
        self.rig = rig
        self.store = store
        self.run_id = run_id
        self.reporter = reporter or SilentReporter()
        self.confirm = confirm
        self.clock = rig.clock
        self.limits = LimitMonitor(protocol.limits, self.clock.now)
        self.follow = FollowMonitor(rig.actuator.info,
                                    getattr(rig.actuator, "expected_speed_rpm", None))
        self.bus = BusVoltageMonitor(protocol.voltage.tolerance_frac if protocol.voltage else 0.25)
        self.unit = rig.actuator.info.command_unit
        self.timing = sensor_timing(protocol, rig.sensor_rate_hz)
        self._power_limited = "power_w" in self.limits.checks
        self._torque_idx = torque_channel(protocol.limits.torque_channel, rig.thrust_channel)
        self._command = rig.actuator.info.neutral
        self._newest_t = -math.inf  # clock time of the newest sample read
        self._t0 = 0.0
        self._depth: float | None = None
        self._voltage: float | None = None
        self._flow: tuple[float, float] | None = None  # (speed, angle) the carriage was set to
        self._supply_used = False  # the run has commanded the supply: leave it safe at the end
        self._signals: _Signals | None = None
        self._fb_last = dict.fromkeys(FEEDBACK_FIELDS, np.nan)
        self._bias_total = np.zeros(6)
        self._stored_idx: int | None = None
        self.samples_read = 0  # every sample taken from the sensor, stored or not (reconciliation)

    # -- public ---------------------------------------------------------------------------
    def run(self, start_idx: int = 0, t_offset_s: float = 0.0) -> Outcome:
        """Run steps from `start_idx`; always ends with the actuator at neutral.

        A resumed run passes the run time already used as `t_offset_s`, so its sample
        times keep increasing across the interruption.
        """
        status, reason, done = "failed", None, 0
        interrupted = False
        self.reporter.start(self.run_id, len(self.plan), self.unit, done=start_idx)
        with _Signals(self.reporter) as signals:
            self._signals = signals
            try:
                self._begin(t_offset_s)
                remaining = self.plan[start_idx:]
                for i, step in enumerate(remaining):
                    if signals.stop_requested:  # Ctrl-C before the first point began
                        status, reason = "aborted", "stopped by the operator (Ctrl-C)"
                        break
                    self._prepare_depth(step)
                    self._prepare_voltage(step)
                    self._prepare_captive(step)
                    self._run_step_or_pause(step)
                    done += 1
                    if signals.stop_requested and i < len(remaining) - 1:
                        status, reason = "aborted", "stopped by the operator (Ctrl-C)"
                        break
                else:
                    status = "completed"
                interrupted = status == "aborted"  # the loop stopped at the operator's Ctrl-C
            except (KeyboardInterrupt, StopNow) as exc:
                status, reason = "aborted", str(exc) or "interrupted (Ctrl-C)"
                interrupted = isinstance(exc, KeyboardInterrupt) or exc.by_operator
            except SafetyTrip as exc:
                status, reason = "aborted", str(exc)
                signals.closing = True
                self._safe_neutral()
                self._safe_carriage()
                self._event("limit_trip", {"message": str(exc), **exc.detail})
            except DeviceError as exc:
                status, reason = "aborted", f"device fault: {exc}"
                signals.closing = True
                self._safe_neutral()
                self._safe_carriage()
                self._event("device_fault", {"message": str(exc)})
            except BaseException as exc:
                status, reason = "failed", f"{type(exc).__name__}: {exc}"
                raise
            finally:
                signals.closing = True
                neutral_ok = self._safe_neutral()
                carriage_ok = self._safe_carriage()
                spinning = self._spin_after_neutral() if neutral_ok else None
                note = NEUTRAL_FAILED if spinning is None else (
                    f"THE ACTUATOR MAY NOT BE AT NEUTRAL: {spinning}")
                if neutral_ok and spinning is None and not carriage_ok:
                    note = CARRIAGE_NOT_STOPPED
                neutral_ok = neutral_ok and spinning is None and carriage_ok
                self._safe_supply()
                self.reporter.finish()
                self._close_run(status, reason, neutral_ok, note)
                if not neutral_ok and status == "failed":
                    raise NeutralNotConfirmed(f"{reason}; {note}: check the thruster and cut "
                                              "its power")
        return Outcome(self.run_id, status, reason, done, neutral_ok, interrupted, note)

    # -- phases ---------------------------------------------------------------------------
    def _begin(self, t_offset_s: float) -> None:
        self.rig.actuator.neutral()
        self._command = self.rig.actuator.info.neutral
        self._t0 = self.clock.now() - t_offset_s
        self._event("run_start", {"rig": self.rig.description, "n_steps": len(self.plan)})
        t, note = self.timing, self.rig.sensor_rate_note
        if note:
            self.reporter.note(f"warning: {note}")
            self._event("warning", {"message": note})
        if t.how != "as planned" or t.sensor_rate_hz != t.protocol_rate_hz or note:
            self.reporter.note(f"sensor rate: {t.describe()}")
            self._event("sensor_rate", {"how": t.how, "sensor_rate_hz": t.sensor_rate_hz,
                                        "protocol_rate_hz": t.protocol_rate_hz,
                                        "stored_rate_hz": t.stored_rate_hz,
                                        "decimate": t.decimate, "n_stored": t.n_stored,
                                        "acquire_s": t.acquire_s, "message": t.describe(),
                                        "note": note})
        if self.protocol.timing.tare == "at_start":
            self._tare("at_start")

    def _prepare_depth(self, step: PlanStep) -> None:
        if step.depth_m != self._depth:
            self._ramp_to(self.rig.actuator.info.neutral)
            stage = self.rig.depth_stage
            reached = stage.move_to(step.depth_m)
            self._event("depth", {"target_m": step.depth_m, "reached_m": reached,
                                  "by": stage.reached_by}, step.idx)
            self._depth = step.depth_m
            if self.protocol.timing.tare == "per_depth":
                self._tare("per_depth", step.idx)
        if self.protocol.timing.tare == "per_point":
            self._tare("per_point", step.idx)

    def _prepare_voltage(self, step: PlanStep) -> None:
        """Set the point's supply voltage at neutral, then wait `settle_s` watching the limits."""
        if step.voltage_v is None or step.voltage_v == self._voltage:
            return
        supply = self.rig.supply
        if supply is None:
            raise DeviceError(f"point {step.idx} needs {step.voltage_v:g} V, but the rig has no "
                              "supply to set it")
        self._ramp_to(self.rig.actuator.info.neutral)
        if self._signals is not None and self._signals.stop_requested:
            raise StopNow("stopped by the operator (Ctrl-C) before the supply was set",
                          by_operator=True)
        self._supply_used = True
        reached = supply.set_voltage(step.voltage_v)
        self._event("voltage", {"target_v": step.voltage_v, "measured_v": reached,
                                "by": supply.reached_by}, step.idx)
        settle = self.protocol.voltage.settle_s if self.protocol.voltage else 0.0
        if settle > 0:
            self._read_for(settle, self.timing.sensor_rate_hz, step)
        self._voltage = step.voltage_v  # judged from here on: settled, before anything is labelled
        self._check_supply(step.voltage_v)

    def _prepare_captive(self, step: PlanStep) -> None:
        """Set the point's flow speed and angle with the actuator at neutral, then wait
        `captive.settle_s` watching the limits."""
        if step.speed_mps is None or (step.speed_mps, step.angle_deg) == self._flow:
            return
        carriage = self.rig.carriage
        if carriage is None:
            raise DeviceError(f"point {step.idx} needs a flow of {step.speed_mps:g} m/s, but the "
                              "rig has no carriage to set it")
        self._ramp_to(self.rig.actuator.info.neutral)
        if self._signals is not None and self._signals.stop_requested:
            raise StopNow("stopped by the operator (Ctrl-C) before the flow was set",
                          by_operator=True)
        angle = step.angle_deg if step.angle_deg is not None else 0.0
        self._flow = None  # moving: no setting holds until the carriage reports it
        speed, reached_angle = carriage.set_flow(step.speed_mps, angle)
        self._flow = (step.speed_mps, angle)
        self._event("captive", {"target_mps": step.speed_mps, "reached_mps": speed,
                                "target_deg": angle, "reached_deg": reached_angle,
                                "by": carriage.reached_by}, step.idx)
        settle = self.protocol.captive.settle_s if self.protocol.captive else 0.0
        if settle > 0:
            self._read_for(settle, self.timing.sensor_rate_hz, step)

    def _stop_carriage(self) -> None:
        """Speed 0 (raises what the carriage raises); the next point sets its flow again."""
        if self.rig.carriage is not None and self._flow is not None:
            self._flow = None
            self.rig.carriage.stop()

    def _safe_carriage(self) -> bool:
        """Speed 0 on every exit path, whatever state the carriage is in; never raises.
        Returns whether it worked (a carriage never set counts as stopped)."""
        carriage = self.rig.carriage
        if carriage is None:
            return True
        try:
            self._flow = None
            carriage.stop()
            return True
        except BaseException as exc:  # noqa: BLE001 - the run is ending; report, do not mask
            self.reporter.note(f"ERROR: could not stop the carriage: {exc!r}. "
                               "STOP THE FLOW OR THE CARRIAGE BY HAND.")
            with contextlib.suppress(StoreError):
                self._event("carriage_unsafe", {"message": str(exc)})
            return False

    def _run_step_or_pause(self, step: PlanStep) -> None:
        """Run a point; with `on_trip: pause`, a trip goes neutral and the operator may go on.

        A trip before the point was stored retries the point; a trip while resting after
        it was stored just continues with the next point.
        """
        while True:
            try:
                self._run_step(step)
                return
            except SafetyTrip as trip:
                if self.protocol.limits.on_trip != "pause" or self.confirm is None:
                    raise
                stored = self._stored_idx == step.idx
                neutral = "Thruster at neutral" if self._safe_neutral() else "NEUTRAL FAILED"
                if self.rig.carriage is not None:
                    neutral += ", carriage stopped" if self._safe_carriage() else (
                        ", CARRIAGE NOT STOPPED")
                self._event("limit_trip", {"message": str(trip), **trip.detail, "action": "paused"},
                            step.idx)
                self.limits.reset()
                what = "Continue with the next point" if stored else f"Retry point {step.idx}"
                try:
                    go_on = self.confirm(f"{trip}. {neutral}. {what}?")
                except EOFError:
                    go_on = False
                if not go_on:
                    raise StopNow(f"{trip}; the operator stopped the run") from None
                self._event("resumed", {"after": "limit_trip", "retry_idx": step.idx}, step.idx)
                if stored:
                    return
                self._prepare_captive(step)

    def _run_step(self, step: PlanStep) -> None:
        timing = self.protocol.timing
        rate = self.timing.sensor_rate_hz
        t_start = self._now()
        counters = self.rig.counters()
        self.follow.start_point()
        steps = self.protocol.is_steps
        if steps:  # a step: sent at once, acquired from that instant
            self._step_to(step.command)
        else:
            self._ramp_to(step.command, step)
        self.follow.hold(step.command, self.clock.now())
        settle_s, settled = self._settle(step, rate)
        t_acq = self._now()
        samples = self._acquire(step, self.timing.n_read, rate)
        try:
            if step.voltage_v is not None:  # the bus as the point ends, before it is labelled
                self._check_supply(step.voltage_v)
            self.follow.release()
            if not steps or step.idx == self.plan[-1].idx:
                self._ramp_to(self.rig.actuator.info.neutral, step)
            record = StepRecord(
                idx=step.idx, command=step.command, command_unit=self.unit, depth_m=step.depth_m,
                repeat=step.repeat, direction=step.direction, t_start_s=t_start, t_acquire_s=t_acq,
                t_end_s=self._now(), settle_s=settle_s, settled=settled,
                rate_hz=self.timing.stored_rate_hz,
                counters=counter_delta(counters, self.rig.counters()), voltage_v=step.voltage_v,
            )
            self.store.add_step(self.run_id, record, samples)
            self._stored_idx = step.idx
            self.reporter.step_done(step, samples.mean("thrust_n"))
        finally:
            samples.close()
        if timing.rest_s > 0:
            self._read_for(timing.rest_s, rate, step)

    # -- helpers --------------------------------------------------------------------------
    def _now(self) -> float:
        return self.clock.now() - self._t0

    def _event(self, kind: str, detail: dict, step_idx: int | None = None) -> None:
        self.store.add_event(self.run_id, kind, detail, t_s=self._now(), step_idx=step_idx)

    def _safe_neutral(self) -> bool:
        """Neutral, whatever state the actuator is in; never raises. Returns whether it worked."""
        try:
            self.rig.actuator.neutral()
            self._command = self.rig.actuator.info.neutral
            return True
        except BaseException as exc:  # noqa: BLE001 - the run is ending; report, do not mask
            self.reporter.note(f"ERROR: could not command neutral: {exc!r}. "
                               "CHECK THE THRUSTER AND CUT ITS POWER IF IT IS STILL RUNNING.")
            return False

    def _spin_after_neutral(self) -> str | None:
        """With speed feedback, whether it fell after neutral was sent (see NEUTRAL_CONFIRM_S):
        None when it did, else the speed it still reads. Feedback that cannot be read or
        gives no speed is no evidence either way (None); never raises."""
        act = self.rig.actuator
        if "speed_rpm" not in act.info.feedback:
            return None
        t_sent = self.clock.now()
        first = last = None
        while True:
            try:
                fb = act.read_feedback()
            except Exception:  # noqa: BLE001 - the run is ending; an unread actuator proves nothing
                return None
            speeds = fb.speed_rpm if fb.speed_rpm is not None else np.empty(0)
            # a reading stamped at the instant neutral was sent was taken before it took effect
            fresh = speeds[(fb.t_s > t_sent) & np.isfinite(speeds)]
            for speed in np.abs(fresh):
                first = speed if first is None else first
                if speed <= NEUTRAL_SPEED_RPM or speed <= NEUTRAL_FALL_FRAC * first:
                    return None
            last = fresh[-1] if fresh.size else last
            if self.clock.now() - t_sent >= NEUTRAL_CONFIRM_S:
                return None if last is None else (f"speed feedback still reads {last:.0f} r/min "
                                                  f"{NEUTRAL_CONFIRM_S:g} s after neutral was sent")
            self.clock.sleep(NEUTRAL_POLL_S)

    def _safe_supply(self) -> None:
        """Leave the supply as the rig file asks (output off or a safe voltage), once the
        thruster is at neutral; never raises. Only a supply this run set is touched."""
        supply = self.rig.supply
        if supply is None or not self._supply_used:
            return
        try:
            supply.safe()
            self._voltage, self._supply_used = None, False
        except BaseException as exc:  # noqa: BLE001 - the run is ending; report, do not mask
            self.reporter.note(f"ERROR: could not make the supply safe: {exc!r}. "
                               "SWITCH ITS OUTPUT OFF BY HAND.")
            with contextlib.suppress(StoreError):
                self._event("supply_unsafe", {"message": str(exc)})

    def _close_run(self, status: str, reason: str | None, neutral_ok: bool = True,
                   note: str = NEUTRAL_FAILED) -> None:
        """Record how the run ended; a store that fails here must not mask the original error."""
        try:
            if not neutral_ok:
                message = ("the final neutral command failed" if note == NEUTRAL_FAILED
                           else note[0] + note[1:].lower())
                self._event("neutral_failed", {"message": message})
            counters = self.rig.counters()
            if counters:
                self._event("transport_counters", counters)
            for ann in self.rig.annotations():
                self.store.add_event(self.run_id, ann["kind"], ann["detail"],
                                     t_s=ann["t_s"] - self._t0)
            self.store.finish_run(self.run_id, status, reason)
        except StoreError as exc:
            self.reporter.note(f"WARNING: could not record the end of the run: {exc}")

    def _step_to(self, target: float) -> None:
        """Send `target` at once (a step-response level), inside the actuator's range."""
        self.rig.actuator.set_command(target)
        self._command = target

    def _ramp_to(self, target: float, step: PlanStep | None = None) -> None:
        """Move the command to `target`, no faster than the slew limit, checking limits as it goes."""
        slew = self.protocol.limits.slew_per_s
        act = self.rig.actuator
        if slew is not None:
            max_step = slew * RAMP_DT_S
            rate = self.timing.sensor_rate_hz
            n = max(1, round(RAMP_DT_S * rate))
            while abs(target - self._command) > max_step:
                self._command += max_step if target > self._command else -max_step
                act.set_command(self._command)
                self._read(n, rate, step)
        if target != self._command or slew is None:
            act.set_command(target)
            self._command = target

    def _read(self, n: int, rate: float, step: PlanStep | None) -> dict[str, np.ndarray]:
        """Read `n` samples, attach feedback and thrust, check limits."""
        block = self.rig.sensor.read(n, rate)
        self.samples_read += len(block)
        ft = block.ft if self.rig.transform is None else block.ft @ self.rig.transform.T
        out: dict[str, np.ndarray] = {"t_s": block.t_s - self._t0}
        for i, name in enumerate(FT_CHANNELS):
            out[name] = ft[:, i]
        out["thrust_n"] = self.rig.thrust_sign * ft[:, self.rig.thrust_channel]
        if len(block) and math.isnan(out["thrust_n"][0]) and np.isnan(out["thrust_n"]).all():
            raise SafetyTrip(f"no thrust readings on channel {FT_CHANNELS[self.rig.thrust_channel]}: "
                             "check the rig's `thrust:` channel against the sensor")
        self._device_warnings(step)
        feedback = self.rig.actuator.read_feedback()
        if feedback.fault:
            raise SafetyTrip(f"driver fault: {feedback.fault}")
        if len(block):
            self._newest_t = float(block.t_s[-1])
        staleness = self.clock.now() - float(block.t_s[-1]) if len(block) else float("inf")
        if staleness > self.protocol.limits.max_staleness_s:
            raise SafetyTrip(f"sensor stale: newest sample is {staleness:.2f} s old "
                             f"(limit {self.protocol.limits.max_staleness_s:g} s)")
        out.update(self._align_feedback(block.t_s, feedback))
        out["command"] = np.full(len(block), self._command)
        out["seq"] = block.seq if block.seq is not None else np.full(len(block), np.nan)
        # feedback limits count feedback frames as received, not the force samples they are
        # held over: one bad 50 Hz frame would otherwise count as 20 samples at 1 kHz
        self.limits.check({"thrust_n": out["thrust_n"], "torque_nm": ft[:, self._torque_idx]})
        self.limits.check({"temperature_c": block.temperature_c}, "sensor")
        self.limits.check(feedback_limits(feedback, self._power_limited), "actuator")
        self.follow.check(feedback)
        self._check_bus(step, feedback)
        if step is not None and self.reporter.wants_live:
            thrust = float(out["thrust_n"].mean()) if len(block) else None
            self.reporter.live(step, thrust, self._command)  # the reading of the command sent
        return out

    def _check_bus(self, step: PlanStep | None, feedback: FeedbackBlock) -> None:
        """The bus voltage must be the one the point is labelled with (BusVoltageMonitor)."""
        if step is None or step.voltage_v is None or step.voltage_v != self._voltage:
            return
        volts = feedback.voltage_v
        if volts is not None and len(volts) and np.isfinite(volts).any():
            self.bus.check_feedback(step.voltage_v, float(np.nanmedian(volts)))
        if self.bus.supply_due(self.clock.now()):
            self._check_supply(step.voltage_v)

    def _check_supply(self, set_v: float) -> None:
        """The supply's own measurement of its terminals, where it has one."""
        supply = self.rig.supply
        measure = getattr(supply, "measure", None)
        if measure is None:
            return
        measured_v, amps = measure()
        self.limits.check({"bus_v": np.array([measured_v]),
                           "power_w": np.array([measured_v * amps])}, "supply")
        self.bus.check_supply(set_v, measured_v, supply.reached_by, amps,
                              getattr(supply, "current_limit_a", None))

    def _device_warnings(self, step: PlanStep | None) -> None:
        """Store warnings a driver has queued (e.g. a Net F/T status word, a stream restart)."""
        for dev in (self.rig.sensor, self.rig.actuator):
            pop = getattr(dev, "pop_warnings", None)
            for message in pop() if pop else ():
                self.reporter.note(f"warning: {message}")
                self._event("warning", {"message": message}, None if step is None else step.idx)

    def _align_feedback(self, t: np.ndarray, fb: FeedbackBlock) -> dict[str, np.ndarray]:
        """Feedback at each force sample's time: the latest feedback value received (zero-order hold)."""
        out = {}
        same_times = len(fb) == len(t) and len(t) and (
            fb.t_s is t or (fb.t_s[0] == t[0] and fb.t_s[-1] == t[-1]))
        idx = None
        if not same_times and len(fb):
            idx = np.searchsorted(fb.t_s, t, side="right") - 1
        for name in FEEDBACK_FIELDS:
            values = getattr(fb, name)
            if values is None or (idx is None and not same_times):
                out[name] = np.full(len(t), self._fb_last[name])
                continue
            held = values if same_times else np.where(idx >= 0, values[np.clip(idx, 0, None)],
                                                      self._fb_last[name])
            self._fb_last[name] = values[-1]
            out[name] = held
        return out

    def _read_for(self, seconds: float, rate: float, step: PlanStep) -> float:
        """Read and discard `seconds` of samples (monitoring limits); return the mean thrust.

        Blocks are folded into a running sum past FOLD_SAMPLES, so a day-long settle or rest
        needs no more memory than a short one.
        """
        n_total = max(1, round(seconds * rate))
        chunk = max(1, round(CHUNK_S * rate))
        thrust: list[np.ndarray] = []
        held = folded = 0
        total = 0.0
        while n_total > 0:
            n = min(chunk, n_total)
            thrust.append(self._read(n, rate, step)["thrust_n"])
            held += len(thrust[-1])
            n_total -= n
            if held > FOLD_SAMPLES:
                total += float(np.sum(np.concatenate(thrust)))
                folded, held, thrust = folded + held, 0, []
        if not folded:
            return float(np.mean(np.concatenate(thrust)))
        return (total + float(np.sum(np.concatenate(thrust) if thrust else 0.0))) / (folded + held)

    def _settle(self, step: PlanStep, rate: float) -> tuple[float, bool]:
        """Wait for the point to settle; return (seconds waited, whether the criterion was met)."""
        settle = self.protocol.timing.settle
        sent = self.clock.now()
        if settle.seconds is not None:
            if settle.seconds > 0:
                self._read_for(settle.seconds, rate, step)
                self._catch_up(sent + settle.seconds, rate, step)
            return settle.seconds, True
        crit = settle.until_steady
        t0 = self._now()
        if crit.min_s > 0:
            self._read_for(crit.min_s, rate, step)
        previous = self._read_for(crit.window_s, rate, step)
        while True:
            current = self._read_for(crit.window_s, rate, step)
            waited = self._now() - t0
            if abs(current - previous) < crit.tolerance_n:
                self._catch_up(sent + waited, rate, step)
                return waited, True
            if waited >= crit.timeout_s:
                self._event("warning", {"message": f"point {step.idx} did not settle within "
                                        f"{crit.timeout_s:g} s; acquiring anyway"}, step.idx)
                return waited, False
            previous = current

    def _catch_up(self, until: float, rate: float, step: PlanStep) -> None:
        """Read on, discarding, until the newest sample is stamped at `until` (clock time):
        settling counts samples, and a reader that fell behind (a busy machine) hands over
        samples taken before the command was sent, which must not be the point's."""
        behind = until - self._newest_t - CATCH_UP_SLACK / rate
        if not behind > 0:
            return
        chunk = max(1, round(CHUNK_S * rate))
        for _ in range(MAX_CATCH_UP_READS):
            if self._newest_t >= until - CATCH_UP_SLACK / rate:
                break
            n = min(chunk, max(1, math.ceil((until - self._newest_t) * rate)))
            self._read(n, rate, step)
        if behind < LAG_WARN_S:
            return
        self._event("warning", {"message": f"point {step.idx}: the sensor's samples lagged "
                                f"the clock by {behind:.3g} s as it settled (a busy machine?); "
                                "samples stamped before the settling time ended were "
                                "discarded"}, step.idx)

    def _acquire(self, step: PlanStep, n_total: int, rate: float) -> SampleSpool:
        """Read the point's samples into a spool: memory stays bounded by the block size.
        A sensor at a multiple of the protocol's rate is averaged down to it as it is read."""
        k = self.timing.decimate
        chunk = max(1, round(CHUNK_S * rate))
        chunk += -chunk % k  # whole groups of k in every block
        spool = SampleSpool(SAMPLE_COLUMNS[1:], STAT_FIELDS, spill_dir=self.store.path.parent)
        remaining = n_total
        try:
            while remaining > 0:
                n = min(chunk, remaining)
                block = self._read(n, rate, step)
                spool.add(block if k == 1 else decimated(block, k))
                remaining -= n
        except BaseException:
            spool.close()
            raise
        return spool

    def _tare(self, why: str, step_idx: int | None = None) -> None:
        """Re-zero the sensor at neutral (and in still water) from `tare_s` seconds of readings."""
        self._ramp_to(self.rig.actuator.info.neutral)
        self._stop_carriage()
        rate = self.timing.sensor_rate_hz
        n = max(1, round(self.protocol.timing.tare_s * rate))
        parts, remaining = [], n
        while remaining > 0:  # one read as before; in blocks only beyond FOLD_SAMPLES
            block = self.rig.sensor.read(min(remaining, FOLD_SAMPLES), rate)
            self.samples_read += len(block)
            remaining -= FOLD_SAMPLES
            feedback = self.rig.actuator.read_feedback()
            if feedback.fault:
                raise SafetyTrip(f"driver fault: {feedback.fault}")
            # feedback limits hold at neutral too; thrust is not checked: the bias is not removed yet
            self.limits.check({"temperature_c": block.temperature_c}, "sensor")
            self.limits.check(feedback_limits(feedback, self._power_limited), "actuator")
            parts.append(block.ft.mean(axis=0) if n <= FOLD_SAMPLES else block.ft.sum(axis=0))
        offset = parts[0] if n <= FOLD_SAMPLES else np.sum(parts, axis=0) / n
        self.rig.sensor.set_bias(offset)
        self._bias_total = self._bias_total + offset
        self._event("tare", {"why": why, "bias": self._bias_total.tolist(),
                             "offset": offset.tolist(), "n": n}, step_idx)
