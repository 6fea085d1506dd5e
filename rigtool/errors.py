"""User-facing errors. The CLI prints them without a traceback and exits with their status."""

from __future__ import annotations

# Exit statuses of rigtool commands (docs/cli.md).
EXIT_COMPLETED = 0
EXIT_FAILED = 1  # an error, a limit trip, a device fault, SIGTERM or SIGHUP
EXIT_USAGE = 2  # bad arguments or configuration; damaged or crafted data
EXIT_NOT_AT_NEUTRAL = 3  # the final neutral command was not confirmed: the thruster may run
EXIT_INTERRUPTED = 130  # 128 + SIGINT: the operator's Ctrl-C stopped the command


class RigtoolError(Exception):
    """Base for errors that are the user's or the environment's, not a bug."""

    exit_status = EXIT_FAILED


class UsageError(RigtoolError):
    """Bad arguments or configuration (exit status 2)."""

    exit_status = EXIT_USAGE


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

    exit_status = EXIT_USAGE


class DeviceError(RigtoolError):
    """A device is missing, silent or reports a fault; the message names it."""


class SafetyTrip(RigtoolError):
    """A safety limit tripped during a sweep; `detail` is stored with its event."""

    def __init__(self, message: str, detail: dict | None = None) -> None:
        super().__init__(message)
        self.detail = detail or {}
