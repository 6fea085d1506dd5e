"""Thrust -> command as a vehicle needs it, through sweep, calibrate and the API, on seeds and
twins the semantics were not developed on: every finite thrust gets a command; beyond the
largest thrust measured, the extreme command (and "clamped"); below the smallest, neutral;
NaN only for NaN; strict=True keeps NaN outside the table (issue: calibrations that load
where vehicles run them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rigtool
from rigtool.cli import main

PROTOCOLS = Path(__file__).resolve().parents[1] / "protocols"
SWEEP = """\
rigtool_protocol: 1
name: semantics
simulator: {{profile: {profile}, seed: {seed}}}
metadata: {{thruster_id: t-1}}
command: {{unit: {unit}, range: {{start: {lo}, stop: {hi}, step: {step}}}, order: up}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.0}}
  acquire: {{samples: 200, rate_hz: 1000}}
  tare: at_start
"""
CASES = {
    "esc-7301": dict(profile="esc-1100-1900", seed=7301, unit="pulse_us", lo=1100, hi=1900,
                     step=25),
    "can-7302": dict(profile="can-bldc", seed=7302, unit="percent", lo=-100, hi=100, step=8),
    "can-fwd-only-7303": dict(profile="can-bldc", seed=7303, unit="percent", lo=0, hi=100,
                              step=10),
}


def _calibrate(tmp: Path, protocol: Path, *extra: str) -> rigtool.api.Calibration:
    db = str(tmp / "db.sqlite")
    assert main(["sweep", str(protocol), "--sim", "--db", db, *extra]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal")]) == 0
    return rigtool.load_calibration(next((tmp / "cal").iterdir()))


@pytest.fixture(scope="module", params=sorted(CASES) + ["stm32-7304"])
def cal(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    if request.param.startswith("stm32"):
        text = (PROTOCOLS / "stm32-pwm.yaml").read_text()
        text = text.replace("seed: 2017", "seed: 7304").replace("samples: 500", "samples: 60")
        text = text.replace("step: 1}", "step: 2}")
    else:
        text = SWEEP.format(**CASES[request.param])
    (tmp / "p.yaml").write_text(text)
    return _calibrate(tmp, tmp / "p.yaml")


def _extremes(cal) -> dict[str, tuple[float, float]]:
    """Largest fitted thrust per direction on the command curve, and the smallest |thrust|
    of the inverse table."""
    m = cal.thrust_map()
    out = {}
    for direction in ("forward", "reverse"):
        lim = m.limits(direction)
        if lim is not None:
            out[direction] = lim
    return out


def test_every_finite_thrust_gets_a_command_and_a_reason(cal):
    lims = _extremes(cal)
    top = max(hi for _, hi in lims.values())
    f = np.linspace(-1.6 * top, 1.6 * top, 4001)
    c = cal.command(f)
    status = cal.command_status(f)
    assert np.isfinite(c).all()
    assert set(status) <= {"ok", "clamped", "below_min", "gap"}
    for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
        mine = sign * f > 0
        if direction not in lims:
            assert (c[mine] == cal.neutral).all() and (status[mine] == "clamped").all()
            continue
        lo, hi = lims[direction]
        below = mine & (sign * f < lo)
        beyond = mine & (sign * f > hi)
        assert (c[below] == cal.neutral).all() and (status[below] == "below_min").all()
        assert (status[beyond] == "clamped").all() and beyond.any()
        assert np.unique(c[beyond]).size == 1  # the extreme command
    assert cal.command(0.0) == cal.neutral and np.isnan(cal.command(np.nan))
    huge = np.array([np.inf, 1e308, 1e19, -1e19, -1e308, -np.inf])
    edge = cal.command(np.array([1.6 * top, 1.6 * top, 1.6 * top, -1.6 * top, -1.6 * top,
                                 -1.6 * top]))
    np.testing.assert_array_equal(cal.command(huge), edge)  # the extreme, however far
    assert cal.command(-0.0) == cal.neutral
    assert cal.command_status(np.nan) == "nan"


def test_the_command_gives_the_thrust_asked_or_the_most_there_is(cal):
    """Round trip through the command curve: inside the range within 0.5 % of full scale;
    beyond it the extreme command gives the largest thrust measured."""
    lims = _extremes(cal)
    full = max(hi for _, hi in lims.values())
    for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
        if direction not in lims:
            continue
        lo, hi = lims[direction]
        inside = sign * np.linspace(lo, hi, 300)
        ok = cal.command_status(inside) == "ok"
        got = cal.thrust(cal.command(inside[ok]))
        assert np.max(np.abs(got - inside[ok])) <= 0.005 * full
        assert ok.mean() > 0.9
        assert cal.thrust(cal.command(sign * 2 * hi)) == pytest.approx(sign * hi, abs=0.005 * full)


def test_strict_keeps_the_older_answer(cal):
    lims = _extremes(cal)
    hi = lims["forward"][1]
    f = np.array([0.5 * lims["forward"][0], 0.5 * hi, 2 * hi, np.nan])
    got = cal.command(f, strict=True)
    assert np.isnan(got[[0, 2, 3]]).all() and np.isfinite(got[1])


def test_stm32_thrust_in_the_saturated_range_is_reachable(tmp_path_factory):
    """Issue: on the STM32 twin 5.0 N is reachable but gave NaN. Every thrust up to the
    largest measured now gets a command that gives it (seed 7305, not developed on)."""
    tmp = tmp_path_factory.mktemp("stm32-sat")
    text = (PROTOCOLS / "stm32-pwm.yaml").read_text().replace("seed: 2017", "seed: 7305")
    (tmp / "p.yaml").write_text(text.replace("samples: 500", "samples: 60"))
    cal = _calibrate(tmp, tmp / "p.yaml")
    curve_max = float(np.nanmax(cal.thrust(np.arange(0, 800))))
    f = np.linspace(0.5 * curve_max, curve_max, 50)
    c = cal.command(f)
    assert np.isfinite(c).all() and (cal.command_status(f) == "ok").all()
    assert np.max(np.abs(cal.thrust(c) - f)) <= 0.01 * curve_max
