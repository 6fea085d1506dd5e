"""Shared fixtures: paths to shipped protocols, a temporary run database."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PROTOCOLS = ROOT / "protocols"


@pytest.fixture
def live(request):
    """A LiveTwin of the test module's LIVE_PROFILE (default can-bldc) and LIVE_SEED, stopped after."""
    from rigtool.sim.live import LiveTwin
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.thruster_profiles import PROFILES

    profile = getattr(request.module, "LIVE_PROFILE", "can-bldc")
    twin = LiveTwin(ThrusterTwin(PROFILES[profile], seed=getattr(request.module, "LIVE_SEED", 1)))
    twin.start()
    yield twin
    twin.stop()


@pytest.fixture
def recorder(channel):
    """A second bus on the test module's `channel` that records every frame sent on it."""
    import can

    bus = can.Bus(interface="virtual", channel=channel)
    yield bus
    bus.shutdown()


@pytest.fixture
def db_path(tmp_path: Path) -> Path:
    return tmp_path / "runs.sqlite"


@pytest.fixture
def write_yaml(tmp_path: Path):
    """Write YAML text to a file in tmp_path and return its path."""

    def _write(text: str, name: str = "protocol.yaml") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return _write


SMALL_PROTOCOL = """\
rigtool_protocol: 1
name: small
simulator: {profile: can-bldc, seed: 3}
command:
  unit: percent
  values: [-50, 0, 50, 100]
depth:
  unit: m
  values: [1.0]
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 200, rate_hz: 500}
  rest_s: 0.2
  tare: at_start
limits:
  max_thrust_n: 90
  slew_per_s: 400
"""
