"""Benchmark: STM32 dead zones, break-aways and zero drift on drifting twins (held-out grid).

Every six consecutive seeds share an STM32 PWM-bridge layout (forward start 40-260, forward
end, second dead zone of 3-30 counts); each seed then draws a creep of 1-40 counts before the
reverse break-away, takes another sensor drift from -0.3 to +0.3 N/h, and sweeps up or up and
down in turn. Each case is swept on the twin through the CLI and calibrated in process. It prints per case the error of every dead-zone edge and break-away
(counts), of the drift (N/h), whether a drift/creep warning fired, and whether
`cal.command()` returned a command inside a true dead zone for a nonzero thrust; then the
typical (median) and worst errors over the cases that gave no warning.

A case passes when every edge and the break-away lie within 2 counts and the drift within
0.05 N/h, or a warning names the commands; and, in every case, no command from
`cal.command()` falls in a true dead zone.

    python benchmarks/bench_dead_zones.py [--seeds 70000-70047] [--samples 500] [--verbose]

Development used seeds 1000-1099; the held-out figures are from seeds 70000-70047.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from rigtool.analysis.calibrate import calibrate_run
from rigtool.analysis.results import CalibrationResult
from rigtool.api import Calibration as ApiCalibration
from rigtool.cli import main
from rigtool.store import Store

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = ROOT / "protocols" / "stm32-pwm.yaml"
DRIFTS = (-0.3, -0.2, -0.1, -0.05, 0.05, 0.1, 0.2, 0.3)
RUNS_PER_LAYOUT = 6  # consecutive seeds share a bridge layout
EDGE_TOL = 2
DRIFT_TOL = 0.05
AMBIGUOUS = "cannot tell a zero drift from"  # the curve analysis's drift/creep warning


@dataclass(frozen=True)
class Case:
    """One twin setting: PWM layout overrides, drift, sweep order and simulator seed."""

    seed: int
    overrides: dict
    order: str
    tare: str = "per_depth"

    @property
    def zones(self) -> list[tuple[int, int]]:
        """The true dead zones."""
        o = self.overrides
        return [(0, o["pwm_fwd_start"] - 1), (o["pwm_fwd_end"] + 1, o["pwm_rev_creep_start"] - 1)]

    @property
    def break_away(self) -> int:
        """The true reverse break-away."""
        return int(self.overrides["pwm_rev_breakaway"])

    @property
    def drift(self) -> float:
        """The true sensor drift (N/h)."""
        return float(self.overrides["drift_n_per_h"])


@dataclass
class Result:
    """What the calibration found for one case, against the truth."""

    case: Case
    zones: list[tuple[float, float]]
    break_aways: list[float]
    drift: float
    edge_err: float
    break_err: float
    drift_err: float
    warned: bool
    into_dead: list[float]
    seconds: float

    @property
    def within(self) -> bool:
        """Edges, break-away and drift within tolerance."""
        return (self.edge_err <= EDGE_TOL and self.break_err <= EDGE_TOL
                and self.drift_err <= DRIFT_TOL)

    @property
    def passed(self) -> bool:
        """Within tolerance or warned, and no LUT command in a true dead zone."""
        return (self.within or self.warned) and not self.into_dead


def draw_case(seed: int) -> Case:
    """Case `seed`: the bridge layout of its group of RUNS_PER_LAYOUT seeds, then its own creep
    length, drift (each run of a layout another) and order (up and up-down in turn)."""
    group = np.random.default_rng(seed // RUNS_PER_LAYOUT)
    fwd_start = int(group.integers(40, 261))
    fwd_end = int(group.integers(max(fwd_start + 120, 330), 431))
    creep_start = fwd_end + 1 + int(group.integers(3, 31))
    drifts = group.permutation(DRIFTS)
    rng = np.random.default_rng(seed)
    breakaway = creep_start + int(rng.integers(1, 41))
    creep_end_n = round(float(rng.uniform(-0.2, -0.1)), 3)
    overrides = {
        "pwm_fwd_start": fwd_start, "pwm_fwd_sat_end": fwd_end - int(group.integers(20, 41)),
        "pwm_fwd_end": fwd_end, "pwm_rev_creep_start": creep_start,
        "pwm_rev_breakaway": breakaway,
        "pwm_rev_sat_start": min(breakaway + int(rng.integers(19, 31)), 790),
        "thrust_rev_creep_start_n": round(float(rng.uniform(-0.1, -0.05)), 3),
        "thrust_rev_creep_end_n": creep_end_n,
        "thrust_rev_breakaway_n": round(creep_end_n - float(rng.uniform(0.4, 0.7)), 3),
        "drift_n_per_h": float(drifts[seed % RUNS_PER_LAYOUT]),
    }
    return Case(seed, overrides, "up" if seed % 2 == 0 else "up-down")


def example_case(seed: int) -> Case:
    """The issue's example: forward 120-350, creep from 372, break-away 380, +0.2 N/h, up."""
    overrides = {
        "pwm_fwd_start": 120, "pwm_fwd_sat_end": 319, "pwm_fwd_end": 350,
        "pwm_rev_creep_start": 372, "pwm_rev_breakaway": 380, "pwm_rev_sat_start": 399,
        "drift_n_per_h": 0.2,
    }
    return Case(seed, overrides, "up")


