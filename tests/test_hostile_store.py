"""Hostile input in the run database and in user text, through the CLI: Rich markup in run
names, run-id references, ids that are paths, a full disk, and exports taken mid-sweep."""

from __future__ import annotations

import csv
import os
import resource
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.export import export_run
from rigtool.store import Store

NAME = "tank-2 [/] run [bold]"
THRUSTER = "[red]stern[/red] [/]"
PROTOCOL = f"""\
rigtool_protocol: 1
name: "{NAME}"
simulator: {{profile: stm32-pwm, seed: 5}}
metadata: {{thruster_id: "{THRUSTER}"}}
command: {{unit: pwm_counts, values: [400, 430, 460], order: up}}
depth: {{unit: cm, values: [30], mode: preset}}
timing: {{settle: {{seconds: 0.2}}, acquire: {{samples: 40, rate_hz: 250}}, rest_s: 0.0,
         tare: per_depth}}
limits: {{max_thrust_n: 10}}
"""


def _last_id(db: Path) -> str:
    store = Store(db, read_only=True)
    try:
        return store.resolve_run_id("last")
    finally:
        store.close()


@pytest.fixture
def swept(tmp_path, capsys) -> tuple[Path, Path, str]:
    """A finished run named with Rich markup: (protocol file, database, run id)."""
    protocol = tmp_path / "markup.yaml"
    protocol.write_text(PROTOCOL)
    db = tmp_path / "db.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    capsys.readouterr()
    return protocol, db, _last_id(db)


# -- untrusted text -----------------------------------------------------------------------
def test_markup_in_names_is_printed_literally(swept, capsys):
    protocol, db, run_id = swept
    assert main(["runs", "--db", str(db)]) == 0
    assert NAME in capsys.readouterr().out
    assert main(["show", run_id, "--db", str(db)]) == 0
    shown = capsys.readouterr().out
    assert NAME in shown and THRUSTER in shown
    assert main(["sweep", str(protocol), "--sim", "--dry-run"]) == 0
    assert NAME in capsys.readouterr().out


