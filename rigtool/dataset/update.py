"""`rigtool export --all DIR`: bring the Hive-partitioned dataset in DIR up to date with a run
database. A run is rewritten only when its fingerprint (points, status, calibrations, events,
the dataset layout) differs from the one the manifest recorded, or its file is missing or of
another size; every other partition is left untouched. Runs the database does not hold are
kept (a lab exports each rig's database into one DIR), marked in the manifest. A run whose
thruster id cannot name a folder (stored before the protocol refused such ids) is left out
and named in `Summary.skipped`; the other runs are exported."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from rigtool.dataset.files import (
    LOCK,
    exclusive,
    partition_dir,
    remove_partition,
    replace_atomically,
    temp_name,
)
from rigtool.dataset.hive import segment
from rigtool.dataset.manifest import MANIFEST, Entry, read_manifest, write_manifest
from rigtool.dataset.partition import DATA_FILE, DATASET_VERSION, SCHEMA, write_partition
from rigtool.dataset.tables import CALIBRATIONS_FILE, OLD_TABLE_FILES, RUNS_FILE, write_tables
from rigtool.errors import DataError, RigtoolError, UsageError
from rigtool.ids import utc_now
from rigtool.progress_hook import ProgressHook, counted, no_progress
from rigtool.store import RunRecord, Store
from rigtool.version import __version__

CHECKPOINT_S = 10.0  # the manifest is saved this often during a long export


@dataclass
class Summary:
    """What one export did."""

    written: list[str] = field(default_factory=list)  # runs whose partition was (re)written
    unchanged: int = 0
    kept: list[str] = field(default_factory=list)  # in the dataset, not in this database
    skipped: list[str] = field(default_factory=list)  # why each run it cannot file was left out
    runs: int = 0  # runs the dataset holds now
    rows: int = 0  # sample rows it holds now


def export_dataset(store: Store, folder: Path, progress: ProgressHook = no_progress) -> Summary:
    """Update the dataset in `folder` from `store` (see the module docstring). Runs are
    planned and checked before the folder is made or anything is written in it; each run
    written is reported to `progress`."""
    _check_folder(folder)
    old = read_manifest(folder) if folder.is_dir() else None
    with store.snapshot():
        update = _Update(store, folder, old or {})
        todo = update.plan()
        for record, _ in todo:  # a damaged run is refused before any file is written
            store.check_run(record.id)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise UsageError(f"--all {folder}: a part of the path is a file; give a folder "
                             "for the dataset") from None
        with exclusive(folder):
            if read_manifest(folder) != old:
                raise RigtoolError(f"another rigtool export changed {folder} meanwhile; run "
                                   "this one again")
            if old is None:  # marks the folder as a dataset before any partition is written
                write_manifest(folder, {}, _schema_names(), DATASET_VERSION)
            return update.write(todo, progress)


def _check_folder(folder: Path) -> None:
    """Refuse a file, or a folder holding something other than a rigtool dataset."""
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"--all {folder}: is a file; give a folder for the dataset")
    own = {LOCK, temp_name(folder / MANIFEST).name}  # what a first export killed leaves
    if (folder.is_dir() and not (folder / MANIFEST).is_file()
            and any(p.name not in own or p.is_symlink() or not p.is_file()
                    for p in folder.iterdir())):
        raise UsageError(f"--all {folder}: the folder holds files but no rigtool dataset "
                         f"({MANIFEST}); give an empty or new folder")


def _schema_names() -> dict[str, str]:
    """The samples table's columns and types, as the manifest lists them."""
    return {f.name: str(f.type) for f in SCHEMA}


def _intact(path: Path, entry: Entry) -> bool:
    """Whether the partition file the manifest lists is there, of the size it recorded."""
    try:
        return path.stat().st_size == entry.bytes
    except OSError:
        return False


def partition_file(folder: Path, run_id: str, thruster_id: str | None) -> Path:
    """Where a run's partition file is: DIR/thruster_id=<id>/run_id=<id>/samples.parquet."""
    return folder / segment("thruster_id", thruster_id, run_id) / segment(
        "run_id", run_id, run_id) / DATA_FILE