def protocol_text(case: Case, samples: int) -> str:
    """The shipped stm32-pwm protocol with the case's twin, order, tares and samples per count."""
    doc = yaml.safe_load(PROTOCOL.read_text())
    doc["simulator"] = {"profile": "stm32-pwm", "seed": case.seed, "overrides": case.overrides}
    doc["command"]["order"] = case.order
    doc["timing"]["acquire"]["samples"] = samples
    doc["timing"]["tare"] = case.tare
    return yaml.safe_dump(doc, sort_keys=False)


def calibrate_case(case: Case, samples: int, folder: Path) -> CalibrationResult:
    """Sweep the case on the twin through the CLI and calibrate the run in process."""
    protocol = folder / f"case-{case.seed}.yaml"
    protocol.write_text(protocol_text(case, samples))
    db = folder / f"case-{case.seed}.sqlite"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        if main(["sweep", str(protocol), "--sim", "--db", str(db)]) != 0:
            raise RuntimeError(f"sweep of case {case.seed} failed")
    store = Store(db)
    try:
        return calibrate_run(store, store.resolve_run_id("last"))
    finally:
        store.close()


def edge_error(found: list[tuple[float, float]], truth: list[tuple[int, int]]) -> float:
    """Largest edge error over the true zones (inf if the zone count differs)."""
    if len(found) != len(truth):
        return math.inf
    return max(max(abs(lo - a), abs(hi - b)) for (lo, hi), (a, b) in zip(found, truth,
                                                                          strict=True))


def break_error(found: list[float], truth: int) -> float:
    """Error of the break-away found (inf unless exactly one was found)."""
    return abs(found[0] - truth) if len(found) == 1 else math.inf


def commands_into_dead(cal: CalibrationResult, zones: list[tuple[int, int]]) -> list[float]:
    """Commands `cal.command()` gives for nonzero thrusts that the twin runs as a dead count."""
    api = ApiCalibration.from_results(cal, "2000-01-01T00:00:00Z")
    thrust = np.concatenate([np.linspace(-4.0, -1e-4, 4000), np.linspace(1e-4, 6.0, 6000)])
    command = np.asarray(api.command(thrust))
    counts = np.floor(command[np.isfinite(command)] + 0.5)
    bad = np.zeros(counts.size, dtype=bool)
    for lo, hi in zones:
        bad |= (counts >= lo) & (counts <= hi)
    return sorted(set(counts[bad].tolist()))


def evaluate(case: Case, samples: int, folder: Path) -> Result:
    """Run one case and compare what the calibration found with the truth."""
    start = time.perf_counter()
    cal = calibrate_case(case, samples, folder)
    (sec,) = cal.sections
    curve = sec.curve
    drift = sensor_drift(cal)
    zones = [(float(a), float(b)) for a, b in curve.dead_zones]
    return Result(
        case, zones, list(curve.break_aways), drift, edge_error(zones, case.zones),
        break_error(curve.break_aways, case.break_away), abs(drift - case.drift),
        any(AMBIGUOUS in w for w in cal.warnings), commands_into_dead(cal, case.zones),
        time.perf_counter() - start)


