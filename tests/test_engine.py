"""The engine on the simulator twin: storage, statistics, and safe exits on every path."""

from __future__ import annotations

import dataclasses
import os
import signal

import numpy as np
import pytest

from rigtool.engine import Engine
from rigtool.errors import SafetyTrip
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

from .conftest import SMALL_PROTOCOL

pytestmark = pytest.mark.usefixtures("terminal_signals")  # the Ctrl-C, SIGTERM and SIGHUP tests, and the handlers they restore


class RecordingActuator:
    """Wraps the twin's actuator and records every command it is sent."""

    def __init__(self, inner):
        self.inner = inner
        self.info = inner.info
        self.sent: list[float] = []

    def set_command(self, value):
        self.sent.append(value)
        self.inner.set_command(value)

    def neutral(self):
        self.sent.append(self.info.neutral)
        self.inner.neutral()

    def read_feedback(self):
        return self.inner.read_feedback()

    def close(self):
        self.inner.close()


class FaultySensor:
    """Wraps the twin's sensor; on read number `at` it runs `action` (raise, or send a signal)."""

    def __init__(self, inner, at: int, action):
        self.inner = inner
        self.channels = inner.channels
        self.reads = 0
        self.at = at
        self.action = action

    def read(self, n, rate_hz):
        self.reads += 1
        if self.reads == self.at:
            self.action()
        return self.inner.read(n, rate_hz)

    def set_bias(self, bias):
        self.inner.set_bias(bias)

    def close(self):
        self.inner.close()


def _setup(write_yaml, text=SMALL_PROTOCOL):
    setup = resolve(write_yaml(text), sim=True)
    rigset = open_checked(setup)
    rigset.actuator = RecordingActuator(rigset.actuator)
    return setup, rigset


def _run(setup, rigset, db_path):
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    return store, outcome


