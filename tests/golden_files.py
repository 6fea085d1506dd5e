"""The golden files of a calibration folder (tests/golden/<protocol>/): compared within a
tolerance, and, with RIGTOOL_UPDATE_GOLDEN=1, updated file by file: a file is rewritten only
when it differs beyond that tolerance, added when it appears, removed when it vanishes. The
folder's file list is its own golden (FILE_LIST)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import rigtool

FILE_LIST = "FILES"  # the names a protocol's folder holds, one a line
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def normalised(text: str, folder: Path) -> str:
    """`text` with what changes from run to run replaced: the run id, creation times and the
    tool version."""
    text = text.replace(folder.name, "RUN-ID")
    text = re.sub(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?(\+00:00|Z)", "TIME", text)
    return text.replace(rigtool.__version__, "VERSION")


def differences(got: str, want: str, rel: float = 1e-4) -> list[tuple[str, str]]:
    """Where `got` differs from `want`: all text outside numbers byte for byte, and each number
    within `rel` of the golden one. The last digits of a fitted value move with the machine's
    BLAS kernels (same wheels, another CPU: C_p in its tenth digit, an ill-conditioned 70 us
    step delay by 2e-5 of itself); a restructuring's change does not hide in the fifth. Runs
    of white space compare equal: a list of numbers wraps where its numbers' lengths put it."""
    got_parts, want_parts = ([" ".join(part.split()) for part in NUMBER.split(text)]
                             for text in (got, want))
    if got_parts != want_parts:
        return [("text", next(f"{g!r} != {w!r}" for g, w in zip(got_parts, want_parts, strict=False)
                              if g != w) if len(got_parts) == len(want_parts) else "layout")]
    return [(g, w) for g, w in zip(NUMBER.findall(got), NUMBER.findall(want), strict=True)
            if not math.isclose(float(g), float(w), rel_tol=rel, abs_tol=1e-12)]


def listed(want: Path) -> list[str]:
    """The file names the golden folder's list names (empty for a new folder)."""
    path = want / FILE_LIST
    return path.read_text().split() if path.is_file() else []


def mismatches(want: Path, got: dict[str, str]) -> list[str]:
    """What differs between the files `got` (name -> normalised text) and the golden folder:
    a file added or missing against the list, a file beyond the tolerance."""
    out = [f"file list: {sorted(got)} != {listed(want)}"] if sorted(got) != listed(want) else []
    return out + [f"{want.name}/{name} differs from tests/golden: {found[:3]}"
                  for name, text in sorted(got.items()) if (want / name).is_file()
                  and (found := differences(text, (want / name).read_text()))]


def update(want: Path, got: dict[str, str]) -> list[str]:
    """Bring the golden folder to `got`: rewrite only files beyond the tolerance, add new ones,
    remove vanished ones, rewrite the list when it changed; return what was touched."""
    want.mkdir(parents=True, exist_ok=True)
    touched = []
    for name in sorted(set(listed(want)) - set(got)):
        (want / name).unlink(missing_ok=True)
        touched.append(f"removed {name}")
    for name, text in sorted(got.items()):
        path = want / name
        if not path.is_file():
            touched.append(f"added {name}")
        elif differences(text, path.read_text()):
            touched.append(f"rewrote {name}")
        else:
            continue
        path.write_text(text)
    if listed(want) != sorted(got):
        (want / FILE_LIST).write_text("".join(f"{name}\n" for name in sorted(got)))
        touched.append(f"listed {len(got)} files")
    return touched
