"""bias29: per-twin summary of `cav_eval.py eval` output (LABEL-eval.json) for the docs.

    python table.py WORK LABEL
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def inside(c: float) -> bool:
    return 0.90 <= c <= 0.98


def main() -> None:
    rows = json.loads((Path(sys.argv[1]) / f"{sys.argv[2]}-eval.json").read_text())
    print("| twin, training runs | in 90-98 % (both classes) | event coverage worst / median | "
          "event error model - measured (N), per training | below / above the interval, event |")
    print("|---|--:|---|---|---|")
    for v in dict.fromkeys(r["variant"] for r in rows):
        for kind in ("single", "two"):
            rs = [r for r in rows if r["variant"] == v and r["kind"].startswith(kind)]
            if not rs:
                continue
            ev = np.array([r["event"]["cover"] for r in rs])
            ok = sum(inside(r["event"]["cover"]) and inside(r["outside"]["cover"]) for r in rs)
            bias = ", ".join(f"{r['event']['bias']:+.2f}" for r in rs)
            sides = ", ".join(f"{r['event']['below']:.1%}/{r['event']['above']:.1%}" for r in rs)
            print(f"| {v}, {1 if kind == 'single' else 2} | {ok} of {len(rs)} | "
                  f"{ev.min():.1%} / {np.median(ev):.1%} | {bias} | {sides} |")
    for r in rows:
        print(f"{r['variant']:5} {r['kind']:9} event {r['event']['cover']:.1%} outside "
              f"{r['outside']['cover']:.1%} bias {r['event']['bias']:+.2f} below {r['event']['below']:.1%}"
              f" above {r['event']['above']:.1%} check {((r.get('check') or {}).get('classes') or {}).get('event', {}).get('coverage')}")


if __name__ == "__main__":
    main()
