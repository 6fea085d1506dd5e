"""Partition folder names the Hive way (`thruster_id=bow%2F1`), which DuckDB, pyarrow and Spark
decode back to the value: ids come from users and merged databases, so every character that
could split, hide or escape a path is percent-encoded, and a name too long for a folder is
refused (the rule is `rigtool.ids.folder_problem`, which the protocol applies too)."""

from __future__ import annotations

from rigtool.errors import DataError
from rigtool.ids import folder_problem, folder_value


def segment(key: str, value: str | None, run_id: str) -> str:
    """The folder name `key=<encoded value>` of one partition level; a DataError naming the
    run when the value cannot be a folder name on every file system."""
    problem = folder_problem(key, value)
    if problem:
        raise DataError(f"run {run_id!r}: {problem}; it cannot name a partition folder")
    return f"{key}={folder_value(value)}"
