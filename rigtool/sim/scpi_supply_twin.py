"""Simulated programmable bench supply speaking SCPI on a pty and on TCP.

Commands: `*IDN?`, `VOLT <v>`, `VOLT?`, `CURR <a>`, `CURR?`, `OUTP ON|OFF|1|0`, `OUTP?`,
`MEAS:VOLT?`, `MEAS:CURR?`, `SYST:ERR?` (the error queue: `0,"No error"` or the oldest
error), several joined by `;`; with `protection=True` also over-voltage protection
(`VOLT:PROT <v>`, `VOLT:PROT?`: the output trips off when the setpoint exceeds it) and an
output watchdog (`OUTP:PROT:WDOG ON|OFF`, `OUTP:PROT:WDOG?`, `OUTP:PROT:WDOG:DEL <s>`,
`OUTP:PROT:WDOG:DEL?`: the output goes off after `DEL` seconds without a line received).
A supply without them answers nothing and queues `-113` (undefined header), as real ones do.
Setting commands reply nothing. The output feeds a resistive load through the supply's source
resistance; at the current limit the supply goes constant-current. A supply may start with a
leftover setpoint and its output on or off (a shared bench); it refuses a protection level below
its setpoint (-221), may round setpoints to `resolution_v`, and may answer `OUTP?` with
`ON`/`OFF` (`state_words`, as Rigol supplies do). Fault switches: `garbage` (a junk
line before every reply) and `no_replies` (the supply stops answering). `lines` records every
line received; `on_states` the (setpoint, current limit) at every switch-on.
"""

from __future__ import annotations

import re
import time

import numpy as np

from rigtool.sim.line_server import LineServer

_NUMBER = r"(?P<value>[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)"
_SET = re.compile(rf"(?P<cmd>VOLT|CURR|VOLT:PROT|OUTP:PROT:WDOG:DEL)\s+{_NUMBER}", re.IGNORECASE)
_SWITCH = re.compile(r"(?P<cmd>OUTP(?:UT)?|OUTP:PROT:WDOG)\s+(?P<state>ON|OFF|1|0)", re.IGNORECASE)
_PROTECTION = ("VOLT:PROT", "OUTP:PROT:WDOG", "OUTP:PROT:WDOG:DEL")
IDN = "RIGTOOL,SIM-PSU,0001,1.0"