def test_all_points_stored_and_stats_match_samples(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "completed" and outcome.steps_done == 4
    steps = store.steps(outcome.run_id)
    assert [s["command"] for s in steps] == [-50, 0, 50, 100]
    samples = store.samples(outcome.run_id, ["step_id", "t_s", "thrust_n", "speed_rpm", "current_a", "command"])
    assert samples["t_s"].size == 4 * 200
    for s in steps:
        mask = samples["step_id"] == s["id"]
        thrust = samples["thrust_n"][mask]
        assert s["n"] == 200 == mask.sum()
        assert s["thrust_all_mean_n"] == pytest.approx(thrust.mean())
        assert s["thrust_all_std_n"] == pytest.approx(thrust.std(ddof=1))
        assert s["thrust_all_max_n"] == pytest.approx(thrust.max())
        assert s["speed_all_mean_rpm"] == pytest.approx(samples["speed_rpm"][mask].mean())
        assert np.all(samples["command"][mask] == s["command"])
        assert np.all(np.diff(samples["t_s"][mask]) > 0)
    # thrust follows the command through the physics: reverse negative, forward positive
    means = [s["thrust_all_mean_n"] for s in steps]
    assert means[0] < -3 and abs(means[1]) < 0.5 and means[3] > means[2] > 3
    assert rigset.actuator.sent[-1] == 0.0
    assert [e["kind"] for e in store.events(outcome.run_id)][:3] == ["run_start", "tare", "depth"]


def test_depth_events_say_who_reported_the_depth(write_yaml, db_path):
    setup, rigset = _setup(write_yaml, SMALL_PROTOCOL.replace("values: [1.0]", "values: [0.5, 1.0]"))
    store, outcome = _run(setup, rigset, db_path)
    assert [e["detail"] for e in store.events(outcome.run_id, "depth")] == [
        {"target_m": 0.5, "reached_m": 0.5, "by": "simulator"},
        {"target_m": 1.0, "reached_m": 1.0, "by": "simulator"}]


def test_a_preset_depth_is_never_recorded_as_reached(write_yaml, db_path):
    from rigtool.devices.depth import PresetDepth

    setup, rigset = _setup(write_yaml)
    rigset.depth_stage = PresetDepth()  # a hardware rig without a stage: nothing sets the depth
    store, outcome = _run(setup, rigset, db_path)
    (depth,) = store.events(outcome.run_id, "depth")
    assert depth["detail"] == {"target_m": 1.0, "reached_m": None, "by": "preset"}


def test_slew_limit_ramps_the_command(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    _run(setup, rigset, db_path)
    sent = np.array(rigset.actuator.sent)
    # 400 %/s at 50 ms updates: never more than 20 % between consecutive commands
    assert np.max(np.abs(np.diff(sent))) <= 20 + 1e-9


def test_exception_in_sensor_leaves_neutral_and_marks_failed(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)

    def boom():
        raise OSError("sensor cable pulled")

    rigset.sensor = FaultySensor(rigset.sensor, at=25, action=boom)
    with pytest.raises(OSError):
        _run(setup, rigset, db_path)
    store = Store(db_path)
    run = store.runs()[0]
    assert run["status"] == "failed"
    assert rigset.actuator.sent[-1] == 0.0
    assert rigset.actuator.inner.command == 0.0
    # completed points are whole: every stored step has all its samples
    for s in store.steps(run["id"]):
        assert s["n"] == 200


def test_first_ctrl_c_finishes_point_then_aborts(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    rigset.sensor = FaultySensor(rigset.sensor, at=12,
                                 action=lambda: os.kill(os.getpid(), signal.SIGINT))
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "Ctrl-C" in outcome.reason
    steps = store.steps(outcome.run_id)
    assert 1 <= len(steps) < 4 and all(s["n"] == 200 for s in steps)
    assert rigset.actuator.sent[-1] == 0.0
    assert store.run(outcome.run_id)["status"] == "aborted"


def test_second_ctrl_c_stops_at_once(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)

    def twice():
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)

    rigset.sensor = FaultySensor(rigset.sensor, at=12, action=twice)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "second Ctrl-C" in outcome.reason
    steps = store.steps(outcome.run_id)
    assert len(steps) == outcome.steps_done and all(s["n"] == 200 for s in steps)
    assert rigset.actuator.sent[-1] == 0.0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_at_neutral(write_yaml, db_path, sig):
    setup, rigset = _setup(write_yaml)
    rigset.sensor = FaultySensor(rigset.sensor, at=20, action=lambda: os.kill(os.getpid(), sig))
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and signal.Signals(sig).name in outcome.reason
    assert rigset.actuator.sent[-1] == 0.0
    # the handlers are restored afterwards
    assert signal.getsignal(sig) is not None and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_limit_trip_aborts_with_event(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20")
    setup, rigset = _setup(write_yaml, text)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "limit trip" in outcome.reason
    assert [s["command"] for s in store.steps(outcome.run_id)] == [-50, 0, 50]
    trips = store.events(outcome.run_id, "limit_trip")
    assert len(trips) == 1 and "thrust_n" in trips[0]["detail"]["message"]
    assert rigset.actuator.sent[-1] == 0.0


def test_limit_monitor_debounces():
    from rigtool.protocol import Limits
    from rigtool.safety import LimitMonitor

    mon = LimitMonitor(Limits(max_thrust_n=10, debounce_samples=3))
    mon.check({"thrust_n": np.array([0, 11, 11, 0, 11, 0])})  # runs of 2 and 1: no trip
    mon.check({"thrust_n": np.array([0, 0, 11, 11])})
    with pytest.raises(SafetyTrip):  # the run continues across blocks: 2 + 1 = 3
        mon.check({"thrust_n": np.array([-11, 0])})
    mon.reset()
    mon.check({"thrust_n": np.array([np.nan] * 10), "current_a": None})


def test_until_steady_settling_records_settle_time(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace(
        "settle: {seconds: 0.5}",
        "settle:\n    until_steady: {window_s: 0.2, tolerance_n: 0.5, timeout_s: 3}")
    setup, rigset = _setup(write_yaml, text)
    store, outcome = _run(setup, rigset, db_path)
    steps = store.steps(outcome.run_id)
    assert outcome.status == "completed"
    assert all(0.39 <= s["settle_s"] <= 3.5 for s in steps)
    assert all(s["settled"] == 1 for s in steps)


class StaleSensor(FaultySensor):
    """From read `at` on, returns samples that are seconds old (a stalled stream)."""

    def read(self, n, rate_hz):
        block = super().read(n, rate_hz)
        if self.reads >= self.at:
            block.t_s = block.t_s - 5.0
        return block


class FaultyActuator(RecordingActuator):
    """Reports a driver fault in its feedback after `at` feedback reads."""

    def __init__(self, inner, at):
        super().__init__(inner)
        self.at, self.reads = at, 0

    def read_feedback(self):
        fb = self.inner.read_feedback()
        self.reads += 1
        if self.reads >= self.at:
            fb.fault = "over-temperature"
        return fb


def test_stale_sensor_trips_to_neutral(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    rigset.sensor = StaleSensor(rigset.sensor, at=12, action=lambda: None)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "sensor stale" in outcome.reason
    assert rigset.actuator.sent[-1] == 0.0
    assert store.events(outcome.run_id, "limit_trip")


def test_driver_fault_trips_to_neutral(write_yaml, db_path):
    setup, rigset = _setup(write_yaml)
    rigset.actuator = FaultyActuator(rigset.actuator.inner, at=10)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "over-temperature" in outcome.reason
    assert rigset.actuator.sent[-1] == 0.0


def test_lost_device_aborts_with_event_and_neutral(write_yaml, db_path):
    from rigtool.errors import DeviceError

    setup, rigset = _setup(write_yaml)

    def lost():
        raise DeviceError("no samples from Net F/T 127.0.0.1:49152 for 1.0 s")

    rigset.sensor = FaultySensor(rigset.sensor, at=15, action=lost)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "device fault" in outcome.reason
    assert store.events(outcome.run_id, "device_fault")
    assert rigset.actuator.sent[-1] == 0.0


def test_pause_on_trip_asks_and_retries_the_point(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20\n  on_trip: pause")
    setup, rigset = _setup(write_yaml, text)
    questions = []

    def confirm(question):
        questions.append(question)
        return len(questions) == 1  # retry once, then give up

    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id, confirm=confirm).run()
    assert len(questions) == 2 and "Thruster at neutral" in questions[0]
    assert outcome.status == "aborted" and "operator stopped" in outcome.reason
    assert [s["command"] for s in store.steps(run_id)] == [-50, 0, 50]
    assert rigset.actuator.sent[-1] == 0.0
    paused = [e for e in store.events(run_id, "limit_trip") if e["detail"].get("action") == "paused"]
    assert len(paused) == 2 and len(store.events(run_id, "resumed")) == 1


def test_pause_without_an_operator_aborts(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20\n  on_trip: pause")
    setup, rigset = _setup(write_yaml, text)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "limit trip" in outcome.reason


def test_limits_are_checked_during_the_slew_ramp(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 10").replace(
        "slew_per_s: 400", "slew_per_s: 5").replace("[-50, 0, 50, 100]", "[100]")
    setup, rigset = _setup(write_yaml, text)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "limit trip" in outcome.reason
    peak = max(rigset.actuator.sent)
    assert peak < 60, f"the ramp went on to {peak} % past a 10 N limit"
    assert rigset.actuator.sent[-1] == 0.0


def test_pause_after_a_stored_point_continues_without_duplicating(write_yaml, db_path):
    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 90\n  on_trip: pause").replace(
        "rest_s: 0.2", "rest_s: 1.0")
    setup, rigset = _setup(write_yaml, text)
    inner = rigset.actuator.inner
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    fired = []

    class FaultOnceInRest(FaultyActuator):
        def read_feedback(self):
            fb = self.inner.read_feedback()
            if not fired and len(store.steps(run_id)) == 1:  # resting after point 0 was stored
                fired.append(True)
                fb.fault = "transient over-current"
            return fb

    rigset.actuator = FaultOnceInRest(inner, at=0)
    asked = []
    outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id,
                     confirm=lambda q: asked.append(q) or True).run()
    assert outcome.status == "completed", outcome
    assert asked and "Continue with the next point" in asked[0]
    assert [s["idx"] for s in store.steps(run_id)] == [0, 1, 2, 3]


def test_failed_neutral_is_reported_not_hidden(write_yaml, db_path):
    from rigtool.errors import DeviceError

    text = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20")
    setup, rigset = _setup(write_yaml, text)

    class BrokenNeutral(RecordingActuator):
        def neutral(self):
            if len(self.sent) > 2:
                raise DeviceError("port closed")
            super().neutral()

    rigset.actuator = BrokenNeutral(rigset.actuator.inner)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and outcome.neutral_ok is False
    assert store.events(outcome.run_id, "neutral_failed")


class FrameFeedback:
    """Wraps the twin's actuator: feedback as 50 Hz frames (every 10th of 500 Hz samples), with
    current frames `spike` (indices counted over the run) replaced by 50 A."""

    def __init__(self, inner, spike: set[int]):
        self.inner, self.info, self.spike, self.frames = inner, inner.info, spike, 0

    def set_command(self, value):
        self.inner.set_command(value)

    def neutral(self):
        self.inner.neutral()

    def read_feedback(self):
        from dataclasses import replace

        fb = self.inner.read_feedback()
        keep = np.arange(0, len(fb), 10)
        current = fb.current_a[keep].copy()
        for k in range(len(keep)):
            if self.frames + k in self.spike:
                current[k] = 50.0
        self.frames += len(keep)
        return replace(fb, t_s=fb.t_s[keep], speed_rpm=fb.speed_rpm[keep], current_a=current,
                       voltage_v=fb.voltage_v[keep])

    def close(self):
        self.inner.close()


@pytest.mark.parametrize("spike, trips", [({100}, False), ({100, 101}, False),
                                          ({100, 101, 102}, True),
                                          ({40, 41, 42}, True)])  # during the first tare
def test_feedback_limits_count_frames_not_held_samples(write_yaml, db_path, spike, trips):
    text = SMALL_PROTOCOL.replace("  max_thrust_n: 90", "  max_thrust_n: 90\n  max_current_a: 12\n"
                                  "  debounce_samples: 3")
    setup = resolve(write_yaml(text), sim=True)
    rigset = open_checked(setup)
    rigset.actuator = FrameFeedback(rigset.actuator, spike)
    store, outcome = _run(setup, rigset, db_path)
    assert (outcome.status == "aborted") == trips
    assert bool(store.events(outcome.run_id, "limit_trip")) == trips


@pytest.mark.parametrize(("after_s", "alarm"), [(0.0, False), (0.01, True)])
def test_neutral_check_reads_only_feedback_taken_after_neutral(write_yaml, db_path, after_s,
                                                               alarm):
    """A speed reading stamped at the instant neutral was sent was taken before it: it made a
    stopped twin run exit 3 ('may not be at neutral'). One stamped after it still counts."""
    from rigtool.devices.base import FeedbackBlock

    setup, rigset = _setup(write_yaml)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    engine = Engine(setup.protocol, setup.plan, rigset, store, run_id)
    assert "speed_rpm" in rigset.actuator.info.feedback
    now = rigset.clock.now()
    rigset.actuator.inner.world.feedback.append(
        FeedbackBlock(np.array([now + after_s]), speed_rpm=np.array([1060.0])))
    problem = engine._spin_after_neutral()
    assert (problem is not None) == alarm, problem
    if alarm:
        assert "still reads 1060 r/min" in problem


class LaggingSensor(FaultySensor):
    """The twin's sensor behind a reader that fell `lag_s` behind (a busy machine): every
    sample it hands over was taken that long before the clock says."""

    def __init__(self, inner, lag_s: float):
        super().__init__(inner, at=0, action=lambda: None)
        self.lag_s = lag_s

    def read(self, n, rate_hz):
        block = self.inner.read(n, rate_hz)
        return dataclasses.replace(block, t_s=block.t_s - self.lag_s)

    def set_bias(self, bias):
        self.inner.set_bias(bias)


def test_a_lagging_reader_never_hands_a_point_samples_from_before_it_settled(write_yaml,
                                                                            db_path):
    """Settling counts samples; a reader 0.4 s behind would give the point samples taken
    before its 0.5 s settle ended (the -18 % point of issue 49's attack). The engine reads on
    until the samples are stamped after it, and says so."""
    setup, rigset = _setup(write_yaml)
    rigset.sensor = LaggingSensor(rigset.sensor, 0.4)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "completed", outcome.reason
    samples = store.samples(outcome.run_id, ["step_id", "t_s"])
    for s in store.steps(outcome.run_id):
        first = samples["t_s"][samples["step_id"] == s["id"]].min()
        assert first >= s["t_start_s"] + 0.5 - 1 / 500, (s["idx"], first, s["t_start_s"])
    lagged = [e for e in store.events(outcome.run_id, "warning")
              if "lagged" in e["detail"].get("message", "")]
    assert len(lagged) == 4, store.events(outcome.run_id, "warning")
