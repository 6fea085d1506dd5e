"""`rigtool merge` brings what changed of runs the lab copy already has (issue item 9): a run
resumed and calibrated on the rig after an earlier merge reaches the lab complete, merging
again changes nothing, a point both copies hold but that differs is refused, and a run the
lab itself is still sweeping is left alone. Through the CLI, on sweeps of the twins."""

from __future__ import annotations

import hashlib
import os
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import rigtool
from rigtool.cli import main
from rigtool.store import Store

PROTOCOL = """\
rigtool_protocol: 1
name: merge-resume
simulator: {profile: stm32-pwm, seed: 57}
metadata: {thruster_id: aft-port}
command: {unit: pwm_counts, values: [380, 400, 430, 460, 490, 520], order: up}
depth: {unit: m, values: [0.8]}
timing: {settle: {seconds: 0.3}, acquire: {samples: 120, rate_hz: 400}, rest_s: 0.0,
         tare: at_start}
limits: {max_thrust_n: 40}
"""
CUT = 2  # points the first sweep "did not reach"


def _digest(path: Path) -> str:
    """The SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _sql(db: Path, *statements: tuple[str, tuple]) -> None:
    """Change a closed store by raw SQL, as a crash, a crafted copy or an editor would."""
    conn = sqlite3.connect(db)
    try:
        with conn:
            for sql, args in statements:
                conn.execute(sql, args)
    finally:
        conn.close()


def _interrupt(db: Path, run_id: str, n: int) -> None:
    """Make a finished run look interrupted `n` points before its end."""
    _sql(db, ("DELETE FROM sample_blocks WHERE step_id IN (SELECT id FROM steps WHERE "
              "run_id = ? ORDER BY idx DESC LIMIT ?)", (run_id, n)),
         ("DELETE FROM steps WHERE id IN (SELECT id FROM steps WHERE run_id = ? ORDER BY idx "
          "DESC LIMIT ?)", (run_id, n)),
         ("UPDATE runs SET status = 'interrupted', stop_reason = 'power cut' WHERE id = ?",
          (run_id,)))


def _content(db: Path, run_id: str) -> dict:
    """What the API reads of a run: record, points, samples, events, latest calibration."""
    with rigtool.open(db) as lab:
        run = lab.run(run_id)
        points, samples = run.points(), run.samples()
        events = [(e["kind"], e["t_s"], e["step_idx"], e["detail"]) for e in run.events()]
        record = (run.status, run.record.finished_utc, run.record.stop_reason)
        cal = lab.store.latest_calibration(run_id)
    return {"record": record, "events": events, "points": _lists(points),
            "samples": _lists(samples),
            "calibration": None if cal is None else (cal["created_utc"], cal["summary"])}


def _lists(columns: dict[str, np.ndarray]) -> dict[str, list]:
    """Columns as lists that compare equal when the arrays are (NaN included)."""
    return {k: (np.nan_to_num(v, nan=-1e300) if v.dtype.kind == "f" else v).tolist()
            for k, v in columns.items()}


def _step_ids(db: Path, run_id: str) -> dict[int, int]:
    """Point index -> row id in a store (a rewritten point would get a new one)."""
    with Store(db, read_only=True) as store:
        return {s["idx"]: s["id"] for s in store.steps(run_id)}


@pytest.fixture
def rig(tmp_path, capsys) -> tuple[Path, Path, str]:
    """A rig store with an interrupted run, merged once into an empty lab store."""
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    db, lab = tmp_path / "rig.sqlite", tmp_path / "lab.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    with Store(db, read_only=True) as store:
        run_id = store.resolve_run_id("last")
    _interrupt(db, run_id, CUT)
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    assert "1 run(s) added" in capsys.readouterr().out
    return db, lab, run_id


def _resume_and_calibrate(tmp_path: Path, db: Path, run_id: str) -> None:
    """Finish the run on the rig and calibrate it there, after the first merge."""
    assert main(["sweep", "--resume", run_id, "--db", str(db)]) == 0
    assert main(["calibrate", run_id, "--db", str(db), "--out", str(tmp_path / "cal")]) == 0


def test_a_run_resumed_and_calibrated_after_a_merge_reaches_the_lab(rig, tmp_path, capsys):
    db, lab, run_id = rig
    first, merged = _step_ids(lab, run_id), len(_content(lab, run_id)["events"])
    _resume_and_calibrate(tmp_path, db, run_id)
    new_events = len(_content(db, run_id)["events"]) - merged  # `resumed`, a tare...
    capsys.readouterr()
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    assert _content(lab, run_id) == _content(db, run_id)
    out = capsys.readouterr().out
    assert "0 run(s) added, 1 updated, 0 already present" in out, out
    assert (f"run {run_id}: +{CUT} point(s), status interrupted -> completed, "
            f"+1 calibration(s), +{new_events} event(s)") in out, out
    after = _step_ids(lab, run_id)
    assert {i: after[i] for i in first} == first and len(after) == len(first) + CUT
    with rigtool.open(lab) as lab_api, rigtool.open(db) as rig_api:
        mine, theirs = lab_api.calibration(run_id), rig_api.calibration(run_id)
        assert mine.coefficients == theirs.coefficients  # the stored analysis state too
        assert lab_api.run("last").id == run_id  # resumed last, in both stores

    before = _digest(lab)
    assert main(["merge", str(db), "-o", str(lab)]) == 0  # again: nothing new
    assert "0 run(s) added, 0 updated, 1 already present" in capsys.readouterr().out
    assert _content(lab, run_id) == _content(db, run_id) and _step_ids(lab, run_id) == after
    assert _digest(lab) == before


def test_an_older_copy_of_the_rig_store_changes_nothing(rig, tmp_path, capsys):
    db, lab, run_id = rig
    old = shutil.copyfile(db, tmp_path / "rig-before-resume.sqlite")
    _resume_and_calibrate(tmp_path, db, run_id)
    capsys.readouterr()
    assert main(["merge", str(old), str(db), str(old), "-o", str(lab)]) == 0
    out = [line for line in capsys.readouterr().out.splitlines() if "run(s) added" in line]
    assert out[0].endswith("0 run(s) added, 0 updated, 1 already present")
    assert out[1].endswith("0 run(s) added, 1 updated, 0 already present")
    assert out[-1].endswith("0 run(s) added, 0 updated, 1 already present")
    assert _content(lab, run_id) == _content(db, run_id)


@pytest.mark.parametrize("change, where", [
    ("UPDATE steps SET thrust_all_mean_n = thrust_all_mean_n + 1e-9 WHERE idx = 2", "point 2, steps."),
    ("UPDATE sample_blocks SET thrust_n = zeroblob(length(thrust_n)) WHERE step_id = "
     "(SELECT id FROM steps WHERE idx = 1)", "point 1, sample_blocks"),
    ("UPDATE runs SET plan_json = json_set(plan_json, '$[0].command', 999)", "runs.plan_json"),
])
def test_a_point_both_copies_hold_but_that_differs_is_refused(rig, tmp_path, capsys, change,
                                                              where):
    db, lab, run_id = rig
    _resume_and_calibrate(tmp_path, db, run_id)
    _sql(db, (change, ()))
    before = _digest(lab)
    capsys.readouterr()
    assert main(["merge", str(db), "-o", str(lab)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"run {run_id}, {where}" in err and "disagree" in err, err
    assert err.endswith(f"nothing was merged into {lab}"), err
    assert _digest(lab) == before


def test_a_run_the_lab_is_still_sweeping_is_not_touched(rig, tmp_path, capsys):
    db, lab, run_id = rig
    _resume_and_calibrate(tmp_path, db, run_id)
    _sql(lab, ("UPDATE runs SET status = 'running', finished_utc = NULL, host = ?, pid = ? "
               "WHERE id = ?", (os.uname().nodename, os.getpid(), run_id)))
    before = _content(lab, run_id)
    capsys.readouterr()
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    captured = capsys.readouterr()
    assert "0 run(s) added, 0 updated, 0 already present" in captured.out
    assert f"run {run_id} is running in {lab}: not updated" in captured.err
    assert _content(lab, run_id) == before


def test_a_newer_calibration_replaces_the_events_it_rewrote(tmp_path, capsys):
    """Calibrate rewrites a run's ventilation events: the lab keeps the newest set only."""
    db, lab = tmp_path / "rig.sqlite", tmp_path / "lab.sqlite"
    with Store(db) as store:
        run_id = store.create_run(name="vent", protocol={}, protocol_path=None, rig={}, plan=[],
                                  metadata={}, seed=None, command_unit="percent",
                                  tool_version="t", status="completed")
        store.add_event(run_id, "tare", {"bias": [0.1]})
        store.replace_events(run_id, "ventilation", [{"t_start_s": 1.0}, {"t_start_s": 5.0}])
        store.add_calibration(run_id, "cal", {}, "t", created_utc="2030-01-01T00:00:00+00:00")
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    with Store(db) as store:
        store.replace_events(run_id, "ventilation", [{"t_start_s": 2.5}])
        store.add_calibration(run_id, "cal", {}, "t", created_utc="2030-01-02T00:00:00+00:00")
    capsys.readouterr()
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    assert ("+1 calibration(s), +1 event(s), 2 event(s) of an older calibration replaced"
            in capsys.readouterr().out)
    with Store(lab, read_only=True) as store:
        vents = store.events(run_id, "ventilation")
        assert [e["detail"] for e in vents] == [{"t_start_s": 2.5}]
        assert len(store.events(run_id, "tare")) == 1
    assert main(["merge", str(db), "-o", str(lab)]) == 0
    assert "1 already present" in capsys.readouterr().out
