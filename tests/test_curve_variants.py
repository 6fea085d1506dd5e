"""Dead zones, break-aways and zero drift on STM32 twins the curve code was not tuned on.

Each case draws a PWM map (forward start 150-260, forward end 380-430, reverse start
440-500, break-away jump 0.3-0.6 N) and a seed from a fixed generator, sweeps it through the
CLI, calibrates through the CLI, and reads calibration.json as a user would.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.store import Store

from .conftest import PROTOCOLS

N_CASES = 4


def _draw(case: int) -> tuple[dict, int]:
    rng = np.random.default_rng(9100 + case)
    fwd_start = int(rng.integers(150, 261))
    fwd_end = int(rng.integers(380, 431))
    rev_start = int(rng.integers(max(fwd_end + 10, 440), 501))
    jump = float(rng.uniform(0.3, 0.6))
    overrides = {
        "pwm_fwd_start": fwd_start, "pwm_fwd_sat_end": fwd_end - 31, "pwm_fwd_end": fwd_end,
        "pwm_rev_creep_start": rev_start, "pwm_rev_breakaway": rev_start + 5,
        "pwm_rev_sat_start": rev_start + 24, "thrust_rev_breakaway_n": -0.15 - jump,
    }
    return overrides, int(rng.integers(10_000, 20_000))


@pytest.mark.parametrize("case", range(N_CASES))
def test_stm32_variant_dead_zones_break_away_and_drift(case, tmp_path, capsys):
    overrides, seed = _draw(case)
    flow = ", ".join(f"{k}: {v}" for k, v in overrides.items())
    text = (PROTOCOLS / "stm32-pwm.yaml").read_text().replace(
        "seed: 2017", f"seed: {seed}\n  overrides: {{{flow}}}")
    protocol = tmp_path / "p.yaml"
    protocol.write_text(text)
    db, out = tmp_path / "s.sqlite", tmp_path / "cal"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
    run_id = Store(db).resolve_run_id("last")
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    curve = depth["command_curve"]
    want = [(0, overrides["pwm_fwd_start"] - 1),
            (overrides["pwm_fwd_end"] + 1, overrides["pwm_rev_creep_start"] - 1)]
    got = curve["dead_zones"]
    assert len(got) == 2, (overrides, got)
    for (lo, hi), (w_lo, w_hi) in zip(got, want, strict=True):
        assert abs(lo - w_lo) <= 2 and abs(hi - w_hi) <= 2, (overrides, got)
    assert [abs(b - overrides["pwm_rev_breakaway"]) <= 2 for b in curve["break_aways"]] == [True]
    # The stm32-pwm profile's zero drifts 0.05 N/h after the tare.
    assert depth["zero"]["drift_n_per_h"] == pytest.approx(0.05, abs=0.01)
