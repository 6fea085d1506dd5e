"""Output paths built from run ids: one safe path component, always inside its folder.

Run ids come from the database, which may be crafted or imported; an id such as
`../../x` must never make calibrate, report or export write outside the folder the user
chose. Ids rigtool generates (`20261123T101500123Z-1a2b3c`) pass through unchanged.
"""

from __future__ import annotations

import re
from pathlib import Path

from rigtool.errors import UsageError

MAX_COMPONENT = 120
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")


REPORT_FILE = "report.html"  # the HTML report in a run's folder


def safe_component(text: str) -> str:
    """`text` as one file-name component: characters other than letters, digits, `.`, `_`
    and `-` become `_`, no leading dot or dash, at most MAX_COMPONENT characters."""
    name = _UNSAFE.sub("_", text).lstrip(".-")[:MAX_COMPONENT]
    return name or "run"


def inside(folder: str | Path, name: str) -> Path:
    """`folder`/`name` for a sanitised `name`; refused if a symlink there leads elsewhere."""
    base = Path(folder)
    path = base / safe_component(name)
    if path.resolve().parent != base.resolve():
        raise UsageError(f"{path} leads outside {base} (a symlink?); choose another --out")
    return path


def run_folder(out_dir: str | Path, run_id: str) -> Path:
    """The folder of one run's artefacts and report: `out_dir`/<sanitised run id>/."""
    return inside(out_dir, run_id)