def test_csv_comment_header_survives_a_newline_in_a_run_id(swept, tmp_path, capsys):
    _, db, run_id = swept
    evil = "x\nthrust_n,0\n# y"
    _rename_run(db, run_id, evil)
    assert main(["calibrate", evil[:1], "--db", str(db), "--out", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    (folder,) = (tmp_path / "out").iterdir()
    assert "\n" not in folder.name
    for csv_file in folder.glob("*.csv"):
        lines = csv_file.read_text().splitlines()
        body = [ln for ln in lines if not ln.startswith("#")]
        widths = {len(row) for row in csv.reader(body)}  # RFC 4180: quoted cells
        assert len(widths) == 1, (csv_file.name, body[:3])


# -- run-id references --------------------------------------------------------------------
@pytest.mark.parametrize("ref", ["", "   ", "%", "_", "2026%", "____"])
def test_run_references_are_literal_prefixes(swept, ref, capsys):
    _, db, _ = swept
    for argv in (["show", ref], ["export", ref], ["sweep", "--resume", ref]):
        assert main([*argv, "--db", str(db)]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("rigtool: error: ") and "Traceback" not in err


def test_a_literal_prefix_still_resolves(swept, capsys):
    _, db, run_id = swept
    assert main(["show", run_id[:10], "--db", str(db)]) == 0
    assert run_id in capsys.readouterr().out


# -- paths built from ids -----------------------------------------------------------------
def _rename_run(db: Path, old: str, new: str) -> None:
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA foreign_keys=OFF")
    with conn:
        for table, column in (("runs", "id"), ("steps", "run_id"), ("events", "run_id"),
                              ("calibrations", "run_id")):
            conn.execute(f"UPDATE {table} SET {column} = ? WHERE {column} = ?", (new, old))
    conn.close()


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file()}


@pytest.mark.parametrize("crafted", ["../../x", "/absolute/x", "..", "a/../../b"])
def test_crafted_run_ids_never_write_outside_the_output_folder(swept, tmp_path, crafted, capsys):
    _, db, run_id = swept
    _rename_run(db, run_id, crafted)
    out = tmp_path / "a" / "b" / "c" / "out"
    before = _files(tmp_path)
    prefix = crafted[:2]
    assert main(["calibrate", prefix, "--db", str(db), "--out", str(out)]) == 0
    assert main(["report", prefix, "--db", str(db), "--out", str(out)]) == 0
    assert main(["export", prefix, "--db", str(db), "--out", str(out / "export")]) == 0
    capsys.readouterr()
    new = _files(tmp_path) - before - {db.with_name(db.name + s) for s in ("-wal", "-shm")}
    assert new and all(out in p.parents for p in new), sorted(map(str, new))


def test_a_symlink_out_of_the_output_folder_is_refused(swept, tmp_path, capsys):
    _, db, run_id = swept
    out = tmp_path / "out"
    out.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / run_id).symlink_to(elsewhere)
    assert main(["calibrate", run_id, "--db", str(db), "--out", str(out)]) == 2
    assert "outside" in capsys.readouterr().err
    assert not any(elsewhere.iterdir())


# -- a full disk --------------------------------------------------------------------------
def _limit_file_size() -> None:
    """A full disk, as SQLite sees it: no file this process writes may grow past 1 KiB."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (1024, 1024))


def _cli_on_full_disk(*args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "RIGTOOL_DB"}
    return subprocess.run([sys.executable, "-m", "rigtool.cli", *args], env=env, text=True,
                          capture_output=True, timeout=60, preexec_fn=_limit_file_size)


def test_read_commands_work_on_a_full_disk_and_the_dead_run_is_marked_later(swept, capsys):
    _, db, run_id = swept
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    holder = sqlite3.connect(db)  # keeps the WAL and its index, as a live process would
    with holder:
        holder.execute("UPDATE runs SET status = 'running', finished_utc = NULL, pid = ? "
                       "WHERE id = ?", (dead.pid, run_id))
    try:
        runs = _cli_on_full_disk("runs", "--db", str(db))
        assert runs.returncode == 0, runs.stderr
        assert run_id in runs.stdout and "running" in runs.stdout
        assert "could not mark" in runs.stderr
        show = _cli_on_full_disk("show", run_id, "--db", str(db))
        assert show.returncode == 0, show.stderr
        assert NAME in show.stdout
        calibrate = _cli_on_full_disk("calibrate", run_id, "--db", str(db), "--out",
                                      str(db.parent / "cal"))
        assert calibrate.returncode != 0 and "Traceback" not in calibrate.stderr
        assert "rigtool: error: " in calibrate.stderr
    finally:
        holder.close()
    assert main(["runs", "--db", str(db)]) == 0  # the disk has room again
    capsys.readouterr()
    store = Store(db, read_only=True)
    assert store.run(run_id)["status"] == "interrupted"
    store.close()


def test_a_read_only_store_of_an_older_schema_asks_for_an_upgrade(tmp_path, capsys):
    db = tmp_path / "old.sqlite"
    Store(db).close()
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA user_version = 1")
    conn.close()
    assert main(["runs", "--db", str(db)]) == 1
    assert "one-time upgrade" in capsys.readouterr().err


# -- consistency --------------------------------------------------------------------------
def test_export_reads_one_snapshot_while_a_sweep_appends(swept, tmp_path):
    _, db, run_id = swept
    store = Store(db, read_only=True)
    writer = sqlite3.connect(db)
    appended = []

    def append_a_point(statement: str) -> None:
        if "FROM sample_blocks" in statement and not appended:
            with writer:
                (last,) = writer.execute("SELECT max(idx) FROM steps WHERE run_id = ?",
                                         (run_id,)).fetchone()
                cols = [r[1] for r in writer.execute("PRAGMA table_info(steps)")]
                row = writer.execute("SELECT * FROM steps WHERE run_id = ? AND idx = ?",
                                     (run_id, last)).fetchone()
                values = dict(zip(cols, row, strict=True))
                values.update(id=None, idx=last + 1)
                cur = writer.execute(
                    f"INSERT INTO steps ({', '.join(values)}) VALUES "
                    f"({', '.join('?' * len(values))})", tuple(values.values()))
                writer.execute("INSERT INTO sample_blocks (step_id, chunk, n, t_s, thrust_n) "
                               "VALUES (?, 0, 1, ?, ?)", (cur.lastrowid, np.zeros(1).tobytes(),
                                                          np.ones(1).tobytes()))
            appended.append(True)

    store.conn.set_trace_callback(append_a_point)
    paths = export_run(store, run_id, tmp_path / "exp")
    store.conn.set_trace_callback(None)
    assert appended
    with paths[0].open() as fh:
        points = {row["step_idx"] for row in csv.DictReader(fh)}
    with paths[1].open() as fh:
        sample_points = {row["step_idx"] for row in csv.DictReader(fh)}
    assert points == sample_points
    store.close()
    writer.close()


def test_samples_are_one_snapshot_while_a_sweep_appends(swept):
    """samples() sizes its arrays, then fills them; blocks a sweep commits between the two
    are neither half seen nor overflowing, and the next read has them."""
    _, db, run_id = swept
    store = Store(db, read_only=True)
    before = len(store.samples(run_id, ["t_s"])["t_s"])
    writer = sqlite3.connect(db)
    step_id = writer.execute("SELECT max(id) FROM steps WHERE run_id = ?", (run_id,)).fetchone()[0]
    added = []

    def add_samples(statement: str) -> None:
        if statement.startswith("SELECT b.n") and not added:  # after the count, before the blocks
            with writer:
                writer.execute("INSERT INTO sample_blocks (step_id, chunk, n, t_s, thrust_n) "
                               "VALUES (?, 99, 3, ?, ?)", (step_id, (1e6 + np.arange(3)).tobytes(),
                                                          np.ones(3).tobytes()))
            added.append(True)

    store.conn.set_trace_callback(add_samples)
    got = store.samples(run_id, ["t_s", "thrust_n"])
    store.conn.set_trace_callback(None)
    assert added and len(got["t_s"]) == before == len(got["thrust_n"])
    again = store.samples(run_id, ["t_s", "thrust_n"])
    assert len(again["t_s"]) == before + 3 and set(again["t_s"][-3:]) == {1e6, 1e6 + 1, 1e6 + 2}
    store.close()
    writer.close()
