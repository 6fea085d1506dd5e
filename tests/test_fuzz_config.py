"""Property-based fuzzing of protocol and rig files: any input gives a model or a ConfigError."""

from __future__ import annotations

import copy
import math
import re
import string
from pathlib import Path
from types import UnionType
from typing import Annotated, Union, get_args, get_origin

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from rigtool.bounds import MAX_POINTS, MAX_RUN_S, MAX_SAMPLES_PER_POINT
from rigtool.errors import ConfigError
from rigtool.protocol import Protocol, load_protocol
from rigtool.rig import Rig, load_rig

from .conftest import SMALL_PROTOCOL

BASE = yaml.safe_load(SMALL_PROTOCOL)

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
    st.text(string.printable, max_size=12),
)
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(string.ascii_letters + "_", max_size=10), inner, max_size=4)),
    max_leaves=12)


def _paths(data, prefix=()):
    yield prefix
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _paths(v, (*prefix, k))


ALL_PATHS = [p for p in _paths(BASE) if p]


def _mutated(path: tuple, value) -> dict:
    data = yaml.safe_load(SMALL_PROTOCOL)
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


def _check(path: Path, loader) -> None:
    try:
        loader(path)
    except ConfigError as exc:
        assert str(exc).strip(), "a config error must say what is wrong"
        for line in str(exc).splitlines():
            assert line.startswith(str(path)), line


FUZZ = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


@FUZZ
@given(st.sampled_from(ALL_PATHS), values)
def test_mutated_protocol_field_gives_model_or_config_error(tmp_path, field, value):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(_mutated(field, value)))
    _check(path, load_protocol)


@FUZZ
@given(st.text(max_size=300))
def test_arbitrary_text_gives_model_or_config_error(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    _check(path, load_protocol)
    _check(path, load_rig)


@FUZZ
@given(st.binary(max_size=200))
def test_arbitrary_bytes_give_config_error(tmp_path, blob):
    path = tmp_path / "p.yaml"
    path.write_bytes(blob)
    _check(path, load_protocol)


@FUZZ
@given(st.dictionaries(st.sampled_from(["name", "simulator", "db", "real_time", "thrust", "bogus"]), values, max_size=5))
def test_random_rig_gives_model_or_config_error(tmp_path, data):
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    _check(path, load_rig)


# -- out-of-range magnitudes in every numeric field (issue 12) ---------------------------------

PROTOCOL_DOCS = [BASE, yaml.safe_load("""\
name: rich
simulator: {profile: stm32-pwm, seed: 5, overrides: {cp_forward: 2.0e-5, tau_s: 0.2}}
metadata: {propeller_diameter_m: 0.1, water_density_kg_m3: 998}
command:
  unit: pwm_counts
  range: {start: 200, stop: 400, step: 20}
  order: random
  seed: 4
  repeats: 2
depth: {unit: cm, values: [20, 40], mode: manual, loop: inner}
timing:
  settle: {until_steady: {window_s: 0.5, tolerance_n: 0.1, min_s: 1, timeout_s: 5}}
  acquire: {seconds: 0.5, rate_hz: 1000}
  rest_s: 0.5
  tare: per_point
  tare_s: 0.5
limits: {max_thrust_n: 9, max_current_a: 5, max_speed_rpm: 900, max_staleness_s: 1,
         slew_per_s: 100, debounce_samples: 3}
""")]

RIG_DOCS = [yaml.safe_load(text) for text in ("""\
name: sim
simulator: {profile: can-bldc, seed: 2, overrides: {cp_forward: 2.0e-5}}
thrust: {channel: fx, sign: 1}
mount: {rotation_axis: z, rotation_deg: 90, offset_m: [0, 0, 0.1]}
""", """\
name: bench
actuator: {driver: stm32-bridge, url: "loop://", baudrate: 115200, channel: 1,
           timer_clock_hz: 72000000, psc: 0, arr: 799, neutral: 0, command_min: 0,
           command_max: 799, timeout_s: 0.5, heartbeat_s: 0.1, watchdog_ms: 500}
sensor: {driver: ascii-gauge, url: "loop://", preset: mark10, baudrate: 9600, scale: 1.0,
         offset: 0.0, timeout_s: 1, max_failures: 5, max_gap_s: 0.25}
depth_stage: {driver: serial-stage, url: "loop://", baudrate: 115200, speed_mm_s: 10,
              timeout_s: 2, min_depth_m: 0, max_depth_m: 1.5, zero_offset_m: 0.0}
""", """\
name: can
actuator: {driver: vesc-can, interface: virtual, channel: x, bitrate: 500000, controller_id: 1,
           host_id: 254, mode: rpm, pole_pairs: 7, max_erpm: 70000, max_current_a: 20,
           command_timeout_s: 1, keepalive_s: 0.1, timeout_s: 1}
sensor: {driver: ati-netft, host: 127.0.0.1, port: 49152, http_port: 80,
         counts_per_force: 1000000, counts_per_torque: 1000000, sample_count: 0,
         timeout_s: 1, max_gap_s: 0.25, buffer_samples: 200000}
mount: {rotation_deg: -90, offset_m: [0.1, 0, 0]}
""", """\
name: dbc
actuator:
  driver: dbc-can
  interface: virtual
  channel: x
  bitrate: 500000
  node_id: 1
  command: {message: SERVO_CONTROL, signal: SpeedCmd_pct, unit: percent, scale: 1, min: -100, max: 100}
  feedback: {speed_rpm: {message: SERVO_STATUS, signal: ActualSpeed_rpm, scale: 1}}
  fault: {message: SERVO_STATUS, signal: FaultCode, ok: 0}
  enable: {message: SERVO_ENABLE, signal: Enable, on_start: 1, on_close: 0}
  neutral: 0
  command_timeout_s: 0.5
  keepalive_s: 0.1
  timeout_s: 1
sensor: {driver: ati-netft, host: 127.0.0.1}
""")]


def _kinds(annotation):
    """The plain types an annotation admits (unions, Optional and Annotated unwrapped)."""
    origin = get_origin(annotation)
    if origin is Annotated:
        yield from _kinds(get_args(annotation)[0])
    elif origin in (Union, UnionType):
        for arg in get_args(annotation):
            yield from _kinds(arg)
    elif annotation is not type(None):
        yield annotation


def _numeric_paths(model, doc, prefix=()):
    """Paths to every int or float field of `model` reachable in `doc` (the union member a
    `driver:` names; list and tuple items by their first index; override values by name)."""
    for name, field in model.model_fields.items():
        sub = doc.get(name) if isinstance(doc, dict) else None
        for kind in _kinds(field.annotation):
            origin = get_origin(kind)
            if kind in (int, float):
                yield (*prefix, name)
            elif (origin in (list, tuple) and isinstance(sub, list) and sub
                  and any(k in (int, float) for k in _kinds(get_args(kind)[0]))):
                yield (*prefix, name, 0)
            elif origin is dict and isinstance(sub, dict):
                yield from ((*prefix, name, key) for key in sub)
            elif isinstance(kind, type) and issubclass(kind, BaseModel) and isinstance(sub, dict):
                driver = kind.model_fields.get("driver")
                if driver is None or sub.get("driver") in get_args(driver.annotation):
                    yield from _numeric_paths(kind, sub, (*prefix, name))


NUMERIC_CASES = sorted({(kind, i, path)
                        for kind, model, docs in (("protocol", Protocol, PROTOCOL_DOCS),
                                                  ("rig", Rig, RIG_DOCS))
                        for i, doc in enumerate(docs) for path in _numeric_paths(model, doc)},
                       key=str)
MAGNITUDES = st.one_of(
    st.sampled_from([0, -1, 1e-300, -1e-300, 1e300, -1e300, math.inf, -math.inf, math.nan,
                     2**31, 2**32, 2**63, 2**64, 10**30, -(10**30), 10**400]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**40), 10**40),
    st.floats(1e6, 1e308).flatmap(lambda x: st.sampled_from([x, -x, 1 / x])),
)


