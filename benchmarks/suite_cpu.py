"""pytest plugin for bench_suite.py --per-file: the CPU seconds of every test (its process
and the child processes it waited for, user + system), one JSON file per pytest-xdist worker
in the folder $SUITE_CPU_DIR."""

from __future__ import annotations

import json
import os
import resource
import time
from pathlib import Path

import pytest

_RECORDS: dict[str, tuple[float, float]] = {}


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished (waited-for) children."""
    own, kids = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                      resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """Time one test's setup, call and teardown: (CPU s, wall s)."""
    cpu0, wall0 = _cpu_s(), time.perf_counter()
    yield
    _RECORDS[item.nodeid] = (_cpu_s() - cpu0, time.perf_counter() - wall0)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Write this process's records (workers and, without xdist, the one process)."""
    folder = os.environ.get("SUITE_CPU_DIR")
    if folder and _RECORDS:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        (Path(folder) / f"{worker}.json").write_text(json.dumps(_RECORDS))
