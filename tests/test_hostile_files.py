"""Special and oversized files: FIFOs, devices, huge, undecodable or deeply nested files are
refused at once with exit 2 and a message naming the file; nothing hangs or fills memory."""

from __future__ import annotations

import os
import re

import pytest

from rigtool.config import MAX_NESTING
from rigtool.devices.dbc_can import load_dbc
from rigtool.errors import ConfigError, UsageError
from rigtool.files import MAX_CONFIG_BYTES, read_regular_text
from rigtool.protocol import load_protocol
from rigtool.rig import load_rig

from .conftest import SMALL_PROTOCOL
from .hostile import run_cli


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe.yaml"
    os.mkfifo(path)
    return path


@pytest.fixture
def zero_link(tmp_path):
    path = tmp_path / "zero.yaml"
    path.symlink_to("/dev/zero")
    return path


@pytest.mark.parametrize("command", [["sweep", "{}", "--sim", "--dry-run"], ["check", "{}"],
                                     ["sweep", "PROTO", "--rig", "{}", "--dry-run"],
                                     ["import", "{}", "--db", "runs.sqlite"]])
@pytest.mark.parametrize("special", ["fifo", "zero_link"])
def test_cli_refuses_special_files_at_once(request, tmp_path, command, special):
    path = request.getfixturevalue(special)
    (tmp_path / "p.yaml").write_text(SMALL_PROTOCOL)
    args = [str(path) if a == "{}" else "p.yaml" if a == "PROTO" else a for a in command]
    proc = run_cli(*args, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert f"{path}: not a regular file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_fifo_and_device_are_refused_without_blocking(fifo, zero_link):
    for path in (fifo, zero_link):
        with pytest.raises(ConfigError, match="not a regular file"):
            load_protocol(path)
        with pytest.raises(ConfigError, match="not a regular file"):
            load_rig(path)
    with pytest.raises(UsageError, match="pipe.yaml: not a regular file"):
        load_dbc(fifo)


def test_directory_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not a regular file: it is a directory"):
        load_protocol(tmp_path)
    with pytest.raises(ConfigError, match="nope.yaml: file not found"):
        load_protocol(tmp_path / "nope.yaml")


def test_oversized_config_is_refused(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(SMALL_PROTOCOL + "# " + "x" * MAX_CONFIG_BYTES + "\n")
    with pytest.raises(ConfigError, match=r"big.yaml: file too large .* limit is 1 MiB"):
        load_protocol(path)
    assert read_regular_text(tmp_path / "big.yaml", 2 * MAX_CONFIG_BYTES).startswith("rigtool")


def _one_line_error(exc: ConfigError, path) -> str:
    lines = str(exc).splitlines()
    assert all(re.match(rf"^{re.escape(str(path))}:\d+: ", line) for line in lines), lines
    return lines[0]


def test_non_utf8_names_the_line(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_bytes(SMALL_PROTOCOL.replace("name: small", "name: sm\xe4ll").encode("latin-1"))
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert _one_line_error(info.value, path).startswith(f"{path}:2: not UTF-8")


@pytest.mark.parametrize("text", ["[" * 20000 + "]" * 20000,
                                  "a:\n" + "".join(" " * i + "-\n" for i in range(1, 800)),
                                  "{a: " * 5000 + "1" + "}" * 5000])
def test_deep_nesting_is_refused_with_a_line(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    for loader in (load_protocol, load_rig):
        with pytest.raises(ConfigError) as info:
            loader(path)
        assert f"nested more than {MAX_NESTING} levels" in _one_line_error(info.value, path)


def test_nesting_up_to_the_limit_is_parsed(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("[" * MAX_NESTING + "]" * MAX_NESTING + "\n")
    with pytest.raises(ConfigError, match="expected a mapping of fields"):
        load_protocol(path)


def test_huge_integer_literal_names_its_line(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text(SMALL_PROTOCOL.replace("seed: 3", "seed: " + "9" * 5000))
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    assert _one_line_error(info.value, path).startswith(f"{path}:3: ")
