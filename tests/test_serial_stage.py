"""The serial stage driver against its twin over a real pty, moving in real time."""

from __future__ import annotations

import os
import threading
import time

import pytest
from pydantic import ValidationError

from rigtool.devices.base import DepthStage
from rigtool.devices.serial_stage import SerialStage, SerialStageConfig
from rigtool.errors import DeviceError, UsageError
from rigtool.sim.line_server import open_pty
from rigtool.sim.stage_twin import StageTwin

SPEED = 250.0  # mm/s, fast enough to keep the tests short


@pytest.fixture
def stage_twin(live):
    # propeller centre at the surface with the carriage at 100 mm; deeper = larger position
    twin = StageTwin(live, speed_mm_s=SPEED, position_mm=100.0, zero_offset_m=0.1, seed=3).start()
    yield twin
    twin.stop()


@pytest.fixture
def open_stage():
    opened = []

    def _open(url: str, **fields) -> SerialStage:
        fields.setdefault("speed_mm_s", SPEED)
        fields.setdefault("timeout_s", 0.5)
        drv = SerialStage(SerialStageConfig(driver="serial-stage", url=url, **fields))
        opened.append(drv)
        return drv

    yield _open
    for drv in opened:
        drv.close()


def test_move_to_takes_real_time_and_reports_depth(stage_twin, live, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1)
    assert isinstance(drv, DepthStage)
    assert drv.depth_m(drv.position_mm()) == pytest.approx(0.0)
    t0 = time.monotonic()
    reached = drv.move_to(0.2)
    elapsed = time.monotonic() - t0
    assert reached == pytest.approx(0.2, abs=1e-6)
    assert elapsed >= 0.9 * 200.0 / SPEED
    assert stage_twin.position_mm == pytest.approx(300.0)
    assert live.twin.depth_m == pytest.approx(0.2)
    assert drv.move_to(0.2) == pytest.approx(0.2)  # already there: DONE at once
    assert drv.stats["garbage"] == 0 and drv.stats["timeouts"] == 0


def test_twin_depth_follows_the_carriage_while_moving(stage_twin, live, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1)
    seen = []
    mover = threading.Thread(target=drv.move_to, args=(0.25,))
    mover.start()
    while mover.is_alive():
        seen.append(live.twin.depth_m)
        time.sleep(0.02)
    mover.join()
    assert any(0.02 < d < 0.23 for d in seen)
    assert seen == sorted(seen)
    assert live.twin.depth_m == pytest.approx(0.25)


def test_reversed_direction(live, open_stage):
    # carriage at 1000 mm puts the propeller at the surface; lower positions are deeper
    with StageTwin(live, speed_mm_s=SPEED, position_mm=1000.0, zero_offset_m=1.0,
                   direction=-1) as twin:
        drv = open_stage(twin.pty_path, zero_offset_m=1.0, direction=-1)
        assert drv.move_to(0.3) == pytest.approx(0.3)
        assert twin.position_mm == pytest.approx(700.0)
        assert live.twin.depth_m == pytest.approx(0.3)
        drv.close()


def test_home(stage_twin, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1)
    assert drv.home() == pytest.approx(0.0)
    assert stage_twin.position_mm == 0.0


def test_soft_limits_refuse_before_moving(stage_twin, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1, max_depth_m=0.5)
    before = stage_twin.lines_received
    with pytest.raises(UsageError, match="outside the soft limits 0..0.5 m"):
        drv.move_to(0.6)
    with pytest.raises(UsageError):
        drv.move_to(float("nan"))
    assert stage_twin.lines_received == before
    assert stage_twin.position_mm == 100.0


def test_err_reply_raises_and_is_counted(live, open_stage):
    with StageTwin(live, speed_mm_s=SPEED, max_mm=200.0) as twin:
        drv = open_stage(twin.pty_path)
        with pytest.raises(DeviceError, match="refused 'MOVE 300.000': out of travel"):
            drv.move_to(0.3)
        assert drv.stats["errors"] == 1
        drv.close()


def test_stall_times_out_with_the_position(stage_twin, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1, timeout_s=0.3)
    stage_twin.stalled = True
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match=r"no DONE reply from serial stage on .*stopped at 100.000 mm"):
        drv.move_to(0.1)
    assert time.monotonic() - t0 < 2.0
    assert stage_twin.target_mm is None  # the driver sent STOP
    assert drv.stats["timeouts"] == 1
    stage_twin.stalled = False
    assert drv.move_to(0.05) == pytest.approx(0.05)


def test_garbage_is_counted_and_skipped(stage_twin, open_stage):
    drv = open_stage(stage_twin.pty_path, zero_offset_m=0.1)
    stage_twin.garbage = True
    assert drv.move_to(0.05) == pytest.approx(0.05)
    assert drv.stats["garbage"] >= 3  # before POS, OK and DONE


def test_silent_port_fails_on_open():
    master, slave, path = open_pty()
    try:
        with pytest.raises(DeviceError, match=f"no POS reply from serial stage on {path}"):
            SerialStage(SerialStageConfig(driver="serial-stage", url=path, timeout_s=0.2))
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_names_it():
    with pytest.raises(DeviceError, match="cannot open /dev/ttyUSB9-rigtool-missing"):
        SerialStage(SerialStageConfig(driver="serial-stage", url="/dev/ttyUSB9-rigtool-missing"))


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"min_depth_m": 1.0, "max_depth_m": 0.5}, "min_depth_m < max_depth_m"),
        ({"direction": 2}, "direction"),
        ({"speed_mm_s": 0}, "speed_mm_s"),
        ({"port": "x"}, "Extra inputs"),
    ],
)
def test_config_rejects_inconsistent_settings(fields, message):
    with pytest.raises(ValidationError, match=message):
        SerialStageConfig(driver="serial-stage", url="/dev/ttyUSB0", **fields)
