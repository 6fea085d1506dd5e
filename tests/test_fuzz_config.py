"""Property-based fuzzing of protocol and rig files: any input gives a model or a ConfigError."""

from __future__ import annotations

import string
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigtool.errors import ConfigError
from rigtool.protocol import load_protocol
from rigtool.rig import load_rig

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


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


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
