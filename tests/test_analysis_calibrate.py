"""`calibrate_run` end to end on synthetic runs written through the Store, and the artefacts."""

import csv
import io
import json
import math

import numpy as np
import pytest

import rigtool
from rigtool.analysis.calibrate import calibrate_run
from rigtool.artefacts.calibration import CALIBRATION_FILES, write_artefacts
from rigtool.store import StepRecord, Store

CP_FWD, CP_REV, CN, I0 = 1.926e-5, 0.8 * 1.926e-5, 1.2e-9, 0.3
DIAMETER, RHO = 0.1, 1000.0
DRIFT_N_PER_H = 0.2
CREATED = "2024-05-01T12:00:00+00:00"


def can_samples(rng, cmd, direction, tt, previous):
    """Luo-style CAN thruster: speed transient, f = C_p|n|n, I = C_n|n|^3 + I_0, noise."""
    target = 1800.0 * cmd / 100.0 if abs(cmd) > 3 else 0.0
    n = target + (previous - target) * np.exp(-(tt + 0.05) / 0.03) + rng.normal(0, 2, tt.size)
    f = np.where(n >= 0, CP_FWD, CP_REV) * np.abs(n) * n
    f = f + rng.normal(0, 0.2, tt.size) + 0.1 * np.sin(2 * np.pi * 37 * tt + rng.uniform(0, 6))
    f = f + (0.05 if direction == "down" else 0.0)  # hysteresis
    cur = CN * np.abs(n) ** 3 + I0 + rng.normal(0, 0.05, tt.size)
    return {"thrust_n": f, "speed_rpm": n, "current_a": cur}, target


def stm32_samples(rng, cmd, direction, tt, previous):
    """STM32 bench rig (domain.md 1B): PWM map with dead zones; no speed or current feedback."""
    p = cmd
    if 207 <= p <= 396:
        f = 5.0 - 0.0005 * (p - 207)
    elif 397 <= p <= 427:
        f = 4.9 + (0.15 - 4.9) * (p - 397) / 30
    elif 446 <= p <= 450:
        f = -0.1
    elif 451 <= p <= 470:
        f = -1.0 - 2.0 * (p - 451) / 19
    elif p > 470:
        f = -3.0 - 0.0003 * (p - 470)
    else:
        f = 0.0
    sd = 0.08 if f > 0 else 0.015
    return {"thrust_n": f + rng.normal(0, sd, tt.size)}, 0.0


def write_run(store, model, unit, plan, *, n_samples, rate=1000.0, status="completed",
              tare_every=40, seed=0):
    """Write `plan` [(command, depth, repeat, direction)] through the Store's public API."""
    rng = np.random.default_rng(seed)
    protocol = {"command": {"unit": unit},
                "metadata": {"propeller_diameter_m": DIAMETER, "water_density_kg_m3": RHO,
                             "thruster_id": "T1"}}
    run_id = store.create_run(name="synthetic", protocol=protocol, protocol_path=None, rig={},
                              plan=[], metadata={}, seed=seed, command_unit=unit,
                              tool_version=rigtool.__version__)
    bias0 = np.array([0.5, -0.2, 0.1, 0.01, 0.0, 0.02])
    store.add_event(run_id, "tare", {"bias": bias0.tolist()}, t_s=0.0)
    t, previous, tared = 0.0, 0.0, 0.0
    tt = np.arange(n_samples) / rate
    for i, (cmd, depth, repeat, direction) in enumerate(plan):
        s, previous = model(rng, cmd, direction, tt, previous)
        # Thrust is tared at the last tare; the zero keeps drifting after it.
        s["thrust_n"] = s["thrust_n"] + DRIFT_N_PER_H * (t + tt) / 3600 - tared
        s["t_s"] = t + 0.05 + tt
        s["fx"] = -s["thrust_n"]
        s["fy"] = rng.normal(0, 0.05, n_samples)
        s["command"] = np.full(n_samples, float(cmd))
        step = StepRecord(i, float(cmd), unit, depth, repeat, direction, t, t + 0.05,
                          t + 0.05 + n_samples / rate, 0.05, True, rate)
        store.add_step(run_id, step, s)
        t += 0.05 + n_samples / rate + 0.5
        if i % tare_every == tare_every - 1:
            tared = DRIFT_N_PER_H * t / 3600
            bias = bias0 - [tared, 0, 0, 0, 0, 0]  # fx = -thrust
            store.add_event(run_id, "tare", {"bias": bias.tolist()}, t_s=t)
    store.finish_run(run_id, status)
    return run_id


