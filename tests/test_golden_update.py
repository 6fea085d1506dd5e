"""`RIGTOOL_UPDATE_GOLDEN=1` touches only what changed (tests/golden_files.py): a file within
the comparison's tolerance is left as it is, one beyond it is rewritten, a new file is added, a
vanished one removed, and the folder's file list is its own golden. A new calibration file is
one declaration in artefacts/calibration.py: calibrate writes it, calibration.json lists it,
and the update switch adds its golden and rewrites nothing else."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from rigtool.analysis.results import CalibrationResult
from rigtool.artefacts import calibration
from rigtool.artefacts.calibration import CalibrationFile
from rigtool.cli import main

from . import golden_files
from .conftest import copy_db
from .test_shipped_protocols import GOLDEN


def test_update_touches_only_files_beyond_the_tolerance(tmp_path):
    want = tmp_path / "golden"
    golden_files.update(want, {"a.csv": "x,1.000000001\n", "b.csv": "y,2\n"})
    assert golden_files.listed(want) == ["a.csv", "b.csv"]
    got = {"a.csv": "x,1.000000002\n", "c.csv": "z,3\n"}  # a: last digit; b gone; c new
    assert golden_files.mismatches(want, got) == [
        "file list: ['a.csv', 'c.csv'] != ['a.csv', 'b.csv']"]
    assert golden_files.update(want, got) == ["removed b.csv", "added c.csv", "listed 2 files"]
    assert (want / "a.csv").read_text() == "x,1.000000001\n"  # within tolerance: kept
    assert sorted(p.name for p in want.iterdir()) == ["FILES", "a.csv", "c.csv"]
    assert golden_files.mismatches(want, got) == []
    moved = {**got, "a.csv": "x,1.01\n"}
    assert golden_files.mismatches(want, moved) != []
    assert golden_files.update(want, moved) == ["rewrote a.csv"]
    assert golden_files.update(want, moved) == []


def test_every_golden_folder_lists_its_files():
    for folder in sorted(p for p in GOLDEN.iterdir() if p.is_dir()):
        held = sorted(p.name for p in folder.iterdir() if p.name != golden_files.FILE_LIST)
        assert golden_files.listed(folder) == held, folder.name


def _thrust_per_ampere(cal: CalibrationResult, created: str) -> str:
    """A throwaway calibration output: thrust per ampere of each live point."""
    rows = ["depth_m,command,thrust_per_ampere_n_per_a"]
    for sec in cal.sections:
        p = sec.points
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = p.thrust_corrected_n / p.current.mean
        rows += [f"{sec.depth_m or 0:g},{c:g},{r:.6g}" for c, r in zip(p.command, ratio, strict=True)
                 if math.isfinite(r)]
    return "\n".join(rows) + "\n"


@pytest.mark.slow
def test_a_new_calibration_file_is_one_declaration(shipped_sweep, tmp_path, monkeypatch):
    extra = CalibrationFile("thrust_per_ampere", "thrust_per_ampere.csv",
                            lambda cal: True, _thrust_per_ampere,
                            "thrust per ampere of each point (test only)")
    monkeypatch.setattr(calibration, "CALIBRATION_FILES", (*calibration.CALIBRATION_FILES, extra))
    db = copy_db(shipped_sweep("quick-demo"), tmp_path / "db.sqlite")
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp_path / "cal")]) == 0
    folder = next((tmp_path / "cal").iterdir())
    names = [f.name for f in calibration.CALIBRATION_FILES]
    got = {n: golden_files.normalised((folder / n).read_text(), folder) for n in names
           if (folder / n).is_file()}
    assert "thrust_per_ampere.csv" in got and "thrust_per_ampere" in got["calibration.json"]
    want = tmp_path / "golden"  # the shipped golden's calibration files, as committed
    want.mkdir()
    kept = [n for n in golden_files.listed(GOLDEN / "quick-demo") if n in names]
    for name in kept:
        shutil.copy(GOLDEN / "quick-demo" / name, want / name)
    (want / golden_files.FILE_LIST).write_text("".join(f"{n}\n" for n in kept))
    before = {n: (want / n).read_text() for n in kept}
    assert golden_files.update(want, got) == ["rewrote calibration.json",
                                              "added thrust_per_ampere.csv",
                                              f"listed {len(kept) + 1} files"]
    assert all((want / n).read_text() == before[n] for n in kept if n != "calibration.json")
    now, was = (json.loads(t) for t in ((want / "calibration.json").read_text(),
                                         before["calibration.json"]))
    assert now.pop("files") == {**was.pop("files"), "thrust_per_ampere": "thrust_per_ampere.csv"}
    assert golden_files.differences(json.dumps(now, indent=1), json.dumps(was, indent=1)) == []


def test_docs_list_each_declared_calibration_file():
    """docs/artefacts.md's table of files is each declaration's name and docs line."""
    text = (GOLDEN.parents[1] / "docs" / "artefacts.md").read_text()
    rows = [f"| `{f.name}` | {f.doc} |" for f in calibration.CALIBRATION_FILES]
    assert [r for r in rows if r not in text] == []
