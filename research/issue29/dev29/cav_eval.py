"""att29d (attack on issue 29 part 3, one-run trainings): held-out coverage of the exported
quasi-cavitation 95 % intervals, measured through the CLI and the exported model file.
Copied from att29d's attack/one29/cav_eval.py for bias29: dev seeds 110000-113999, fewer
trainings and held-out runs, and the mean error (model minus measured) and the sides of the
misses per class.

    python cav_eval.py runs  WORK                 # record every run once (twin, CLI)
    python cav_eval.py train WORK LABEL CHECKOUT  # copy the db, calibrate each training there
    PYTHONPATH=CHECKOUT python cav_eval.py eval WORK LABEL   # score held-out runs per training

Truth: the twin's sim.ventilation intervals; the measured (tared) block thrust is the target.
Own blocking (0.2 s, within each point), own classes (event / outside; blocks within 0.5 s of a
true event start/end or of a point start are left out). `eval` also stores per-block hits
(class, run, event id) per training in LABEL-blocks/ for the bootstrap in noise.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

# base seed per twin: trainings' baselines S+100+k, training runs S+200+k, held-out S+500+k
SEEDS = {"stock": 110000, "weak": 111000, "v4": 112000, "x5": 113000}
N_SINGLE = {"stock": 4, "weak": 6, "v4": 6, "x5": 6}
FIRST_SINGLE = {"stock": 4, "weak": 6, "v4": 6, "x5": 6}  # the first round; later ones get other seeds
N_TWO = {"stock": 0, "weak": 1, "v4": 1, "x5": 1}
N_TEST = 4
VARIANTS = {
    "stock": {},
    "weak": {"cp_forward": 2.2e-5, "cp_reverse": 0.8 * 2.2e-5, "cn": 1.0e-9,
             "current_noise_a": 0.22, "cav_current_drop": 0.06},
    "v4": {"cp_forward": 1.8e-5, "cp_reverse": 0.6 * 1.8e-5, "cn": 1.5e-9,
           "current_noise_a": 0.25, "cav_current_drop": 0.05,
           "cav_mean_onset_s": [9.0, 16.0, 22.0, 60.0], "cav_mean_duration_s": [40.0, 9.0, 4.5, 1.8],
           "cav_drop_min": 0.4, "cav_drop_max": 0.9, "cav_noise_frac": 0.05},
    # att29d's own twin: C_p_rev/C_p 0.7, a lighter motor's current law, noisier speed and
    # current (0.20 A), frequent short exponential-length shallow events (drop 0.15-0.55),
    # slower ramps, a current drop of 7 % and more vibration noise.
    "x5": {"cp_forward": 2.05e-5, "cp_reverse": 0.7 * 2.05e-5, "cn": 1.1e-9,
           "speed_noise_rpm": 25.0, "current_noise_a": 0.20, "vibration_noise_frac": 0.015,
           "cav_current_drop": 0.07, "cav_mean_onset_s": [4.0, 7.0, 10.0, 25.0],
           "cav_mean_duration_s": [12.0, 3.0, 1.8, 0.9], "cav_duration_shape": 1.0,
           "cav_drop_min": 0.15, "cav_drop_max": 0.55, "cav_ramp_in_s": 0.35, "cav_ramp_out_s": 0.5},
}
EDGE_S = 0.5
BLOCK_S = 0.2


def protocol(work: Path, name: str, variant: str) -> Path:
    """Shipped protocol `name` with the variant's simulator overrides."""
    root = Path(__file__).resolve().parents[2]
    doc = yaml.safe_load((root / "protocols" / f"{name}.yaml").read_text())
    doc["name"] = f"{doc['name']}-{variant}"
    if VARIANTS[variant]:
        doc["simulator"]["overrides"] = VARIANTS[variant]
    path = work / f"{doc['name']}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def sweep(db: Path, proto: Path, seed: int) -> str:
    out = subprocess.run([sys.executable, "-m", "rigtool", "sweep", str(proto), "--sim", "--db",
                          str(db), "--seed", str(seed)], check=True, capture_output=True, text=True)
    return out.stdout.strip().splitlines()[-1].split()[1]


