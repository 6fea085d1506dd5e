"""Partition folder names the Hive way (`thruster_id=bow%2F1`), which DuckDB, pyarrow and Spark
decode back to the value: ids come from users and merged databases, so every character that
could split, hide or escape a path is percent-encoded, and a name too long for a folder is
refused."""

from __future__ import annotations

from rigtool.errors import DataError

HIVE_NULL = "__HIVE_DEFAULT_PARTITION__"  # Hive's folder value for null (and the empty text)
MAX_SEGMENT_BYTES = 255  # NAME_MAX of ext4, APFS, NTFS
# Hive's FileUtils.escapePathName set (control characters, " # % ' * / : = ? \ DEL { [ ] ^),
# with the characters Spark also escapes on Windows (space < > |).
_ESCAPED = frozenset([chr(c) for c in range(0x20)] + list("\"#%'*/:=?\\\x7f{[]^ <>|"))


def encode_value(value: str | None) -> str:
    """`value` as the text after `key=` in a folder name; None and "" as HIVE_NULL, and the
    text HIVE_NULL itself with its first `_` encoded (DuckDB reads it back as text)."""
    if value is None or value == "":
        return HIVE_NULL
    if value == HIVE_NULL:
        return "%5F" + value[1:]
    return "".join(f"%{ord(c):02X}" if c in _ESCAPED else c for c in value)


def segment(key: str, value: str | None, run_id: str) -> str:
    """The folder name `key=<encoded value>` of one partition level; a DataError naming the
    run when the value cannot be a folder name on every file system."""
    name = f"{key}={encode_value(value)}"
    try:
        size = len(name.encode("utf-8"))
    except UnicodeEncodeError:
        raise DataError(f"run {run_id!r}: its {key} {value!r} is not valid text (a lone "
                        "surrogate); it cannot name a partition folder") from None
    if size > MAX_SEGMENT_BYTES:
        raise DataError(f"run {run_id!r}: its {key} is {size - len(key) - 1:,} bytes as a "
                        f"folder name; at most {MAX_SEGMENT_BYTES - len(key) - 1} fit")
    return name
