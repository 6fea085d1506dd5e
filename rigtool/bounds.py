"""Bounds on every number in protocol and rig files, so that no file can exhaust the host.

The table in docs/protocols.md lists them. Each bound is far beyond any real rig and far
below what would hang rigtool or fill its memory.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

MAX_RATE_HZ = 100_000.0  # sample rate
MIN_RATE_HZ = 0.1
MAX_SAMPLES_PER_POINT = 100_000_000  # samples acquired (and stored) per point: 4 h at 7 kHz
MAX_BUFFER_SAMPLES = 10_000_000  # a driver's receive buffer (held in memory)
MAX_COMMAND_VALUES = 100_000  # commands in one sweep direction
MAX_POINTS = 100_000  # points in the whole plan (the plan is stored with the run)
MAX_DURATION_S = 86_400.0  # any single duration in a file: one day
MIN_WINDOW_S = 1e-3  # settling windows: shorter ones hold no samples at any sane rate
MAX_RUN_S = 30 * 86_400.0  # estimated length of a whole run: 30 days
MAX_DEBOUNCE_SAMPLES = 1_000_000
MAX_COMMAND = 1e10  # |command| in any unit (STM32 compare values reach 2**32 - 1)
MAX_DEPTH_M = 1_000.0  # |depth| and stage positions
MAX_SEED = 2**32 - 1  # seeds of the simulator and of random command order
MAX_SCALE = 1e12  # |scale|, |offset| and the like in driver configs
MAX_BAUDRATE = 100_000_000  # serial baud rates and CAN bit rates
MAX_CLOCK_HZ = 1e10  # timer input clocks
MAX_THRUST_N = 1e6  # protocol limits
MAX_CURRENT_A = 1e5
MAX_SPEED_RPM = 1e7
MAX_POWER_W = 1e7
MAX_TORQUE_NM = 1e6
MAX_TEMPERATURE_C = 1_000.0
MAX_SUPPLY_V = 1_000.0  # supply voltages a protocol may sweep
MAX_VOLTAGES = 1_000  # voltages in one sweep
MAX_FLOW_MPS = 20.0  # |flow or tow speed| of a captive run
MAX_CAPTIVE_SETTINGS = 1_000  # speeds, and angles, in one captive axis

# Reusable field types: finite, with both ends bounded.
Seconds = Annotated[float, Field(ge=0, le=MAX_DURATION_S, allow_inf_nan=False)]
PositiveSeconds = Annotated[float, Field(gt=0, le=MAX_DURATION_S, allow_inf_nan=False)]
Command = Annotated[float, Field(ge=-MAX_COMMAND, le=MAX_COMMAND, allow_inf_nan=False)]
DepthM = Annotated[float, Field(ge=-MAX_DEPTH_M, le=MAX_DEPTH_M, allow_inf_nan=False)]
Scale = Annotated[float, Field(ge=-MAX_SCALE, le=MAX_SCALE, allow_inf_nan=False)]
PositiveScale = Annotated[float, Field(gt=0, le=MAX_SCALE, allow_inf_nan=False)]
Seed = Annotated[int, Field(ge=0, le=MAX_SEED)]
Baudrate = Annotated[int, Field(gt=0, le=MAX_BAUDRATE)]