class ScpiSupplyTwin:
    """A supply of `max_voltage_v` / `max_current_a` into `load_ohm` (plus `source_ohm`)."""

    def __init__(self, *, max_voltage_v: float = 30.0, max_current_a: float = 10.0,
                 load_ohm: float = 4.0, source_ohm: float = 0.05, seed: int = 0,
                 host: str = "127.0.0.1", setpoint_v: float = 0.0, output: bool = False,
                 protection: bool = True, state_words: bool = False,
                 resolution_v: float = 0.0, meter_gain: float = 1.0) -> None:
        self.max_voltage_v, self.max_current_a = max_voltage_v, max_current_a
        self.load_ohm, self.source_ohm = load_ohm, source_ohm
        self.voltage_set = setpoint_v
        self.current_limit = max_current_a
        self.output = output
        self.protection = protection
        self.state_words = state_words  # OUTP? answers ON/OFF (Rigol) instead of 1/0
        self.resolution_v = resolution_v  # setpoints are rounded to this (0: exact)
        self.meter_gain = meter_gain  # MEAS:CURR? reads the current times this (accuracy)
        self.ovp_v = max_voltage_v
        self.watchdog = False
        self.watchdog_s = 60.0
        self.garbage = False
        self.no_replies = False
        self.history: list[tuple[str, float]] = []  # (what, value) of every accepted setting
        self.lines: list[str] = []  # every line received
        self.on_states: list[tuple[float, float]] = []  # (setpoint V, limit A) at each switch-on
        self._last_rx = time.monotonic()
        self._errors: list[str] = []
        self._rng = np.random.default_rng(seed)
        self._server = LineServer(self._on_line, "scpi-supply-twin", host, tick=self._tick)
        self.pty_path, self.url = self._server.pty_path, self._server.url

    def start(self) -> ScpiSupplyTwin:
        self._server.start()
        return self

    def stop(self) -> None:
        self._server.stop()

    def __enter__(self) -> ScpiSupplyTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def measured(self) -> tuple[float, float]:
        """(volts, amps) at the output terminals: 0 V, 0 A with the output off."""
        if not self.output:
            return 0.0, 0.0
        amps = self.voltage_set / (self.load_ohm + self.source_ohm)
        if amps > self.current_limit:  # constant-current mode
            amps = self.current_limit
        return amps * self.load_ohm, amps

    def _tick(self) -> None:
        """The output watchdog: off after `watchdog_s` without a line received."""
        if self.watchdog and self.output and time.monotonic() - self._last_rx > self.watchdog_s:
            self._switch_output(False, "WDOG")

    def _switch_output(self, on: bool, why: str = "OUTP") -> None:
        if on and not self.output:
            self.on_states.append((self.voltage_set, self.current_limit))
        self.output = on
        self.history.append((why, float(on)))

    def _on_line(self, end: object, raw: bytes) -> None:
        self._last_rx = time.monotonic()
        line = raw.decode("ascii", errors="replace")
        self.lines.append(line.strip())
        for part in filter(None, (p.strip() for p in line.split(";"))):
            reply = self._command(part)
            if reply is not None and not self.no_replies:
                data = reply.encode("ascii") + b"\n"
                if self.garbage:
                    junk = bytes(self._rng.integers(0x80, 0x100, size=8, dtype=np.uint8))
                    data = junk + b"\n" + data
                self._server.send(end, data)

    def _command(self, text: str) -> str | None:
        upper = text.upper()
        volts, amps = self.measured()
        queries = {"*IDN?": IDN, "VOLT?": f"{self.voltage_set:.4f}",
                   "CURR?": f"{self.current_limit:.4f}", "OUTP?": self._state(self.output),
                   "MEAS:VOLT?": f"{volts:.4f}", "MEAS:CURR?": f"{amps * self.meter_gain:.4f}"}
        if self.protection:
            queries |= {"VOLT:PROT?": f"{self.ovp_v:.4f}",
                        "OUTP:PROT:WDOG?": "1" if self.watchdog else "0",
                        "OUTP:PROT:WDOG:DEL?": f"{self.watchdog_s:.3f}"}
        if upper in queries:
            return queries[upper]
        if upper in ("SYST:ERR?", "SYSTEM:ERROR?"):
            return self._errors.pop(0) if self._errors else '0,"No error"'
        m = _SET.fullmatch(text) or _SWITCH.fullmatch(text)
        if m is None or (m["cmd"].upper() in _PROTECTION and not self.protection):
            self._errors.append('-113,"Undefined header"')
            return None
        if "value" in m.groupdict():
            self._setting(m["cmd"].upper(), float(m["value"]))
        elif m["cmd"].upper() == "OUTP:PROT:WDOG":
            self.watchdog = m["state"].upper() in ("ON", "1")
            self.history.append(("WDOG_ARM", float(self.watchdog)))
        else:
            self._switch_output(m["state"].upper() in ("ON", "1"))
        return None

    def _state(self, on: bool) -> str:
        if self.state_words:
            return "ON" if on else "OFF"
        return "1" if on else "0"

    def _setting(self, cmd: str, value: float) -> None:
        top = {"VOLT": self.max_voltage_v, "CURR": self.max_current_a,
               "VOLT:PROT": self.max_voltage_v * 1.1, "OUTP:PROT:WDOG:DEL": 3600.0}[cmd]
        if not 0.0 <= value <= top:
            self._errors.append('-222,"Data out of range"')
            return
        if cmd == "VOLT:PROT" and value < self.voltage_set:
            self._errors.append('-221,"Settings conflict"')  # protection below the setpoint
            return
        if cmd == "VOLT":
            if self.resolution_v:
                value = round(value / self.resolution_v) * self.resolution_v
            self.voltage_set = value
        elif cmd == "CURR":
            self.current_limit = value
        elif cmd == "VOLT:PROT":
            self.ovp_v = value
        else:
            self.watchdog_s = value
        self.history.append((cmd, value))
        if self.output and self.voltage_set > self.ovp_v:
            self._switch_output(False, "OVP")
