"""Rig files with numbers that used to raise tracebacks, kill the heartbeat thread or fail
mid-run, and paths that exited 2 without a line: all are file:line config errors now."""

from __future__ import annotations

import re

import pytest
import yaml

from rigtool.cli import main

from .conftest import SMALL_PROTOCOL
from .hostile import run_cli

BENCH = """\
name: bench
actuator: {driver: stm32-bridge, url: "loop://", command_unit: pwm_counts, arr: 799,
           heartbeat_s: 0.1, watchdog_ms: 500, timeout_s: 0.5, timer_clock_hz: 72000000}
sensor: {driver: ascii-gauge, url: "loop://", preset: mark10}
depth_stage: {driver: serial-stage, url: "loop://", zero_offset_m: 0.0}
"""
SIM = "name: sim\nsimulator: {profile: can-bldc, seed: 1}\n"

HOSTILE = {
    "heartbeat": (BENCH, ("actuator", "heartbeat_s"), float("inf")),
    "command-max": (BENCH, ("actuator", "command_max"), float("inf")),
    "timer-clock": (BENCH, ("actuator", "timer_clock_hz"), float("inf")),
    "timeout": (BENCH, ("actuator", "timeout_s"), float("inf")),
    "watchdog": (BENCH, ("actuator", "watchdog_ms"), 10**20),
    "gauge-scale": (BENCH, ("sensor", "scale"), float("nan")),
    "zero-offset": (BENCH, ("depth_stage", "zero_offset_m"), float("nan")),
    "seed": (SIM, ("simulator", "seed"), -1),
    "override-name": (SIM, ("simulator", "overrides"), {"bogus": 1.0}),
    "override-value": (SIM, ("simulator", "overrides"), {"tau_s": "nan"}),
    "override-huge": (SIM, ("simulator", "overrides"), {"tau_s": 1e300}),
    "mount": (SIM, ("mount",), {"rotation_deg": float("inf")}),
    "bool-arr": (BENCH, ("actuator", "arr"), True),  # lax pydantic would read it as 1
    "bool-scale": (BENCH, ("sensor", "scale"), True),
}


def _rig(tmp_path, base: str, where: tuple = (), value=None, name: str = "rig.yaml"):
    data = yaml.safe_load(base)
    if where:
        node = data
        for key in where[:-1]:
            node = node[key]
        node[where[-1]] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _assert_located(stderr: str, path, field: str) -> None:
    lines = stderr.replace("rigtool: error: ", "").strip().splitlines()
    assert lines and all(re.match(rf"^{re.escape(str(path))}:\d+: ", s) for s in lines), lines
    assert any(f": {field}" in s for s in lines), (field, lines)


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_check_on_hostile_rig_exits_2_with_file_and_line(tmp_path, case):
    base, where, value = HOSTILE[case]
    path = _rig(tmp_path, base, where, value)
    proc = run_cli("check", path, "--seconds", "0.2", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    _assert_located(proc.stderr, path, ".".join(where))


def test_sweep_dry_run_on_hostile_rig_exits_2(tmp_path):
    (tmp_path / "p.yaml").write_text(SMALL_PROTOCOL)
    path = _rig(tmp_path, *HOSTILE["heartbeat"][:2], float("inf"))
    proc = run_cli("sweep", "p.yaml", "--rig", path, "--dry-run", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    _assert_located(proc.stderr, path, "actuator.heartbeat_s")


def test_missing_rig_named_by_the_protocol_names_the_protocol_line(tmp_path, capsys):
    path = tmp_path / "p.yaml"
    path.write_text(SMALL_PROTOCOL.replace("name: small", "name: small\nrig: rigs/nope.yaml"))
    assert main(["sweep", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    _assert_located(err, path, "rig")
    assert "rigs/nope.yaml" in err and "file not found" in err


def test_protocol_without_rig_names_the_protocol(tmp_path, capsys):
    path = tmp_path / "p.yaml"
    path.write_text(SMALL_PROTOCOL)
    assert main(["sweep", str(path), "--dry-run"]) == 2
    _assert_located(capsys.readouterr().err, path, "no rig given")


def test_unit_mismatch_names_the_protocol_line(tmp_path, capsys):
    path = tmp_path / "p.yaml"
    path.write_text(SMALL_PROTOCOL.replace("unit: percent", "unit: pulse_us"))
    assert main(["sweep", str(path), "--sim", "--dry-run"]) == 2
    _assert_located(capsys.readouterr().err, path, "command.unit")
    path.write_text(SMALL_PROTOCOL.replace("[-50, 0, 50, 100]", "[-50, 0, 50, 150]"))
    assert main(["sweep", str(path), "--sim", "--dry-run"]) == 2
    _assert_located(capsys.readouterr().err, path, "command.values")


def test_db_path_from_the_rig_names_the_rig_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("RIGTOOL_DB", raising=False)
    (tmp_path / "p.yaml").write_text(SMALL_PROTOCOL)
    (tmp_path / "adir").mkdir()
    rig = _rig(tmp_path, SIM + f"db: {tmp_path / 'adir'}\n")
    assert main(["sweep", str(tmp_path / "p.yaml"), "--rig", str(rig)]) == 2
    _assert_located(capsys.readouterr().err, rig, "db")
    rig = _rig(tmp_path, SIM + f"db: {tmp_path / 'none.sqlite'}\n")
    assert main(["sweep", "--resume", "last", "--rig", str(rig)]) == 2
    _assert_located(capsys.readouterr().err, rig, "db")


def test_seed_option_out_of_range_is_a_usage_error(tmp_path, capsys):
    (tmp_path / "p.yaml").write_text(SMALL_PROTOCOL)
    assert main(["sweep", str(tmp_path / "p.yaml"), "--sim", "--dry-run", "--seed", "-1"]) == 2
    assert "--seed -1" in capsys.readouterr().err


HOSTILE_FORMATS = {  # issue 49: a format string from a file was checked by trying it once
    "globals": "{value.__class__.__init__.__globals__}",  # was a traceback, exit 1
    "attribute": "SET {value.__class__.__name__}",  # was accepted
    "huge-width": "SET {channel} {value:>99999999}",  # was accepted: 153 MB to check
    "index": "SET {channel[0]} {value}",
    "conversion": "SET {channel!r} {value}",
    "positional": "SET {} {value}",
    "nested-spec": "SET {channel} {value:{channel}}",
    "unknown": "SET {motor} {value}",
    "lone-brace": "SET {channel} {value",
    # attack report: a second command line, control and non-ASCII text, a line too long for
    # the firmware's 64 bytes
    "newline": "SET {channel} {value}\nSTOP",
    "nul-fill": "PING {value:\x00>5}",
    "line-separator": "SET {channel} {value}\u2028",
    "emoji-fill": "SET {value:\U0001F600^9}",
    "too-long": "SET {channel} {value:>99}",
}


@pytest.mark.parametrize("case", sorted(HOSTILE_FORMATS))
def test_a_hostile_command_format_exits_2_with_file_and_line(tmp_path, case):
    path = _rig(tmp_path, BENCH, ("actuator", "set_format"), HOSTILE_FORMATS[case])
    proc = run_cli("check", path, "--seconds", "0.2", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    _assert_located(proc.stderr, path, "actuator.set_format")


def test_allowed_command_formats_are_kept():
    """Literal text, {channel} and {value}, and an integer spec whose line fits the
    firmware's 64 bytes all pass."""
    from rigtool.devices.stm32_bridge import command_format

    for text in ("SET {channel} {value}", "PWM{channel:02d}={value:>50}", "{{HB}}", "T{value:04X}"):
        assert command_format(text) == text
