"""Where the spread of one-run trainings' event coverage comes from (issue 29, part 3).

    python benchmarks/bench_cavitation_spread.py dump --db DB --variant V --base SEED
        --train SEED[,SEED] --out FILE.npz [--set cal-dev]
    python benchmarks/bench_cavitation_spread.py analyse FILE.npz [FILE.npz ...]

`dump` trains the model `calibrate` would export on runs that `bench_cavitation.py --set S
--variant V --db DB` recorded (the same DB; only development sets, never a final one) and saves the held-out check's inputs (`calibrate_gate`'s arrays) and, on the set's
held-out runs, each block's thrust, class by the twin's truth, truth event, the model's
estimate and its variance parts with the noise model before the scale. `analyse` replays
the scale on those arrays (bit for bit what the model exports; blocks flagged out of domain
or current fault left out) and splits the spread of new-run event coverage into:

- the test's own noise: bootstrap over the held-out truth events (sd in points);
- what one run can tell at best: the exported model's event shift set on the events of ONE
  held-out run (then of two), tested on the other held-out runs (spread over the choices);
- where the check's event shift lies among what each held-out run alone would ask (rank);
- candidate rules: the event shift shrunk toward the outside shift by m / (m + m0), m the
  check's events.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_cavitation as bench  # noqa: E402

import rigtool.analysis.cavitation as cav  # noqa: E402
from rigtool.analysis import gp as G  # noqa: E402
from rigtool.analysis.blocks import classify  # noqa: E402
from rigtool.analysis.cavitation_truth import truth_intervals  # noqa: E402
from rigtool.analysis.results import CavitationParams  # noqa: E402
from rigtool.models import Z95  # noqa: E402
from rigtool.models.domain import CURRENT_FAULT, OUT_OF_DOMAIN  # noqa: E402
from rigtool.models.qctm import gate  # noqa: E402
from rigtool.store import Store  # noqa: E402

CHECK_KEYS = ("resid", "post", "noise", "z", "event", "outside", "speed", "level")
RNG = np.random.default_rng(0)


def dump(db: Path, variant: str, base_seed: int, train_seeds: list[int], out: Path,
         set_name: str) -> None:
    """Train as `calibrate` does, record the check's inputs and the held-out blocks."""
    rec: dict = {}
    held: list[dict] = []
    orig_gate, orig_shift, orig_eval = cav.calibrate_gate, cav.shift_noise, cav.evaluate

    def calibrate_gate(resid, post, noise, z, event, outside, z0, s, *a, speed_rpm=None,  # noqa: ANN001, ANN202
                       speed_level=None, **k):
        rec.update(resid=resid, post=post, noise=noise, z=z, event=event, outside=outside,
                   z0=z0, s=s, speed=speed_rpm, level=speed_level)
        return orig_gate(resid, post, noise, z, event, outside, z0, s, *a,
                         speed_rpm=speed_rpm, speed_level=speed_level, **k)

    def shift_noise(noise, shift):  # noqa: ANN001, ANN202
        rec["noise0"] = noise
        return orig_shift(noise, shift)

    def evaluate(store, run_id, blocks, det_blocks, detected, pred, lo, hi, p, source):  # noqa: ANN001, ANN202
        truth = truth_intervals(store, run_id)
        ep = np.full(len(blocks), -1)
        for j, (a, b) in enumerate(truth):
            ep[(blocks.t_s >= a) & (blocks.t_s <= b)] = j
        held.append({"y": blocks.thrust_n, "cls": classify(blocks, truth, p.edge_s).astype(str),
                     "ep": ep, "pred": pred})
        return orig_eval(store, run_id, blocks, det_blocks, detected, pred, lo, hi, p, source)

    cav.calibrate_gate, cav.shift_noise, cav.evaluate = calibrate_gate, shift_noise, evaluate
    folder = Path(tempfile.mkdtemp())
    cavp = bench.variant_protocol(folder, "luo2020-cavitation", variant)
    basep = bench.variant_protocol(folder, "luo2020-baseline", variant)
    known = {(r["name"], r["seed"]): r["id"] for r in bench._runs(db)}
    name, bname = (yaml.safe_load(q.read_text())["name"] for q in (cavp, basep))
    store, p = Store(db), CavitationParams()
    betm, gp, training = cav.train_model(store, [known[(name, s)] for s in train_seeds],
                                         known[(bname, base_seed)], p)
    model = cav.thrust_model(betm, gp, training, p)
    feats: list[dict] = []

    def predict(n, i, h, segment=None):  # noqa: ANN001, ANN202
        o = model.evaluate(n, i, h, segment)
        x = model.features(n, i, h, segment)
        x = np.where(np.all(np.isfinite(x), axis=1)[:, None], x, model.x_mean)
        _, std = model.correction(x)
        feats.append({"n": np.asarray(n, float), "zz": x[:, 1], "flags": o.flags,
                      "post": std**2 - model.noise.var_n2(x), "noise": rec["noise0"].var_n2(x)})
        return o.thrust_n, o.lo95, o.hi95

    for s in bench.SETS[set_name][1]:
        cav.evaluate_on_run(store, known[(name, s)], predict, betm, p)
    rows = {**{k: np.concatenate([d[k] for d in held]) for k in held[0]},
            **{k: np.concatenate([d[k] for d in feats]) for k in feats[0]}}
    run = np.concatenate([np.full(len(d["y"]), j) for j, d in enumerate(held)])
    np.savez(out, **{k: np.asarray(rec[k]) for k in CHECK_KEYS}, z0=rec["z0"], s=rec["s"],
             n_events=gp.check["intervals"]["n_events"], h_run=run,
             **{"h_" + k: v for k, v in rows.items()})


