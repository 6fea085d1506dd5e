"""File-system steps of a dataset export: a file replaced atomically under a temporary name no
reader of the dataset picks up, one exporter at a time per folder, and partition folders kept
inside the dataset."""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

from rigtool.errors import RigtoolError, UsageError

LOCK = "_rigtool_export.lock"


def temp_name(path: Path) -> Path:
    """Where `path` is written before it is renamed into place: a leading `.` (pyarrow and
    Spark skip it) and a `.tmp` ending (DuckDB's `*.parquet` glob misses it)."""
    return path.with_name(f".{path.name}.tmp")


def replace_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """Write `path` through `write(temp path)`, flush it to disk, and rename it over `path`: a
    crash at any moment leaves the old file or the new one, never half of one."""
    tmp = temp_name(path)
    tmp.unlink(missing_ok=True)  # a leftover, or a planted symlink the writer would follow
    try:
        write(tmp)
        with tmp.open("rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def exclusive(folder: Path) -> Iterator[None]:
    """Hold the dataset folder's export lock: a second export into it is refused, not mixed."""
    path = folder / LOCK
    try:  # never through a planted symlink, never blocking on a planted FIFO
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        raise UsageError(f"{path}: cannot be opened as the export lock ({exc.strerror}); "
                         "remove it") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UsageError(f"{path} is not a file; remove it")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RigtoolError(f"another rigtool export is writing {folder}; try again when it "
                               "has finished") from None
        yield
    finally:
        os.close(fd)


def partition_dir(root: Path, *segments: str) -> Path:
    """`root`/segments, each folder made if missing; a symlink among them is refused, so no
    folder is ever made or written outside `root`."""
    folder = root
    for name in segments:
        folder = folder / name
        if folder.is_symlink():
            raise UsageError(f"{folder} is a symlink; a dataset's partition folders must be "
                             "folders: remove it or export to another folder")
        folder.mkdir(exist_ok=True)
    return folder


def remove_partition(root: Path, file: Path) -> None:
    """Delete a partition file and the folders it leaves empty, up to `root`."""
    file.unlink(missing_ok=True)
    folder = file.parent
    while folder != root and folder.is_relative_to(root):
        with contextlib.suppress(OSError):  # not empty: another run's partition is there
            folder.rmdir()
        folder = folder.parent
