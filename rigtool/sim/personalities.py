"""The sensor personalities `rigtool sim` can serve: the one list its help text and
sim/server.py read. Plain data, so the CLI builds its parser without the personalities'
transport libraries."""

from __future__ import annotations

# Sensor personality -> the ascii-gauge preset it speaks (None: the Net F/T over UDP).
SENSORS: dict[str, str | None] = {"netft": None, "mark10": "mark10", "hx711": "hx711-csv"}