def shift_of(d: dict, shrink: float | None = None) -> G.GateShift:
    """The check's scale, replayed (`shrink`: EVENT_SHRINK for this call)."""
    old = G.EVENT_SHRINK
    G.EVENT_SHRINK = old if shrink is None else shrink
    try:
        return G.calibrate_gate(d["resid"], d["post"], d["noise"], d["z"], d["event"],
                                d["outside"], float(d["z0"]), float(d["s"]), cav.CHECK_LEVEL,
                                cav.OUTSIDE_CHECK_LEVEL, speed_rpm=d["speed"],
                                speed_level=np.abs(d["level"]))
    finally:
        G.EVENT_SHRINK = old


def inside(d: dict, sh: G.GateShift, d_event: float | None = None) -> tuple[np.ndarray, ...]:
    """Held-out blocks inside their interval under `sh` (event shift `d_event` if given), and
    the masks of usable event and outside blocks."""
    n, g = d["h_n"], gate(d["h_zz"], float(d["z0"]), float(d["s"]))
    de = sh.d_event if d_event is None else d_event
    half = Z95 * np.sqrt(d["h_post"] + d["h_noise"] * np.exp((1 - g) * sh.d_quiet + g * de))
    miss = sh.missed(n, d["h_zz"])
    up = np.sign(n) >= 0
    lo = d["h_pred"] - half - np.where(up, miss, 0.0)
    hi = d["h_pred"] + half + np.where(up, 0.0, miss)
    ok = ((d["h_flags"] & (OUT_OF_DOMAIN | CURRENT_FAULT)) == 0) & np.isfinite(d["h_pred"])
    return ((d["h_y"] >= lo) & (d["h_y"] <= hi), ok & (d["h_cls"] == "event"),
            ok & (d["h_cls"] == "outside"))


def event_boot_sd(d: dict, hit: np.ndarray, ev: np.ndarray, b: int = 400) -> float:
    """Bootstrap sd of the pooled event coverage over held-out truth events."""
    _, inv = np.unique(d["h_run"][ev] * 10_000 + d["h_ep"][ev], return_inverse=True)
    h, c = np.bincount(inv, hit[ev].astype(float)), np.bincount(inv)
    draws = [RNG.integers(0, c.size, c.size) for _ in range(b)]
    return float(np.std([h[s].sum() / c[s].sum() for s in draws]))


