"""Benchmark: storage layouts for bulk samples, measured on the same data.

The same synthetic run (points x samples of the 13 sample columns, noise-like values as a
sensor gives them) is written and read back in five layouts:

- rows: today's `samples` table, one row per sample, `executemany` in one transaction per point;
- blob64: one row per point in a `sample_blocks` table, each column a float64 BLOB
  (`ndarray.tobytes`), in the point's transaction;
- blob32: the same with float32 for the measured channels (t_s and seq stay 64-bit);
- blob64z: blob64 compressed with zlib level 1;
- parquet: a Parquet sidecar file, one row group per point (pyarrow), points listed in SQLite.

For each: ingest rate (as a ratio to rows, measured in this process), reading one column and
all columns of the run, file size in bytes per sample; and crash consistency: a child process
writes points in a loop and is killed with SIGKILL; every point the database lists must then
be whole (every column holds its n samples) and readable.

    python benchmarks/bench_storage.py [--points 400] [--samples 3000]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import signal
import sqlite3
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

COLUMNS = ("t_s", "fx", "fy", "fz", "tx", "ty", "tz", "thrust_n", "speed_rpm", "current_a",
           "voltage_v", "command", "seq")
WIDE = ("t_s", "seq")  # kept 64-bit in blob32


def make_points(n_points: int, n_samples: int, seed: int = 7) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out, t0, seq0 = [], 0.0, 0
    for k in range(n_points):
        level = 40 * np.sin(k / 30)
        cols = {c: level * 0.01 + rng.normal(0, 0.05, n_samples) for c in COLUMNS}
        cols["t_s"] = t0 + np.arange(n_samples) / 1000.0
        cols["thrust_n"] = level + rng.normal(0, 0.4, n_samples)
        cols["speed_rpm"] = 30 * level + rng.normal(0, 10, n_samples)
        cols["command"] = np.full(n_samples, float(k))
        cols["seq"] = np.arange(seq0, seq0 + n_samples, dtype=np.int64)
        out.append(cols)
        t0 += n_samples / 1000.0 + 1.0
        seq0 += n_samples
    return out


def connect(path: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(path, isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")
    conn.execute("CREATE TABLE IF NOT EXISTS steps (id INTEGER PRIMARY KEY, n INTEGER)")
    return conn


class Rows:
    name = "rows"

    def __init__(self, path: Path) -> None:
        self.conn = connect(path)
        cols = ", ".join(f"{c} {'INTEGER' if c == 'seq' else 'REAL'}" for c in COLUMNS)
        self.conn.execute(f"CREATE TABLE IF NOT EXISTS samples (step_id INTEGER, {cols})")
        self.conn.execute("CREATE INDEX IF NOT EXISTS samples_step ON samples(step_id)")
        self.sql = (f"INSERT INTO samples (step_id, {', '.join(COLUMNS)}) "
                    f"VALUES (?{', ?' * len(COLUMNS)})")

    def write(self, k: int, cols: dict[str, np.ndarray]) -> None:
        n = cols["t_s"].size
        rows = zip([k] * n, *(cols[c].tolist() for c in COLUMNS), strict=True)
        self.conn.execute("BEGIN IMMEDIATE")
        self.conn.execute("INSERT INTO steps (id, n) VALUES (?, ?)", (k, n))
        self.conn.executemany(self.sql, rows)
        self.conn.execute("COMMIT")

    def read(self, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
        cur = self.conn.execute(f"SELECT {', '.join(columns)} FROM samples s JOIN steps st ON "
                                "st.id = s.step_id ORDER BY st.id")
        data = np.array(cur.fetchall(), dtype=float)
        return {c: data[:, i] for i, c in enumerate(columns)}

    def check(self) -> tuple[int, int]:
        """(points listed, points whole)."""
        listed = self.conn.execute("SELECT id, n FROM steps").fetchall()
        counts = dict(self.conn.execute("SELECT step_id, count(*) FROM samples GROUP BY step_id"))
        return len(listed), sum(counts.get(k, 0) == n for k, n in listed)

    def close(self) -> None:
        self.conn.close()


class Blobs(Rows):
    def __init__(self, path: Path, dtype: str = "f8", compress: bool = False) -> None:
        self.name = "blob" + ("32" if dtype == "f4" else "64") + ("z" if compress else "")
        self.dtype, self.compress = dtype, compress
        self.conn = connect(path)
        cols = ", ".join(f"{c} BLOB" for c in COLUMNS)
        self.conn.execute(f"CREATE TABLE IF NOT EXISTS sample_blocks (step_id INTEGER PRIMARY "
                          f"KEY, n INTEGER, {cols})")
        self.sql = (f"INSERT INTO sample_blocks (step_id, n, {', '.join(COLUMNS)}) "
                    f"VALUES (?, ?{', ?' * len(COLUMNS)})")

    def _dtype(self, c: str) -> str:
        return ("i8" if c == "seq" else "f8") if c in WIDE else self.dtype

    def write(self, k: int, cols: dict[str, np.ndarray]) -> None:
        n = cols["t_s"].size
        blobs = [np.ascontiguousarray(cols[c], dtype=self._dtype(c)).tobytes() for c in COLUMNS]
        if self.compress:
            blobs = [zlib.compress(b, 1) for b in blobs]
        self.conn.execute("BEGIN IMMEDIATE")
        self.conn.execute("INSERT INTO steps (id, n) VALUES (?, ?)", (k, n))
        self.conn.execute(self.sql, (k, n, *blobs))
        self.conn.execute("COMMIT")

    def read(self, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
        rows = self.conn.execute(f"SELECT n, {', '.join(columns)} FROM sample_blocks "
                                 "ORDER BY step_id").fetchall()
        total = sum(r[0] for r in rows)
        out = {c: np.empty(total) for c in columns}
        pos = 0
        for row in rows:
            n = row[0]
            for c, blob in zip(columns, row[1:], strict=True):
                raw = zlib.decompress(blob) if self.compress else blob
                out[c][pos:pos + n] = np.frombuffer(raw, dtype=self._dtype(c))
            pos += n
        return out

    def check(self) -> tuple[int, int]:
        listed = dict(self.conn.execute("SELECT id, n FROM steps").fetchall())
        whole = 0
        for k, *blobs in self.conn.execute(f"SELECT step_id, {', '.join(COLUMNS)} FROM "
                                           "sample_blocks"):
            sizes = {len(zlib.decompress(b) if self.compress else b) // np.dtype(
                self._dtype(c)).itemsize for c, b in zip(COLUMNS, blobs, strict=True)}
            whole += sizes == {listed.get(k)}
        return len(listed), whole


class ParquetSidecar(Rows):
    name = "parquet"

    def __init__(self, path: Path) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.pa, self.pq = pa, pq
        self.conn = connect(path)
        self.file = path.with_suffix(".parquet")
        self.schema = pa.schema([(c, pa.int64() if c == "seq" else pa.float64())
                                 for c in COLUMNS])
        self.writer = None

    def write(self, k: int, cols: dict[str, np.ndarray]) -> None:
        if self.writer is None:
            self.writer = self.pq.ParquetWriter(self.file, self.schema, compression="none")
        self.writer.write_table(self.pa.table({c: cols[c] for c in COLUMNS}, schema=self.schema))
        self.conn.execute("INSERT INTO steps (id, n) VALUES (?, ?)", (k, cols["t_s"].size))

    def finish(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None

    def read(self, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
        table = self.pq.read_table(self.file, columns=list(columns))
        return {c: table.column(c).to_numpy() for c in columns}

    def check(self) -> tuple[int, int]:
        listed = self.conn.execute("SELECT count(*) FROM steps").fetchone()[0]
        try:
            n = self.pq.ParquetFile(self.file).metadata.num_row_groups
        except Exception:  # noqa: BLE001 - a killed writer leaves no footer
            n = 0
        return listed, min(n, listed)

    def close(self) -> None:
        self.finish()
        self.conn.close()


LAYOUTS = {"rows": Rows, "blob64": Blobs, "blob32": lambda p: Blobs(p, "f4"),
           "blob64z": lambda p: Blobs(p, compress=True), "parquet": ParquetSidecar}


def size_of(path: Path) -> int:
    return sum(f.stat().st_size for f in path.parent.iterdir()
               if f.name.startswith(path.stem))


def _writer_forever(layout: str, path: str, n_samples: int) -> None:
    store = LAYOUTS[layout](Path(path))
    points = make_points(4, n_samples)
    k = 0
    while True:
        store.write(k, points[k % 4])
        k += 1


def crash_check(layout: str, root: Path, n_samples: int) -> tuple[int, int]:
    """Kill a writer mid-run with SIGKILL; (points listed, points whole) afterwards."""
    path = root / f"crash-{layout}.sqlite"
    proc = mp.get_context("spawn").Process(target=_writer_forever,
                                           args=(layout, str(path), n_samples))
    proc.start()
    time.sleep(2.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.join()
    store = LAYOUTS[layout](path)
    try:
        return store.check()
    finally:
        store.conn.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=400)
    parser.add_argument("--samples", type=int, default=3000)
    args = parser.parse_args()
    points = make_points(args.points, args.samples)
    total = args.points * args.samples
    print(f"{args.points} points x {args.samples} samples = {total / 1e6:.2f} M samples, "
          f"{len(COLUMNS)} columns")
    print(f"{'layout':8} {'ingest s':>9} {'vs rows':>8} {'read 1 col s':>12} {'read all s':>10} "
          f"{'B/sample':>9} {'after kill -9: listed/whole':>28}")
    base = None
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name, make in LAYOUTS.items():
            path = root / f"{name}.sqlite"
            store = make(path)
            t0 = time.perf_counter()
            for k, cols in enumerate(points):
                store.write(k, cols)
            if hasattr(store, "finish"):
                store.finish()
            ingest = time.perf_counter() - t0
            base = base or ingest
            t0 = time.perf_counter()
            one = store.read(("thrust_n",))
            read1 = time.perf_counter() - t0
            t0 = time.perf_counter()
            every = store.read(COLUMNS)
            read_all = time.perf_counter() - t0
            want = np.concatenate([p["thrust_n"] for p in points])
            tol = 1e-6 * np.max(np.abs(want)) if name == "blob32" else 0.0
            assert np.max(np.abs(one["thrust_n"] - want)) <= tol and every["t_s"].size == total
            store.close()
            listed, whole = crash_check(name, root, args.samples)
            print(f"{name:8} {ingest:9.2f} {base / ingest:7.2f}x {read1:12.3f} {read_all:10.3f} "
                  f"{size_of(path) / total:9.1f} {listed:>15} / {whole}", flush=True)


if __name__ == "__main__":
    main()