def sensor_drift(cal: CalibrationResult) -> float:
    """The sensor drift (N/h) found: the zero's drift during the sweep, or, where the sensor
    was tared at every point (so the zero of the points does not drift), the tares' drift."""
    (sec,) = cal.sections
    if cal.drift is not None and cal.drift.slope.n > 2:
        return cal.drift.slope.value
    return sec.zero.drift_n_per_s * 3600.0 if sec.zero is not None else 0.0


def layout(case: Case) -> str:
    """Short text of a case's layout."""
    o = case.overrides
    return (f"fwd {o['pwm_fwd_start']}-{o['pwm_fwd_end']} creep {o['pwm_rev_creep_start']}"
            f"-{o['pwm_rev_breakaway'] - 1} ({o['pwm_rev_breakaway'] - o['pwm_rev_creep_start']})"
            f" {case.drift:+.2f} N/h {case.order} {case.tare}")


def report_line(r: Result) -> str:
    """One line per case."""
    verdict = "ok" if r.passed else "FAIL"
    warn = "warned" if r.warned else ""
    into = f" into dead {r.into_dead[:5]}" if r.into_dead else ""
    return (f"{r.case.seed:6d} {layout(r.case):58s} edges {r.edge_err:5.1f} "
            f"break {r.break_err:5.1f} drift {r.drift:+.3f} (err {r.drift_err:.3f}) "
            f"{r.seconds:4.1f}s {warn}{into} {verdict}")


def summary(results: list[Result]) -> list[str]:
    """Typical (median) and worst errors, counts of warnings and failures."""
    quiet = [r for r in results if not r.warned]
    lines = [f"{len(results)} cases, {sum(r.warned for r in results)} warned, "
             f"{sum(not r.passed for r in results)} failed, "
             f"{sum(bool(r.into_dead) for r in results)} with a LUT command in a true dead zone"]
    for name, key in (("edge error (counts)", "edge_err"), ("break-away error (counts)",
                                                            "break_err"),
                      ("drift error (N/h)", "drift_err")):
        values = [getattr(r, key) for r in quiet] or [math.nan]
        lines.append(f"{name:26s} typical {statistics.median(values):.3g}  "
                     f"worst {max(values):.3g}  (cases without a warning)")
    warned = [r for r in results if r.warned]
    if warned:
        lines.append("warned cases: " + ", ".join(
            f"{r.case.seed} (edges {r.edge_err:g}, drift err {r.drift_err:.3f})" for r in warned))
    return lines


def seed_range(text: str) -> list[int]:
    """'70000-70047' or '5,7,9' as a list of seeds."""
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def run(seeds: list[int], samples: int, verbose: bool, example: bool,
        variant: dict[str, str]) -> list[Result]:
    """Evaluate every case, printing one line each."""
    results = []
    cases = [replace(example_case(s) if example else draw_case(s), **variant) for s in seeds]
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            r = evaluate(case, samples, Path(tmp))
            results.append(r)
            print(report_line(r), flush=True)
            if verbose and not r.passed:
                print(f"       found zones {r.zones} break-aways {r.break_aways}, "
                      f"true zones {case.zones} break-away {case.break_away}")
    return results


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Command-line options."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="70000-70047", help="seed range a-b or list a,b,c")
    ap.add_argument("--samples", type=int, default=500, help="samples per PWM count")
    ap.add_argument("--example", action="store_true", help="the issue's example layout")
    ap.add_argument("--order", help="sweep order for every case (default: drawn, up or up-down)")
    ap.add_argument("--tare", help="tare mode for every case (default: per_depth, as shipped)")
    ap.add_argument("--verbose", action="store_true")
    return ap.parse_args(argv)


def entry(argv: list[str] | None = None) -> int:
    """Run the grid and print the summary; exit 1 if any case failed."""
    args = parse_args(argv)
    start = time.perf_counter()
    variant = {k: v for k, v in (("order", args.order), ("tare", args.tare)) if v}
    results = run(seed_range(args.seeds), args.samples, args.verbose, args.example, variant)
    print("\n".join(summary(results)))
    print(f"total {time.perf_counter() - start:.0f} s")
    return 0 if all(r.passed for r in results) else 1


if __name__ == "__main__":
    sys.exit(entry())