def per_run_asks(d: dict, sh: G.GateShift) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Event shift grid, coverage per (shift, held-out run) and event blocks per run."""
    grid = np.round(np.arange(-3.0, 4.001, 0.02), 2)
    _, ev, _ = inside(d, sh)
    runs = np.unique(d["h_run"])
    cover = np.array([[np.mean(h[ev & (d["h_run"] == r)]) for r in runs]
                      for h in (inside(d, sh, c)[0] for c in grid)])
    return grid, cover, np.array([np.sum(ev & (d["h_run"] == r)) for r in runs])


def calibrated_on(grid: np.ndarray, cover: np.ndarray, count: np.ndarray, k: int) -> np.ndarray:
    """Coverage on the other runs with the event shift set on every choice of k runs."""
    out = []
    for sub in itertools.combinations(range(count.size), k):
        rest = [j for j in range(count.size) if j not in sub]
        c_sub = (cover[:, list(sub)] * count[list(sub)]).sum(1) / count[list(sub)].sum()
        j = int(np.argmax(c_sub >= 0.95)) if np.any(c_sub >= 0.95) else grid.size - 1
        out.append((cover[j, rest] * count[rest]).sum() / count[rest].sum())
    return 100 * np.array(out)


def analyse(files: list[str]) -> None:
    """Per training and summed up: see the module docstring."""
    shrink_m0 = (5, 10, 20)
    rows, ideal = [], {1: [], 2: []}
    for f in files:
        d = dict(np.load(f))
        sh = shift_of(d)
        hit, ev, out = inside(d, sh)
        grid, cover, count = per_run_asks(d, sh)
        asks = np.array([grid[np.argmax(c >= 0.95)] if np.any(c >= 0.95) else grid[-1]
                         for c in (cover[:, j] for j in range(count.size))])
        raw = shift_of(d, shrink=99.0).d_event
        m = int(d["n_events"])
        shr = []
        for m0 in shrink_m0:
            de = sh.d_quiet + m / (m + m0) * (sh.d_event - sh.d_quiet)
            h, e, _ = inside(d, sh, de)
            shr.append(100 * np.mean(h[e]))
        for k in ideal:
            ideal[k].append(calibrated_on(grid, cover, count, k))
        rows.append((Path(f).stem, m, 100 * np.mean(hit[ev]), 100 * np.mean(hit[out]),
                     100 * event_boot_sd(d, hit, ev), sh.d_quiet, sh.d_event, raw,
                     int(np.sum(asks < raw)), asks.size, shr, ideal[1][-1], ideal[2][-1]))
    print(f"{'training':18} {'events':>6} {'event %':>7} {'out %':>6} {'test sd':>7} "
          f"{'d_quiet':>7} {'d_event':>7} {'raw':>6} {'rank':>5} | shrink m0 "
          + "/".join(map(str, shrink_m0)) + " | set on 1 new run: range | on 2")
    for r in rows:
        print(f"{r[0]:18} {r[1]:6d} {r[2]:7.1f} {r[3]:6.1f} {r[4]:7.2f} {r[5]:7.2f} {r[6]:7.2f} "
              f"{r[7]:6.2f} {r[8]:2d}/{r[9]:<2d} | " + " ".join(f"{v:5.1f}" for v in r[10])
              + f" | {r[11].min():5.1f}-{r[11].max():5.1f} | {r[12].min():5.1f}-{r[12].max():5.1f}")
    ce = np.array([r[2] for r in rows])
    print(f"event coverage: {_spread(ce)}")
    print(f"test noise (bootstrap over held-out events): sd median "
          f"{np.median([r[4] for r in rows]):.2f}, rms {np.sqrt(np.mean([r[4]**2 for r in rows])):.2f}")
    for j, m0 in enumerate(shrink_m0):
        print(f"shrink toward d_quiet, m0 {m0}: {_spread(np.array([r[10][j] for r in rows]))}")
    for k, v in ideal.items():
        print(f"event shift set on {k} new run(s) alone, tested on the others: "
              f"{_spread(np.concatenate(v))}")
    edge = sum(r[8] in (0, r[9]) for r in rows)
    print(f"check's event shift outside the range of one new run's asks: {edge} of {len(rows)}")


def _spread(c: np.ndarray) -> str:
    """sd, range and share in 90-98 % of coverages in %."""
    return (f"sd {c.std():.2f}, {c.min():.1f}-{c.max():.1f}, median {np.median(c):.1f}, "
            f"in 90-98 % {np.mean((c >= 90) & (c <= 98)):.0%} ({np.mean(c < 90):.0%} below, "
            f"{np.mean(c > 98):.0%} above) of {c.size}")


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("--db", required=True)
    d.add_argument("--variant", choices=sorted(bench.VARIANTS), default="stock")
    d.add_argument("--base", type=int, required=True)
    d.add_argument("--train", required=True, help="training seeds, comma-separated")
    d.add_argument("--set", default="cal-dev", choices=sorted(bench.SETS))
    d.add_argument("--out", required=True)
    a = sub.add_parser("analyse")
    a.add_argument("files", nargs="+")
    args = ap.parse_args()
    if args.cmd == "dump":
        dump(Path(args.db), args.variant, args.base, [int(s) for s in args.train.split(",")],
             Path(args.out), args.set)
    else:
        analyse(args.files)


if __name__ == "__main__":
    main()
