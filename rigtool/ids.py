"""Run ids and timestamps: what `new_run_id` makes, how to recognise and print one, and UTC now.

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
