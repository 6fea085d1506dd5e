"""rigtool: sweep, calibrate and report on underwater thrusters on a test rig.

The Python API (docs/api.md): `rigtool.open(db)` for runs, points and samples, and
`rigtool.load_calibration(folder)` for a calibration's coefficients and curves.
"""

from typing import Any

from rigtool.version import __version__

__all__ = ["__version__", "load_calibration", "open"]


def __getattr__(name: str) -> Any:
    """The API is imported on first use, so the CLI and the model runtime start fast."""
    if name in ("open", "load_calibration"):
        from rigtool import api

        return getattr(api, name)
    raise AttributeError(f"module 'rigtool' has no attribute {name!r}")
