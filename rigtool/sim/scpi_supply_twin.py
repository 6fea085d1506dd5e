"""Simulated programmable bench supply speaking SCPI on a pty and on TCP.

Commands: `*IDN?`, `VOLT <v>`, `VOLT?`, `CURR <a>`, `CURR?`, `OUTP ON|OFF|1|0`, `OUTP?`,
`MEAS:VOLT?`, `MEAS:CURR?`, `SYST:ERR?` (the error queue: `0,"No error"` or the oldest
error), several joined by `;`. Setting commands reply nothing, as on real supplies. The
output feeds a resistive load through the supply's source resistance; at the current limit
the supply goes constant-current. Fault switches: `garbage` (a junk line before every
reply) and `no_replies` (the supply stops answering).
"""

from __future__ import annotations

import re

import numpy as np

from rigtool.sim.line_server import LineServer

_SET = re.compile(r"(?P<cmd>VOLT|CURR)\s+(?P<value>[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)",
                  re.IGNORECASE)
_OUTP = re.compile(r"OUTP(?:UT)?\s+(?P<state>ON|OFF|1|0)", re.IGNORECASE)
IDN = "RIGTOOL,SIM-PSU,0001,1.0"


class ScpiSupplyTwin:
    """A supply of `max_voltage_v` / `max_current_a` into `load_ohm` (plus `source_ohm`)."""

    def __init__(self, *, max_voltage_v: float = 30.0, max_current_a: float = 10.0,
                 load_ohm: float = 4.0, source_ohm: float = 0.05, seed: int = 0,
                 host: str = "127.0.0.1") -> None:
        self.max_voltage_v, self.max_current_a = max_voltage_v, max_current_a
        self.load_ohm, self.source_ohm = load_ohm, source_ohm
        self.voltage_set = 0.0
        self.current_limit = max_current_a
        self.output = False
        self.garbage = False
        self.no_replies = False
        self.history: list[tuple[str, float]] = []  # (what, value) of every accepted setting
        self._errors: list[str] = []
        self._rng = np.random.default_rng(seed)
        self._server = LineServer(self._on_line, "scpi-supply-twin", host)
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

    def _on_line(self, end: object, raw: bytes) -> None:
        line = raw.decode("ascii", errors="replace")
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
                   "CURR?": f"{self.current_limit:.4f}", "OUTP?": "1" if self.output else "0",
                   "MEAS:VOLT?": f"{volts:.4f}", "MEAS:CURR?": f"{amps:.4f}"}
        if upper in queries:
            return queries[upper]
        if upper in ("SYST:ERR?", "SYSTEM:ERROR?"):
            return self._errors.pop(0) if self._errors else '0,"No error"'
        m = _SET.fullmatch(text)
        if m:
            value = float(m["value"])
            top = self.max_voltage_v if m["cmd"].upper() == "VOLT" else self.max_current_a
            if not 0.0 <= value <= top:
                self._errors.append('-222,"Data out of range"')
                return None
            if m["cmd"].upper() == "VOLT":
                self.voltage_set = value
            else:
                self.current_limit = value
            self.history.append((m["cmd"].upper(), value))
            return None
        m = _OUTP.fullmatch(text)
        if m:
            self.output = m["state"].upper() in ("ON", "1")
            self.history.append(("OUTP", float(self.output)))
            return None
        self._errors.append('-113,"Undefined header"')
        return None
