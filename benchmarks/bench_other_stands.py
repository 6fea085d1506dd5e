"""Issue 47 figures on logs in other stands' designs, built from known truth by
tests/standlogs.py (not the twin), through `rigtool import` and `rigtool calibrate`.

Per case and seed range: how often the right thrust-law family is chosen, how often the
quadratic-adequacy flag is right (set exactly when C_p n^2 misses the truth by more than 2 %
of full scale between 10 and 100 % speed), the C_p interval coverage and worst error where
the law is quadratic, the worst thrust_from_speed error (% of full scale), and, for the
hysteretic ESC, whether cal.command ever answers between the stop and start edges. For
command ramps with a speed column (5 and 100 Hz, neutral at both ends, the thrust channel
lagging the speed by a load cell's first-order filter or not): the C_p interval's coverage
(the full interval, and the statistical one without the 0.1 % scale allowance), the worst
C_p error, and the thrust_lag_s interval's coverage of the lag.

    python benchmarks/bench_other_stands.py 47000 47040           # held-out seeds
    python benchmarks/bench_other_stands.py 47000 47040 "ramp"    # only cases named so
    python benchmarks/bench_other_stands.py 47000 47040 steps     # only the step tables
    python benchmarks/bench_other_stands.py 47000 47020 "rov"     # only the in-water table
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rigtool  # noqa: E402
from tests.standlogs import Stand, ramp_log, rov_table, step_table  # noqa: E402

CASES = {
    "quadratic, one-way": (Stand(offset_n=0.1), "quadratic", False),
    "power k=2.15": (Stand(law="power", k=2.15), "power", False),
    "power k=1.85": (Stand(law="power", k=1.85), "power", False),
    "quadratic+linear": (Stand(law="quadratic+linear", cp=4e-7, linear=3e-4),
                         "quadratic+linear", False),
    "hysteretic ESC, up-down": (Stand(start_us=40.0, stop_us=5.0), "quadratic", True),
    "1.5 % crosstalk, declared": (Stand(crosstalk_frac=0.015), "quadratic", False),
}
IMPORT_ARGS = {"1.5 % crosstalk, declared": ["--sensor-accuracy", "crosstalk=1.5"]}


def run_case(stand: Stand, seed: int, updown: bool, tmp: Path,
             args: tuple[str, ...] = ()) -> tuple[dict, object]:
    """Import and calibrate one log through the CLI; (depth section, API calibration)."""
    csv, db, out = tmp / f"{seed}.csv", tmp / "b.sqlite", tmp / "cal"
    csv.write_text(step_table(stand, seed, step_us=5.0 if updown else 25.0, updown=updown)[0],
                   encoding="utf-8")
    text = subprocess.run(["rigtool", "import", str(csv), "--db", str(db), *args], check=True,
                          capture_output=True, text=True).stdout
    run_id = text.split("run ")[-1].strip()
    subprocess.run(["rigtool", "calibrate", run_id, "--db", str(db), "--out", str(out)],
                   check=True, capture_output=True)
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    return depth, rigtool.load_calibration(out / run_id)


def ramp_case(seed: int, tmp: Path, end_hold_s: float) -> tuple[float, bool]:
    """A 5 Hz ramp without speed: the worst error of cal.command over 10-90 % of full-scale
    thrust (% FS, the thrust the stand gives at the command answered), and whether a drift
    warning was given (there is none in the log)."""
    stand = Stand(offset_n=0.05)
    csv, db, out = tmp / f"r{seed}.csv", tmp / "r.sqlite", tmp / "cal"
    csv.write_text(ramp_log(stand, seed, 5.0, end_hold_s=end_hold_s), encoding="utf-8")
    text = subprocess.run(["rigtool", "import", str(csv), "--db", str(db)], check=True,
                          capture_output=True, text=True).stdout
    run_id = text.split("run ")[-1].strip()
    subprocess.run(["rigtool", "calibrate", run_id, "--db", str(db), "--out", str(out)],
                   check=True, capture_output=True)
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    cal = rigtool.load_calibration(out / run_id)
    full = float(stand.thrust(np.array([stand.top_rpm]))[0])
    want = np.linspace(0.1, 0.9, 17) * full
    cmd = np.asarray(cal.command(want))
    got = stand.thrust(np.where(cmd - 1500 >= stand.start_us, stand.top_rpm * (cmd - 1500) / 400,
                                0.0))
    warned = any(w.startswith("sensor zero drifts") for w in depth["warnings"])
    return float(np.max(np.abs(got - want)) / full), warned


def rov_case(seed: int, tmp: Path) -> float:
    """An in-water table (10 rows a side, 1.5 % FS noise, reverse 0.8 x forward): the worst
    error of cal.command over 10-95 % of each side's full thrust, % of forward full scale
    (the thrust the thruster gives at the command answered, minus the thrust asked)."""
    csv, db, out = tmp / f"w{seed}.csv", tmp / "w.sqlite", tmp / "cal"
    csv.write_text(rov_table(seed), encoding="utf-8")
    text = subprocess.run(["rigtool", "import", str(csv), "--db", str(db)], check=True,
                          capture_output=True, text=True).stdout
    run_id = text.split("run ")[-1].strip()
    subprocess.run(["rigtool", "calibrate", run_id, "--db", str(db), "--out", str(out)],
                   check=True, capture_output=True)
    cal = rigtool.load_calibration(out / run_id)
    cp, rev, full = 5e-6, 0.8, 5e-6 * 2700.0**2
    worst = 0.0
    for sign, top in ((1.0, full), (-1.0, rev * full)):
        want = sign * np.linspace(0.1, 0.95, 30) * top
        cmd = np.asarray(cal.command(want), dtype=float)
        n = np.where(np.abs(cmd - 1500.0) < 25.0, 0.0, 3000.0 * (cmd - 1500.0) / 400.0)
        got = np.where(n > 0, cp, cp * rev) * np.abs(n) * n
        worst = max(worst, float(np.max(np.abs(got - want)) / full))
    return worst


RAMP_SPEED_CASES = {f"ramp {rate:g} Hz with speed, {f'lag {lag:g} s' if lag else 'no lag'}":
                    (rate, lag) for rate in (5.0, 100.0) for lag in (0.0, 0.2)}


def ramp_speed_case(seed: int, tmp: Path, rate_hz: float, lag_s: float) -> dict:
    """One ramp with a speed column through the CLI; its depth section."""
    csv, db, out = tmp / f"s{seed}.csv", tmp / "s.sqlite", tmp / "cal"
    csv.write_text(ramp_log(Stand(offset_n=0.05), seed, rate_hz, end_hold_s=10.0, speed=True,
                            lag_s=lag_s), encoding="utf-8")
    text = subprocess.run(["rigtool", "import", str(csv), "--db", str(db)], check=True,
                          capture_output=True, text=True).stdout
    run_id = text.split("run ")[-1].strip()
    subprocess.run(["rigtool", "calibrate", run_id, "--db", str(db), "--out", str(out)],
                   check=True, capture_output=True)
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    return depth


def ramp_speed_line(name: str, first: int, stop: int, rate_hz: float, lag_s: float) -> str:
    """The C_p and lag figures of one ramp-with-speed case over the seeds."""
    cp = Stand().cp
    cover, stat, lag_cover, err = 0, 0, 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(first, stop):
            coef = ramp_speed_case(seed, Path(tmp), rate_hz, lag_s)["coefficients"]
            c, lag = coef["C_p_fwd"], coef.get("thrust_lag_s")
            cover += c["lo"] <= cp <= c["hi"]
            lo, hi = c.get("stat_lo") or c["lo"], c.get("stat_hi") or c["hi"]
            stat += lo <= cp <= hi
            lag_cover += bool(lag) and lag["lo"] <= lag_s <= lag["hi"]
            err.append(abs(c["value"] / cp - 1))
    k = stop - first
    return (f"{name}: C_p coverage {cover}/{k} (statistical {stat}/{k}), worst C_p error "
            f"{100 * max(err):.2f} % (median {100 * float(np.median(err)):.3f} %), "
            f"thrust_lag_s coverage {lag_cover}/{k}")


def main(first: int, stop: int, only: str = "") -> None:
    steps = only == "steps"
    for name, (rate_hz, lag_s) in RAMP_SPEED_CASES.items():
        if only in name and not steps:
            print(ramp_speed_line(name, first, stop, rate_hz, lag_s), flush=True)
    for name, (stand, family, updown) in CASES.items():
        if only not in name and not steps:
            continue
        right, flag_right, cover, cp_err, curve_err, in_band = [], [], [], [], [], 0
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(first, stop):
                depth, cal = run_case(stand, seed, updown, Path(tmp),
                                      tuple(IMPORT_ARGS.get(name, ())))
                law = depth["thrust_law"]["fwd"]
                n = np.linspace(0.1, 1.0, 50) * stand.top_rpm
                truth = stand.thrust(n)
                full = float(stand.thrust(np.array([stand.top_rpm]))[0])
                miss = np.max(np.abs(law["quadratic_c_p"] * n**2 - truth)) / full
                right.append(law["family"] == family)
                flag_right.append(law["quadratic_adequate"] == bool(miss <= 0.02))
                curve_err.append(float(np.max(np.abs(cal.thrust_from_speed(n) - truth)) / full))
                if stand.law == "quadratic":
                    c = depth["coefficients"]["C_p_fwd"]
                    cover.append(c["lo"] <= stand.cp <= c["hi"])
                    cp_err.append(abs(c["value"] / stand.cp - 1))
                if updown:
                    edges = (depth["command_curve"]["start_stop"] or {}).get("above")
                    cmd = cal.command(np.linspace(0.0, full, 400))
                    start = edges["start"] if edges else 1500 + stand.start_us
                    in_band += int(np.any((cmd > 1500) & (cmd < start)))
        k = stop - first
        line = (f"{name}: family {sum(right)}/{k}, flag {sum(flag_right)}/{k}, "
                f"thrust_from_speed worst {100 * max(curve_err):.2f} % FS "
                f"(median {100 * float(np.median(curve_err)):.2f} %)")
        if cover:
            line += (f", C_p coverage {sum(cover)}/{k}, worst C_p error "
                     f"{100 * max(cp_err):.2f} %")
        if updown:
            line += f", commands between the edges in {in_band}/{k} seeds"
        print(line, flush=True)
    if only in "rov table" and not steps:
        with tempfile.TemporaryDirectory() as tmp:
            errs = [rov_case(seed, Path(tmp)) for seed in range(first, stop)]
        print(f"rov table, 10 rows a side: cal.command worst {100 * max(errs):.2f} % FS "
              f"(median {100 * float(np.median(errs)):.2f} %)", flush=True)
    for end_hold_s in (0.0, 10.0) if only in "ramp 5 Hz, no speed" and not steps else ():
        with tempfile.TemporaryDirectory() as tmp:
            res = [ramp_case(seed, Path(tmp), end_hold_s) for seed in range(first, stop)]
        errs = [e for e, _ in res]
        print(f"ramp 5 Hz, no speed{', neutral at both ends' if end_hold_s else ''}: "
              f"cal.command worst {100 * max(errs):.2f} % FS (median "
              f"{100 * float(np.median(errs)):.2f} %), drift warned in "
              f"{sum(w for _, w in res)}/{stop - first}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "")