def cmd_runs(work: Path) -> None:
    """Record (resumable) every run: per twin held-out runs, then trainings."""
    db = work / "runs.sqlite"
    path = work / "runs.json"
    runs: dict = json.loads(path.read_text()) if path.exists() else {}
    for v, s in SEEDS.items():
        r = runs.setdefault(v, {"test": [], "trainings": {}})
        base_p, cav_p = protocol(work, "luo2020-baseline", v), protocol(work, "luo2020-cavitation", v)
        while len(r["test"]) < N_TEST:
            r["test"].append(sweep(db, cav_p, s + 500 + len(r["test"])))
            path.write_text(json.dumps(runs, indent=1))
        want = [(f"single-{k}", 1) for k in range(1, FIRST_SINGLE[v] + 1)] + \
               [(f"two-{k}", 2) for k in range(1, N_TWO[v] + 1)] + \
               [(f"single-{k}", 1) for k in range(FIRST_SINGLE[v] + 1, N_SINGLE[v] + 1)]
        for j0, (name, n) in enumerate(want):
            if name in r["trainings"]:
                continue
            j = j0 if j0 < FIRST_SINGLE[v] + N_TWO[v] else 20 + j0
            r["trainings"][name] = {"base": sweep(db, base_p, s + 100 + j),
                                    "train": [sweep(db, cav_p, s + 200 + 3 * j + q) for q in range(n)],
                                    "seeds": [s + 100 + j] + [s + 200 + 3 * j + q for q in range(n)]}
            path.write_text(json.dumps(runs, indent=1))
            print(v, name, r["trainings"][name], flush=True)


def trainings(runs: dict) -> list[tuple[str, str, str, list[str]]]:
    return [(v, name, t["base"], t["train"]) for v, r in runs.items() for name, t in r["trainings"].items()]


def cmd_train(work: Path, label: str, checkout: str) -> None:
    runs = json.loads((work / "runs.json").read_text())
    db = work / f"{label}.sqlite"
    if not db.exists():
        shutil.copy(work / "runs.sqlite", db)
    env = {**os.environ, "PYTHONPATH": checkout}
    only = os.environ.get("CAV_ONLY", "").split(",")
    logf = work / label / "train_log.json"
    (work / label).mkdir(parents=True, exist_ok=True)
    log = json.loads(logf.read_text()) if logf.exists() else {}
    for v, name, base, train in trainings(runs):
        key = f"{v}-{name}"
        out = work / label / key
        if out.exists() or (only != [""] and key not in only):
            continue
        cmd = [sys.executable, "-m", "rigtool", "calibrate", train[0], "--db", str(db), "--base", base,
               "--out", str(out), "--report"]
        for r in train[1:]:
            cmd += ["--train-with", r]
        t0 = time.time()
        p = subprocess.run(cmd, env=env, capture_output=True, text=True)
        log[key] = {"rc": p.returncode, "s": round(time.time() - t0, 1),
                    "stderr": p.stderr[-3000:], "stdout": p.stdout[-3000:]}
        logf.write_text(json.dumps(log, indent=1))
        print(key, "rc", p.returncode, f"{time.time() - t0:.0f} s", flush=True)


def blocks(run) -> dict[str, np.ndarray]:  # noqa: ANN001
    """0.2 s block means within each point (partial last block dropped)."""
    out: dict[str, list] = {k: [] for k in ("t", "t0", "f", "n", "i", "h", "seg", "tp")}
    for pb in run.source.blocks(("t_s", "thrust_n", "speed_rpm", "current_a")):
        _point_blocks(run, pb, out)
    return {k: np.concatenate(v) for k, v in out.items()}


def _point_blocks(run, pb, out: dict) -> None:  # noqa: ANN001
    s, off = pb.samples, pb.samples.offsets
    for q in range(len(off) - 1):
        p = pb.first_row + q
        a, b = int(off[q]), int(off[q + 1])
        if b - a < 10:
            continue
        t = s.t_s[a:b]
        size = max(1, int(round(BLOCK_S * (b - a - 1) / (t[-1] - t[0]))))
        nb = (b - a) // size
        sl = slice(a, a + nb * size)

        def m(x, sl=sl, size=size, nb=nb):  # noqa: ANN001, ANN202
            return x[sl].reshape(nb, size).mean(axis=1)
        out["t"].append(m(s.t_s))
        out["t0"].append(np.full(nb, t[0]))
        out["f"].append(m(s.thrust_n))
        out["n"].append(m(s.speed_rpm))
        out["i"].append(m(s.current_a))
        out["h"].append(np.full(nb, run.steps.depth_m[p]))
        out["seg"].append(np.full(nb, p))
        out["tp"].append(np.full(nb, t[-1]))


