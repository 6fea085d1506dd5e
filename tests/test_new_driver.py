"""A new sensor driver is one module plus one line in devices/registry.py: a throwaway load
cell, registered in a fresh interpreter, is accepted by the rig schema (with file:line errors),
its declared capabilities decide which protocol limits have data and whether a `mount:` applies,
and the dry run names it; nothing else in rigtool is edited."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .test_protocol_limits import NO_FEEDBACK

DRIVER = '''\
"""A throwaway single-axis load cell with a temperature channel (test only)."""

from typing import Literal

from pydantic import ConfigDict, Field

from rigtool.devices.base import Device
from rigtool.devices.capabilities import SensorSection


class LoadCellConfig(SensorSection):
    """The `sensor:` section of the load cell."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    driver: Literal["load-cell"]
    url: str = Field(min_length=1)

    def temperature_source(self) -> bool:
        return True


class LoadCell(Device):
    """Never opened by these tests (a dry run opens nothing)."""
'''
# In a fresh interpreter: register the load cell (one table line), then run each case's dry
# run through the CLI in its own folder; print each exit status and error text as JSON.
REGISTER = """\
import contextlib, io, json, sys
from rigtool.devices.registry import DRIVERS, Driver
if sys.argv[1] == "register":
    DRIVERS["sensor"]["load-cell"] = Driver("load_cell", "LoadCell", "LoadCellConfig")
from rigtool.cli import main
results = []
for folder in sys.argv[2:]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["sweep", f"{folder}/p.yaml", "--rig", f"{folder}/rig.yaml",
                     "--db", f"{folder}/db.sqlite", "--dry-run"])
    results.append([code, out.getvalue(), err.getvalue()])
print(json.dumps(results))
"""
RIG = ("rigtool_rig: 1\nname: load-cell-bench\n"
       "actuator: {{driver: stm32-bridge, url: 'socket://127.0.0.1:9'}}\n"
       "sensor:\n  driver: load-cell\n  url: /dev/null\n{extra}")


CASES = {  # name: (protocol limit, rig addition)
    "temperature": ("  max_temperature_c: 60", ""),
    "torque": ("  max_torque_nm: 2", ""),
    "mount": ("", "mount: {rotation_deg: 90}\n"),
    "field": ("", "  baud: 9600\n"),
}


def _dry_runs(tmp_path: Path, register: bool) -> dict[str, tuple[int, str, str]]:
    """Each case's (exit status, output, errors) from one interpreter."""
    (tmp_path / "load_cell.py").write_text(DRIVER)
    for name, (limit, extra) in CASES.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "rig.yaml").write_text(RIG.format(extra=extra))
        (tmp_path / name / "p.yaml").write_text(NO_FEEDBACK.format(limit=limit))
    done = subprocess.run([sys.executable, "-c", REGISTER, "register" if register else "plain",
                           *(str(tmp_path / name) for name in CASES)],
                          capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    return dict(zip(CASES, map(tuple, json.loads(done.stdout)), strict=True))


def test_a_registered_driver_is_parsed_and_its_declared_capabilities_are_used(tmp_path):
    got = _dry_runs(tmp_path, register=True)
    code, out, err = got["temperature"]  # its temperature channel feeds the limit
    assert code == 0, err
    assert "load-cell sensor" in out and "measured over 0.5 s" in out
    assert not (tmp_path / "temperature" / "db.sqlite").exists()
    for name, where, why in (("torque", "p.yaml:11", "limits.max_torque_nm"),
                             ("mount", "rig.yaml", "single-axis"),
                             ("field", "rig.yaml:7", "sensor.baud: unknown field")):
        code, _, err = got[name]
        assert code == 2 and "Traceback" not in err, err
        assert where in err and why in err, err
    assert "force only" in got["torque"][2]


def test_without_its_registration_the_driver_name_is_refused(tmp_path):
    code, _, err = _dry_runs(tmp_path, register=False)["temperature"]
    assert code == 2 and "Traceback" not in err
    assert "rig.yaml:4" in err and "load-cell" in err
