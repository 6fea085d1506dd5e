"""Quasi-cavitation artefacts (cavitation.json, qctm_gp.json + kinv, GP training CSV/Parquet)
and the report's "Quasi-cavitation" HTML section (docs/cavitation.md)."""

from __future__ import annotations

import dataclasses
import html
import json
import math
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import rigtool
from rigtool.analysis.cavitation import CavitationResult
from rigtool.analysis.qctm_export import model_document
from rigtool.models import MODEL_FILE, VARIANCE_FILE
from rigtool.outpaths import run_folder
from rigtool.store import utc_now

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


def _clean(obj: object) -> object:
    """JSON-safe copy: numpy to Python, NaN/inf to None, dataclasses to dicts."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _clean(dataclasses.asdict(obj))
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.generic):
        return _clean(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


IN_SAMPLE_NOTE = ("partly in-sample: each fold is refitted on the other fold's points, but the "
                  "hyperparameters, noise model and mean term come from the fit on all points; "
                  "held-out runs (benchmarks/bench_cavitation.py) give the honest figures")


def summary_document(res: CavitationResult, created: str) -> dict:
    """cavitation.json: parameters, BETM, deep errors, events, training provenance, evaluation."""
    ev = res.evaluation
    return _clean({
        "format": "rigtool-cavitation", "format_version": 1,
        "tool_version": rigtool.__version__, "created_utc": created,
        "run_id": res.run_id, "base_run_id": res.base_run_id,
        "params": res.params.to_dict(), "betm": res.betm.to_dict(),
        "deep_errors_blocks": res.deep_errors, "deep_errors_samples": res.deep_errors_samples,
        "events": res.events, "event_table": res.event_table,
        "training": {"n_selected": len(res.training), "n_blocks": res.n_blocks_total,
                     **res.training.provenance},
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
        "warnings": res.warnings,
    })


def _atomic(path: Path, write: object) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)  # type: ignore[operator]
    os.replace(tmp, path)


def training_table(res: CavitationResult) -> dict[str, np.ndarray]:
    """Column arrays of the selected GP training set."""
    t = res.training
    return {"speed_rpm": t.x[:, 0], "current_a": t.x[:, 1], "depth_m": t.x[:, 2],
            "shortfall_thrust_n": t.xf[:, 1], "y_n": t.y,
            "weight": t.w, "thrust_n": t.thrust_n, "betm_n": t.betm_n, "t_s": t.t_s,
            "command": t.command, "ventilated": t.ventilated.astype(int),
            "run_id": t.run_id.astype(str)}


def _header(res: CavitationResult, created: str) -> list[str]:
    prov = res.training.provenance
    lines = [f"rigtool {rigtool.__version__} QCTM-GP training set of run {res.run_id}, "
             f"created {created}",
             f"runs: {', '.join(prov.get('run_ids', []))}; BETM base run: {res.base_run_id}",
             f"decimation: {prov.get('block_s')} s block means, {len(res.training)} of "
             f"{res.n_blocks_total} blocks selected, stratified over (depth, command, ventilated)",
             f"weights: Huber k = 1.345 on residuals against a 5-block running median, robust "
             f"scale {prov.get('huber_scale_n', float('nan')):.4g} N",
             "columns:"]
    lines += [f"  {name} [{unit}]: {doc}" for name, unit, doc in TRAIN_COLUMNS]
    return lines


def write_cavitation_artefacts(res: CavitationResult, out_dir: str | Path,
                               created_utc: str | None = None) -> list[Path]:
    """Write the quasi-cavitation files into `out_dir`/<run-id>/ and return their paths."""
    created = created_utc or utc_now()
    target = run_folder(out_dir, res.run_id)
    target.mkdir(parents=True, exist_ok=True)
    paths = []
    summary = json.dumps(summary_document(res, created), indent=2, sort_keys=True,
                         allow_nan=False) + "\n"
    model = json.dumps(_clean(model_document(res.betm, res.gp, {
        "run_ids": res.training.provenance.get("run_ids", []), "base_run_id": res.base_run_id,
        "created_utc": created, "tool_version": rigtool.__version__},
        window=res.params.window_blocks, block_s=res.params.train_block_s,
        lead=res.params.lead_blocks, bounds=res.bounds, domain=res.domain)),
        allow_nan=False) + "\n"
    for name, text in ((SUMMARY_FILE, summary), (MODEL_FILE, model)):
        path = target / name
        _atomic(path, lambda p, text=text: p.write_text(text, encoding="utf-8", newline="\n"))
        paths.append(path)
    if res.gp.k_inv is not None:
        path = target / VARIANCE_FILE
        with open(path.with_name(path.name + ".tmp"), "wb") as fh:
            np.save(fh, res.gp.k_inv)
        os.replace(path.with_name(path.name + ".tmp"), path)
        paths.append(path)
    cols = training_table(res)
    head = _header(res, created)
    lines = ["# " + h for h in head] + [",".join(cols)]
    arrays = list(cols.values())
    for i in range(len(res.training)):
        lines.append(",".join(a[i] if isinstance(a[i], str) else f"{a[i]:.9g}" for a in arrays))
    path = target / TRAIN_CSV
    _atomic(path, lambda p: p.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="\n"))
    paths.append(path)
    table = pa.table(cols).replace_schema_metadata({"rigtool": "\n".join(head)})
    path = target / TRAIN_PARQUET
    _atomic(path, lambda p: pq.write_table(table, str(p)))
    paths.append(path)
    return paths


def _time_series_figure(res: CavitationResult) -> object:
    """Measured, BETM and QCTM-GP thrust over the run, detected events shaded."""
    from rigtool.report import figures as fg

    s = res.series
    fig = fg._figure((8.0, 3.2))
    ax = fig.add_subplot(111)
    ax.fill_between(s["t_s"], s["lo95_n"], s["hi95_n"], color="C2", alpha=0.25, lw=0,
                    label="95 % interval")
    ax.plot(s["t_s"], s["thrust_n"], ".", ms=1.5, color="C0", label="measured")
    ax.plot(s["t_s"], s["betm_n"], ".", ms=1.0, color="C1", label="BETM")
    ax.plot(s["t_s"], s["pred_n"], ".", ms=1.0, color="C2", label="QCTM-GP (held-out fold)")
    for i, e in enumerate(res.events):
        ax.axvspan(e["t_start_s"], e["t_end_s"], color="C3", alpha=0.15, lw=0,
                   label="detected event" if i == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("thrust (N)")
    ax.legend(loc="upper left", fontsize=7, ncol=5)
    return fig


def _event_rate_figure(res: CavitationResult) -> object:
    """Events per minute and mean event duration vs depth, one line per command."""
    from rigtool.report import figures as fg

    fig = fg._figure((8.0, 2.6))
    rate, dur = fig.add_subplot(121), fig.add_subplot(122)
    rows = res.event_table
    for k, cmd in enumerate(sorted({r["command"] for r in rows})):
        mine = sorted((r for r in rows if r["command"] == cmd), key=lambda r: r["depth_m"])
        depth = [100 * r["depth_m"] for r in mine]
        rate.plot(depth, [r["rate_per_min"] for r in mine], "o-", color=f"C{k}", label=f"{cmd:g}")
        dur.plot(depth, [r["mean_duration_s"] for r in mine], "o-", color=f"C{k}")
    rate.set_xlabel("depth (cm)")
    rate.set_ylabel("events per minute")
    dur.set_xlabel("depth (cm)")
    dur.set_ylabel("mean duration (s)")
    rate.legend(title="command", fontsize=7, title_fontsize=7)
    return fig


def _table(head: list[str], rows: list[list[str]], cls: str) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>'


def _f(v: float, d: int = 3) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{d}g}"


def cavitation_section_html(res: CavitationResult, image_format: str = "svg") -> str:
    """HTML of the report's "Quasi-cavitation" section (tables + one embedded figure)."""
    from rigtool.report import figures as fg

    ev = res.evaluation
    parts = ['<section id="cavitation" class="keep"><h2>Quasi-cavitation</h2>',
             f"<p>BETM coefficients from base run <code>{html.escape(res.base_run_id)}</code>; "
             f"{len(res.events)} ventilation event(s) detected; GP trained on "
             f"{len(res.training)} of {res.n_blocks_total} blocks of {res.params.train_block_s:g} s."
             "</p>"]
    parts.append("<h3>Estimators on deep points (held-out points of the base run)</h3>")
    rows = [[e.name, base, _f(e.max_abs_n), _f(e.p95_abs_n), _f(e.rms_n), f"{e.within_1n:.1%}"]
            for base, errors in (("samples", res.deep_errors_samples),
                                 (f"{res.params.train_block_s:g} s blocks", res.deep_errors))
            for e in errors]
    parts.append(_table(["estimator", "time base", "max |e| N", "p95 |e| N", "rms N",
                         "within 1 N"], rows, "kv cav-deep"))
    parts.append("<h3>Events by depth and command</h3>")
    rows = [[_f(r["depth_m"]), _f(r["command"]), str(r["n_events"]), _f(r["rate_per_min"]),
             _f(r["mean_duration_s"]), f"{r['ventilated_frac']:.0%}"] for r in res.event_table]
    parts.append(_table(["depth m", "command", "events", "per minute", "mean duration s",
                         "time ventilated"], rows, "kv cav-events"))
    parts.append(f"<h3>QCTM-GP errors ({html.escape(ev.source)}; events from "
                 f"{html.escape(ev.truth_source)})</h3>")
    rows = [[c.name, str(c.n), _f(c.p95_abs_n), _f(c.max_abs_n), _f(c.rms_n),
             _f(100 * c.coverage95, 3) + " %", c.max_at] for c in ev.classes]
    parts.append(_table(["class", "blocks", "p95 |e| N", "max |e| N", "rms N", "95 % coverage",
                         "max at"], rows, "kv cav-eval"))
    parts.append(f'<p class="note">This check is {html.escape(IN_SAMPLE_NOTE)}.</p>')
    if ev.matching is not None:
        m = ev.matching
        parts.append(f"<p>Event detection vs ground truth: {m.n_true_found}/{m.n_true} found, "
                     f"{m.n_false}/{m.n_detected} false; {m.n_true_short} true event(s) shorter "
                     f"than {res.params.events.min_duration_s:g} s reported apart "
                     f"({m.n_true_short_found} found).</p>")
    with fg.style():
        rate_uri = fg.encode(_event_rate_figure(res), image_format)  # type: ignore[arg-type]
        uri = fg.encode(_time_series_figure(res), image_format)  # type: ignore[arg-type]
    parts.append(f'<figure id="cavitation-rates" data-figure="cavitation-rates"><img '
                 f'src="{rate_uri}" alt="event rate and duration vs depth"><figcaption><b>Events '
                 "vs depth and speed.</b> Detected events per minute of acquisition and their "
                 "mean duration, one line per command.</figcaption></figure>")
    parts.append(f'<figure id="cavitation-series" data-figure="cavitation"><img src="{uri}" '
                 'alt="thrust with ventilation events"><figcaption><b>Thrust during the run.</b> '
                 "Measured, BETM and QCTM-GP (each fold predicted by the model trained on the "
                 "other) with its 95 % interval; detected events shaded.</figcaption></figure>")
    parts.append("</section>")
    return "\n".join(parts)