def sweep(commands, depths=(None,), repeats=1, updown=False):
    plan = []
    for d in depths:
        for r in range(repeats):
            plan += [(c, d, r, "up") for c in commands]
            if updown:
                plan += [(c, d, r, "down") for c in commands[::-1]]
    return plan


@pytest.fixture(scope="module")
def can_cal(tmp_path_factory):
    store = Store(tmp_path_factory.mktemp("can") / "runs.sqlite")
    plan = sweep(np.arange(-100.0, 100.1, 10.0), depths=(0.5, 1.0), repeats=2, updown=True)
    run_id = write_run(store, can_samples, "percent", plan, n_samples=200)
    return calibrate_run(store, run_id)


@pytest.fixture(scope="module")
def stm32_cal(tmp_path_factory):
    store = Store(tmp_path_factory.mktemp("stm") / "runs.sqlite")
    pwm = np.r_[0:180:10, 180:480, 480:800:10].astype(float)  # every count near the edges
    run_id = write_run(store, stm32_samples, "pwm_counts", sweep(pwm), n_samples=100,
                       tare_every=50, seed=5)
    return calibrate_run(store, run_id)


def _inside(c, true):
    return c.lo < true < c.hi


def test_can_run_thrust_current_coefficients(can_cal):
    assert [s.depth_m for s in can_cal.sections] == [0.5, 1.0]
    for sec in can_cal.sections:
        f = sec.fits
        assert abs(f["C_p_fwd"].value / CP_FWD - 1) < 0.01 and _inside(f["C_p_fwd"], CP_FWD)
        assert abs(f["C_p_rev"].value / CP_REV - 1) < 0.01 and _inside(f["C_p_rev"], CP_REV)
        assert abs(f["C_n"].value / CN - 1) < 0.03
        assert f["I_0"].value == pytest.approx(I0, abs=0.02)
        assert abs(f["k_free"].value - 3) < 0.1
        ci = CP_FWD / CN ** (2 / 3)
        assert f["C_i_fwd"].value == pytest.approx(ci, rel=0.02)
        assert f["C_i_fwd_direct"].value == pytest.approx(ci, rel=0.02)
        kt = CP_FWD * 3600 / (RHO * DIAMETER**4)
        assert f["K_T_fwd"].value == pytest.approx(kt, rel=0.01) and f["K_T_fwd"].unit == "1"
        assert f["sigma_n_sample"].value == pytest.approx(0.22, rel=0.3)
        assert 0 < f["sigma_n_point"].value < f["sigma_n_sample"].value
        assert f["C_p_fwd"].r2 > 0.999 and f["C_p_fwd"].n >= 30


def test_can_run_curve_quality_and_windows(can_cal):
    sec, deep = can_cal.sections
    # 0.5 m may ventilate: its zero comes from the neutral points, not through its live points.
    assert sec.zero.source == "dead zones" and abs(sec.zero.offset_n) < 0.05  # down: +0.05 N
    assert deep.zero.source == "model fit" and abs(deep.zero.offset_n) < 0.05
    assert sec.curve.dead_zones == [(0.0, 0.0)]
    assert [b.direction for b in sec.curve.branches] == ["reverse", "forward"]
    # Down sweeps read 0.05 N high (plus what is left of the speed transient from above).
    assert -0.15 < np.median(sec.hysteresis.diff_n) < -0.03
    assert sec.hysteresis.max_abs_n > 0.05
    assert sec.repeatability is not None and sec.repeatability.median_std_n < 0.05
    assert can_cal.drift.slope.value == pytest.approx(DRIFT_N_PER_H, rel=0.05)
    assert can_cal.drift.slope.unit == "N/h"
    # 0.2 N/h moves the zero about 0.01 N over this 2-minute sweep, against 0.2 N of noise
    assert not any("drift" in w for w in can_cal.warnings)
    p = sec.points
    assert not p.used_in_fits[p.command == 0].any()
    # The first point starts from standstill: its window starts later than the others.
    assert p.window_start_s[0] > np.median(p.window_start_s)
    assert np.all(p.kept_fraction >= 0.5)


