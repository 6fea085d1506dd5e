"""Plan expansion: counts, orders, repeats, depth loops, duration estimate, dry run."""

from __future__ import annotations

import pytest

from rigtool.cli import main
from rigtool.plan import estimate_duration_s, expand
from rigtool.protocol import Settle, load_protocol

from .conftest import PROTOCOLS, SMALL_PROTOCOL


def _plan(write_yaml, text: str):
    protocol, _ = load_protocol(write_yaml(text))
    return protocol, expand(protocol)


def test_baseline_plan_has_401_points():
    protocol, _ = load_protocol(PROTOCOLS / "luo2020-baseline.yaml")
    plan = expand(protocol)
    assert len(plan) == 401
    assert [s.idx for s in plan] == list(range(401))
    assert plan[200].command == 0.0


def test_up_down_repeats_and_depths(write_yaml):
    text = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]", "values: [0, 50, 100]\n  order: up-down\n  repeats: 2")
    text = text.replace("values: [1.0]", "values: [1.0, 0.5]")
    _, plan = _plan(write_yaml, text)
    assert len(plan) == 2 * 2 * 6
    first = [(s.command, s.direction) for s in plan[:6]]
    assert first == [(0, "up"), (50, "up"), (100, "up"), (100, "down"), (50, "down"), (0, "down")]
    assert {s.depth_m for s in plan[:12]} == {1.0} and {s.depth_m for s in plan[12:]} == {0.5}
    assert [s.repeat for s in plan[:12]] == [0] * 6 + [1] * 6


def test_inner_depth_loop(write_yaml):
    text = SMALL_PROTOCOL.replace("values: [1.0]", "values: [100, 50]\n  loop: inner").replace("unit: m", "unit: cm")
    _, plan = _plan(write_yaml, text)
    assert [(s.command, s.depth_m) for s in plan[:4]] == [(-50, 1.0), (-50, 0.5), (0, 1.0), (0, 0.5)]


def test_random_order_is_seeded(write_yaml):
    text = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]", "range: {start: 0, stop: 100, step: 5}\n  order: random\n  seed: 11")
    _, a = _plan(write_yaml, text)
    _, b = _plan(write_yaml, text)
    _, c = _plan(write_yaml, text.replace("seed: 11", "seed: 12"))
    assert [s.command for s in a] == [s.command for s in b]
    assert [s.command for s in a] != [s.command for s in c]
    assert sorted(s.command for s in a) == [5.0 * i for i in range(21)]


def test_duration_estimate_counts_every_phase(write_yaml):
    protocol, plan = _plan(write_yaml, SMALL_PROTOCOL)
    per_point = 0.5 + 200 / 500 + 0.2
    est = estimate_duration_s(protocol, neutral=0.0)
    slew = sum(2 * abs(s.command) / 400 for s in plan)
    assert abs(est - (4 * per_point + slew + 10 + 1.0)) < 1e-9


def test_dry_run_prints_plan_and_stores_nothing(capsys, db_path):
    status = main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--sim", "--dry-run", "--db", str(db_path)])
    text = capsys.readouterr().out
    assert status == 0
    assert "42 points" in text and "estimated duration" in text and "samples to store: 42,000" in text
    assert not db_path.exists()


@pytest.mark.parametrize("min_s, window_s, timeout_s, longest", [
    (0.0, 0.5, 10.0, 10.0), (9.5, 0.5, 10.0, 10.5), (0.0, 0.3, 1.0, 1.2), (2.0, 1.0, 1.0, 4.0)])
def test_until_steady_max_settle_matches_the_engine_loop(min_s, window_s, timeout_s, longest):
    s = Settle(until_steady={"min_s": min_s, "window_s": window_s, "timeout_s": timeout_s})
    assert s.max_seconds() == pytest.approx(longest)
