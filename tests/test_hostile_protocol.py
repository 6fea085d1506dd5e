"""Protocol files that would exhaust the host: every size is bounded, counted arithmetically,
and refused with exit 2 and file:line before anything runs."""

from __future__ import annotations

import re

import pytest
import yaml

import rigtool.plan
from rigtool.bounds import MAX_POINTS, MAX_RUN_S
from rigtool.cli import main
from rigtool.errors import ConfigError
from rigtool.plan import estimate_duration_s, expand, step_at
from rigtool.protocol import load_protocol

from .conftest import SMALL_PROTOCOL
from .hostile import run_cli

BASE = yaml.safe_load(SMALL_PROTOCOL)


def _protocol(tmp_path, **changes) -> tuple:
    """SMALL_PROTOCOL with `section.field=value` changes, written to tmp_path/p.yaml."""
    data = yaml.safe_load(SMALL_PROTOCOL)
    for dotted, value in changes.items():
        *parents, leaf = dotted.split("__")
        node = data
        for key in parents:
            node = node.setdefault(key, {})
        if value is None:
            node.pop(leaf, None)
        else:
            node[leaf] = value
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


HOSTILE = {
    "samples": ({"timing__acquire__samples": 10**13}, "timing.acquire.samples"),
    "samples-by-seconds": ({"timing__acquire__samples": None, "timing__acquire__seconds": 86_400,
                            "timing__acquire__rate_hz": 100_000}, "timing.acquire.seconds"),
    "repeats": ({"command__repeats": 10**9}, "command.repeats"),
    "points": ({"command__values": None, "command__repeats": 100_000,
                "command__range": {"start": 0, "stop": 100, "step": 0.002}}, "command.repeats"),
    "range-step": ({"command__values": None,
                    "command__range": {"start": -1e9, "stop": 1e9, "step": 1e-300}}, "command.range.step"),
    "rate": ({"timing__acquire__rate_hz": 1e12}, "timing.acquire.rate_hz"),
    "tiny-rate": ({"timing__acquire__rate_hz": 1e-300}, "timing.acquire.rate_hz"),
    "tare": ({"timing__tare_s": 1e9}, "timing.tare_s"),
    "settle": ({"timing__settle": {"seconds": 1e12}}, "timing.settle.seconds"),
    "window": ({"timing__settle": {"until_steady": {"window_s": float("inf")}}},
               "timing.settle.until_steady.window_s"),
    "rest": ({"timing__rest_s": 1e11}, "timing.rest_s"),
    "run-length": ({"command__repeats": 2000, "timing__rest_s": 86_400}, "timing"),
    "slew": ({"limits__slew_per_s": 1e-200}, "limits.slew_per_s"),
    "depth": ({"depth__values": [1e300]}, "depth.values"),
    "debounce": ({"limits__debounce_samples": 10**30}, "limits.debounce_samples"),
    "order-seed": ({"command__seed": -1}, "command.seed"),
    "sim-seed": ({"simulator__seed": -1}, "simulator.seed"),
    "sim-seed-huge": ({"simulator__seed": 2**64}, "simulator.seed"),
    "override-name": ({"simulator__overrides": {"bogus": 1.0}}, "simulator.overrides"),
    "override-value": ({"simulator__overrides": {"cp_forward": "inf"}}, "simulator.overrides"),
    "profile": ({"simulator__profile": "warp-drive"}, "simulator.profile"),
    "thrust-limit": ({"limits__max_thrust_n": float("nan")}, "limits.max_thrust_n"),
    # true/false where a number belongs: pydantic's lax mode would read them as 1 and 0
    "bool-step": ({"command__values": None, "command__range": {"start": -80, "stop": 80,
                                                                "step": True}}, "command.range.step"),
    "bool-samples": ({"timing__acquire__samples": True}, "timing.acquire.samples"),
    "bool-seed": ({"simulator__seed": False}, "simulator.seed"),
    "bool-override": ({"simulator__overrides": {"cp_forward": True}},
                      "simulator.overrides.cp_forward"),
    "bool-depth": ({"depth__values": [1.0, True]}, "depth.values.1"),
    "quoted-samples": ({"timing__acquire__samples": "1000"}, "timing.acquire.samples"),
    "quoted-seed": ({"simulator__seed": "7"}, "simulator.seed"),
    # characters that print as nothing: two ids would read alike in the files they name
    "control-thruster-id": ({"metadata__thruster_id": "de\x07mo"}, "metadata.thruster_id"),
    "rtl-override-name": ({"name": "demo\u202eomed"}, "name"),
    "zero-width-operator": ({"metadata__operator": "a\u200bb"}, "metadata.operator"),
}


def _assert_located(message: str, path, field: str) -> None:
    lines = message.strip().splitlines()
    assert lines, "a config error must say what is wrong"
    for line in lines:
        assert re.match(rf"^{re.escape(str(path))}:\d+: ", line), line
    assert any(f": {field}" in line for line in lines), (field, lines)


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_protocol_is_a_located_config_error(tmp_path, case):
    changes, field = HOSTILE[case]
    path = _protocol(tmp_path, **changes)
    with pytest.raises(ConfigError) as info:
        load_protocol(path)
    _assert_located(str(info.value), path, field)


