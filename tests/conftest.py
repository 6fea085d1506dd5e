"""Shared fixtures: paths to shipped protocols, a temporary run database, and the simulated
sweeps of shipped protocols that several test files start from (made once per test run)."""

from __future__ import annotations

import compileall
import fcntl
import os
import signal
import sqlite3
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PROTOCOLS = ROOT / "protocols"


def pytest_configure(config: pytest.Config) -> None:
    """Compile once, not in every worker, run and CLI subprocess: write bytecode even where the
    environment says not to (PYTHONDONTWRITEBYTECODE), for pytest's rewritten test modules and
    for rigtool, which the controller compiles before any worker or subprocess starts. One BLAS
    thread per process: the suite's parallelism is its workers, and OpenBLAS threads spinning
    beside another worker cost a third more CPU on the GP tests for no faster result."""
    sys.dont_write_bytecode = False
    for threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.setdefault(threads, "1")
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        compileall.compile_dir(ROOT / "rigtool", quiet=2)


# Test files that take over ~30 s in one process (idle machine), longest first. They are
# handed out first under `--dist loadfile`, so that no worker is left running one of them
# alone at the end of the run. Re-measure with `--durations` when the suite changes.
LONG_FILES = ("test_resumed_zero.py", "test_hostile_readback.py", "test_shipped_protocols.py",
              "test_supply_safety.py", "test_drift_dead_zones.py", "test_import_tables.py",
              "test_cavitation_intervals.py", "test_fuzz_config.py", "test_voltage_sweep.py",
              "test_watch.py", "test_import_hostile.py", "test_state_hostile.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the long files first; every other file keeps its place (the sort is stable)."""
    rank = {name: i for i, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture
def terminal_signals():
    """Signals as at an interactive shell, for a test that sends them: SIGINT raises
    KeyboardInterrupt, SIGTERM and SIGHUP have their default action, here and in the
    processes the test starts. A suite launched in the background inherits SIGINT ignored
    (`cmd &` in a script) and under nohup SIGHUP too, and rigtool rightly keeps ignoring what
    its launcher ignored; so such a test sets what it needs, and the launch's dispositions
    come back after it."""
    wanted = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL,
              signal.SIGHUP: signal.SIG_DFL}
    before = {sig: signal.signal(sig, handler) for sig, handler in wanted.items()}
    yield
    for sig, handler in before.items():
        signal.signal(sig, handler)


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


def copy_db(src: Path, dst: Path) -> Path:
    """A consistent copy of the SQLite database `src` at `dst` (SQLite's online backup), for a
    test that writes to a database another test also reads."""
    with sqlite3.connect(src) as source, sqlite3.connect(dst) as target:
        source.backup(target)
    source.close()
    target.close()
    return dst


def shared_dir(tmp_path_factory) -> Path:
    """A folder for what a whole test run builds once: the run's base temporary folder, which
    under pytest-xdist every worker of the run shares."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = root / "shared"
    folder.mkdir(exist_ok=True)
    return folder


@pytest.fixture(scope="session")
def shipped_sweep(tmp_path_factory) -> Callable[[str], Path]:
    """`shipped_sweep(name)`: the database of one `rigtool sweep protocols/<name>.yaml --sim`,
    swept on first use by whichever pytest-xdist worker asks first (the others wait on a lock)
    and kept for the test run. Read it, or `copy_db` it before writing: other tests start
    from the same file."""
    from rigtool.cli import main

    folder = shared_dir(tmp_path_factory)

    def sweep(name: str) -> Path:
        db, done = folder / f"{name}.sqlite", folder / f"{name}.done"
        with open(folder / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not done.exists():
                db.unlink(missing_ok=True)  # a worker that failed half-way
                assert main(["sweep", str(PROTOCOLS / f"{name}.yaml"), "--sim", "--db",
                             str(db)]) == 0
                done.touch()
        return db

    return sweep


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
