"""The tool version, stored with every run and calibration and written into every file."""

__version__ = "0.1.0"