def test_stm32_run(stm32_cal):
    (sec,) = stm32_cal.sections
    assert sec.depth_m is None and sec.fits == {}
    (lo1, hi1), (lo2, hi2) = sec.curve.dead_zones
    assert abs(lo1) <= 2 and abs(hi1 - 206) <= 2 and abs(lo2 - 428) <= 2 and abs(hi2 - 445) <= 2
    assert sec.curve.break_aways == [451.0]
    assert sec.curve.branches[0].inverted
    assert sec.zero.source == "dead zones"
    assert np.all(np.isnan(sec.points.speed.mean))
    assert sec.points.dead[sec.points.command == 100].all()
    assert not sec.points.dead[sec.points.command == 448].any()


def test_interrupted_run_warns(tmp_path):
    store = Store(tmp_path / "runs.sqlite")
    plan = sweep(np.arange(0.0, 40.1, 10.0))
    run_id = write_run(store, can_samples, "percent", plan, n_samples=100, status="interrupted")
    cal = calibrate_run(store, run_id)
    assert any("interrupted" in w for w in cal.warnings)
    assert any("few points: C_p_fwd" in w for w in cal.warnings)  # 4 forward points
    assert "C_p_rev" not in cal.sections[0].fits


# -- artefacts ----------------------------------------------------------------------------------


def _read_csv(path):
    """The sidecar's rows (path.columns.csv), the header and the rows of a calibration CSV."""
    body = path.read_text().splitlines()
    assert not any(ln.startswith("#") for ln in body)  # a header row, then the rows
    rows = list(csv.DictReader(io.StringIO("\n".join(body))))
    with path.with_name(f"{path.stem}.columns.csv").open(newline="") as fh:
        notes = list(csv.DictReader(fh))
    return notes, body[0].split(","), rows


