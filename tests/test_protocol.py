"""Protocol files: the shipped ones load, bad ones fail with file, line and field."""

from __future__ import annotations

import pytest

from rigtool.cli import main
from rigtool.errors import ConfigError
from rigtool.protocol import load_protocol

from .conftest import PROTOCOLS, SMALL_PROTOCOL

SHIPPED = sorted(PROTOCOLS.glob("*.yaml"))


def test_all_expected_protocols_are_shipped():
    names = {p.stem for p in SHIPPED}
    assert {"luo2020-baseline", "luo2020-cavitation", "stm32-pwm", "esc-1100-1900",
            "quick-demo"} <= names


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_protocols_validate(path):
    protocol, _ = load_protocol(path)
    assert protocol.simulator is not None, "every shipped protocol must run with --sim"
    assert protocol.command.command_values()


def test_baseline_matches_source_rig():
    p, _ = load_protocol(PROTOCOLS / "luo2020-baseline.yaml")
    values = p.command.command_values()
    assert len(values) == 401 and values[0] == -100 and values[-1] == 100
    assert p.timing.acquire.n_samples == 3000
    assert p.depth.depths_m() == [1.0]


def test_cavitation_protocol_dwells_at_least_20s():
    p, _ = load_protocol(PROTOCOLS / "luo2020-cavitation.yaml")
    assert p.command.command_values() == [40, 69, 90]
    assert p.depth.depths_m() == [0.2, 0.3, 0.4, 0.55]
    assert p.timing.acquire.n_samples / p.timing.acquire.rate_hz >= 20


def _error(write_yaml, text: str) -> str:
    path = write_yaml(text)
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    return str(info.value)


def test_unknown_key_names_file_line_and_field(write_yaml):
    text = SMALL_PROTOCOL.replace("  rest_s: 0.2", "  rest_s: 0.2\n  reset_s: 1")
    msg = _error(write_yaml, text)
    line = text.splitlines().index("  reset_s: 1") + 1
    assert f"protocol.yaml:{line}: timing.reset_s: unknown field" in msg


def test_wrong_type_names_the_value(write_yaml):
    text = SMALL_PROTOCOL.replace("rate_hz: 500", "rate_hz: fast")
    msg = _error(write_yaml, text)
    line = next(i for i, t in enumerate(text.splitlines(), 1) if "fast" in t)
    assert f"protocol.yaml:{line}: timing.acquire.rate_hz" in msg and "'fast'" in msg


def test_negative_step_and_missing_field(write_yaml):
    text = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]", "range: {start: 0, stop: 10, step: -1}")
    assert "command.range.step" in _error(write_yaml, text)
    msg = _error(write_yaml, SMALL_PROTOCOL.replace("  unit: percent\n", ""))
    assert "command.unit: required field is missing" in msg


def test_values_and_range_are_exclusive(write_yaml):
    text = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]",
                                  "values: [1]\n  range: {start: 0, stop: 1, step: 1}")
    assert "exactly one of `values`" in _error(write_yaml, text)


def test_bad_unit_lists_choices(write_yaml):
    msg = _error(write_yaml, SMALL_PROTOCOL.replace("unit: percent", "unit: volts"))
    assert "command.unit" in msg and "percent" in msg and "'volts'" in msg


def test_duplicate_keys_are_errors(write_yaml):
    msg = _error(write_yaml, SMALL_PROTOCOL + "name: again\n")
    assert "duplicate key 'name'" in msg


def test_yaml_syntax_error_has_line(write_yaml):
    msg = _error(write_yaml, "name: x\ncommand: [unclosed\n")
    assert "YAML syntax error" in msg and "protocol.yaml:" in msg


def test_cli_config_error_exits_2_without_traceback(write_yaml, capsys, db_path):
    path = write_yaml(SMALL_PROTOCOL.replace("order", "ordr").replace("  values: [-50", "  ordr: up\n  values: [-50"))
    status = main(["sweep", str(path), "--sim", "--db", str(db_path)])
    captured = capsys.readouterr()
    assert status == 2
    assert "command.ordr: unknown field" in captured.err
    assert "Traceback" not in captured.err


def test_cli_missing_file_exits_2(capsys, tmp_path):
    status = main(["sweep", str(tmp_path / "nope.yaml"), "--sim"])
    assert status == 2
    assert "nope.yaml: file not found" in capsys.readouterr().err


def test_unit_mismatch_with_rig_is_config_error(write_yaml, capsys, db_path):
    path = write_yaml(SMALL_PROTOCOL.replace("unit: percent", "unit: pwm_counts"))
    assert main(["sweep", str(path), "--sim", "--db", str(db_path)]) == 2
    assert "the rig's actuator takes percent" in capsys.readouterr().err


def test_out_of_range_command_is_config_error(write_yaml, capsys, db_path):
    path = write_yaml(SMALL_PROTOCOL.replace("[-50, 0, 50, 100]", "[0, 150]"))
    assert main(["sweep", str(path), "--sim", "--db", str(db_path)]) == 2
    assert "leave the actuator's range" in capsys.readouterr().err


def test_no_rig_is_usage_error(write_yaml, capsys, db_path):
    path = write_yaml(SMALL_PROTOCOL)
    assert main(["sweep", str(path), "--db", str(db_path)]) == 2
    assert "--sim" in capsys.readouterr().err


def test_aliases_non_finite_and_complex_keys_are_config_errors(write_yaml):
    assert "aliases" in _error(write_yaml, "name: x\na: &x [*x]\n")
    assert "plain names" in _error(write_yaml, "? [a, b]\n: 1\n")
    assert "finite number" in _error(write_yaml, SMALL_PROTOCOL.replace("[-50, 0, 50, 100]", "[.nan]"))
    assert "finite number" in _error(write_yaml, SMALL_PROTOCOL.replace("rate_hz: 500", "rate_hz: .inf"))
