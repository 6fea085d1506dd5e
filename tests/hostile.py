"""Run the rigtool CLI the way a hostile file would meet it: in a subprocess, 1 GiB of address
space, a time limit."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

MEMORY_LIMIT = 1 << 30
TIME_LIMIT_S = 20


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess:
    """`python -m rigtool.cli ARGS` under RLIMIT_AS = 1 GiB; TimeoutExpired after TIME_LIMIT_S."""
    env = {k: v for k, v in os.environ.items() if k != "RIGTOOL_DB"}
    env["OPENBLAS_NUM_THREADS"] = "1"
    return subprocess.run([sys.executable, "-m", "rigtool.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=TIME_LIMIT_S,
                          stdin=subprocess.DEVNULL, preexec_fn=_limit_memory)
