// rigtool watch: polls /data once a second and draws it with uPlot.
// Every stored text is put in the page with textContent, never parsed as HTML.
"use strict";

const POLL_MS = 1000;
const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
                "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#999999"];
const state = { pointsPlot: null, pointsKey: "", tracePlot: null, traceKey: "",
                traceUpdates: 0, traceStep: null, timer: null, ended: false };

function $(id) { return document.getElementById(id); }

function text(id, value) { $(id).textContent = value == null ? "" : String(value); }

function fmt(x, digits) {
  return x == null ? "–" : Number(x).toPrecision(digits || 4).replace(/\.?0+(e|$)/, "$1");
}

function duration(s) {
  if (s == null) return "–";
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = Math.round(s % 60);
  return h ? `${h} h ${String(m).padStart(2, "0")} min` : `${m} min ${String(sec).padStart(2, "0")} s`;
}

function width(el) { return Math.max(300, el.clientWidth - 10); }

function cell(row, value, cls) {
  const td = document.createElement("td");
  td.textContent = value == null ? "" : String(value);
  if (cls) td.className = cls;
  row.appendChild(td);
  return td;
}

function fill(tbody, rows) {
  tbody.replaceChildren(...rows);
}

function utc(iso) {
  // "2026-12-02T02:57:31.123+00:00" -> "2026-12-02 02:57:31"
  return iso ? String(iso).replace("T", " ").slice(0, 19) : "";
}

function showRun(d) {
  const run = d.run;
  text("run-name", run.name);
  text("run-id", `run ${run.id}`);
  text("run-started", run.created_utc ? `· started ${utc(run.created_utc)}` +
       (run.finished_utc ? `, ended ${utc(run.finished_utc)}` : "") : "");
  text("run-rig", run.rig ? `· rig ${run.rig}` : "");
  const ended = $("ended");
  if (run.ended) {
    ended.hidden = false;
    ended.className = `ended ${run.status}`;
    ended.textContent = `run ended: ${run.status}` + (run.stop_reason ? ` (${run.stop_reason})` : "");
  } else {
    ended.hidden = true;
  }
  document.title = `${run.ended ? run.status : "running"} · ${run.name} · ${d.database} · rigtool watch`;
}

function showProgress(p, unit) {
  $("progress-bar").max = Math.max(1, p.planned);
  $("progress-bar").value = p.done;
  text("progress-text", `${p.done} / ${p.planned} points`);
  text("eta", p.eta_s == null ? "–" : duration(p.eta_s) + (p.eta_basis ? ` (from the ${p.eta_basis})` : ""));
  const c = p.current;
  text("current", c ? `#${c.idx}: ${fmt(c.command)} ${unit}, depth ${fmt(c.depth_m)} m` +
       (c.voltage_v == null ? "" : `, ${fmt(c.voltage_v)} V`) + `, repeat ${c.repeat}, ${c.direction}` : "–");
  text("state", p.state);
  text("state-note", p.state === "rest" || p.state === "settling" || p.state === "acquiring" ? `(${p.state_note})` : "");
}

function noLine() { return null; }

function showPoints(pts, unit) {
  const el = $("points-chart");
  const n = pts.command.length;
  const order = [...Array(n).keys()].sort((a, b) => (pts.command[a] ?? 0) - (pts.command[b] ?? 0));
  const xs = order.map(i => pts.command[i]);
  const data = [xs];
  pts.groups.forEach((_, g) => data.push(order.map(i => (pts.group[i] === g ? pts.thrust[i] : null))));
  data.push(order.map(i => (pts.current_pass[i] ? pts.thrust[i] : null)));
  const key = pts.groups.join("|") + unit;
  if (!state.pointsPlot || state.pointsKey !== key) {
    if (state.pointsPlot) state.pointsPlot.destroy();
    const series = [{ label: `command (${unit})` }];
    pts.groups.forEach((g, i) => series.push({ label: g, stroke: COLORS[i % COLORS.length],
      paths: noLine, points: { show: true, size: 5, fill: COLORS[i % COLORS.length] } }));
    series.push({ label: "current pass", stroke: "#000", paths: noLine,
      points: { show: true, size: 11, width: 2, fill: "rgba(0,0,0,0)" } });
    state.pointsPlot = new uPlot({ width: width(el), height: 320, series,
      scales: { x: { time: false } },
      axes: [{ label: `command (${unit})` }, { label: "mean thrust (N)" }] }, data, el);
    state.pointsKey = key;
  } else {
    state.pointsPlot.setData(data);
  }
  const plotted = pts.thrust.filter(v => v != null).length;
  $("npoints").dataset.count = String(plotted);
  text("npoints", `${plotted} points plotted (${pts.n_stored} stored` +
       (pts.truncated ? `, newest ${pts.n_sent} sent` : "") + ")");
}

const TRACE_HEIGHT = 320;  // the three quantities share it, one chart each, one time axis

function traceChart(el, c, last, height, data) {
  // One quantity over run time, on its own axis; the charts share the cursor.
  const div = document.createElement("div");
  div.id = `trace-${c[0]}`;
  el.appendChild(div);
  return new uPlot({ width: width(el), height, cursor: { sync: { key: "trace" } },
    series: [{ label: "t (s)" }, { label: c[1], stroke: c[3], width: 1 }],
    scales: { x: { time: false } }, legend: { show: false },
    axes: [{ label: last ? "run time (s)" : null, size: last ? 50 : 20, values: last ? undefined : (u, splits) => splits.map(() => "") },
           { label: c[1], stroke: c[3], size: 60 }] }, data, div);
}

