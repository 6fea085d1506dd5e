"""A VISA resource (`TCPIP::host::5025::SOCKET`, `USB0::...::INSTR`, `ASRL/dev/ttyUSB0::INSTR`)
as a byte link for a line-based SCPI driver, through pyvisa (the optional `visa` extra).

pyvisa is imported when a link opens, never when rigtool.rig is imported. Reads are bounded:
at most `max_bytes` per read, ending early at `\\n`. VISA errors become DeviceError naming
the resource; a missing pyvisa is a UsageError naming the extra. The backend is one of
pyvisa's selectors (LIBRARY_FORMS), never a library path: a rig file does not load native code.
"""

from __future__ import annotations

import re
from typing import Any

from rigtool.errors import DeviceError, UsageError

EXTRA = "pip install 'rigtool[visa]'"  # pyvisa + the pure-Python pyvisa-py backend
_HOST = r"(?:[A-Za-z0-9_.-]+|\[[0-9A-Fa-f:.]+\])"
_NUM = r"(?:0[xX][0-9A-Fa-f]+|\d+)"
# The resource strings VISA defines for instruments a bench supply is reached by.
RESOURCE = re.compile(
    rf"TCPIP\d*::{_HOST}::(?P<port>\d+)::SOCKET"
    rf"|TCPIP\d*::{_HOST}(?:::[A-Za-z0-9_,.\[\]-]+)?::INSTR"
    rf"|USB\d*::{_NUM}::{_NUM}::[A-Za-z0-9_.-]+(?:::\d+)?::(?:INSTR|RAW)"
    r"|ASRL(?:\d+|/[A-Za-z0-9_./-]+|COM\d+)::INSTR"
    r"|GPIB\d*::\d+(?:::\d+)?::INSTR",
    re.IGNORECASE | re.ASCII)  # ASCII digits only: `int()` would read other scripts' digits
MAX_RESOURCE_CHARS = 256
# pyvisa's backend selectors: pyvisa-py, pyvisa-sim (its default instruments or an instrument
# YAML file), and the system's installed VISA that pyvisa finds itself
LIBRARY_FORMS = "@py, @ivi, @sim or path/to/instruments.yaml@sim"
_SIM_FILE = re.compile(r"[^\x00-\x1f\x7f]+\.ya?ml@sim")


def check_resource(text: str) -> str:
    """`text` if it is a VISA resource string of a kind listed in RESOURCE; else ValueError
    naming the forms (validates rig files, without pyvisa)."""
    match = RESOURCE.fullmatch(text) if len(text) <= MAX_RESOURCE_CHARS else None
    if match is None:
        raise ValueError(f"{text[:80]!r} is not a VISA resource string; expected one of "
                         "TCPIP::host::5025::SOCKET, TCPIP::host::INSTR, "
                         "USB0::0x2A8D::0x1102::SERIAL::INSTR, ASRL/dev/ttyUSB0::INSTR, "
                         "GPIB0::5::INSTR")
    port = match.group("port")
    if port is not None and not 0 < int(port) < 65536:
        raise ValueError(f"port {port} of {text!r} is outside 1..65535")
    return text


def check_library(text: str) -> str:
    """`text` if it is one of pyvisa's backend selectors (LIBRARY_FORMS); else ValueError. A
    library path is refused: pyvisa would load it with ctypes, running its code."""
    if text in ("@py", "@ivi", "@sim") or _SIM_FILE.fullmatch(text):
        return text
    raise ValueError(f"visa_library {text[:80]!r} is not a pyvisa backend; expected one of "
                     f"{LIBRARY_FORMS} (the system's VISA library is found by @ivi, "
                     "never given as a path)")


def sim_file(text: str) -> str | None:
    """The instrument YAML file of a `file.yaml@sim` selector, else None."""
    return text[:-len("@sim")] if _SIM_FILE.fullmatch(text) else None


def looks_like_resource(text: str) -> bool:
    """Whether `text` starts like a VISA resource string (a kind name and `::`)."""
    return re.match(r"(TCPIP|USB|ASRL|GPIB|VXI|PXI)[^:]*::", text, re.IGNORECASE) is not None


class VisaLink:
    """One open VISA resource: raw writes, bounded reads, line termination `\\n`."""

    def __init__(self, resource: str, library: str, baudrate: int, timeout_s: float) -> None:
        try:
            import pyvisa
        except ImportError:
            raise UsageError(f"the VISA resource {resource!r} needs pyvisa and pyvisa-py: "
                             f"{EXTRA}") from None
        try:
            check_library(library)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        self.resource = resource
        self._pyvisa = pyvisa
        try:
            self._rm = pyvisa.ResourceManager(library)
        except Exception as exc:  # noqa: BLE001 - backends raise anything while loading
            raise DeviceError(f"cannot open VISA resource {resource!r}: VISA backend "
                              f"{library!r} cannot be loaded ({_describe(exc)}); for the "
                              f"pure-Python backend: {EXTRA}") from None
        try:
            self._inst: Any = self._rm.open_resource(
                resource, write_termination="", read_termination="\n",
                timeout=round(timeout_s * 1000), open_timeout=round(timeout_s * 1000))
            if self._inst.interface_type == pyvisa.constants.InterfaceType.asrl:
                self._inst.baud_rate = baudrate
        except Exception as exc:  # noqa: BLE001 - backends raise anything, even bare Exception
            self._rm.close()
            raise DeviceError(f"cannot open VISA resource {resource!r}: {_describe(exc)}") from None

    def write(self, data: bytes) -> None:
        """Send `data` as it is (the caller adds the line end); OSError when the link fails."""
        try:
            self._inst.write_raw(data)
        except self._pyvisa.VisaIOError as exc:
            raise OSError(_describe(exc)) from None

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Up to `max_bytes`, ending at `\\n`; b"" when nothing came within `timeout_s`."""
        self._inst.timeout = max(0, round(timeout_s * 1000))
        try:
            return bytes(self._inst.read_bytes(max_bytes, break_on_termchar=True))
        except self._pyvisa.VisaIOError as exc:
            if exc.error_code == self._pyvisa.constants.StatusCode.error_timeout:
                return b""
            raise OSError(_describe(exc)) from None

    def discard_input(self, max_reads: int = 64) -> None:
        """Drop what has arrived unasked (a late reply), at most `max_reads` reads of it."""
        for _ in range(max_reads):
            if not self.read(4096, 0.0):
                return

    def close(self) -> None:
        """Release the resource and the resource manager."""
        try:
            self._inst.close()
        finally:
            self._rm.close()


def _describe(exc: Exception) -> str:
    """A VISA error as one line: its abbreviation and description."""
    return " ".join(str(exc).split())
