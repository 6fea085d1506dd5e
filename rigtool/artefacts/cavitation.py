"""Quasi-cavitation artefacts: cavitation.json, qctm_gp.json (+ kinv when the GP keeps a
signal), GP training CSV/Parquet (docs/cavitation.md)."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from rigtool.analysis.cavitation import IN_SAMPLE_NOTE
from rigtool.analysis.qctm_export import model_document
from rigtool.analysis.results import CavitationResult
from rigtool.artefacts.write import (
    atomic_write,
    columns_path,
    columns_text,
    json_clean,
    json_text,
)
from rigtool.ids import utc_now
from rigtool.models import MODEL_FILE, VARIANCE_FILE
from rigtool.models.qctm import VALIDATED_RUNS
from rigtool.outpaths import run_folder
from rigtool.version import __version__

SUMMARY_FILE = "cavitation.json"
TRAIN_CSV = "gp_training.csv"
TRAIN_PARQUET = "gp_training.parquet"
TRAIN_COLUMNS = (
    ("speed_rpm", "r/min", "GP input n_p: block-mean propeller speed"),
    ("current_a", "A", "block-mean driver current (enters the GP through shortfall_thrust_n)"),
    ("depth_m", "m", "GP input h: depth of the propeller centre"),
    ("shortfall_thrust_n", "N", "GP input z: f_n(n) * (1 - |I| / (C_n |n|^3 + I_0)), mean over "
     "the shortfall window (centred, or past blocks only with --causal)"),
    ("y_n", "N", "GP target: measured thrust minus BETM estimate"),
    ("weight", "1", "Huber weight (outliers < 1) ; noise of row i is var(x_i) / weight"),
    ("thrust_n", "N", "block-mean measured thrust"),
    ("betm_n", "N", "BETM fused estimate"),
    ("t_s", "s", "block centre on the run clock"),
    ("command", "command unit", "command in force"),
    ("ventilated", "0/1", "1 if the block lies inside a detected ventilation event"),
    ("run_id", "", "run the block comes from"),
)


def training_runs(res: CavitationResult) -> dict:
    """How many runs trained the model, and whether its 95 % intervals were checked run by
    run (two runs or more); one run's block folds cannot validate them."""
    runs = len(set(res.training.provenance.get("run_ids", []))) or 1
    return {"training_runs": runs, "intervals_validated": runs >= VALIDATED_RUNS}


def summary_document(res: CavitationResult, created: str) -> dict:
    """cavitation.json: parameters, BETM, deep errors, events, training provenance, evaluation."""
    ev = res.evaluation
    return json_clean({
        "format": "rigtool-cavitation", "format_version": 1,
        "tool_version": __version__, "created_utc": created,
        "run_id": res.run_id, "base_run_id": res.base_run_id,
        "params": res.params.to_dict(), "betm": res.betm.to_dict(),
        "deep_errors_blocks": res.deep_errors, "deep_errors_samples": res.deep_errors_samples,
        "events": res.events, "event_table": res.event_table,
        "training": {"n_selected": len(res.training), "n_blocks": res.n_blocks_total,
                     **res.training.provenance, **training_runs(res)},
        "gp": {"length_scales": res.gp.hyper.length_scales, "signal_var": res.gp.hyper.signal_var,
               "signal_scale_cv": res.gp.signal_scale,
               "noise_var_n2": res.gp.noise_var_n2,
               "noise_model": None if res.gp.noise is None else "log-variance GP",
               "shortfall_window_blocks": res.params.window_blocks,
               "shortfall_lead_blocks": res.params.lead_blocks},
        "evaluation": {"source": ev.source, "truth": ev.truth_source,
                       "in_sample": IN_SAMPLE_NOTE,
                       "coverage95": ev.coverage95, "classes": ev.classes,
                       "matching": None if ev.matching is None else {
                           **dataclasses.asdict(ev.matching), "recall": ev.matching.recall,
                           "false_rate": ev.matching.false_rate}},
        "interval_check": res.interval_check, "floor": res.floor,
        "warnings": res.warnings,
    })



