"""The post-run workflows the CLI and the Python API both call: calibrate (fit, quasi-cavitation,
artefacts, stored results) and report (render what calibrate stored, recompute nothing)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rigtool.artefacts import state
from rigtool.errors import DataError, UsageError
from rigtool.ids import is_run_id, run_label, utc_now
from rigtool.outpaths import REPORT_FILE, run_folder
from rigtool.progress import stage
from rigtool.readback import brief
from rigtool.store import Store
from rigtool.version import __version__

if TYPE_CHECKING:
    from rigtool.analysis.compare import CompareResult
    from rigtool.analysis.results import CalibrationResult, CavitationResult
    from rigtool.artefacts.vehicle import DynamicsSource, ExportOptions

# Analysis, artefact and comparison modules are imported by the workflow that needs them:
# `report` only decodes stored results, and starts without scikit-learn or pyarrow.

CAUSAL_WARNING = ("quasi-cavitation: the causal (past-only) shortfall window misses the accuracy "
                  "target outside ventilation events: p95 |error| up to 1.2 N on held-out twin "
                  "runs against 1 N, and its event intervals are wider than needed "
                  "(docs/cavitation.md)")


@dataclass
class Results:
    """What calibrate found for one run: the fit, the quasi-cavitation result (its GP omitted
    once stored; the model files hold it) and the warnings about both."""

    run_id: str
    created_utc: str
    calibration: CalibrationResult | None
    cavitation: CavitationResult | None = None
    notes: list[str] = field(default_factory=list)
    folder: Path | None = None
    paths: list[Path] = field(default_factory=list)


def calibrate(store: Store, run_ref: str, out_dir: str | Path = "calibrations", *,
              base: str | None = None, causal: bool = False,
              train_with: Sequence[str] = (),
              check: Callable[[CalibrationResult], None] | None = None) -> Results:
    """Calibrate a stored run: write calibrations/<run-id>/ and store the results.

    Every reference (the run, `base`, `train_with`) is checked before any file is written;
    UsageError names the bad one. `check` sees the analysis before anything is written or
    stored (calibrate --export checks the formats' prerequisites there).
    """
    from rigtool.analysis.calibrate import calibrate as analyse
    from rigtool.analysis.calibrate import mark_ventilated
    from rigtool.analysis.cavitation import EVENT_KIND, calibrate_cavitation
    from rigtool.analysis.cavitation_runs import cavitation_stage, training_runs, unchecked_thruster
    from rigtool.analysis.dataset import load_run
    from rigtool.analysis.results import CavitationParams
    from rigtool.artefacts.calibration import calibration_document, write_artefacts
    from rigtool.artefacts.cavitation import write_cavitation_artefacts
    from rigtool.artefacts.formats import remove_exports

    run_id = store.resolve_run_id(run_ref)
    cav_stage = cavitation_stage(store, run_id, base)
    if train_with and cav_stage.base_run_id is None:
        raise UsageError(f"--train-with: run {run_id} has no quasi-cavitation model to train "
                         f"({'; '.join(cav_stage.warnings) or 'no base run'})")
    extra = training_runs(store, run_id, train_with)
    stage_notes = [*cav_stage.warnings, *(
        f"quasi-cavitation: {n}" for n in (unchecked_thruster(store, run_id, rid, "training")
                                           for rid in extra) if n)]
    with stage(f"calibrating run {run_id}") as progress:
        run = load_run(store, run_id)
        cal = analyse(run, progress=progress)
        if _add_captive(store, run_id, cal):  # a held vehicle: no propeller to ventilate
            cav_stage = dataclasses.replace(cav_stage, base_run_id=None, warn=False, notes=())
            stage_notes = []
    if check is not None:
        check(cal)
    created = utc_now()
    folder = run_folder(out_dir, run_id)
    remove_exports(folder)
    (folder / REPORT_FILE).unlink(missing_ok=True)  # the earlier calibration's: write it again
    cav, notes, paths = None, list(stage_notes), []
    if cav_stage.base_run_id is not None:
        with stage(f"quasi-cavitation model of run {run_id} (base run {cav_stage.base_run_id})"
                   ) as progress:
            cav = calibrate_cavitation(store, run_id, cav_stage.base_run_id,
                                       params=CavitationParams(causal=causal), train_with=extra,
                                       run=run, progress=progress)
        store.replace_events(run_id, EVENT_KIND, cav.events)
        cal.warnings += mark_ventilated(cal, cav.events)
        paths += write_cavitation_artefacts(cav, out_dir, created_utc=created)
        notes = [*stage_notes, *(f"quasi-cavitation: {w}" for w in cav.warnings)]
        if causal:
            notes.append(CAUSAL_WARNING)
    paths = write_artefacts(cal, out_dir, created_utc=created) + paths
    results = Results(run_id, created, cal, cav, notes, folder, paths)
    store.add_calibration(run_id, str(folder), calibration_document(cal, created),
                          __version__, state=_encode(results), created_utc=created)
    return results


def _add_captive(store: Store, run_id: str, cal: CalibrationResult) -> bool:
    """A captive run's damping laws, with its warnings; a thruster held at one command the
    whole run has no thruster law, and says so once instead of in every fit's words.
    Returns whether the run is a captive one."""
    from rigtool.analysis.captive import fit_captive
    from rigtool.analysis.dataset import load_captive

    data = load_captive(store, run_id)
    if data is None:
        return False
    cal.captive = fit_captive(data)
    commands = {float(c) for s in cal.sections for c in s.points.command}
    if len(commands) == 1:
        cal.warnings = [f"thruster: held at {commands.pop():g} {cal.command_unit} throughout "
                        "this captive run, so no thruster law is fitted"]
    cal.warnings += cal.captive.warnings
    return True


def _encode(results: Results) -> bytes:
    cav = results.cavitation
    return state.encode({
        "calibration": results.calibration,
        "cavitation": None if cav is None else dataclasses.replace(cav, gp=None),
        "notes": results.notes,
    })


def stored_results(store: Store, run_id: str) -> Results:
    """The results calibrate stored for `run_id`. A run without points needs none (its results
    are empty); any other uncalibrated run is a UsageError that says what to run."""
    record = store.latest_calibration(run_id)
    if record is None or record["state"] is None:
        if not store.steps(run_id):
            return Results(run_id, utc_now(), None)
        when = "" if record is None else " by this rigtool version"
        raise UsageError(f"run {run_id} has not been calibrated{when}: run "
                         f"`rigtool calibrate {run_id}` first (the report shows what it stored)")
    data = _stored_state(record["state"], run_id, store.path)
    return Results(run_id, record["created_utc"], data["calibration"], data["cavitation"],
                   data["notes"], Path(record["out_dir"]))


def _stored_state(blob: bytes, run_id: str, db: Path) -> dict:
    """The results a state blob holds, checked to be this run's; DataError otherwise."""
    try:
        data = state.decode(blob)
    except Exception as exc:  # the blob is untrusted: every failure means "calibrate again"
        raise _bad_state(db, run_id, f"is unreadable ({brief(exc)})") from None
    if not isinstance(data, dict) or not {"calibration", "cavitation", "notes"} <= data.keys():
        raise _bad_state(db, run_id, "is not the results `rigtool calibrate` stores")
    cal, cav, notes = data["calibration"], data["cavitation"], data["notes"]
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise _bad_state(db, run_id, "has notes that are not a list of texts")
    if cal is not None:
        from rigtool.analysis.results import CalibrationResult

        if not isinstance(cal, CalibrationResult):
            raise _bad_state(db, run_id, f"holds a {type(cal).__name__}, not a calibration")
        if cal.run_id != run_id:
            raise _bad_state(db, run_id, f"is the calibration of run {run_label(cal.run_id)}")
        problem = _inconsistency(cal)
        if problem:
            raise _bad_state(db, run_id, f"is inconsistent: {problem}")
    if cav is not None and type(cav).__name__ != "CavitationResult":
        raise _bad_state(db, run_id, f"holds a {type(cav).__name__}, not a cavitation result")
    return {"calibration": cal, "cavitation": cav, "notes": list(notes)}


def _inconsistency(cal: Any) -> str | None:
    """What makes a decoded calibration unusable by its readers (report, exports, the API),
    beyond the field types the decoder checks: no section, arrays of one table that disagree
    in length or are not numeric, scalars out of any physical range."""
    if not cal.sections:
        return "it has no section"
    if not _finite_within(cal.neutral_command, 1e9):
        return f"neutral_command is {cal.neutral_command!r}"
    for name in ("propeller_diameter_m", "water_density_kg_m3"):
        value = getattr(cal, name)
        if value is not None and not math.isnan(value) and not (0 < value <= 1e4):
            return f"{name} is {value!r}"
    for i, sec in enumerate(cal.sections):
        problem = _table_problem(sec.points) or (sec.curve and _curve_problem(sec.curve))
        if problem:
            return f"section {i}: {problem}"
    return None if cal.captive is None else _captive_problem(cal.captive)


def _captive_problem(res: Any) -> str | None:
    """A captive result's point table: one row per point, three flow and six load columns,
    numeric; an angle kind the fits know; law zeros one per angle."""
    p = res.points
    if res.angle not in ("yaw", "attack"):
        return f"captive.angle is {res.angle!r}"
    problem = _columns_problem("captive.points", {
        "step_idx": p.step_idx, "speed_mps": p.speed_mps, "angle_deg": p.angle_deg})
    if problem:
        return problem
    n = p.step_idx.size
    for name, cols in (("velocity_mps", 3), ("mean", 6), ("se", 6)):
        value = getattr(p, name)
        if not isinstance(value, np.ndarray) or value.shape != (n, cols) or \
                value.dtype.kind not in "biuf":
            return f"captive.points.{name} is not a {n} x {cols} numeric table"
    for law in res.laws:
        if law.offsets.shape != law.offset_angles_deg.shape:
            return f"captive law {law.force!r}: zeros and angles disagree"
    return None


def _finite_within(value: float, bound: float) -> bool:
    return math.isfinite(value) and abs(value) <= bound


def _columns_problem(owner: str, columns: dict[str, Any], allow_empty: bool = False) -> str | None:
    """Columns of one table: one-dimensional, numeric (or text where named so), one length."""
    lengths = set()
    for name, values in columns.items():
        if not isinstance(values, np.ndarray) or values.ndim != 1:
            return f"{owner}.{name} is not a one-dimensional array"
        if values.dtype.kind not in "biufU":
            return f"{owner}.{name} holds {values.dtype} values"
        if not (allow_empty and values.size == 0):
            lengths.add(values.size)
    return f"{owner} columns have lengths {sorted(lengths)}" if len(lengths) > 1 else None


def _table_problem(points: Any) -> str | None:
    """The point table: every column, and every channel's statistics, one row per point."""
    columns = {f.name: getattr(points, f.name) for f in dataclasses.fields(points)
               if isinstance(getattr(points, f.name), np.ndarray)}
    for f in dataclasses.fields(points):
        stats = getattr(points, f.name)
        if dataclasses.is_dataclass(stats):
            columns |= {f"{f.name}.{g.name}": getattr(stats, g.name)
                        for g in dataclasses.fields(stats)
                        if isinstance(getattr(stats, g.name), np.ndarray)}
    if points.command.dtype.kind not in "biuf" or points.step_idx.dtype.kind not in "biuf":
        return "points.command and points.step_idx must be numbers"
    if points.step_idx.size and not np.all(np.abs(points.step_idx) < 2**53):
        return "points.step_idx out of range"
    return _columns_problem("points", columns, allow_empty=True)


def _curve_problem(curve: Any) -> str | None:
    """The command curve: its columns, and each branch's two pairs of columns."""
    columns = {f.name: getattr(curve, f.name) for f in dataclasses.fields(curve)
               if isinstance(getattr(curve, f.name), np.ndarray)}
    problem = _columns_problem("curve", columns)
    if problem or not _finite_within(curve.neutral_command, 1e9):
        return problem or f"curve.neutral_command is {curve.neutral_command!r}"
    for branch in curve.branches:
        for pair in (("command", "thrust_fit_n"), ("lut_command", "lut_thrust_n")):
            cols = {k: getattr(branch, k) for k in pair if hasattr(branch, k)}
            problem = _columns_problem(f"curve branch {branch.direction}", cols)
            if problem:
                return problem
    return None


def _bad_state(db: Path, run_id: str, problem: str) -> DataError:
    """The error for a stored calibration state that cannot be used."""
    return DataError(f"run database {db}: run {run_label(run_id)}, calibrations.state: the "
                     f"stored calibration {problem}; run `rigtool calibrate` on it again")


def report(store: Store, run_ref: str, out_dir: str | Path = "calibrations", *,
           results: Results | None = None, image_format: str = "svg") -> Path:
    """Write calibrations/<run-id>/report.html from the stored results (or `results`, just
    computed) and return its path."""
    from rigtool.report import write_report

    run_id = store.resolve_run_id(run_ref)
    res = results or stored_results(store, run_id)
    with stage(f"report of run {run_id}"):
        return write_report(store, run_id, run_folder(out_dir, run_id), res.calibration,
                            cavitation=res.cavitation, extra_warnings=res.notes,
                            image_format=image_format)


def calibration_of(store: Store, run_id: str) -> CalibrationResult:
    """The run's stored calibration, or (never calibrated) one computed now and not stored."""
    from rigtool.analysis.calibrate import calibrate_run

    record = store.latest_calibration(run_id)
    if record is not None and record["state"] is not None:
        cal = _stored_state(record["state"], run_id, store.path)["calibration"]
        if cal is None:
            raise UsageError(f"run {run_id} has no points: there is no calibration to compare")
        return cal
    with stage(f"calibrating run {run_id}") as progress:
        return calibrate_run(store, run_id, progress=progress)


def compare(store: Store, run_refs: Sequence[str], reference: str | None = None,
            out_dir: str | Path = "calibrations/compare", *, floor_frac: float = 0.1
            ) -> tuple[CompareResult, list[Path]]:
    """Compare thrusters (runs): corrections and compare.html in `out_dir`; the reference run
    joins the compared runs if missing."""
    from rigtool.analysis.compare import compare_curves, curve_from_calibration
    from rigtool.artefacts.compare import write_corrections
    from rigtool.report.compare_html import write_compare_report

    ids = [store.resolve_run_id(r) for r in run_refs]
    ref = store.resolve_run_id(reference) if reference else None
    ids = list(dict.fromkeys(ids + ([ref] if ref else [])))
    cals = [calibration_of(store, r) for r in ids]
    units = {c.command_unit for c in cals}
    if len(units) > 1:
        raise UsageError(f"runs use different command units ({', '.join(sorted(units))}): "
                         "cannot compare their command curves")
    result = compare_curves([curve_from_calibration(c) for c in cals], ref,
                            command_unit=units.pop(), floor_frac=floor_frac)
    folder = Path(out_dir)
    return result, [*write_corrections(result, folder), write_compare_report(result, folder)]


def export_calibration(store: Store, run_ref: str, out_dir: str | Path, formats: Sequence[str],
                       *, results: Results | None = None, dynamics_run: str | None = None,
                       options: ExportOptions | None = None) -> list[Path]:
    """Write vehicle artefacts (rigtool.artefacts.formats) of a calibrated run from its stored
    results (or `results`, just computed); return their paths. The time constants come from
    the run itself when it is a step-response run, else from `dynamics_run`. Every format's
    prerequisites are checked first: all files or none."""
    from rigtool.artefacts.formats import write_vehicle_artefacts

    run_id = _exportable(store, run_ref)
    res = results or stored_results(store, run_id)
    cal = res.calibration
    if cal is None:
        raise UsageError(f"run {run_id} has no points: nothing to export")
    source = _own_dynamics(run_id, cal)
    if dynamics_run is not None:
        source = _dynamics_source(store, dynamics_run, cal)
    return write_vehicle_artefacts(cal, out_dir, formats, res.created_utc, source, options)


def export_check(store: Store, run_ref: str, formats: Sequence[str], *,
                 dynamics_run: str | None = None, options: ExportOptions | None = None
                 ) -> Callable[[CalibrationResult], None]:
    """What calibrate --export runs on the analysis before it writes anything: the dynamics
    run's checks and every format's prerequisites (UsageError naming each missing one)."""
    from rigtool.artefacts.formats import check_formats, export_input

    run_id = _exportable(store, run_ref)

    def check(cal: CalibrationResult) -> None:
        source = _own_dynamics(run_id, cal)
        if dynamics_run is not None:
            source = _dynamics_source(store, dynamics_run, cal)
        check_formats(formats, export_input(cal, "", source, options))

    return check


def _exportable(store: Store, run_ref: str) -> str:
    """The run id of `run_ref`, refused unless rigtool could have made it (it names files)."""
    run_id = store.resolve_run_id(run_ref)
    if not is_run_id(run_id):
        raise DataError(f"run database {store.path}: run {run_label(run_id)}, runs.id: not a "
                        "run id rigtool makes, and vehicle artefacts take their folder and names "
                        "from it: not exported")
    return run_id


def _own_dynamics(run_id: str, cal: CalibrationResult) -> DynamicsSource | None:
    from rigtool.artefacts.vehicle import DynamicsSource

    return None if cal.dynamics is None else DynamicsSource(run_id, cal.dynamics)


def _dynamics_source(store: Store, run_ref: str, cal: CalibrationResult) -> DynamicsSource:
    """The identified dynamics of a calibrated step-response run of the same thruster."""
    from rigtool.artefacts.vehicle import DynamicsSource

    run_id = store.resolve_run_id(run_ref)
    other = stored_results(store, run_id).calibration
    if other is None or other.dynamics is None:
        raise UsageError(f"run {run_id} has no identified dynamics: --dynamics takes a "
                         "calibrated step-response run (a protocol with command.steps)")
    if not getattr(other.dynamics, "identified", True):
        raise UsageError(f"run {run_id}: no dynamics were identified "
                         f"({other.dynamics.reason or 'see its report'}), so no export carries "
                         "time constants from it")
    if cal.thruster_id and other.thruster_id and cal.thruster_id != other.thruster_id:
        raise UsageError(f"run {run_id} is thruster {other.thruster_id!r}, run {cal.run_id} is "
                         f"thruster {cal.thruster_id!r}: their artefacts would mix two thrusters")
    if other.command_unit != cal.command_unit:
        raise UsageError(f"run {run_id} commands in {other.command_unit}, run {cal.run_id} in "
                         f"{cal.command_unit}: not the same driver")
    return DynamicsSource(run_id, other.dynamics)