@pytest.mark.parametrize("case", ["samples", "repeats", "points", "rate", "settle", "slew",
                                  "sim-seed", "override-name", "bool-step"])
def test_dry_run_of_hostile_protocol_exits_2_in_bounded_memory(tmp_path, case):
    changes, field = HOSTILE[case]
    path = _protocol(tmp_path, **changes)
    proc = run_cli("sweep", path, "--sim", "--dry-run", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    _assert_located(proc.stderr.replace("rigtool: error: ", ""), path, field)


def test_run_length_with_ramps_is_checked_against_the_actuator_neutral(tmp_path, capsys):
    # one command far from neutral: no lower bound without the neutral, caught at the rig
    path = _protocol(tmp_path, command__values=[100], limits__slew_per_s=1e-5)
    load_protocol(path)
    assert main(["sweep", str(path), "--sim", "--dry-run"]) == 2
    _assert_located(capsys.readouterr().err.replace("rigtool: error: ", ""), path,
                    "limits.slew_per_s")


def test_largest_plan_dry_run_never_expands(tmp_path, capsys, monkeypatch):
    with pytest.raises(ConfigError, match="the limit is 100,000"):
        load_protocol(_protocol(tmp_path, command__values=None, command__repeats=101,
                                command__range={"start": 0, "stop": 999, "step": 1}))
    path = _protocol(tmp_path, command__values=None, command__repeats=100,
                     command__range={"start": -99.9, "stop": 0, "step": 0.1}, command__order="random",
                     timing__rest_s=0, timing__settle={"seconds": 0})
    assert load_protocol(path)[0].n_points() == MAX_POINTS

    def refuse(protocol):
        raise AssertionError("--dry-run expanded the plan")

    monkeypatch.setattr(rigtool.plan, "expand", refuse)
    monkeypatch.setattr("rigtool.sweep.expand", refuse)
    assert main(["sweep", str(path), "--sim", "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert f"{MAX_POINTS} points" in text and "99999" in text


def test_largest_plan_dry_run_in_a_subprocess(tmp_path):
    path = _protocol(tmp_path, command__values=None, command__repeats=100,
                     command__range={"start": 0, "stop": 99.9, "step": 0.1}, command__order="up-down",
                     depth__values=[1.0, 0.5, 0.25, 0.125, 0.5], depth__mode="manual",
                     timing__rest_s=0, timing__settle={"seconds": 0})
    proc = run_cli("sweep", path, "--sim", "--dry-run", cwd=tmp_path)
    assert proc.returncode == 2 and "1,000,000 points" in proc.stderr
    path = _protocol(tmp_path, command__values=None, command__repeats=10,
                     command__range={"start": 0, "stop": 99.9, "step": 0.1}, command__order="up-down",
                     depth__values=[1.0, 0.5, 0.25, 0.125, 0.5], depth__mode="manual",
                     timing__rest_s=0, timing__settle={"seconds": 0})
    proc = run_cli("sweep", path, "--sim", "--dry-run", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "100000 points" in proc.stdout


SHAPES = [
    {},
    {"command__order": "up-down", "command__repeats": 3, "depth__values": [1.0, 0.5, 0.5]},
    {"command__order": "random", "command__repeats": 2, "depth__values": [1.0, 0.5],
     "depth__loop": "inner"},
    {"command__order": "down", "depth__values": [0.3, 0.3, 0.6], "depth__loop": "inner",
     "command__repeats": 2, "timing__tare": "per_depth"},
    {"command__values": None, "command__range": {"start": 0, "stop": 1, "step": 0.3},
     "timing__tare": "per_point", "depth__values": [0.2, 0.4]},
    {"command__values": None, "command__range": {"start": -1, "stop": 1, "step": 0.1},
     "timing__tare": "never", "command__order": "up-down"},
]


def _plan_estimate(protocol, plan, neutral):
    """The estimate as a walk over the expanded plan (the reference for the arithmetic one)."""
    timing = protocol.timing
    total = timing.point_s() * len(plan)
    total += sum(2 * abs(s.command - neutral) / protocol.limits.slew_per_s for s in plan)
    changes = 1 + sum(1 for a, b in zip(plan, plan[1:], strict=False) if a.depth_m != b.depth_m)
    total += changes * rigtool.plan.DEPTH_MOVE_S
    tares = {"per_point": len(plan), "per_depth": changes, "at_start": 1, "never": 0}
    return total + timing.tare_s * tares[timing.tare]


@pytest.mark.parametrize("shape", range(len(SHAPES)))
def test_counts_steps_and_estimate_match_the_expanded_plan(tmp_path, shape):
    protocol, _ = load_protocol(_protocol(tmp_path, **SHAPES[shape]))
    plan = expand(protocol)
    assert protocol.n_points() == len(plan)
    assert [step_at(protocol, i) for i in range(len(plan))] == plan
    assert estimate_duration_s(protocol, 0.25) == pytest.approx(_plan_estimate(protocol, plan, 0.25))
    assert protocol.min_duration_s() <= estimate_duration_s(protocol, 0.25) <= MAX_RUN_S
