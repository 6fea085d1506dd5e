"""Every export format on calibrations with and without dead zones, a reverse branch, speed
feedback, torque and dynamics: each writes its file or refuses with exit 2 naming what is
missing and writes nothing; no file holds an empty list (ROS 2 cannot read one); every YAML
file parses; `calibrate --export` with every format writes all files or none (issue:
calibrations that load where vehicles run them). The shipped protocols' calibrate --export with
every format is checked in test_shipped_protocols.py."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

import rigtool
from rigtool.artefacts.formats import FORMATS, MODULES
from rigtool.cli import main

from .conftest import PROTOCOLS

OPTIONS = ["--joint", "prop_joint", "--link", "thruster_link", "--namespace", "auv",
           "--index", "2", "--mesh", "prop.obj", "--material", "Steel"]
SWEEP = """\
rigtool_protocol: 1
name: {name}
simulator: {{profile: {profile}, seed: {seed}}}
metadata: {{thruster_id: t-{seed}{meta}}}
command: {{unit: {unit}, range: {{start: {lo}, stop: {hi}, step: {step}}}, order: up}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{samples: 150, rate_hz: 1000}}
  tare: at_start
"""
PROPELLER = ", propeller_diameter_m: 0.09, water_density_kg_m3: 998"
CASES = {  # a dead band and a reverse branch, each left out somewhere; torque on can-bldc
    "esc-both": dict(profile="esc-1100-1900", seed=8101, unit="pulse_us", lo=1100, hi=1900,
                     step=25, meta=PROPELLER),
    "esc-forward": dict(profile="esc-1100-1900", seed=8102, unit="pulse_us", lo=1500, hi=1900,
                        step=25, meta=""),
    "can-both": dict(profile="can-bldc", seed=8103, unit="percent", lo=-100, hi=100, step=10,
                     meta=PROPELLER),
    "can-forward": dict(profile="can-bldc", seed=8104, unit="percent", lo=0, hi=100, step=10,
                        meta=PROPELLER),
}
STEPS = ("rigtool_protocol: 1\nname: steps\nsimulator: {profile: can-bldc, seed: 8105}\n"
         "metadata: {thruster_id: t-8103}\n"
         "command: {unit: percent, steps: [0, 50, 0, -50, 0, 90, 0, -90, 0]}\n"
         "depth: {unit: m, values: [1.0]}\n"
         "timing: {settle: {seconds: 0}, acquire: {seconds: 2.0, rate_hz: 500}, rest_s: 0, "
         "tare: at_start}\n")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Calibrated runs of each case, and a step run of can-both's thruster."""
    tmp = tmp_path_factory.mktemp("formats")
    db = str(tmp / "db.sqlite")
    runs = {}
    for name, case in CASES.items():
        (tmp / f"{name}.yaml").write_text(SWEEP.format(name=name, **case))
        assert main(["sweep", str(tmp / f"{name}.yaml"), "--sim", "--db", db]) == 0
        assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal")]) == 0
        runs[name] = next(p.name for p in (tmp / "cal").iterdir()
                          if p.name not in runs.values())
    (tmp / "steps.yaml").write_text(STEPS)
    assert main(["sweep", str(tmp / "steps.yaml"), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal")]) == 0
    runs["steps"] = next(p.name for p in (tmp / "cal").iterdir() if p.name not in runs.values())
    return tmp, db, runs


def empty_lists(path: Path) -> list[str]:
    """Where a file holds an empty list, in its own grammar."""
    text = path.read_text()
    empty = r"\{\s*\}" if path.suffix == ".h" else r"\[\s*\]"  # C: name[] declares an array
    found = [m.group() for m in re.finditer(empty, text)]
    if path.suffix == ".yaml":
        def walk(node: object, where: str) -> None:
            if isinstance(node, list) and not node:
                found.append(where)
            for k, v in (node.items() if isinstance(node, dict) else
                         enumerate(node) if isinstance(node, list) else ()):
                walk(v, f"{where}/{k}")
        walk(yaml.safe_load(text), "")
    if path.suffix in (".sdf", ".xml"):
        root = ET.fromstring(f"<r>{re.sub(r'<[?]xml[^>]*>', '', text)}</r>")
        found += [f"{e.tag}@{k}" for e in root.iter() for k, v in e.attrib.items()
                  if not v.strip()]
    return found


@pytest.mark.parametrize("case", [*CASES, "can-both+dynamics"])
def test_each_format_writes_or_refuses_and_never_an_empty_list(lab, case, capsys):
    tmp, db, runs = lab
    name, dynamics = case.split("+")[0], "+dynamics" in case
    extra = ["--dynamics", runs["steps"]] if dynamics else []
    written = 0
    for fmt in MODULES:
        out = tmp / f"out-{case}-{fmt}"
        capsys.readouterr()
        code = main(["export-cal", runs[name], "--format", fmt, "--db", db, "--out", str(out),
                     *OPTIONS, *extra])
        err = capsys.readouterr().err
        if code == 2:
            assert f"{fmt}: " in err and not out.exists(), (fmt, err)
            continue
        assert code == 0, (fmt, err)
        path = out / runs[name] / FORMATS[fmt]
        assert path.is_file() and empty_lists(path) == [], (fmt, empty_lists(path))
        written += 1
    assert written >= 5  # the table formats never need more than the calibration


def ros2_command(p: dict, direction: str, f: float) -> float:
    """The ROS 2 file's documented reading of a map: interpolate within a branch, the nearer
    end between branches, the last command beyond, the neutral below the first thrust."""
    thrust = p[f"map_{direction}_thrust_n"]
    command = p[f"map_{direction}_command"]
    starts = [*p.get(f"map_{direction}_branch_start", [0]), len(thrust)]
    if abs(f) < min(abs(thrust[0]), abs(thrust[-1])):
        return p["neutral_command"]
    for lo, hi in zip(starts, starts[1:], strict=False):
        if thrust[lo] <= f <= thrust[hi - 1]:
            return float(np.interp(f, thrust[lo:hi], command[lo:hi]))
    ends = [(thrust[i], command[i]) for lo, hi in zip(starts, starts[1:], strict=False) for i in (lo, hi - 1)]
    return min(ends, key=lambda e: abs(e[0] - f))[1]


def test_a_direction_with_two_branches_maps_like_cal_command(tmp_path):
    """Two forward branches split by a dead zone at 1650-1700 us (a Tyto-style log built
    here): the ROS 2 map holds both and reads as cal.command does."""
    rng = np.random.default_rng(8106)
    rows, t = ["Time (s),ESC signal (µs),Thrust (N)"], 0.0
    for pwm in range(1100, 1901, 10):
        thrust = (-35 * ((1470 - pwm) / 370) ** 2 if pwm < 1470 else 0.0 if pwm <= 1530 else
                  15 * ((pwm - 1530) / 110) ** 1.5 if pwm < 1650 else 0.0 if pwm <= 1700
                  else 22 + 20 * (pwm - 1700) / 200)
        for _ in range(30):
            t += 0.05
            rows.append(f"{t:.3f},{pwm},{thrust + 0.02 * rng.normal():.4f}")
    (tmp_path / "log.csv").write_text("\n".join(rows) + "\n")
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["import", str(tmp_path / "log.csv"), "--db", db, "--settle-s", "0.3"]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out), "--export", "ros2"]) == 0
    folder = next(out.iterdir())
    p = yaml.safe_load((folder / FORMATS["ros2"]).read_text())["/**"]["ros__parameters"][
        "rigtool"]
    assert len(p["map_forward_branch_start"]) == 2
    cal = rigtool.load_calibration(folder)
    for f in np.linspace(0.05, 60, 600):
        assert ros2_command(p, "forward", f) == pytest.approx(cal.command(f), abs=1e-6), f


