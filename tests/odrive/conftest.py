"""What the ODrive tests share: an ODrive twin at NODE on a fresh virtual bus, and a factory
of odrive_velocity drivers on that bus, all closed at teardown."""

from __future__ import annotations

import uuid

import pytest

from rigtool.devices.dbc_can import DbcCanConfig, DbcCanDriver
from rigtool.sim.odrive_twin import OdriveTwin

NODE = 3


@pytest.fixture
def channel() -> str:
    return f"odrive-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def twin(live, channel):
    twin = OdriveTwin(live, channel=channel, node_id=NODE).start()
    yield twin
    twin.stop()


@pytest.fixture
def open_driver(channel):
    """Factory for odrive_velocity drivers on the test's channel; all closed at teardown."""
    drivers = []

    def _open(**fields) -> DbcCanDriver:
        cfg = {"driver": "dbc-can", "interface": "virtual", "channel": channel,
               "mapping": "odrive_velocity", "node_id": NODE, "timeout_s": 0.5, **fields}
        driver = DbcCanDriver(DbcCanConfig(**cfg))
        drivers.append(driver)
        return driver

    yield _open
    for driver in drivers:
        driver.close()
