"""The follow check: a held command whose feedback does not follow it trips, never a stored point.

Unit tests of FollowMonitor on synthetic first-order speed traces, then the engine on the
simulator twin. The same check over real transports (VESC twin on a python-can bus) is in
test_run_labels.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from rigtool.devices.base import ActuatorInfo, FeedbackBlock
from rigtool.engine import Engine
from rigtool.errors import SafetyTrip
from rigtool.safety import FollowMonitor
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

RATE_HZ = 50.0  # VESC status rate
TAU_S = 0.3
NOISE_RPM = 15.0
INFO = ActuatorInfo("percent", 0.0, -100.0, 100.0, ("speed_rpm", "current_a", "voltage_v"))


def trace(t0_s: float, seconds: float, start_rpm: float, target_rpm: float,
          stop_at_s: float | None = None, seed: int = 0, noise_rpm: float = NOISE_RPM,
          step_rpm: float = 0.0) -> FeedbackBlock:
    """First-order speed from `start_rpm` towards `target_rpm` (towards 0 after `stop_at_s`),
    with white noise, reported in steps of `step_rpm` (0: not quantised)."""
    rng = np.random.default_rng(seed)
    t = t0_s + np.arange(0, seconds, 1 / RATE_HZ)
    n = target_rpm + (start_rpm - target_rpm) * np.exp(-(t - t0_s) / TAU_S)
    if stop_at_s is not None:
        at = t0_s + stop_at_s
        n_stop = target_rpm + (start_rpm - target_rpm) * np.exp(-stop_at_s / TAU_S)
        n = np.where(t < at, n, n_stop * np.exp(-(t - at) / TAU_S))
    n = n + rng.normal(0, noise_rpm, t.size)
    return FeedbackBlock(t, speed_rpm=np.round(n / step_rpm) * step_rpm if step_rpm else n)


def feed(monitor: FollowMonitor, block: FeedbackBlock, read_s: float = 0.2) -> None:
    """Hand the block over in engine-sized reads."""
    edges = np.arange(block.t_s[0], block.t_s[-1] + read_s, read_s)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (block.t_s >= lo) & (block.t_s < hi)
        monitor.check(FeedbackBlock(block.t_s[m], speed_rpm=block.speed_rpm[m]))


def held(monitor: FollowMonitor, command: float, block: FeedbackBlock) -> None:
    monitor.start_point()
    monitor.hold(command, float(block.t_s[0]))
    feed(monitor, block)


@pytest.mark.parametrize("start_rpm", [0.0, 350.0, -360.0])  # from rest, or after a short rest
def test_a_drive_that_stops_while_the_command_is_held_trips(start_rpm):
    monitor = FollowMonitor(INFO)
    with pytest.raises(SafetyTrip, match="not following the command.*fell from") as info:
        held(monitor, 40.0, trace(10.0, 3.0, start_rpm, 720.0, stop_at_s=0.5))
    assert info.value.detail["check"] == "follow" and 0.7 < info.value.detail["held_s"] < 1.3


@pytest.mark.parametrize(("start_rpm", "target_rpm"), [
    (3800.0, 0.0),  # a dead-zone command after full speed, no rest: the speed only decays
    (-1800.0, 0.0),  # same from full reverse
    (-1800.0, 180.0),  # reversal to a small command: through zero, then up
    (1800.0, 180.0),  # big to small, same direction
    (0.0, 720.0),  # an ordinary point
    (20.0, 22.0),  # inside the noise
])  # fmt: skip
@pytest.mark.parametrize(("noise_rpm", "step_rpm"), [(NOISE_RPM, 0.0), (0.0, 1.0), (0.3, 1.0)])
def test_settling_and_dead_zones_never_trip(start_rpm, target_rpm, noise_rpm, step_rpm):
    monitor = FollowMonitor(INFO)
    for seed in range(20):
        held(monitor, 10.0, trace(0.0, 4.0, start_rpm, target_rpm, seed=seed,
                                  noise_rpm=noise_rpm, step_rpm=step_rpm))


def test_the_command_map_catches_a_drive_that_never_starts():
    monitor = FollowMonitor(INFO, speed_map=lambda c: 18.0 * c)  # 1800 r/min at 100 %
    with pytest.raises(SafetyTrip, match=r"expected about 720") as info:
        held(monitor, 40.0, trace(0.0, 2.0, 0.0, 0.0))
    assert 1.3 <= info.value.detail["held_s"] <= 1.5  # checked from 1 s of hold, two windows
    held(monitor, 40.0, trace(0.0, 3.0, -1800.0, 720.0))  # settling from full reverse is fine
    held(monitor, 2.0, trace(0.0, 3.0, 0.0, 0.0))  # below 10 % of full speed: not checked


def test_without_speed_or_current_feedback_nothing_is_checked():
    monitor = FollowMonitor(ActuatorInfo("pwm_counts", 0.0, 0.0, 799.0, ()))
    assert monitor.signal is None
    monitor.start_point()
    monitor.hold(400.0, 0.0)
    monitor.check(FeedbackBlock(np.arange(0, 3, 0.02)))  # timestamps only, like the bridge


def test_only_the_held_command_is_judged():
    monitor = FollowMonitor(INFO)
    block = trace(0.0, 3.0, 0.0, 720.0, stop_at_s=1.0)
    monitor.start_point()
    feed(monitor, block)  # never held (still ramping): not judged
    monitor.hold(40.0, 0.0)
    monitor.release()  # ramping back to neutral: the speed falls, as it should
    feed(monitor, trace(3.0, 2.0, 720.0, 0.0))


SIM_PROTOCOL = """\
rigtool_protocol: 1
name: follow
simulator: {profile: PROFILE, seed: 3}
command: {unit: UNIT, values: VALUES, order: ORDER}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 1.5}
  acquire: {samples: 250, rate_hz: 500}
  rest_s: 0
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 90}
"""


def _protocol(profile: str, unit: str, values: list[float], order: str = "up") -> str:
    return (SIM_PROTOCOL.replace("PROFILE", profile).replace("UNIT", unit)
            .replace("VALUES", str(values)).replace("ORDER", order))


class ForwardDeafActuator:
    """The twin's actuator behind a drive that stops hearing commands once one is positive."""

    def __init__(self, inner):
        self.inner, self.info, self.deaf = inner, inner.info, False
        self.expected_speed_rpm = inner.expected_speed_rpm

    def set_command(self, value):
        self.deaf = self.deaf or value > 0
        if not self.deaf:
            self.inner.set_command(value)

    def neutral(self):
        self.inner.neutral()

    def read_feedback(self):
        return self.inner.read_feedback()

    def close(self):
        self.inner.close()