def test_a_failed_write_leaves_no_file_and_a_new_calibration_no_stale_one(lab, capsys):
    tmp, db, runs = lab
    out, run = tmp / "blocked", runs["esc-both"]
    (out / run / FORMATS["ros2"]).mkdir(parents=True)  # a target that cannot be written
    capsys.readouterr()
    code = main(["export-cal", run, "--db", db, "--out", str(out), "--format", "c-header",
                 "--format", "csv-lut", "--format", "ros2"])
    assert code == 1 and "nothing exported" in capsys.readouterr().err
    assert sorted(p.name for p in (out / run).iterdir()) == [FORMATS["ros2"]]
    (out / run / FORMATS["ros2"]).rmdir()
    assert main(["export-cal", run, "--db", db, "--out", str(out), "--format", "c-header",
                 "--format", "px4"]) == 0
    assert main(["report", run, "--db", db, "--out", str(out)]) == 0
    assert main(["calibrate", run, "--db", db, "--out", str(out)]) == 0
    left = {p.name for p in (out / run).iterdir()}
    assert not left & {FORMATS["c-header"], FORMATS["px4"], "report.html"}
    assert "calibration.json" in left


def test_px4_refuses_a_curve_its_model_cannot_follow(tmp_path, capsys):
    """The STM32 bridge's inverted forward branch (seed 8107): PX4's thrust rising from the
    neutral command would need a negative CA_ROTOR_CT; refused, not written."""
    text = (PROTOCOLS / "stm32-pwm.yaml").read_text().replace("seed: 2017", "seed: 8107")
    text = text.replace("samples: 500", "samples: 40").replace("step: 1}", "step: 4}")
    (tmp_path / "p.yaml").write_text(text)
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["sweep", str(tmp_path / "p.yaml"), "--sim", "--db", db]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(out), "--export", "px4"]) == 2
    assert "outside PX4's range" in capsys.readouterr().err and not out.exists()
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    capsys.readouterr()
    code = main(["export-cal", "last", "--db", db, "--out", str(out), "--format",
                 "auv-controllers", "--joint", "j"])
    assert code == 2 and "forward thrust must come from commands above" in (
        capsys.readouterr().err)  # nor a dead band with min above max
