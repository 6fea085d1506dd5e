"""Every shipped protocol runs sweep -> calibrate (with every export format) -> report through
the CLI with exit 0, as a user would run it on the simulated rig (luo2020-cavitation after its
deep base run). calibrate --export writes every vehicle file or none (exit 2 naming what is
missing), no file holds an empty list, and the calibration and vehicle files are byte for byte
those committed under tests/golden/ (run id, times and tool version aside; numbers within
golden_files' tolerance): a restructuring must not change a number. `RIGTOOL_UPDATE_GOLDEN=1`
updates them after an intended change, touching only what changed (tests/golden_files.py)."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigtool.analysis.blocks import block_means
from rigtool.analysis.dataset import load_run
from rigtool.artefacts.calibration import FILES
from rigtool.artefacts.formats import FORMATS, MODULES
from rigtool.artefacts.vehicle import ExportOptions
from rigtool.cli import main
from rigtool.errors import UsageError
from rigtool.models import MODEL_FILE, VARIANCE_FILE, load_model
from rigtool.store import Store
from rigtool.thruster_profiles import profile_with_overrides
from rigtool.workflows import export_calibration, stored_results

from . import golden_files
from .conftest import PROTOCOLS, copy_db
from .test_c_evaluator import C_DIR, CC, _agree
from .test_export_all_formats import OPTIONS, empty_lists

SHIPPED = sorted(p.stem for p in PROTOCOLS.glob("*.yaml"))
NEEDS = {"luo2020-cavitation": "luo2020-baseline"}  # a deep base run of the same thruster
GOLDEN = Path(__file__).parent / "golden"
EXPORT_OPTIONS = ExportOptions(joint="prop_joint", link="thruster_link", namespace="auv",
                               index=2, mesh="prop.obj", material="Steel")  # as OPTIONS
COMPARED = (*FILES.values(), *FORMATS.values())


def test_the_list_is_the_shipped_protocols():
    assert {"quick-demo", "luo2020-baseline", "luo2020-cavitation", "esc-1100-1900",
            "stm32-pwm"} <= set(SHIPPED)


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_sweep_calibrate_report(name, tmp_path, monkeypatch, capsys, shipped_sweep):
    """The first sweep is the session's (conftest.shipped_sweep), copied: the same CLI sweep
    the other files that start from a shipped protocol share; a needed run is swept after it."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RIGTOOL_DB", str(tmp_path / "rigtool.sqlite"))
    first, *then = filter(None, (NEEDS.get(name), name))
    copy_db(shipped_sweep(first), tmp_path / "rigtool.sqlite")
    for protocol in then:
        assert main(["sweep", str(PROTOCOLS / f"{protocol}.yaml"), "--sim"]) == 0
    capsys.readouterr()
    exports = [a for f in MODULES for a in ("--export", f)]
    code = main(["calibrate", "last", *OPTIONS, *exports])
    if code == 2:  # a format lacks what it needs: nothing written, then calibrate alone
        assert "nothing exported" in capsys.readouterr().err
        assert not (tmp_path / "calibrations").exists()
        assert main(["calibrate", "last"]) == 0
    else:
        assert code == 0
    drift = [w for w in capsys.readouterr().err.splitlines() if "drift" in w]
    setting, matters = _twin_drift(name, tmp_path / "rigtool.sqlite")
    assert len(drift) == int(matters), (setting, drift)
    if matters:  # the rate quoted is the twin's
        rate = float(re.search(r"at (\S+) N/h", drift[0]).group(1))
        assert rate == pytest.approx(setting["drift_n_per_h"], rel=0.1), drift
    folder = next((tmp_path / "calibrations").iterdir())
    written = {f for f in FORMATS.values() if (folder / f).is_file()}
    assert written in ({FORMATS["csv-lut"]}, set(FORMATS.values())), written
    if written != set(FORMATS.values()):  # each format alone: written, or refused
        with Store(tmp_path / "rigtool.sqlite", read_only=True) as store:
            run_id = store.resolve_run_id("last")
            results = stored_results(store, run_id)  # decoded once for the ten formats
            for fmt in MODULES:
                try:
                    export_calibration(store, run_id, tmp_path / "calibrations", [fmt],
                                       results=results, options=EXPORT_OPTIONS)
                except UsageError as exc:
                    assert f"{fmt}: " in str(exc)
                    assert not (folder / FORMATS[fmt]).exists(), fmt
    assert all(empty_lists(folder / f) == [] for f in FORMATS.values() if (folder / f).is_file())
    _golden(name, folder)
    assert main(["report", "last"]) == 0
    report = capsys.readouterr().out.strip().splitlines()[-1]
    assert report.endswith("report.html") and (tmp_path / report).is_file()
    if name in NEEDS:
        assert 'id="cavitation"' in (tmp_path / report).read_text()
        _qctm_model_is_slim_and_read_by_both(folder, tmp_path)


