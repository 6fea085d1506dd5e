"""Towing carriage (or flume pump) with a rotary stage, over a serial line protocol.

Protocol (docs/drivers/serial-carriage.md): `FLOW <m/s> <deg>` -> `OK`, later
`DONE <m/s> <deg>` once the speed is reached (the carriage stops before it turns to a new
angle); `STATE?` -> `STATE <m/s> <deg>`; `STOP` -> `OK`, and a carriage that was moving
ends with `DONE 0 <deg>` at rest; refusals are `ERR <reason>`. Speeds are signed (negative:
the flow comes from astern), angles are the yaw or attack angle of the held vehicle.
"""

from __future__ import annotations

import contextlib
import math
import re
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from rigtool.bounds import MAX_FLOW_MPS, Baudrate, PositiveSeconds
from rigtool.devices.line_protocol import LineProtocolDevice
from rigtool.errors import DeviceError, UsageError

_LINE = re.compile(r"(?P<kind>OK|ERR|DONE|STATE)(?:\s+(?P<arg>.*?))?\s*")
Speed = Annotated[float, Field(gt=0, le=MAX_FLOW_MPS, allow_inf_nan=False)]


class SerialCarriageConfig(BaseModel):
    """Rig-file section for the serial carriage (`driver: serial-carriage`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["serial-carriage"]
    url: str = Field(min_length=1)  # pyserial URL: /dev/ttyUSB0, socket://host:port
    baudrate: Baudrate = 115200  # ignored by socket:// and loop://
    max_speed_mps: Speed = 2.0  # soft limit on |speed|
    accel_mps2: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = 0.5  # for timeouts
    turn_deg_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = 10.0  # for timeouts
    min_angle_deg: Annotated[float, Field(ge=-180, le=180)] = -90.0  # soft limits on the angle
    max_angle_deg: Annotated[float, Field(ge=-180, le=180)] = 90.0
    timeout_s: PositiveSeconds = 2.0  # reply timeout, and slack added to every move

    @model_validator(mode="after")
    def _limits(self) -> SerialCarriageConfig:
        if not self.min_angle_deg < self.max_angle_deg:
            raise ValueError("need min_angle_deg < max_angle_deg")
        return self


class SerialCarriage(LineProtocolDevice):
    """Carriage driver: sets the flow speed and angle and reports what was reached."""

    reached_by = "carriage"
    line_pattern = _LINE

    def __init__(self, config: SerialCarriageConfig) -> None:
        self.config = config
        self.name = f"serial carriage on {config.url}"
        self._open_port(config.url, config.baudrate, config.timeout_s, "serial carriage")
        try:
            self.state()
        except DeviceError:
            self.close()
            raise

    # -- Carriage -------------------------------------------------------------------------
    def set_flow(self, speed_mps: float, angle_deg: float) -> tuple[float, float]:
        """Reach `speed_mps` at `angle_deg`; block until DONE; return (speed, angle) reached."""
        cfg = self.config
        if not (math.isfinite(speed_mps) and abs(speed_mps) <= cfg.max_speed_mps):
            raise UsageError(f"speed {speed_mps!r} m/s beyond the soft limit "
                             f"{cfg.max_speed_mps:g} m/s of {self.name}")
        if not (math.isfinite(angle_deg) and cfg.min_angle_deg <= angle_deg <= cfg.max_angle_deg):
            raise UsageError(f"angle {angle_deg!r} deg outside the soft limits "
                             f"{cfg.min_angle_deg:g}..{cfg.max_angle_deg:g} deg of {self.name}")
        speed0, angle0 = self.state()
        self._request(f"FLOW {speed_mps:.4f} {angle_deg:.3f}", "OK")
        turn = abs(angle_deg - angle0)
        budget = ((abs(speed0) + abs(speed_mps)) / cfg.accel_mps2 if turn else
                  abs(speed_mps - speed0) / cfg.accel_mps2) + turn / cfg.turn_deg_s + cfg.timeout_s
        return self._wait_done(budget, f"reach {speed_mps:g} m/s at {angle_deg:g} deg")

    def stop(self) -> None:
        """Speed 0 and wait until the carriage is at rest (or its time is up)."""
        speed, _ = self.state()
        self._request("STOP", "OK")
        if speed != 0:
            self._wait_done(abs(speed) / self.config.accel_mps2 + self.config.timeout_s, "stop")

    def state(self) -> tuple[float, float]:
        """The carriage's reported (speed m/s, angle deg)."""
        return _pair(self._request("STATE?", "STATE"), self.name)

    def _safe_state(self) -> None:
        """Speed 0 on `close`."""
        self.stop()

    # -- internals ------------------------------------------------------------------------
    def _wait_done(self, budget_s: float, what: str) -> tuple[float, float]:
        try:
            return _pair(self._expect("DONE", budget_s, what), self.name)
        except DeviceError as exc:
            if what != "stop":
                with contextlib.suppress(DeviceError):
                    self._request("STOP", "OK")
            raise DeviceError(str(exc)) from None


def _pair(text: str | None, name: str) -> tuple[float, float]:
    """(speed, angle) from a `DONE`/`STATE` argument; DeviceError when it is not two numbers."""
    try:
        speed, angle = (float(x) for x in (text or "").split())
    except ValueError:
        raise DeviceError(f"{name}: expected '<m/s> <deg>', got {text!r}") from None
    if not (math.isfinite(speed) and math.isfinite(angle)):
        raise DeviceError(f"{name}: expected finite speed and angle, got {text!r}")
    return speed, angle