def _set(data, path, value):
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value


def _get(model, path):
    node = model
    for key in path:
        node = node[key] if isinstance(node, dict | list | tuple) else getattr(node, key)
    return node


def test_numeric_cases_cover_every_driver_and_section():
    fields = {path[-1] if isinstance(path[-1], str) else path[-2] for _, _, path in NUMERIC_CASES}
    for name in ("samples", "rate_hz", "repeats", "tare_s", "rest_s", "window_s", "seconds",
                 "seed", "cp_forward", "heartbeat_s", "timer_clock_hz", "command_max", "zero_offset_m",
                 "max_erpm", "buffer_samples", "counts_per_force", "on_start", "offset_m", "values"):
        assert name in fields, name


EXTREMES = (0, -1, 5e-324, 1e-300, -1e-300, 1e300, -math.inf, math.nan, 2**64, 10**400)


def test_every_numeric_field_against_every_extreme(tmp_path):
    """The exhaustive part of the fuzz below: a tiny positive window once divided to inf."""
    for case in NUMERIC_CASES:
        for value in EXTREMES:
            _check_loads_in_range(tmp_path, case, value)


@settings(max_examples=400, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(NUMERIC_CASES), MAGNITUDES)
def test_out_of_range_numbers_load_in_range_or_give_located_errors(tmp_path, case, value):
    _check_loads_in_range(tmp_path, case, value)


def _check_loads_in_range(tmp_path, case, value):
    kind, i, field = case
    data = copy.deepcopy((PROTOCOL_DOCS if kind == "protocol" else RIG_DOCS)[i])
    _set(data, field, value)
    path = tmp_path / f"{kind}.yaml"
    path.write_text(yaml.safe_dump(data))
    try:
        model, _ = (load_protocol if kind == "protocol" else load_rig)(path)
    except ConfigError as exc:
        lines = str(exc).splitlines()
        assert lines, "a config error must say what is wrong"
        for line in lines:
            assert re.match(rf"^{re.escape(str(path))}:\d+: ", line), line
        return
    got = _get(model, field)
    assert isinstance(got, int | float) and math.isfinite(got) and abs(got) <= 1e12, got
    if kind == "protocol":
        assert model.n_points() <= MAX_POINTS
        assert model.timing.acquire.n_samples <= MAX_SAMPLES_PER_POINT
        assert model.min_duration_s() <= MAX_RUN_S


def test_every_numeric_field_has_both_bounds():
    """The class, not the examples: any int or float field without a lower and an upper
    bound in the JSON schema of protocol or rig files fails here."""
    def walk(node, where, out):
        if isinstance(node, dict):
            numeric = node.get("type") in ("number", "integer") and not {"const", "enum"} & node.keys()
            bounded = ({"minimum", "exclusiveMinimum"} & node.keys()
                       and {"maximum", "exclusiveMaximum"} & node.keys())
            if numeric and not bounded:
                out.append(where)
            for key, value in node.items():
                walk(value, f"{where}/{key}", out)
        elif isinstance(node, list):
            for n, value in enumerate(node):
                walk(value, f"{where}/{n}", out)

    for model in (Protocol, Rig):
        unbounded: list[str] = []
        walk(model.model_json_schema(), model.__name__, unbounded)
        assert not unbounded, unbounded
