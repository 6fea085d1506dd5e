"""In-process device twins: the physics twin behind the Actuator/ForceSensor/DepthStage interfaces.

These are the embedded simulator used by `rigtool sweep --sim`. They share one clock
and one ThrusterTwin, so the engine drives them exactly as it drives hardware.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.devices.base import ActuatorInfo, Clock, Device, FeedbackBlock, ForceBlock
from rigtool.sim.flow import CaptiveFlow
from rigtool.sim.physics import ThrusterTwin

STAGE_SPEED_M_S = 0.05
STAGE_SETTLE_S = 2.0
SUPPLY_SLEW_V_S = 10.0  # simulated supply's voltage ramp
SUPPLY_RAMP_S = 0.05  # a new setpoint this often while ramping


class SimWorld:
    """The shared state of one simulated rig: clock, twin, and feedback waiting to be read."""

    def __init__(self, twin: ThrusterTwin, clock: Clock) -> None:
        self.twin = twin
        self.clock = clock
        self.feedback: list[FeedbackBlock] = []
        self.flow: CaptiveFlow | None = None  # the held vehicle of a captive run

    def wait_until(self, t: float) -> None:
        """Let time pass until `t` (instant on a virtual clock)."""
        delay = t - self.clock.now()
        if hasattr(self.clock, "advance_to"):
            self.clock.advance_to(t)
        elif delay > 0:
            self.clock.sleep(delay)


class SimActuator(Device):
    """The twin's motor driver: commands in the profile's unit, feedback as the profile allows."""

    def __init__(self, world: SimWorld) -> None:
        p = world.twin.profile
        self.world = world
        self.info = ActuatorInfo(
            p.command_unit, p.neutral, p.command_min, p.command_max, tuple(p.feedback)
        )
        self.command = p.neutral

    def set_command(self, value: float) -> None:
        self.command = float(value)
        twin = self.world.twin
        twin.set_command(max(self.world.clock.now(), twin.t_s), self.command)

    def neutral(self) -> None:
        self.set_command(self.info.neutral)

    def expected_speed_rpm(self, command: float) -> float:
        """The twin's steady speed at `command` (its command map), for the follow check."""
        return self.world.twin.steady_state(command)[0]

    def read_feedback(self) -> FeedbackBlock:
        blocks, self.world.feedback = self.world.feedback, []
        if not blocks:
            return FeedbackBlock(np.empty(0))
        one = len(blocks) == 1  # the usual read: one sensor block, nothing to join
        t = blocks[0].t_s if one else np.concatenate([b.t_s for b in blocks])
        fields = {}
        for name in ("speed_rpm", "current_a", "voltage_v", "temperature_c"):
            if name not in self.info.feedback:
                fields[name] = None
            elif one:
                fields[name] = getattr(blocks[0], name)
            else:
                fields[name] = np.concatenate([getattr(b, name) for b in blocks])
        return FeedbackBlock(t, **fields)


class SimForceSensor(Device):
    """The twin's force sensor: six channels at the requested rate, with bias and noise."""

    channels = ("fx", "fy", "fz", "tx", "ty", "tz")
    follows_rate = True  # samples at whatever rate the engine asks (rigtool/sensor_rate.py)

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self._bias = np.zeros(6)
        self._next_t: float | None = None
        self._seq = 0

    def read(self, n: int, rate_hz: float) -> ForceBlock:
        now = self.world.clock.now()
        start = now if self._next_t is None or self._next_t < now else self._next_t
        t = start + np.arange(n) / rate_hz
        out = self.world.twin.sample(t)
        self.world.wait_until(float(t[-1]))
        self._next_t = float(t[-1]) + 1.0 / rate_hz
        self.world.feedback.append(FeedbackBlock(t, out.speed_rpm, out.current_a, out.voltage_v,
                                                 temperature_c=out.temperature_c))
        seq = np.arange(self._seq, self._seq + n)
        self._seq += n
        ft = out.ft if self.world.flow is None else out.ft + self.world.flow.loads(t)
        return ForceBlock(t, ft - self._bias, seq)

    def set_bias(self, bias: np.ndarray) -> None:
        self._bias = self._bias + np.asarray(bias, dtype=float)


class SimDepthStage(Device):
    """A motorised truss on the twin: takes time to move, then the twin sees the new depth."""

    reached_by = "simulator"

    def __init__(self, world: SimWorld) -> None:
        self.world = world

    def move_to(self, depth_m: float) -> float:
        travel = abs(depth_m - self.world.twin.depth_m)
        if travel > 0:
            self.world.clock.sleep(travel / STAGE_SPEED_M_S + STAGE_SETTLE_S)
        self.world.twin.set_depth(self.world.clock.now(), depth_m)
        return depth_m


class SimSupply(Device):
    """The twin's programmable supply: ramps at `slew_v_per_s` in the world's time, then the
    twin runs on the new voltage; `safe()` switches the output off (0 V)."""

    reached_by = "simulator"

    def __init__(self, world: SimWorld, slew_v_per_s: float = SUPPLY_SLEW_V_S) -> None:
        self.world = world
        self.slew_v_per_s = slew_v_per_s

    def set_voltage(self, volts: float) -> float:
        """Ramp to `volts`; return the bus voltage measured at the end (the sag included)."""
        twin, clock = self.world.twin, self.world.clock
        start = twin.supply_voltage_v
        steps = max(1, math.ceil(abs(volts - start) / self.slew_v_per_s / SUPPLY_RAMP_S))
        for k in range(1, steps + 1):
            if k > 1:
                clock.sleep(SUPPLY_RAMP_S)
            twin.set_supply_voltage(max(clock.now(), twin.t_s), start + (volts - start) * k / steps)
        return self.measure()[0]

    def measure(self) -> tuple[float, float]:
        """(volts, amps) at the supply's terminals, as a supply in constant-voltage mode
        measures them: the setpoint (the sag is in the leads, after them) and the current."""
        twin = self.world.twin
        _, _, amps = twin.steady_state(twin.command)
        if twin.supply_voltage_v <= 0:
            return 0.0, 0.0
        return twin.supply_voltage_v, amps

    def safe(self) -> None:
        twin = self.world.twin
        twin.set_supply_voltage(max(self.world.clock.now(), twin.t_s), 0.0)

    def _safe_state(self) -> None:
        """Output off on `close`."""
        self.safe()


class SimCarriage(Device):
    """The twin's towing carriage (or flume pump) and rotary stage: the flow reaches a new speed
    with its lag, in the world's time; the angle turns with the flow stopped."""

    reached_by = "simulator"

    def __init__(self, world: SimWorld, flow: CaptiveFlow) -> None:
        self.world = world
        self.flow = flow
        world.flow = flow

    def set_flow(self, speed_mps: float, angle_deg: float) -> tuple[float, float]:
        """Stop to turn when the angle changes, then reach `speed_mps`; return what was reached."""
        if angle_deg != self.flow.angle_deg:
            self._reach(0.0)
            self.flow.set_angle(angle_deg)
        return self._reach(speed_mps), self.flow.angle_deg

    def stop(self) -> None:
        """Speed 0, waiting until the flow is at rest (as the real driver waits for DONE)."""
        self._reach(0.0)

    def _reach(self, speed_mps: float) -> float:
        clock = self.world.clock
        self.flow.set_speed(clock.now(), speed_mps)
        self.world.wait_until(self.flow.settled_at(clock.now()))
        return float(self.flow.speed_at(clock.now()))

    def _safe_state(self) -> None:
        """Speed 0 on `close`."""
        self.stop()