def classes(b: dict, truth: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Class per block and the index of its true event (-1 outside)."""
    cls = np.full(b["t"].size, "outside", dtype=object)
    eid = np.full(b["t"].size, -1)
    for k, (a, e) in enumerate(truth):
        m = (b["t"] >= a) & (b["t"] <= e)
        cls[m] = "event"
        eid[m] = k
    for a, e in truth:
        for x in (a, e):
            cls[np.abs(b["t"] - x) <= EDGE_S] = "skip"
    cls[b["t"] - b["t0"] <= EDGE_S] = "skip"
    return cls, eid


_BLOCKS: dict = {}


def score(model, store, run_ids: list[str]) -> tuple[dict, dict]:  # noqa: ANN001
    from rigtool.analysis.dataset import load_run
    from rigtool.models import OUT_OF_DOMAIN
    err, inside, width, cls_all, ood, runix, eids = [], [], [], [], [], [], []
    for k, rid in enumerate(run_ids):
        if rid not in _BLOCKS:
            run = load_run(store, rid)
            b = blocks(run)
            truth = [(float(e["detail"]["t_start_s"]), float(e["detail"]["t_end_s"]))
                     for e in store.events(rid, "sim.ventilation")]
            _BLOCKS[rid] = (b, *classes(b, truth))
        b, cls, eid = _BLOCKS[rid]
        out = model.evaluate(b["n"], b["i"], b["h"], b["seg"])
        inside.append((b["f"] >= out.lo95) & (b["f"] <= out.hi95))
        err.append(out.thrust_n - b["f"])
        width.append((out.hi95 - out.lo95) / 2)
        cls_all.append(cls)
        eids.append(eid)
        runix.append(np.full(cls.size, k))
        ood.append((out.flags & OUT_OF_DOMAIN) > 0)
    e, i, w, c, o, ri, ei = (np.concatenate(x) for x in (err, inside, width, cls_all, ood, runix, eids))
    res = {}
    for k in ("event", "outside"):
        m = c == k
        per_run = [float(i[m & (ri == q)].mean()) for q in range(len(run_ids)) if (m & (ri == q)).any()]
        res[k] = {"n": int(m.sum()), "cover": float(i[m].mean()), "bias": float(np.nanmean(e[m])),
                  "below": float(np.mean(~i[m] & (e[m] > 0))), "above": float(np.mean(~i[m] & (e[m] < 0))),
                  "p95": float(np.quantile(np.abs(e[m]), 0.95)),
                  "halfw_med": float(np.median(w[m])), "halfw_max": float(np.max(w[m])),
                  "nonfinite": int((~np.isfinite(w[m])).sum()), "ood": float(o[m].mean()),
                  "cover_runs": [min(per_run), max(per_run)]}
    keep = c != "skip"
    raw = {"inside": i[keep], "event": (c[keep] == "event"), "run": ri[keep], "eid": ei[keep]}
    return res, raw


def cmd_eval(work: Path, label: str) -> None:
    from rigtool.models import load_model
    from rigtool.store import Store
    runs = json.loads((work / "runs.json").read_text())
    store = Store(work / "runs.sqlite")
    rows = []
    (work / f"{label}-blocks").mkdir(exist_ok=True)
    for v, name, _base, train in trainings(runs):
        found = list((work / label / f"{v}-{name}").glob("*/qctm_gp.json"))
        if not found:
            print(v, name, "NO MODEL", flush=True)
            continue
        cal = found[0].parent
        res, raw = score(load_model(cal), store, runs[v]["test"])
        np.savez_compressed(work / f"{label}-blocks" / f"{v}-{name}.npz", **raw)
        cj = json.loads((cal / "cavitation.json").read_text())
        html = next(cal.glob("*.html"), None)
        res.update({"variant": v, "kind": name, "train": train, "floor": cj.get("floor"),
                    "check": cj.get("interval_check"), "warnings": cj.get("warnings") or [],
                    "report_has_floor": "floor" in (html.read_text().lower() if html else "")})
        rows.append(res)
        ev, ou = res["event"], res["outside"]
        print(f"{v:6} {name:9} | event cov {ev['cover']:.1%} (runs {ev['cover_runs'][0]:.0%}-"
              f"{ev['cover_runs'][1]:.0%}) hw {ev['halfw_med']:.2f}/{ev['halfw_max']:.1f} p95 {ev['p95']:.2f} "
              f"n {ev['n']} bias {ev['bias']:+.2f} below {ev['below']:.1%} | outside cov {ou['cover']:.1%} hw {ou['halfw_med']:.2f} p95 {ou['p95']:.2f} "
              f"| warn {len(res['warnings'])}", flush=True)
    (work / f"{label}-eval.json").write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    verb, work = sys.argv[1], Path(sys.argv[2])
    work.mkdir(parents=True, exist_ok=True)
    if verb == "runs":
        cmd_runs(work)
    elif verb == "train":
        cmd_train(work, sys.argv[3], sys.argv[4])
    else:
        cmd_eval(work, sys.argv[3])
