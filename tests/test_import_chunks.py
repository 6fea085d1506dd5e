"""`rigtool import` reads a text log in chunks: the run it stores does not depend on the chunk
size or on where the file's read blocks end, and the lines are those of `str.splitlines`."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from rigtool import files
from rigtool.cli import main
from rigtool.importers import import_file, table
from rigtool.store import Store


def _log(path: Path, seed: int = 5) -> bytes:
    """A Tyto-style time series with CRLF line ends, a Latin-1 unit, blank and bad rows, a
    quoted cell over two lines, and a CR-only line end."""
    rng = np.random.default_rng(seed)
    rows = []
    for c in (1100, 1300, 1500, 1700, 1900):
        for _ in range(23):
            t = len(rows) * 0.01
            n = 30.0 * (c - 1500) + rng.normal(0, 5)
            rows.append(f"{t:.3f},{c},{1.9e-5 * abs(n) * n + rng.normal(0, 0.2):.5f},{n:.2f},"
                        f"{0.3 + 1e-9 * abs(n) ** 3:.4f}")
    rows[7] = rows[7].replace(",1100,", ",oops,")
    rows[40] = rows[40] + ',"note\r\nover two lines"'
    rows[61] = ""
    rows[88] = rows[88].rsplit(",", 1)[0] + ",1e999"
    text = ("Time (s),ESC signal (µs),Thrust (N),Motor Electrical Speed (RPM),Current (A)\r\n"
            + "\r\n".join(rows[:90]) + "\r" + "\r\n".join(rows[90:]) + "\r\n")
    data = text.encode("latin-1")
    path.write_bytes(data)
    return data


def _stored(db: Path, run_id: str) -> tuple:
    with Store(db, create=False) as store:
        steps = [{k: v for k, v in s.items() if k not in ("id", "run_id")}
                 for s in store.steps(run_id)]
        samples = store.samples(run_id, ("t_s", "command", "thrust_n", "current_a"))
        events = [(e["kind"], e["detail"]) for e in store.events(run_id)]
        rig = store.run(run_id)["rig"]
    return steps, {k: v.tobytes() for k, v in samples.items()}, events, rig


def test_chunk_size_and_read_blocks_do_not_change_the_run(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / "tyto.csv"
    data = _log(log)
    whole = tmp_path / "whole.sqlite"
    assert main(["import", str(log), "--db", str(whole)]) == 0
    with Store(whole, create=False) as store:
        (run_whole,) = store.run_ids()
        detail = store.events(run_whole, "import")[0]["detail"]
    assert detail["skipped"] == 2 and len(detail["errors"]) == 2  # "oops" and 1e999
    assert detail["errors"][0].endswith("command: 'oops' is not a number")
    monkeypatch.setattr(table, "ROWS_PER_CHUNK", 4)  # many chunks, bad rows in several
    monkeypatch.setattr(files, "_READ_CHUNK", 7)  # blocks split CRLF, the quoted cell, µ
    chunked = tmp_path / "chunked.sqlite"
    with Store(chunked) as store:
        result = import_file(store, log)
        assert (result.n_rows, result.n_skipped, result.n_steps) == (114, 2, 5)
    a, b = _stored(whole, run_whole), _stored(chunked, result.run_id)
    assert a[0] == b[0] and a[1] == b[1] and a[2] == b[2]
    assert a[3]["import"]["files"][0]["sha256"] == hashlib.sha256(data).hexdigest()
    assert b[3]["import"]["files"][0]["sha256"] == hashlib.sha256(data).hexdigest()


@pytest.mark.parametrize("text", [
    "a\r\nb\rc\n\nd", "a\r", "\r\n\r\n", "x\x0cy\x1cz\x85w\u2028v\u2029u\x0bt", "", "é\r\nü",
    "\ufeffhead\r\nrow", "x" * 50 + "\r\n" + "y" * 30 + "\r" + "z" * 9])
@pytest.mark.parametrize("block", [1, 2, 3, 1 << 20])
def test_lines_are_those_of_splitlines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       text: str, block: int) -> None:
    path = tmp_path / "t.csv"
    path.write_bytes(text.encode("utf-8"))
    monkeypatch.setattr(files, "_READ_CHUNK", block)
    digest = hashlib.sha256()
    assert list(table._lines(path, "utf-8-sig", digest)) == text.lstrip("\ufeff").splitlines()
    assert digest.hexdigest() == hashlib.sha256(text.encode("utf-8")).hexdigest()


def test_one_huge_line_is_refused_with_a_message(tmp_path: Path, capsys) -> None:
    log = tmp_path / "one-line.csv"
    log.write_bytes(b"7" * (12 << 20))  # 12 MiB and no line break: gathered in linear time
    assert main(["import", str(log), "--db", str(tmp_path / "db.sqlite")]) == 2
    assert "header cannot be read: a cell is longer than" in capsys.readouterr().err