def test_artefacts_formats(can_cal, tmp_path):
    paths = write_artefacts(can_cal, tmp_path, CREATED)
    written = [f for f in CALIBRATION_FILES if f.written(can_cal)]  # no voltage, no captive
    assert [p.name for p in paths] == [f.name for f in written]
    assert len(written) == len(CALIBRATION_FILES) - 4  # each with its sidecar
    assert all(p.parent == tmp_path / can_cal.run_id for p in paths)
    doc = json.loads(paths[0].read_text())
    assert doc["format"] == "rigtool-calibration" and doc["format_version"] == 1
    assert doc["tool_version"] == rigtool.__version__ and doc["created_utc"] == CREATED
    assert doc["files"] == {f.key: f.name for f in written[1:] if f.listed}
    assert doc["source"]["run_id"] == can_cal.run_id
    assert doc["source"]["command_unit"] == "percent"
    assert doc["analysis"]["settling"]["n_blocks"] == 20
    assert doc["steady_window"]["kept_fraction"]["min"] >= 0.5
    depth = doc["depths"][0]
    assert depth["depth_m"] == 0.5
    cp = depth["coefficients"]["C_p_fwd"]
    assert set(cp) == {"value", "lo", "hi", "stat_lo", "stat_hi", "systematic", "unit", "n",
                       "r2", "rms", "rms_unit", "note"}
    assert cp["lo"] < cp["stat_lo"] < cp["value"] < cp["stat_hi"] < cp["hi"]
    assert cp["systematic"] == pytest.approx(1e-3 * cp["value"]) and cp["unit"] == "N/(r/min)^2"
    # The full interval is the statistical one with the allowance added in quadrature.
    assert cp["hi"] - cp["value"] == pytest.approx(
        math.hypot(cp["stat_hi"] - cp["value"], cp["systematic"]))
    assert depth["command_curve"]["dead_zones"] == [[0.0, 0.0]]
    assert doc["tare_drift"]["slope"]["unit"] == "N/h"
    assert depth["zero"]["source"] == "dead zones"  # 0.5 m may ventilate
    assert doc["depths"][1]["zero"]["source"] == "model fit"
    assert set(depth["coefficients"]) >= {"C_p_fwd", "C_p_rev", "C_n", "I_0",
                                           "k_free", "C_i_fwd", "C_i_fwd_direct", "K_T_fwd",
                                           "sigma_n_point", "sigma_i_sample"}
    assert {"f_0", "zero_drift"} <= set(doc["depths"][1]["coefficients"])  # fitted when deep

    comments, header, rows = _read_csv(paths[1])
    assert [c["column"] for c in comments if c["column"]] == header
    assert header[:3] == ["depth_m", "step_idx", "command"]
    assert "thrust_mean_n" in header and "speed_se_rpm" in header and "current_max_a" in header
    assert header[header.index("thrust_peak_n"):][:3] == ["thrust_peak_n", "thrust_zero_n",
                                                           "voltage_mean_v"]
    tail = header[header.index("efficiency_n_per_w"):]
    assert tail[:5] == ["efficiency_n_per_w", "efficiency_se_n_per_w", "efficiency_g_per_w",
                        "voltage_set_v", "torque_mean_nm"]
    assert tail[-4:] == ["mech_power_w", "mech_power_se_w", "overall_efficiency",
                         "overall_efficiency_se"]
    assert {"column": "thrust_mean_n", "unit": "N",
            "description": "thrust mean over the steady window"} in comments
    assert len(rows) == sum(len(s.points) for s in can_cal.sections)
    assert float(rows[0]["thrust_mean_n"]) == pytest.approx(
        can_cal.sections[0].points.thrust.mean[0], rel=1e-8)

    comments, header, rows = _read_csv(paths[3])
    assert header == ["depth_m", "command", "n_points", "state", "branch", "thrust_mean_n",
                      "thrust_se_n", "thrust_min_n", "thrust_max_n", "thrust_fit_n",
                      "speed_mean_rpm", "current_mean_a", "voltage_set_v"]
    assert {r["state"] for r in rows} == {"dead", "live"}

    comments, header, rows = _read_csv(paths[5])
    assert header == ["depth_m", "branch", "direction", "thrust_n", "command", "voltage_set_v"]
    assert any(c["unit"] == "N" for c in comments)
    assert lut_command(rows, 0.5, 20.0) == pytest.approx(
        100 * math.sqrt(20.0 / CP_FWD) / 1800, abs=0.5)
    assert lut_command(rows, 1.0, -20.0) == pytest.approx(
        -100 * math.sqrt(20.0 / CP_REV) / 1800, abs=0.5)


def lut_command(rows, depth, thrust):
    """What a controller does with inverse_lut.csv: linear interpolation within one branch."""
    sel = [r for r in rows if float(r["depth_m"]) == depth
           and (r["direction"] == "forward") == (thrust > 0)]
    f = [float(r["thrust_n"]) for r in sel]
    u = [float(r["command"]) for r in sel]
    assert f == sorted(f)
    return float(np.interp(thrust, f, u))


def test_artefacts_deterministic_and_overwritten(stm32_cal, tmp_path):
    first = [p.read_bytes() for p in write_artefacts(stm32_cal, tmp_path, CREATED)]
    again = [p.read_bytes() for p in write_artefacts(stm32_cal, tmp_path, CREATED)]
    assert first == again
    later = write_artefacts(stm32_cal, tmp_path, "2025-01-01T00:00:00+00:00")
    assert json.loads(later[0].read_text())["created_utc"] == "2025-01-01T00:00:00+00:00"
    assert sorted(p.name for p in (tmp_path / stm32_cal.run_id).iterdir()) == sorted(
        p.name for p in later)
    _, _, rows = _read_csv(later[1])
    assert rows[0]["speed_mean_rpm"] == "nan" and rows[0]["depth_m"] == "nan"
    doc = json.loads(later[0].read_text())
    assert doc["depths"][0]["depth_m"] is None
    assert doc["depths"][0]["command_curve"]["break_aways"] == [451.0]
    branches = doc["depths"][0]["command_curve"]["branches"]
    assert branches[0]["inverted"] is True and branches[0]["direction"] == "forward"
