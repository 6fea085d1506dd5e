"""The report's "Quasi-cavitation" section: its figures and the view its template renders."""

from __future__ import annotations

import math

from matplotlib.figure import Figure

from rigtool.analysis.cavitation import IN_SAMPLE_NOTE
from rigtool.analysis.results import CavitationResult
from rigtool.artefacts.cavitation import training_runs
from rigtool.report import figures as fg


def time_series_figure(res: CavitationResult) -> Figure:
    """Measured, BETM and QCTM-GP thrust over the run, detected events shaded; nothing is
    drawn across the rests and depth moves between points."""
    s = res.series
    keys = ("thrust_n", "betm_n", "pred_n", "lo95_n", "hi95_n")
    t, *cols = fg.break_at_gaps(s["t_s"], *(s[k] for k in keys), segment=s.get("point"))
    y = dict(zip(keys, cols, strict=True))
    fig = fg.figure((8.0, 3.2))
    ax = fig.add_subplot(111)
    ax.fill_between(t, y["lo95_n"], y["hi95_n"], color="C2", alpha=0.25, lw=0,
                    label="95 % interval")
    ax.plot(t, y["thrust_n"], ".", ms=1.5, color="C0", label="measured")
    ax.plot(t, y["betm_n"], ".", ms=1.0, color="C1", label="BETM")
    ax.plot(t, y["pred_n"], ".", ms=1.0, color="C2", label="QCTM-GP (held-out fold)")
    for i, e in enumerate(res.events):
        ax.axvspan(e["t_start_s"], e["t_end_s"], color="C3", alpha=0.15, lw=0,
                   label="detected event" if i == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("thrust (N)")
    ax.legend(loc="upper left", fontsize=7, ncol=5)
    return fig


def event_rate_figure(res: CavitationResult) -> Figure:
    """Events per minute and mean event duration vs depth, one line per command."""
    fig = fg.figure((8.0, 2.6))
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


def _f(v: float | None, d: int = 3) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{d}g}"


def cavitation_view(res: CavitationResult, image_format: str = "svg") -> dict:
    """Everything templates/cavitation.html shows, as text cells and encoded figures."""
    ev = res.evaluation
    with fg.style():
        rate_uri = fg.encode(event_rate_figure(res), image_format)
        series_uri = fg.encode(time_series_figure(res), image_format)
    return {
        "base_run_id": res.base_run_id, "n_events": len(res.events),
        "n_training": len(res.training), "n_blocks": res.n_blocks_total,
        "training_runs": training_runs(res)["training_runs"],
        "intervals_validated": training_runs(res)["intervals_validated"],
        "block_s": f"{res.params.train_block_s:g}",
        "deep_rows": [[e.name, base, _f(e.max_abs_n), _f(e.p95_abs_n), _f(e.rms_n),
                       f"{e.within_1n:.1%}"]
                      for base, errors in (("samples", res.deep_errors_samples),
                                           (f"{res.params.train_block_s:g} s blocks",
                                            res.deep_errors))
                      for e in errors],
        "event_rows": [[_f(r["depth_m"]), _f(r["command"]), str(r["n_events"]),
                        _f(r["rate_per_min"]), _f(r["mean_duration_s"]),
                        f"{r['ventilated_frac']:.0%}"] for r in res.event_table],
        "eval_source": ev.source, "truth_source": ev.truth_source,
        "eval_rows": [[c.name, str(c.n), _f(c.p95_abs_n), _f(c.max_abs_n), _f(c.rms_n),
                       _f(100 * c.coverage95, 3) + " %", c.max_at] for c in ev.classes],
        "in_sample_note": IN_SAMPLE_NOTE,
        "matching": ev.matching,
        "min_duration_s": f"{res.params.events.min_duration_s:g}",
        "rate_uri": rate_uri, "series_uri": series_uri,
        **check_view(res.interval_check, res.floor),
    }


def _floor_cell(f: dict) -> str:
    """The floor with its range over the training's groups (results from before it: alone)."""
    low, high = f.get("floor_range_n") or (math.nan, math.nan)
    if not (isinstance(low, float) and math.isfinite(low) and math.isfinite(high)):
        return _f(f["floor_p95_n"])
    return f"{_f(f['floor_p95_n'])} ({_f(low)}-{_f(high)})"


def check_view(check: dict | None, floor: dict | None) -> dict:
    """The held-out interval check and the floor as text cells (empty for older results)."""
    if not check or not floor:
        return {"check": None}
    rows = []
    for name, c in check["classes"].items():
        f = floor["classes"][name]
        rows.append([name, str(c["n_blocks"]), _pct(c["coverage_before"]), _pct(c["coverage"]),
                     _f(check["sd_factor"][name]), _f(c["p95_abs_n"]), _floor_cell(f),
                     _f(f["target_p95_n"]), f["verdict"]])
    missed = check.get("missed_lower") or {}
    widths = [f"{_f(w)} N at {rpm:.0f} r/min" for rpm, w in
              zip(missed.get("speed_rpm", ()), missed.get("lower_n", ()), strict=False) if w > 0]
    return {"check": {"method": check["method"], "kind": check["kind"],
                      "n_events": check["n_events"], "rows": rows, "basis": floor["basis"],
                      "missed": "; ".join(widths)}}


def _pct(v: float | None) -> str:
    return "" if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"
