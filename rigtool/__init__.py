"""rigtool: sweep, calibrate and report on underwater thrusters on a test rig."""

__version__ = "0.1.0"
