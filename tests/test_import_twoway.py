"""Two-way thrusters from foreign files, on draws the analysis was not developed on.

Each case draws a thruster (C_p forward and reverse, C_n, deadband, command grid, noise) from
its seed with `importdata.random_thruster`, writes it as a Tyto/RCbenchmark log (time series,
or one averaged row per step) or as a manufacturer's table, then runs `rigtool import` and
`rigtool calibrate last` and checks C_p, its interval, the speed sign and the deadband.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.dataset import Samples
from rigtool.analysis.depth_fits import scatter_se
from rigtool.analysis.steady import steady_windows
from rigtool.cli import main
from rigtool.store import Store

from .importdata import TwoWayThruster, maker_table, maker_table_args, random_thruster, stand_log

# (file kind, seed, fixed thruster fields, stand-log options)
CASES = [
    ("stand", 9101, {"unit": "pulse_us"}, {}),
    ("stand", 9102, {"unit": "percent", "mirrored": True}, {"updown": True}),
    ("stand", 9103, {"unit": "pulse_us", "signed": True}, {"hold_s": 1.5, "rate_hz": 10.0}),
    ("steps", 9104, {"unit": "pulse_us"}, {"averaged": True}),
    ("steps", 9105, {"unit": "percent", "mirrored": True}, {"averaged": True}),
    ("table", 9106, {"unit": "pulse_us"}, {}),
    ("table", 9107, {"unit": "percent", "mirrored": True}, {}),
    ("table", 9108, {"unit": "pulse_us", "spread": True}, {}),
    ("table", 9109, {"unit": "percent", "signed": True, "spread": True}, {}),
    ("table", 9110, {"unit": "percent"}, {}),
]
Z_95, Z_999 = 1.96, 3.29
_RESULTS: dict[int, tuple[TwoWayThruster, dict]] = {}


def _calibrate(case: int, root: Path) -> tuple[TwoWayThruster, dict]:
    """Write, import and calibrate case `case` once; its thruster and calibration depth."""
    if case not in _RESULTS:
        kind, seed, fixed, options = CASES[case]
        th = random_thruster(seed, **fixed)
        path, db, out = root / f"{kind}.csv", root / "r.sqlite", root / "cal"
        if kind == "table":
            path.write_text(maker_table(th), encoding="utf-8")
            args = [*maker_table_args(th)]
        else:
            path.write_text(stand_log(th, **options), encoding="utf-8")
            args = ["--settle-s", "1"]
        assert main(["import", str(path), "--db", str(db), *args]) == 0
        assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
        run_id = Store(db).resolve_run_id("last")
        (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
        _RESULTS[case] = th, depth
    return _RESULTS[case]


def _truths(th: TwoWayThruster) -> tuple[tuple[str, float], ...]:
    return ("C_p_fwd", th.cp_fwd), ("C_p_rev", th.cp_rev)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_two_way_thruster_is_recovered(case: int, tmp_path: Path, capsys) -> None:
    th, depth = _calibrate(case, tmp_path)
    coef = depth["coefficients"]
    for key, true in _truths(th):
        c = coef[key]
        assert abs(c["value"] / true - 1) < 0.02, (key, c["value"], true)
        if _drift_hidden(case):
            continue
        # Each 95 % interval must hold the truth at 99.9 %; the 95 % rate is checked below.
        half = (c["hi"] - c["lo"]) / 2 * Z_999 / Z_95
        assert abs(c["value"] - true) <= half, (key, c, true)
    if _drift_hidden(case):
        assert depth["zero"]["drift_design"].startswith("not estimable: one pass")
        assert any(w.startswith("zero drift not estimable") for w in depth["warnings"])
    assert depth["speed_sign"] == ("measured" if th.signed else "inferred from command")
    assert not any("disagrees" in w for w in depth["warnings"])
    ((lo, hi),) = depth["command_curve"]["dead_zones"]
    assert abs(lo - (th.neutral - th.deadband)) <= th.step
    assert abs(hi - (th.neutral + th.deadband)) <= th.step
    assert depth["command_curve"]["break_aways"] == []
    if CASES[case][0] == "table":
        assert "zero_drift" not in coef  # no time column: no time axis to drift along


def _drift_hidden(case: int) -> bool:
    """The averaged step tables: one pass, one row per command, neutral once and no tare,
    while the stand's zero drifts. No design there separates the drift from the law (issue
    47), so none is fitted, the warning says so, and the drift the stand had stays in C_p."""
    return CASES[case][0] == "steps"


def test_95_percent_intervals_hold_the_truth_nearly_always(tmp_path_factory) -> None:
    """Of the 16 C_p intervals of designs that separate the drift or have none to separate
    (no time column) at least 14 hold the truth (a 95 % rate fails this 4 % of the time)."""
    held = []
    for case in range(len(CASES)):
        if _drift_hidden(case):
            continue
        th, depth = _calibrate(case, tmp_path_factory.mktemp(f"case{case}"))
        held += [depth["coefficients"][k]["lo"] <= v <= depth["coefficients"][k]["hi"]
                 for k, v in _truths(th)]
    assert len(held) == 16 and sum(held) >= 14, held


def test_signed_speed_contradicting_the_thrust_is_named(tmp_path: Path, capsys) -> None:
    """A stand whose optical speed is signed the other way round: kept, with a warning."""
    th = random_thruster(9111, unit="pulse_us", signed=True, step=20.0)
    lines = stand_log(th).splitlines()
    col = lines[0].split(",").index("Motor Optical Speed (RPM)")

    def flip(row: str) -> str:
        cells = row.split(",")
        cells[col] = f"{-float(cells[col]):.1f}"
        return ",".join(cells)

    path, db = tmp_path / "flipped.csv", tmp_path / "r.sqlite"
    path.write_text("\n".join([lines[0], *map(flip, lines[1:])]) + "\n", encoding="utf-8")
    assert main(["import", str(path), "--db", str(db), "--settle-s", "1"]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err
    assert "speed_rpm sign disagrees with thrust_n on" in err
    assert "fast points" in err


def test_scatter_se_follows_noise_that_grows_with_the_value() -> None:
    rng = np.random.default_rng(5)
    pred = np.linspace(-30.0, 40.0, 400)
    true_sd = 0.02 + 0.01 * np.abs(pred)
    se = scatter_se(pred, rng.normal(0, 1, pred.size) * true_sd, np.full(pred.size, np.nan))
    assert np.median(se / true_sd) == pytest.approx(1.0, abs=0.15)
    assert se[np.argmax(np.abs(pred))] > 5 * se[np.argmin(np.abs(pred))]


def test_a_channel_that_never_varies_has_no_standard_error() -> None:
    """A table row stored as n samples: constant speed, alternating thrust."""
    n = 100
    samples = Samples(t_s=np.zeros(n), thrust_n=5.0 + np.where(np.arange(n) % 2, 0.1, -0.1),
                      speed_rpm=np.full(n, 1234.0), current_a=np.full(n, 2.5),
                      point=np.zeros(n, dtype=int), offsets=np.array([0, n]))
    w = steady_windows(samples)
    assert np.isfinite(w.channels["thrust_n"].se[0])
    assert np.isnan(w.channels["speed_rpm"].se[0]) and np.isnan(w.channels["current_a"].se[0])
    assert w.channels["speed_rpm"].std[0] == 0.0
