"""Each steady thruster law is written once, in rigtool/models/laws.py, and every user agrees
with it on random inputs: the runtime BETM, the Python API, the twin and the voltage law
(issue: clear rooms, each law written once)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import rigtool
from rigtool.analysis.fits import Coefficient
from rigtool.analysis.results import VoltageLaw
from rigtool.cli import main
from rigtool.models import laws
from rigtool.models.betm import Betm
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

RNG = np.random.default_rng(8201)
SPEED = RNG.uniform(-3000.0, 3000.0, 500)
CURRENT = RNG.uniform(-20.0, 20.0, 500)
PACKAGE = Path(rigtool.__file__).parent
SPELLINGS = (  # a law written out again, as the code spelled it before laws.py
    r"\*\s*np\.abs\((\w+)\)\s*\*\s*\1\b",  # C |n| n
    r"np\.abs\(\w+\)\s*\*\*\s*3\s*\+",  # C |n|^3 + I_0
    r"\*\*\s*\(2\s*/\s*3\)",  # ^(2/3)
    r"np\.maximum\(np\.abs\(.*\)\s*-\s*\w*i_?0",  # max(|I| - I_0, 0)
)


def test_no_module_but_laws_writes_a_law_out():
    hits = [f"{p.relative_to(PACKAGE)}:{i}: {line.strip()}"
            for p in PACKAGE.rglob("*.py") if p.name != "laws.py"
            for i, line in enumerate(p.read_text().splitlines(), 1)
            if not line.lstrip().startswith(("#", '"', "'"))
            and any(re.search(s, line) for s in SPELLINGS)]
    assert hits == []


def test_the_runtime_betm_uses_the_laws():
    betm = Betm(cp_fwd=2.1e-5, cp_rev=1.7e-5, c_n=1.1e-9, i_0=0.35, ci_fwd=18.0, ci_rev=14.0,
                sigma_n=0.1, sigma_i=1.0)
    np.testing.assert_array_equal(betm.speed_estimate(SPEED),
                                  laws.thrust_from_speed(SPEED, 2.1e-5, 1.7e-5))
    sign = np.sign(SPEED)
    want = sign * np.where(sign >= 0, laws.thrust_from_current(CURRENT, 18.0, 0.35),
                           laws.thrust_from_current(CURRENT, 14.0, 0.35))
    np.testing.assert_allclose(betm.current_estimate(CURRENT, sign), want, rtol=1e-12)


def test_the_twin_draws_current_by_the_law():
    profile = profile_with_overrides("can-bldc", {})
    twin = ThrusterTwin(profile, seed=0)
    for command in RNG.uniform(-100.0, 100.0, 20):
        n, _, current = twin.steady_state(float(command))
        assert current == pytest.approx(float(laws.current_from_speed(
            n, twin._cn, twin._idle)), rel=1e-12)


def test_the_voltage_law_derives_c_i_by_the_law():
    def value(v: float) -> Coefficient:
        return Coefficient("c", v, v, v, "")
    law = VoltageLaw(1.0, [], value(2e-7), value(-1.1), value(2e-7), 1.0, True, [])
    for volts in (12.0, 16.0, 20.0):
        assert law.ci_at(volts, 1.9e-5) == pytest.approx(
            laws.c_i_from(1.9e-5, law.cn_at(volts)), rel=1e-12)


def test_the_api_uses_the_laws(tmp_path):
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["sweep", str(Path(__file__).parents[1] / "protocols" / "quick-demo.yaml"),
                 "--sim", "--seed", "8202", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    cal = rigtool.load_calibration(next(out.iterdir()))
    c = {k: v.value for k, v in cal.coefficients.items()}
    np.testing.assert_array_equal(cal.thrust_from_speed(SPEED),
                                  laws.thrust_from_speed(SPEED, c["C_p_fwd"], c["C_p_rev"]))
    c_i = c.get("C_i_fwd_direct", c["C_i_fwd"])
    np.testing.assert_allclose(cal.thrust_from_current(CURRENT),
                               laws.thrust_from_current(CURRENT, c_i, c["I_0"]), rtol=1e-12)
