"""Where the run database is: --db, then $RIGTOOL_DB, then the rig file, then ./rigtool.sqlite."""

from __future__ import annotations

import os
from pathlib import Path

DB_ENV = "RIGTOOL_DB"
DEFAULT_DB = "rigtool.sqlite"


def resolve_db_path(cli_value: str | None, rig_value: str | None = None) -> Path:
    """DB path from --db, then $RIGTOOL_DB, then the rig file, then ./rigtool.sqlite."""
    return Path(cli_value or os.environ.get(DB_ENV) or rig_value or DEFAULT_DB)