def _run(setup, rigset, db_path):
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    return store, Engine(setup.protocol, setup.plan, rigset, store, run_id).run()


def test_engine_trips_a_point_whose_speed_never_comes_and_stores_nothing_of_it(write_yaml, db_path):
    setup = resolve(write_yaml(_protocol("can-bldc", "percent", [-50, 50])), sim=True)
    rigset = open_checked(setup)
    rigset.actuator = ForwardDeafActuator(rigset.actuator)
    store, outcome = _run(setup, rigset, db_path)
    assert outcome.status == "aborted" and "not following" in outcome.reason
    assert [s["command"] for s in store.steps(outcome.run_id)] == [-50]
    (trip,) = store.events(outcome.run_id, "limit_trip")
    assert trip["detail"]["check"] == "follow" and trip["detail"]["expected"] == pytest.approx(900)
    assert rigset.actuator.inner.command == 0.0


def test_engine_dead_zone_points_after_full_speed_do_not_trip(write_yaml, db_path):
    """ESC twin, no rest and no slew: dead-zone commands right after full speed either way."""
    values = [1100, 1490, 1510, 1900]  # up: 1100 -> 1490; down: 1900 -> 1900 -> 1510
    setup = resolve(write_yaml(_protocol("esc-1100-1900", "pulse_us", values, "up-down")), sim=True)
    store, outcome = _run(setup, open_checked(setup), db_path)
    assert outcome.status == "completed", outcome.reason
    steps = store.steps(outcome.run_id)
    assert len(steps) == 8
    assert all(abs(s["speed_all_mean_rpm"]) < 20 for s in steps if s["command"] in (1490, 1510))
    assert min(s["speed_all_mean_rpm"] for s in steps) < -3500 < 3500 < max(s["speed_all_mean_rpm"] for s in steps)
