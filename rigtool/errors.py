"""User-facing errors. The CLI prints them without a traceback and exits with their status."""

from __future__ import annotations


class RigtoolError(Exception):
    """Base for errors that are the user's or the environment's, not a bug."""

    exit_status = 1


class UsageError(RigtoolError):
    """Bad arguments or configuration (exit status 2)."""

    exit_status = 2


class ConfigError(UsageError):
    """A protocol or rig file is invalid; the message names file, line and field."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("\n".join(problems))


class StoreError(RigtoolError):
    """The run database cannot be opened or written."""


class DataError(StoreError):
    """Stored or read-back data is damaged or crafted; the message names the database or
    file, the run and the field (exit status 2)."""

    exit_status = 2


class DeviceError(RigtoolError):
    """A device is missing, silent or reports a fault; the message names it."""


class SafetyTrip(RigtoolError):
    """A safety limit tripped during a sweep; `detail` is stored with its event."""

    def __init__(self, message: str, detail: dict | None = None) -> None:
        super().__init__(message)
        self.detail = detail or {}