function showTrace(tr) {
  const el = $("trace-chart");
  const info = $("trace-info");
  if (!tr) { info.textContent = "no point stored yet"; return; }
  const cols = [["thrust_n", "thrust (N)", "N", "#1f77b4"], ["speed_rpm", "speed (r/min)", "rpm", "#2ca02c"],
                ["current_a", "current (A)", "A", "#d62728"]].filter(c => tr[c[0]] != null);
  const key = cols.map(c => c[0]).join("|");
  if (!state.tracePlot || state.traceKey !== key) {
    if (state.tracePlot) state.tracePlot.forEach(p => p.destroy());
    el.replaceChildren();
    const each = Math.round(TRACE_HEIGHT / cols.length);
    state.tracePlot = cols.map((c, i) => traceChart(el, c, i === cols.length - 1,
      each + (i === cols.length - 1 ? 30 : 0), [tr.t_s, tr[c[0]]]));
    state.traceKey = key;
  } else {
    cols.forEach((c, i) => state.tracePlot[i].setData([tr.t_s, tr[c[0]]]));
  }
  if (state.traceStep !== tr.step_idx) {
    state.traceStep = tr.step_idx;
    state.traceUpdates += 1;
  }
  info.dataset.step = String(tr.step_idx);
  info.dataset.updates = String(state.traceUpdates);
  info.textContent = `point #${tr.step_idx}: command ${fmt(tr.command)}, depth ${fmt(tr.depth_m)} m, ` +
    `${tr.n_samples} samples (${tr.n_sent} drawn` + (tr.n_sent < tr.n_samples ? ", min/max per bucket" : "") + ")";
}

function showFit(fit) {
  text("fit-label", fit.label + (fit.reason ? ` — ${fit.reason}` : ""));
  const rows = [];
  for (const [key, name] of [["fwd", "C_p forward"], ["rev", "C_p reverse"]]) {
    const v = fit[key];
    if (v === undefined || v === null) continue;
    const tr = document.createElement("tr");
    cell(tr, name);
    cell(tr, v.C_p == null ? `not enough points yet (${v.n})` : `${fmt(v.C_p, 4)} ${fit.unit}`);
    cell(tr, v.C_p == null ? "" : `n = ${v.n}` + (v.r2 == null ? "" : `, R² = ${fmt(v.r2, 3)}`));
    rows.push(tr);
  }
  fill($("fit").tBodies[0], rows);
}

function showCounters(c) {
  const rows = [];
  for (const [role, list] of Object.entries(c.roles)) {
    const tr = document.createElement("tr");
    cell(tr, role);
    const td = cell(tr, "");
    list.forEach((item, i) => {
      const span = document.createElement("span");
      span.textContent = `${i ? ", " : ""}${item.name} ${item.n}`;
      if (item.problem) span.className = "problem";
      td.appendChild(span);
    });
    rows.push(tr);
  }
  fill($("counters").tBodies[0], rows);
  text("counters-note", rows.length ? `points with lost, garbage or failed frames: ${c.problem_points} of ${c.points}`
       : "no transport counters stored (simulated devices)");
}

function showEvents(ev) {
  const rows = ev.items.slice().reverse().map(e => {
    const tr = document.createElement("tr");
    if (e.trip) tr.className = "trip";
    cell(tr, e.t_s == null ? "" : e.t_s.toFixed(2));
    cell(tr, e.step_idx);
    cell(tr, e.kind);
    cell(tr, e.detail, "detail");
    return tr;
  });
  fill($("events").tBodies[0], rows);
  text("events-count", `${ev.n_total} stored` + (ev.n_total > ev.items.length ? `, newest ${ev.items.length} shown` : "") +
       (ev.trips ? `, ${ev.trips} trip(s)` : ""));
}

function render(d) {
  if (!d.run) { text("conn", d.waiting || "waiting for a run"); return; }
  const unit = d.run.command_unit || "";
  showRun(d);
  showProgress(d.progress, unit);
  showPoints(d.points, unit);
  showTrace(d.trace);
  showFit(d.fit);
  showCounters(d.counters);
  showEvents(d.events);
  state.ended = d.run.ended;
}

async function poll() {
  const conn = $("conn");
  try {
    const resp = await fetch("/data", { cache: "no-store" });
    const d = await resp.json();
    if (!resp.ok) throw new Error(d.error || resp.statusText);
    render(d);
    conn.className = "conn";
    text("db-name", d.database);
    conn.textContent = `updated ${utc(new Date().toISOString())} UTC` + (d.run && d.run.ended ? " (run ended)" : "");
  } catch (err) {
    conn.className = "conn lost";
    conn.textContent = `no data: ${err.message}` + (state.ended ? "" : " (the watcher or the sweep may have stopped)");
  }
  state.timer = setTimeout(poll, state.ended ? 5 * POLL_MS : POLL_MS);
}

window.addEventListener("resize", () => {
  if (state.pointsPlot) state.pointsPlot.setSize({ width: width($("points-chart")), height: 320 });
  for (const plot of state.tracePlot || []) {
    plot.setSize({ width: width($("trace-chart")), height: plot.height });
  }
});

poll();
