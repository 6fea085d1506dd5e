"""Read the files a user names: regular files only, size-capped, never blocking on a FIFO.

A FIFO, a device such as /dev/zero, or a symlink to one would hang rigtool or fill its
memory, so every config, DBC and CSV file is opened through `read_regular_bytes` (or, for
large logs, `iter_regular_bytes`).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

from rigtool.errors import ConfigError

MAX_CONFIG_BYTES = 1 << 20  # protocol, rig and import-mapping YAML files: 1 MiB
MAX_DBC_BYTES = 16 << 20  # DBC files: whole-vehicle databases run to a few MiB
MAX_TABLE_BYTES = 2 << 30  # CSV logs for `rigtool import`: 2 GiB
_READ_CHUNK = 1 << 20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


class UnreadableFile(ConfigError):
    """A named file is missing, not a regular file, too large or cannot be read (exit 2)."""

    def __init__(self, path: Path, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__([f"{path}: {problem}"])


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "something else")


def _size(n: int) -> str:
    return f"{n / (1 << 30):g} GiB" if n >= 1 << 30 else f"{n / (1 << 20):g} MiB"


def check_regular_file(path: str | Path, max_bytes: int) -> os.stat_result:
    """Stat `path` (following symlinks); refuse anything but a regular file of at most `max_bytes`."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise UnreadableFile(path, "file not found") from None
    except (OSError, ValueError) as exc:
        raise UnreadableFile(path, f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    _check_stat(path, st, max_bytes)
    return st


def _check_stat(path: Path, st: os.stat_result, max_bytes: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise UnreadableFile(path, f"not a regular file: it is {_kind(st.st_mode)} "
                                   "(rigtool reads only regular files)")
    if st.st_size > max_bytes:
        raise UnreadableFile(path, f"file too large ({st.st_size:,} bytes; the limit is "
                                   f"{_size(max_bytes)})")


def read_regular_bytes(path: str | Path, max_bytes: int) -> bytes:
    """The bytes of the regular file `path`, at most `max_bytes`; UnreadableFile otherwise."""
    return b"".join(iter_regular_bytes(path, max_bytes))


def iter_regular_bytes(path: str | Path, max_bytes: int) -> Iterator[bytes]:
    """The bytes of the regular file `path` in blocks of up to 1 MiB, at most `max_bytes` in
    all (UnreadableFile past that), so a large log is read without holding it whole.

    The file is opened non-blocking and checked again through its descriptor, so a FIFO
    or device swapped in after the first check is refused instead of read.
    """
    path = Path(path)
    check_regular_file(path, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise UnreadableFile(path, f"cannot read: {exc.strerror or exc}") from None
    try:
        try:
            st = os.fstat(fd)
        except OSError as exc:
            raise UnreadableFile(path, f"cannot read: {exc.strerror or exc}") from None
        _check_stat(path, st, max_bytes)
        total = 0
        while True:
            try:
                chunk = os.read(fd, min(_READ_CHUNK, max_bytes + 1 - total))
            except OSError as exc:
                raise UnreadableFile(path, f"cannot read: {exc.strerror or exc}") from None
            if not chunk:
                return
            total += len(chunk)
            if total > max_bytes:
                raise UnreadableFile(path, "file too large (grew past the limit of "
                                           f"{_size(max_bytes)})")
            yield chunk
    finally:
        os.close(fd)


def decode_utf8(path: Path, data: bytes) -> str:
    """`data` as UTF-8 text (a BOM is dropped); ConfigError names the line of the first bad byte."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ConfigError([f"{path}:{line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at "
                           f"offset {exc.start}); save the file as UTF-8"]) from None


def read_regular_text(path: str | Path, max_bytes: int) -> str:
    """The UTF-8 text of the regular file `path`, at most `max_bytes` long."""
    path = Path(path)
    return decode_utf8(path, read_regular_bytes(path, max_bytes))
