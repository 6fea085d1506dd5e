"""The public Python API on a twin run: runs, points, samples, events, calibrations."""

from __future__ import annotations

import numpy as np
import pytest

import rigtool
from rigtool.cli import main
from rigtool.errors import UsageError

PROTOCOL = """\
rigtool_protocol: 1
name: api-can
simulator: {profile: can-bldc, seed: 5}
command: {unit: percent, range: {start: -100, stop: 100, step: 20}, order: up}
depth: {unit: m, values: [0.8, 1.0], mode: preset}
timing:
  settle: {seconds: 1.5}
  acquire: {samples: 300, rate_hz: 1000}
  tare: at_start
"""


@pytest.fixture(scope="module")
def lab_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("api")
    (tmp / "p.yaml").write_text(PROTOCOL)
    db = str(tmp / "db.sqlite")
    assert main(["sweep", str(tmp / "p.yaml"), "--sim", "--db", db]) == 0
    uncalibrated_error = None
    with rigtool.open(db) as lab:
        try:
            lab.calibration("last")
        except UsageError as exc:
            uncalibrated_error = str(exc)
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal")]) == 0
    lab = rigtool.open(db)
    yield tmp, lab, lab.run("last"), uncalibrated_error
    lab.close()


def test_run_record_points_and_samples_agree(lab_run):
    _, lab, run, _ = lab_run
    assert [r["id"] for r in lab.runs()] == [run.id] and run.status == "completed"
    assert run.command_unit == "percent" and run.neutral == 0.0
    p = run.points()
    assert len(p["command"]) == 22 and p["step_idx"].dtype == np.int64
    assert set(np.unique(p["depth_m"])) == {0.8, 1.0}
    s = run.samples(columns=["t_s", "thrust_n"])
    assert set(s) == {"step_idx", "t_s", "thrust_n"} and len(s["t_s"]) == p["n_samples"].sum()
    for i in (3, 17):  # the stored statistics are those of the point's samples
        mine = run.samples(steps=[i])
        assert set(np.unique(mine["step_idx"])) == {i} and mine["seq"].dtype == np.int64
        k = int(np.flatnonzero(p["step_idx"] == i)[0])
        assert np.nanmean(mine["thrust_n"]) == pytest.approx(p["thrust_all_mean_n"][k], rel=1e-9)
        assert np.nanmean(mine["speed_rpm"]) == pytest.approx(p["speed_all_mean_rpm"][k], rel=1e-9)
    assert run.samples(steps=[]).keys() and len(run.samples(steps=[])["t_s"]) == 0


def test_events_and_pandas(lab_run):
    _, _, run, _ = lab_run
    tares = run.events("tare")
    assert tares and all(e["kind"] == "tare" for e in tares) and "detail" in tares[0]
    df = run.points().to_pandas()
    assert len(df) == 22 and "thrust_all_mean_n" in df.columns
    assert len(run.events().to_pandas()) == len(run.events())


def test_calibration_from_folder_equals_stored(lab_run):
    tmp, lab, run, uncalibrated_error = lab_run
    assert "has not been calibrated" in uncalibrated_error
    folder = rigtool.load_calibration(tmp / "cal" / run.id)
    stored = lab.calibration(run)
    assert folder.depths == stored.depths == [0.8, 1.0]
    commands = np.linspace(-100, 100, 81)
    np.testing.assert_allclose(folder.thrust(commands), stored.thrust(commands), rtol=1e-8)
    np.testing.assert_allclose(folder.thrust(commands, depth=0.8),
                               stored.thrust(commands, depth=0.8), rtol=1e-8)
    c = folder.coefficients["C_p_fwd"]
    assert c.lo < c.value < c.hi and c.unit == "N/(r/min)^2"
    assert (c.low, c.high) == (c.lo, c.hi)  # the names docs/api.md gave first still read
    assert folder.coefficients["C_p_fwd"] == folder.coefficients_at(1.0)["C_p_fwd"]
    with pytest.raises(ValueError, match="no section at depth 0.5 m"):
        folder.thrust(50, depth=0.5)


def test_thrust_and_command_are_inverse_and_match_the_points(lab_run):
    _, _, run, _ = lab_run
    cal = rigtool.load_calibration(_folder(lab_run))
    p = run.points()
    deep = (p["depth_m"] == 1.0) & (np.abs(p["command"]) >= 40)
    np.testing.assert_allclose(cal.thrust(p["command"][deep]), p["thrust_all_mean_n"][deep],
                               rtol=0.03)
    assert cal.thrust(0.0) == 0.0 and isinstance(cal.thrust(0.0), float)
    f = cal.thrust(np.array([-80.0, -40.0, 40.0, 80.0]))
    np.testing.assert_allclose(cal.command(f), [-80, -40, 40, 80], atol=1e-6)
    assert cal.command(0.0) == 0.0
    beyond = 10 * np.nanmax(p["thrust_all_mean_n"])
    assert cal.command(beyond) == 100.0 and cal.command_status(beyond) == "clamped"
    assert np.isnan(cal.command(beyond, strict=True))
    assert np.isnan(cal.thrust(150.0))


def test_thrust_from_speed_and_current_match_the_points(lab_run):
    _, _, run, _ = lab_run
    cal = rigtool.load_calibration(_folder(lab_run))
    p = run.points()
    live = (p["depth_m"] == 1.0) & (np.abs(p["command"]) >= 40)
    f = p["thrust_all_mean_n"][live]
    np.testing.assert_allclose(cal.thrust_from_speed(p["speed_all_mean_rpm"][live]), f, rtol=0.05)
    fwd = live & (p["command"] > 0)
    np.testing.assert_allclose(cal.thrust_from_current(p["current_all_mean_a"][fwd]),
                               p["thrust_all_mean_n"][fwd], rtol=0.08)
    rev = live & (p["command"] < 0)
    np.testing.assert_allclose(cal.thrust_from_current(p["current_all_mean_a"][rev], "reverse"),
                               p["thrust_all_mean_n"][rev], rtol=0.08)
    with pytest.raises(ValueError, match="direction"):
        cal.thrust_from_current(3.0, "up")


def test_missing_things_are_clear_errors(lab_run, tmp_path):
    with pytest.raises(UsageError, match="no run database"):
        rigtool.open(tmp_path / "none.sqlite")
    with pytest.raises(UsageError, match="no calibration.json"):
        rigtool.load_calibration(tmp_path)
    with pytest.raises(UsageError, match="no run 'zz'"):
        lab_run[1].run("zz")
    with pytest.raises(UsageError, match="open read-only"):
        lab_run[1].calibrate("last", tmp_path / "nowhere")
    assert not (tmp_path / "nowhere").exists()
    folder = tmp_path / "broken"
    folder.mkdir()
    for f in _folder(lab_run).iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
    lines = (folder / "inverse_lut.csv").read_text().splitlines()
    lines[-1] = lines[-1].rsplit(",", 1)[0] + ",abc"
    (folder / "inverse_lut.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(UsageError, match=rf"inverse_lut.csv:{len(lines)}: could not convert"):
        rigtool.load_calibration(folder)


def _folder(lab_run):
    tmp, _, run, _ = lab_run
    return tmp / "cal" / run.id