class _Update:
    """One export: plan from fingerprints, write the changed runs, save the manifest."""

    def __init__(self, store: Store, folder: Path, old: dict[str, Entry]) -> None:
        self.store, self.folder, self.old = store, folder, old
        self.runs: dict[str, Entry] = {}
        self.summary = Summary()
        self.saved_at = time.monotonic()

    def write(self, todo: list[tuple[RunRecord, dict]],
              progress: ProgressHook = no_progress) -> Summary:
        """Write the planned runs, then the runs and calibrations tables and the manifest if
        anything changed; tables under their old names are removed once the new ones are in."""
        for record, fingerprint in counted(todo, "runs written", progress):
            self._write(record, fingerprint)
            if time.monotonic() - self.saved_at > CHECKPOINT_S:
                self._save()
        old_tables = [self.folder / name for name in OLD_TABLE_FILES
                      if (self.folder / name).exists() or (self.folder / name).is_symlink()]
        changed = (bool(todo) or self.runs != self.old or bool(old_tables)
                   or not (self.folder / CALIBRATIONS_FILE).is_file()
                   or not (self.folder / RUNS_FILE).is_file())
        if changed:
            write_tables(self.folder, {
                run_id: (partition_file(self.folder, run_id, e.thruster_id), e)
                for run_id, e in self.runs.items()})
            self._save()
        for path in old_tables:  # a dataset of the old names: its tables now have new ones
            path.unlink()
        self.summary.runs = len(self.runs)
        self.summary.rows = sum(e.rows for e in self.runs.values())
        return self.summary

    def plan(self) -> list[tuple[RunRecord, dict]]:
        """The runs to write with their fingerprints; the others carried over as they are."""
        todo = []
        here = set()
        for fingerprint in self.store.run_fingerprints():
            run_id = fingerprint.pop("run_id")
            here.add(run_id)
            record = self.store.run_record(run_id)
            fingerprint.update(dataset_version=DATASET_VERSION, thruster_id=record.thruster_id,
                               rig=record.rig_name)
            entry = self.old.get(run_id)  # its file is where the entry's thruster id puts it
            intact = entry is not None and _intact(
                partition_file(self.folder, run_id, entry.thruster_id), entry)
            if intact and entry.fingerprint == fingerprint:
                self.runs[run_id] = Entry(**{**entry.__dict__, "in_last_source": True})
                self.summary.unchanged += 1
                continue
            if intact:  # listed as it is on disk until its new file replaces it
                self.runs[run_id] = entry
            try:  # an id no folder takes (an older database's): the run is left out
                partition_file(self.folder, run_id, record.thruster_id)
            except DataError as exc:
                self.summary.skipped.append(str(exc))
                continue
            todo.append((record, fingerprint))
        for run_id, entry in self.old.items():
            if run_id not in here and _intact(
                    partition_file(self.folder, run_id, entry.thruster_id), entry):
                self.runs[run_id] = Entry(**{**entry.__dict__, "in_last_source": False})
                self.summary.kept.append(run_id)
        return todo

    def _write(self, record: RunRecord, fingerprint: dict) -> None:
        """Replace one run's partition file, and drop its old one if the run moved."""
        path = partition_file(self.folder, record.id, record.thruster_id)
        partition_dir(self.folder, *path.relative_to(self.folder).parts[:-1])
        rows = 0

        def write(tmp: Path) -> None:
            nonlocal rows
            rows = write_partition(self.store, record, tmp)

        replace_atomically(path, write)
        before = self.old.get(record.id)
        if before is not None and before.thruster_id != record.thruster_id:
            remove_partition(self.folder, partition_file(self.folder, record.id,
                                                         before.thruster_id))
        self.runs[record.id] = Entry(
            thruster_id=record.thruster_id, rig=record.rig_name, status=record.status,
            fingerprint=fingerprint, file=path.relative_to(self.folder).as_posix(), rows=rows,
            bytes=path.stat().st_size, points=fingerprint["points"],
            calibrated_utc=fingerprint["calibrated_utc"], rigtool_version=__version__,
            written_utc=utc_now(), source=str(self.store.path.resolve()), in_last_source=True)
        self.summary.written.append(record.id)

    def _save(self) -> None:
        write_manifest(self.folder, self.runs, _schema_names(), DATASET_VERSION)
        self.saved_at = time.monotonic()
