"""Progress of long work: in a real terminal (a pty) `rigtool calibrate` draws rich's progress
for the tasks the analysis reports; through a pipe it draws nothing."""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import copy_db

TASK = "fits per depth and supply voltage"


def _environment() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NO_COLOR", "TERM", "COLUMNS")}
    return env | {"TERM": "xterm-256color", "COLUMNS": "160"}


def _calibrate(db: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "rigtool.cli", "calibrate", "last", "--db", str(db), "--out",
            str(out)]


def _in_terminal(cmd: list[str]) -> tuple[int, str]:
    """Run `cmd` with stdin, stdout and stderr on a pty; everything it wrote, and its status."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, env=_environment(),
                            close_fds=True)
    os.close(slave)
    chunks = []
    try:
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the child's side closed
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
        status = proc.wait(timeout=600)
    return status, b"".join(chunks).decode("utf-8", "replace")


@pytest.fixture
def lab(tmp_path, shipped_sweep) -> Path:
    return copy_db(shipped_sweep("quick-demo"), tmp_path / "lab.sqlite")


def test_progress_appears_in_a_terminal(lab, tmp_path):
    status, text = _in_terminal(_calibrate(lab, tmp_path / "cal"))
    assert status == 0, text[-2000:]
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)
    assert TASK in plain and re.search(rf"{TASK}\S*\s.*1/1", plain), plain[-3000:]
    assert re.search(r"calibrating run \S+: \d+\.\d s", plain)


def test_no_progress_through_a_pipe(lab, tmp_path):
    proc = subprocess.run(_calibrate(lab, tmp_path / "cal"), capture_output=True, text=True,
                          env=_environment(), timeout=600)
    assert proc.returncode == 0, proc.stderr
    for stream in (proc.stdout, proc.stderr):
        assert TASK not in stream and "calibrating run" not in stream and "\x1b[" not in stream
    assert "C_p_fwd" in proc.stdout  # the result itself is printed