def training_table(res: CavitationResult) -> dict[str, np.ndarray]:
    """Column arrays of the selected GP training set."""
    t = res.training
    return {"speed_rpm": t.x[:, 0], "current_a": t.x[:, 1], "depth_m": t.x[:, 2],
            "shortfall_thrust_n": t.xf[:, 1], "y_n": t.y,
            "weight": t.w, "thrust_n": t.thrust_n, "betm_n": t.betm_n, "t_s": t.t_s,
            "command": t.command, "ventilated": t.ventilated.astype(int),
            "run_id": t.run_id.astype(str)}


def _notes(res: CavitationResult, created: str) -> list[str]:
    """What the training set is, for its sidecar and its Parquet metadata."""
    prov = res.training.provenance
    lines = [f"rigtool {__version__} QCTM-GP training set of run {res.run_id}, "
             f"created {created}",
             f"runs: {', '.join(prov.get('run_ids', []))}; BETM base run: {res.base_run_id}",
             f"decimation: {prov.get('block_s')} s block means, {len(res.training)} of "
             f"{res.n_blocks_total} blocks selected, stratified over (depth, command, ventilated)",
             f"weights: Huber k = 1.345 on residuals against a 5-block running median, robust "
             f"scale {prov.get('huber_scale_n', float('nan')):.4g} N"]
    return lines


def _header(res: CavitationResult, created: str) -> list[str]:
    """The notes and the columns' documentation, for the Parquet file's metadata."""
    return [*_notes(res, created), "columns:",
            *(f"  {name} [{unit}]: {doc}" for name, unit, doc in TRAIN_COLUMNS)]


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def write_cavitation_artefacts(res: CavitationResult, out_dir: str | Path,
                               created_utc: str | None = None) -> list[Path]:
    """Write the quasi-cavitation files into `out_dir`/<run-id>/ and return their paths."""
    created = created_utc or utc_now()
    target = run_folder(out_dir, res.run_id)
    target.mkdir(parents=True, exist_ok=True)
    model = model_document(res.betm, res.gp, {
        "run_ids": res.training.provenance.get("run_ids", []), **training_runs(res),
        "base_run_id": res.base_run_id,
        "created_utc": created, "tool_version": __version__,
        **json_clean({"interval_check": res.interval_check, "floor": res.floor})},
        window=res.params.window_blocks, block_s=res.params.train_block_s,
        lead=res.params.lead_blocks, bounds=res.bounds, domain=res.domain)
    paths = [atomic_write(target / SUMMARY_FILE, json_text(summary_document(res, created))),
             # the model keeps full precision: its weights are summed over every training row
             atomic_write(target / MODEL_FILE, json_text(model, indent=None, digits=None))]
    if model["gp"]["signal"] and res.gp.k_inv is not None:
        paths.append(atomic_write(target / VARIANCE_FILE, _npy_bytes(res.gp.k_inv)))
    else:  # no GP signal: nothing uses the matrix, and a reader refuses an earlier fit's
        (target / VARIANCE_FILE).unlink(missing_ok=True)
    cols = training_table(res)
    lines = [",".join(cols)]
    arrays = list(cols.values())
    for i in range(len(res.training)):
        lines.append(",".join(a[i] if isinstance(a[i], str) else f"{a[i]:.9g}" for a in arrays))
    paths.append(atomic_write(target / TRAIN_CSV, "\n".join(lines) + "\n"))
    paths.append(atomic_write(columns_path(target / TRAIN_CSV),
                              columns_text(_notes(res, created), TRAIN_COLUMNS)))
    table = pa.table(cols).replace_schema_metadata({"rigtool": "\n".join(_header(res, created))})
    paths.append(atomic_write(target / TRAIN_PARQUET, lambda p: pq.write_table(table, str(p))))
    return paths
