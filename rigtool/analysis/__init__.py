"""Analysis of stored runs: steady-state windows, thruster model fits, command curves, quality.

`rigtool.analysis.dataset` is the only module here that reads the Store; every other module
works on numpy arrays. `rigtool.analysis.calibrate.calibrate_run` ties them together.
"""
