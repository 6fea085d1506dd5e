"""Run ids and timestamps: what `new_run_id` makes, how to recognise and print one, and UTC now;
which names and ids can name a partition folder of the lab dataset (one rule for the protocol
that accepts an id and the dataset that files it).

Kept outside the store so the engine, reports and artefacts can stamp and name runs without
importing it.
"""

from __future__ import annotations

import re
import secrets
import unicodedata
from datetime import datetime, timezone

from rigtool.readback import show

RUN_ID_GRAMMAR = re.compile(r"\d{8}T\d{9}Z-[0-9a-f]{6}")  # what new_run_id makes
HIVE_NULL = "__HIVE_DEFAULT_PARTITION__"  # Hive's folder value for null (and the empty text)
MAX_FOLDER_BYTES = 255  # NAME_MAX of ext4, APFS, NTFS
# Hive's FileUtils.escapePathName set (control characters, " # % ' * / : = ? \ DEL { [ ] ^),
# with the characters Spark also escapes on Windows (space < > |).
_ESCAPED = frozenset([chr(c) for c in range(0x20)] + list("\"#%'*/:=?\\\x7f{[]^ <>|"))
_UNSEEN = {"Cc": "control character", "Cf": "invisible format character",
           "Zl": "line separator", "Zp": "paragraph separator"}


def utc_now(timespec: str = "seconds") -> str:
    """ISO-8601 UTC timestamp, to the second unless `timespec` asks for finer."""
    return datetime.now(timezone.utc).isoformat(timespec=timespec)


def new_run_id() -> str:
    """Sortable, cross-machine unique id: UTC time to the millisecond plus 24 random bits."""
    now = datetime.now(timezone.utc)
    return now.strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z-" + secrets.token_hex(3)


def is_run_id(text: object) -> bool:
    """Whether `text` is a run id as `new_run_id` makes them (safe as a file name)."""
    return isinstance(text, str) and RUN_ID_GRAMMAR.fullmatch(text) is not None


def run_label(run_id: object) -> str:
    """A run id for a one-line message: as it is when well formed, else quoted and cut."""
    return run_id if is_run_id(run_id) else show(run_id)  # type: ignore[return-value]


def label_problem(text: str) -> str | None:
    """Why `text` cannot be a run name or thruster id, or None: a character that prints as
    nothing (a control or format character) would let two ids read alike in the C headers,
    SDF and YAML files they name."""
    for i, char in enumerate(text):
        kind = _UNSEEN.get(unicodedata.category(char))
        if kind:
            return (f"{kind} U+{ord(char):04X} at position {i + 1} (names and ids go into "
                    "generated files: use printable characters)")
    return None


def folder_value(value: str | None) -> str:
    """`value` as the text after `key=` in a Hive partition folder name, percent-encoded;
    None and "" as HIVE_NULL, and the text HIVE_NULL itself with its first `_` encoded
    (DuckDB reads it back as text)."""
    if value is None or value == "":
        return HIVE_NULL
    if value == HIVE_NULL:
        return "%5F" + value[1:]
    return "".join(f"%{ord(c):02X}" if c in _ESCAPED else c for c in value)


def folder_problem(key: str, value: str | None) -> str | None:
    """Why `key=<value>` cannot be a partition folder name on every file system, or None."""
    try:
        size = len(f"{key}={folder_value(value)}".encode())
    except UnicodeEncodeError:
        return f"its {key} {value!r} is not valid text (a lone surrogate)"
    if size > MAX_FOLDER_BYTES:
        return (f"its {key} is {size - len(key) - 1:,} bytes as a folder name; at most "
                f"{MAX_FOLDER_BYTES - len(key) - 1} fit")
    return None
