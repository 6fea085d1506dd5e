"""Stored calibration states of the shipped protocols, kept as fixtures so that every later
rigtool still reads what an earlier one wrote (tests/test_state_blob.py).

`python -m tests.state_fixtures` sweeps each shipped protocol on the simulator, calibrates it
and writes tests/fixtures/state/<protocol>-v<format>.blob with <protocol>-v<format>.json, a
summary of its key values. Existing fixtures are kept: they are the record of an old format.
"""

from __future__ import annotations

import io
import json
import math
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "state"
PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"
SHIPPED = ("quick-demo", "stm32-pwm", "esc-1100-1900", "voltage-sweep", "dynamics-steps",
           "dynamics-steps-esc", "luo2020-cavitation")
# luo2020-cavitation needs a deep base run of its thruster for its quasi-cavitation stage.
MINI_BASE = """rigtool_protocol: 1
name: mini-baseline
simulator: {profile: can-bldc, seed: 7}
metadata: {thruster_id: bldc-350w}
command: {unit: percent, range: {start: -100, stop: 100, step: 10}, order: up}
depth: {unit: m, values: [1.0], mode: preset}
timing: {settle: {seconds: 1.0}, acquire: {samples: 600, rate_hz: 500}, rest_s: 0.2,
         tare: per_depth, tare_s: 0.5}
limits: {max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}
"""


def _num(x: Any) -> float | None:
    """A float for JSON, None for NaN/None."""
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)


def _section(sec: Any) -> dict:
    """Key values of one DepthSection."""
    curve = sec.curve
    return {
        "depth_m": _num(sec.depth_m),
        "n_points": int(len(sec.points.command)),
        "thrust_mean_sum": _num(float(sum(sec.points.thrust.mean))),
        "fits": {k: _num(c.value) for k, c in sorted(sec.fits.items())},
        "curve_commands": None if curve is None else int(len(curve.command)),
        "branches": None if curve is None else [b.direction for b in curve.branches],
        "zero_offset": None if sec.zero is None else _num(sec.zero.offset_n),
    }


def _calibration(cal: Any) -> dict | None:
    """Key values of a Calibration."""
    if cal is None:
        return None
    dyn = cal.dynamics
    return {
        "run_name": cal.run_name,
        "command_unit": cal.command_unit,
        "neutral_command": _num(cal.neutral_command),
        "sections": [_section(s) for s in cal.sections],
        "voltage_b": [_num(law.b.value) for law in cal.voltage_laws],
        "drift_slope": None if cal.drift is None else _num(cal.drift.slope.value),
        "dynamics": None if dyn is None else {
            "selected": dyn.selected, "levels": {str(k): _num(v) for k, v in dyn.levels.items()},
            "n_steps": len(dyn.steps)},
    }


def _cavitation(cav: Any) -> dict | None:
    """Key values of a CavitationResult."""
    if cav is None:
        return None
    return {
        "betm_cp_fwd": _num(cav.betm.cp_fwd),
        "betm_level_n": [_num(v) for v in cav.betm.level_n],
        "n_blocks_total": int(cav.n_blocks_total),
        "n_training": int(len(cav.training.y)),
        "training_run_ids": sorted({str(r) for r in cav.training.run_id}),
        "n_events": len(cav.events),
        "coverage95": _num(cav.evaluation.coverage95),
        "series_keys": sorted(cav.series),
        "has_domain": cav.domain is not None,
    }


def summary(data: dict) -> dict:
    """The values a decoded state must still give, as JSON-able data."""
    return {"calibration": _calibration(data["calibration"]),
            "cavitation": _cavitation(data["cavitation"]),
            "notes": list(data["notes"])}


def format_of(blob: bytes) -> int:
    """The format_version a state blob declares."""
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        return json.loads(zf.read("tree.json"))["format_version"]


def _calibrated_state(tmp: Path, protocol: str) -> bytes:
    """Sweep `protocol` on the simulator, calibrate it, return the stored state blob."""
    from rigtool.cli import main
    from rigtool.store import Store

    db = tmp / f"{protocol}.sqlite"
    if protocol == "luo2020-cavitation":
        (tmp / "base.yaml").write_text(MINI_BASE)
        assert main(["sweep", str(tmp / "base.yaml"), "--sim", "--db", str(db)]) == 0
    assert main(["sweep", str(PROTOCOLS / f"{protocol}.yaml"), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp / "cal")]) == 0
    store = Store(db, read_only=True)
    try:
        return store.latest_calibration(store.resolve_run_id("last"))["state"]
    finally:
        store.close()


def write_fixture(protocol: str, blob: bytes) -> Path | None:
    """Write <protocol>-v<format>.blob and .json unless they exist; the blob's path if written."""
    from rigtool.artefacts import state

    path = FIXTURES / f"{protocol}-v{format_of(blob)}.blob"
    if path.exists():
        return None
    FIXTURES.mkdir(parents=True, exist_ok=True)
    path.write_bytes(blob)
    expected = summary(state.decode(blob))
    path.with_suffix(".json").write_text(json.dumps(expected, indent=1, sort_keys=True) + "\n")
    return path


def main(protocols: list[str]) -> None:
    """Write the fixtures of `protocols` (default: every shipped one) that are missing."""
    with tempfile.TemporaryDirectory() as tmp:
        for protocol in protocols or SHIPPED:
            written = write_fixture(protocol, _calibrated_state(Path(tmp), protocol))
            print(protocol, written or "kept", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
