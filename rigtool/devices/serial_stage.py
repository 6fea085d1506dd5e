"""Motorised linear stage that sets the truss height, over a serial line protocol.

Protocol (docs/drivers/serial-stage.md): `MOVE <mm>` -> `OK`, later `DONE <mm>`;
`POS?` -> `POS <mm>`; `HOME` -> `OK`, later `DONE <mm>`; `STOP` -> `OK` (a move in
progress then ends with its `DONE <mm>`); refusals are `ERR <reason>`. Positions on
the wire are stage millimetres; the driver converts to propeller depth below the
surface with `zero_offset_m` and `direction`.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from rigtool.bounds import Baudrate, DepthM, PositiveSeconds
from rigtool.devices.line_protocol import LineProtocolDevice, ReplyTimeout
from rigtool.errors import DeviceError, UsageError

_LINE = re.compile(r"(?P<kind>OK|ERR|DONE|POS)(?:\s+(?P<arg>.*?))?\s*")


class SerialStageConfig(BaseModel):
    """Rig-file section for the serial linear stage (`driver: serial-stage`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    driver: Literal["serial-stage"]
    url: str = Field(min_length=1)  # pyserial URL: /dev/ttyUSB0, socket://host:port
    baudrate: Baudrate = 115200  # ignored by socket:// and loop://
    speed_mm_s: Annotated[float, Field(gt=0, le=10_000)] = 10.0  # stage speed, for move timeouts
    timeout_s: PositiveSeconds = 2.0  # reply timeout, and slack added to every move
    min_depth_m: DepthM = 0.0  # soft limits on the propeller-centre depth
    max_depth_m: DepthM = 1.5
    zero_offset_m: DepthM = 0.0  # stage position at which the propeller centre is at the surface
    direction: Literal[1, -1] = 1  # +1: larger stage positions put the propeller deeper

    @model_validator(mode="after")
    def _limits(self) -> SerialStageConfig:
        if not self.min_depth_m < self.max_depth_m:
            raise ValueError("need min_depth_m < max_depth_m")
        return self


class SerialStage(LineProtocolDevice):
    """DepthStage driver: moves the truss and reports the depth actually reached."""

    reached_by = "stage"
    line_pattern = _LINE

    def __init__(self, config: SerialStageConfig) -> None:
        self.config = config
        self.name = f"serial stage on {config.url}"
        self._open_port(config.url, config.baudrate, config.timeout_s, "serial stage")
        try:
            self.position_mm()
        except DeviceError:
            self.close()
            raise

    # -- DepthStage -----------------------------------------------------------------------
    def move_to(self, depth_m: float) -> float:
        """Move the propeller centre to `depth_m`; block until DONE; return the depth reached."""
        cfg = self.config
        if not (math.isfinite(depth_m) and cfg.min_depth_m <= depth_m <= cfg.max_depth_m):
            raise UsageError(f"depth {depth_m!r} m outside the soft limits "
                             f"{cfg.min_depth_m:g}..{cfg.max_depth_m:g} m of {self.name}")
        target_mm = self.stage_mm(depth_m)
        start_mm = self.position_mm()
        self._request(f"MOVE {target_mm:.3f}", "OK")
        budget = abs(target_mm - start_mm) / cfg.speed_mm_s + cfg.timeout_s
        reached_mm = self._wait_done(budget, f"reach {target_mm:.3f} mm")
        return self.depth_m(reached_mm)

    # -- extras ---------------------------------------------------------------------------
    def position_mm(self) -> float:
        """The stage's reported position (mm)."""
        return _number(self._request("POS?", "POS"), self.name)

    def home(self) -> float:
        """Run the homing move; return the stage position reached (mm)."""
        start_mm = self.position_mm()
        self._request("HOME", "OK")
        return self._wait_done(abs(start_mm) / self.config.speed_mm_s + self.config.timeout_s,
                               "home")

    def stop(self) -> None:
        """Halt any move in progress."""
        self._request("STOP", "OK")

    def stage_mm(self, depth_m: float) -> float:
        """Stage position that puts the propeller centre at `depth_m`."""
        return (self.config.zero_offset_m + self.config.direction * depth_m) * 1000.0

    def depth_m(self, stage_mm: float) -> float:
        """Propeller-centre depth at stage position `stage_mm`."""
        return self.config.direction * (stage_mm / 1000.0 - self.config.zero_offset_m)

    # -- internals ------------------------------------------------------------------------
    def _wait_done(self, budget_s: float, what: str) -> float:
        try:
            return _number(self._expect("DONE", budget_s, what), self.name)
        except ReplyTimeout as exc:
            where = ""
            try:
                self.stop()
                where = f"; stopped at {self.position_mm():.3f} mm"
            except DeviceError:
                pass
            raise DeviceError(f"{exc}{where}") from None


def _number(text: str | None, name: str) -> float:
    try:
        value = float(text or "")
    except ValueError:
        raise DeviceError(f"{name}: expected a position in mm, got {text!r}") from None
    if not math.isfinite(value):
        raise DeviceError(f"{name}: expected a finite position in mm, got {text!r}")
    return value