def _qctm_model_is_slim_and_read_by_both(folder: Path, tmp_path: Path) -> None:
    """The default QCTM-GP keeps no GP signal: no posterior-variance file (18 MB here before
    format 6), the model files under 1 MB, and rigtool.models and the C evaluator agree on
    the run's own block means."""
    doc = json.loads((folder / MODEL_FILE).read_text())
    assert doc["format_version"] == 7 and doc["gp"]["signal"] is False
    assert not (folder / VARIANCE_FILE).exists()
    assert (folder / MODEL_FILE).stat().st_size < 1_000_000
    with Store(tmp_path / "rigtool.sqlite", read_only=True) as store:
        b = block_means(load_run(store, store.resolve_run_id("last")), 0.2)
    inputs = (b.speed_rpm, b.current_a, b.depth_m, b.point.astype(int))
    assert np.isfinite(load_model(folder).evaluate(*inputs).thrust_n).all()
    if CC is not None:
        exe = tmp_path / "qctm_eval"
        subprocess.run([CC, "-std=c99", "-O2", "-o", str(exe), str(C_DIR / "qctm_gp.c"),
                        str(C_DIR / "qctm_eval_main.c"), "-lm"], check=True)
        _agree(exe, folder, *inputs)


def _twin_drift(name: str, db) -> tuple[dict, bool]:
    """The twin's zero drift and force noise settings for protocol `name`, and whether that
    drift moves the zero by more than the noise over the points that share one zero estimate
    (a depth, at one supply voltage; the whole run where three tares or more give a trend):
    the drift warning's criterion, applied to what the twin was given."""
    sim = yaml.safe_load((PROTOCOLS / f"{name}.yaml").read_text())["simulator"]
    profile = profile_with_overrides(sim["profile"], sim.get("overrides") or {})
    with Store(db) as store:
        run_id = store.resolve_run_id("last")
        steps, n_tares = store.steps(run_id), len(store.events(run_id, "tare"))
    groups: dict[tuple, list[dict]] = {}
    for s in steps:
        groups.setdefault((s["depth_m"], s["voltage_set_v"]), []).append(s)
    spans = [_span_h(g) for g in groups.values()] + ([_span_h(steps)] if n_tares >= 3 else [])
    setting = {"profile": profile.name, "drift_n_per_h": profile.drift_n_per_h,
               "force_noise_n": profile.force_noise_n, "span_h": max(spans)}
    return setting, profile.drift_n_per_h * max(spans) > profile.force_noise_n


def _span_h(steps: list[dict]) -> float:
    """Hours from the first acquired sample of `steps` to the end of the last."""
    return (max(s["t_end_s"] for s in steps) - min(s["t_acquire_s"] for s in steps)) / 3600


def _golden(name: str, folder: Path) -> None:
    """Compare (or, with RIGTOOL_UPDATE_GOLDEN=1, update) the calibration and vehicle files."""
    got = {f: golden_files.normalised((folder / f).read_text(), folder) for f in COMPARED
           if (folder / f).is_file()}
    if os.environ.get("RIGTOOL_UPDATE_GOLDEN") == "1":
        golden_files.update(GOLDEN / name, got)
        return
    assert golden_files.mismatches(GOLDEN / name, got) == []
