"""The stored calibration state: every blob a release wrote still decodes to the same values,
classes are named by registered tags (never imported by name), and the registry covers every
class a real calibration stores."""

from __future__ import annotations

import dataclasses
import io
import json
import re
import sqlite3
import sys
import typing
import zipfile
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest

import rigtool
from rigtool.analysis.fits import Coefficient
from rigtool.analysis.results import CalibrationResult, CavitationResult
from rigtool.artefacts import state, state_types
from rigtool.cli import main
from rigtool.errors import StoreError
from rigtool.store import RunRecord, Store

from .conftest import copy_db
from .state_fixtures import FIXTURES, SHIPPED, format_of, summary

BLOBS = sorted(FIXTURES.glob("*.blob"))
# Annotated fields that reach a class the state never holds: workflows stores gp=None.
NEVER_STORED = {(CavitationResult, "gp")}


def tree_of(blob: bytes) -> dict:
    """The parsed tree.json of a blob."""
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        return json.loads(zf.read("tree.json"))


def blob_of(tree: Any, arrays: tuple[np.ndarray, ...] = ()) -> bytes:
    """A blob holding `tree` as tree.json and `arrays` as 0.npy, 1.npy, ..."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("tree.json", json.dumps(tree))
        for i, a in enumerate(arrays):
            with zf.open(f"{i}.npy", "w") as fh:
                np.save(fh, a, allow_pickle=False)
    return buf.getvalue()


def coefficient_node(tag: str = "fits.Coefficient/1", **fields: Any) -> dict:
    """A dataclass node of a Coefficient with the required fields, `fields` overriding."""
    base = {"name": "C_p", "value": 2.0, "lo": 1.0, "hi": 3.0, "unit": "N"}
    return {"$c": tag, "f": {**base, **fields}}


def tags_in(node: Any) -> set[str]:
    """Every "$c" value in a tree, found without recursion."""
    found, stack = set(), [node]
    while stack:
        n = stack.pop()
        if isinstance(n, dict):
            if "$c" in n:
                found.add(n["$c"])
            stack.extend(n.values())
        elif isinstance(n, list):
            stack.extend(n)
    return found


# -- fixtures: what each release wrote ------------------------------------------------------
def test_every_shipped_protocol_has_a_fixture_of_each_format():
    names = {p.stem for p in BLOBS}
    for version in (1, state.FORMAT_VERSION):
        assert {f"{p}-v{version}" for p in SHIPPED} <= names
    assert all(p.stat().st_size < 1 << 20 for p in BLOBS)


@pytest.mark.parametrize("path", BLOBS, ids=lambda p: p.stem)
def test_fixture_decodes_to_its_expected_values(path: Path):
    blob = path.read_bytes()
    data = state.decode(blob)
    expected = json.loads(path.with_suffix(".json").read_text())
    assert json.loads(json.dumps(summary(data))) == expected
    assert isinstance(data["calibration"], CalibrationResult)
    assert data["cavitation"] is None or isinstance(data["cavitation"], CavitationResult)
    assert int(path.stem.rpartition("-v")[2]) == format_of(blob)


@pytest.mark.parametrize("path", BLOBS, ids=lambda p: p.stem)
def test_fixture_reencodes_to_the_current_tree(path: Path):
    """A fixture decoded, encoded by today's rigtool and decoded again is the same object, and
    today's encoding names every class by a current tag."""
    first = state.decode(path.read_bytes())
    blob = state.encode(first)
    tree = tree_of(blob)
    assert tree["format_version"] == state.FORMAT_VERSION
    assert tags_in(tree["root"]) <= state_types.TYPES.keys()
    _assert_same(first, state.decode(blob), "root")


def _assert_same(a, b, where: str) -> None:
    """Equal objects: dataclasses field by field, arrays element by element (NaN equal)."""
    assert type(a) is type(b), (where, type(a), type(b))
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            _assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.shape == b.shape and a.dtype == b.dtype, where
        if a.dtype.kind == "O":
            for i, (x, y) in enumerate(zip(a.tolist(), b.tolist(), strict=True)):
                _assert_same(x, y, f"{where}[{i}]")
        else:
            assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b or (a != a and b != b), (where, a, b)  # NaN is NaN


def test_v1_fixtures_hold_legacy_names_and_v2_fixtures_tags():
    for path in BLOBS:
        tree = tree_of(path.read_bytes())
        tags = tags_in(tree["root"])
        table = state_types.LEGACY_V1 if tree["format_version"] == 1 else state_types.TYPES
        assert tags and tags <= table.keys(), path.name


# -- the registry ---------------------------------------------------------------------------
def test_registry_tables_are_closed_and_consistent():
    for table in (state_types.TYPES, state_types.UPGRADES, state_types.LEGACY_V1):
        assert isinstance(table, MappingProxyType)
    for tag, cls in state_types.TYPES.items():
        assert re.fullmatch(r"[a-z]+\.[A-Z][A-Za-z]+/[1-9][0-9]*", tag), tag
        assert dataclasses.is_dataclass(cls) and cls.__module__.startswith("rigtool.")
    assert set(state_types.LEGACY_V1.values()) <= state_types.TYPES.keys()
    assert set(state_types.UPGRADES) <= state_types.TYPES.keys()
    for name in state_types.LEGACY_V1:
        assert re.fullmatch(r"rigtool(\.[a-z_]+)+:[A-Z][A-Za-z]+", name), name


def _reachable(roots: tuple[type, ...]) -> set[type]:
    """Dataclasses reachable from `roots` through field annotations."""
    seen: set[type] = set()
    todo = list(roots)
    while todo:
        cls = todo.pop()
        if cls in seen:
            continue
        seen.add(cls)
        hints = typing.get_type_hints(cls, vars(sys.modules[cls.__module__]))
        for f in dataclasses.fields(cls):
            if (cls, f.name) in NEVER_STORED:
                continue
            stack = [hints[f.name]]
            while stack:
                t = stack.pop()
                stack.extend(typing.get_args(t))
                if isinstance(t, type) and dataclasses.is_dataclass(t):
                    todo.append(t)
    return seen


def test_every_class_a_calibration_can_hold_is_registered():
    reachable = _reachable((CalibrationResult, CavitationResult))
    assert reachable - set(state_types.TYPES.values()) == set()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, shipped_sweep) -> Path:
    """The database of a calibrated dynamics-steps run (the step-response stage too): the
    session's sweep of it, copied."""
    tmp = tmp_path_factory.mktemp("calibrated")
    db = copy_db(shipped_sweep("dynamics-steps"), tmp / "db.sqlite")
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp / "out")]) == 0
    return db


def _stored_state(db: Path) -> bytes:
    store = Store(db, read_only=True)
    try:
        return store.latest_calibration(store.resolve_run_id("last"))["state"]
    finally:
        store.close()


def test_a_real_calibration_encodes_with_registered_tags_only(calibrated):
    blob = _stored_state(calibrated)
    assert format_of(blob) == state.FORMAT_VERSION
    assert {"calibrate.Calibration/1", "dynamics.Dynamics/2"} <= tags_in(tree_of(blob)["root"])
    assert state.decode(blob)["calibration"].dynamics is not None


def test_report_on_a_crafted_state_runs_nothing_it_names(calibrated, tmp_path, capsys):
    """The audit's blob: format 1 naming rigtool.__main__ ran the CLI inside `report`."""
    db = tmp_path / "db.sqlite"
    db.write_bytes(calibrated.read_bytes())
    crafted = blob_of({"format_version": 1, "root": {"$d": [
        ["calibration", {"$c": "rigtool.__main__:X", "f": {}}], ["cavitation", None],
        ["notes", []]]}})
    conn = sqlite3.connect(db)
    with conn:
        conn.execute("UPDATE calibrations SET state = ?", (crafted,))
    conn.close()
    before = set(sys.modules)
    assert main(["report", "last", "--db", str(db), "--out", str(tmp_path / "out")]) != 0
    err = capsys.readouterr().err
    assert "rigtool.__main__:X" in err and "calibrate" in err and "Traceback" not in err
    assert "rigtool.__main__" not in set(sys.modules) - before


def test_encoding_an_unregistered_dataclass_is_a_type_error():
    @dataclasses.dataclass
    class Local:
        x: int

    @dataclasses.dataclass(frozen=True)
    class Sub(Coefficient):
        pass

    record = object.__new__(RunRecord)  # a rigtool dataclass that is not registered
    for obj in (Local(1), Sub("C", 1.0, 0.0, 2.0, "N"), record, [{"k": Local(2)}]):
        with pytest.raises(TypeError, match="not a registered state type"):
            state.encode(obj)


def test_encoding_writes_the_highest_version_of_a_class(monkeypatch):
    monkeypatch.setattr(state_types, "TYPES", MappingProxyType(
        {**state_types.TYPES, "fits.Coefficient/7": Coefficient}))
    blob = state.encode(Coefficient("C", 1.0, 0.0, 2.0, "N"))
    assert tree_of(blob)["root"]["$c"] == "fits.Coefficient/7"


def test_an_old_version_is_read_through_its_upgrade(monkeypatch):
    monkeypatch.setattr(state_types, "TYPES", MappingProxyType(
        {**state_types.TYPES, "fits.Coefficient/0": Coefficient}))
    monkeypatch.setattr(state_types, "UPGRADES", MappingProxyType(
        {"fits.Coefficient/0": lambda f: {**{k: v for k, v in f.items() if k != "val"},
                                          "value": f["val"]}}))
    node = coefficient_node("fits.Coefficient/0", val=4.5)
    del node["f"]["value"]
    c = state.decode(blob_of({"format_version": 2, "root": node}))
    assert c == Coefficient("C_p", 4.5, 1.0, 3.0, "N")


# -- decoding by tag ------------------------------------------------------------------------
def test_decoding_a_tag_builds_its_class_with_defaults():
    c = state.decode(blob_of({"format_version": 2, "root": coefficient_node()}))
    assert c == Coefficient("C_p", 2.0, 1.0, 3.0, "N")


@pytest.mark.parametrize(("tag", "said"), [
    ("steady.PointTable/9", "steady.PointTable version 9, this rigtool reads version 1"),
    ("nope.Thing/1", "unknown type 'nope.Thing/1'"),
    ("fits.Coefficient", "unknown type 'fits.Coefficient'"),
    ("rigtool.analysis.fits:Coefficient", "unknown type 'rigtool.analysis.fits:Coefficient'"),
])
def test_an_unknown_tag_or_version_is_named(tag: str, said: str):
    with pytest.raises(StoreError, match=re.escape(said)) as err:
        state.decode(blob_of({"format_version": 2, "root": coefficient_node(tag)}))
    assert str(err.value).endswith("calibrate again")


@pytest.mark.parametrize("name", ["rigtool.__main__:X", "rigtool.cli:main", "os:system",
                                  "rigtool.store:RunRecord", "rigtool.analysis.gp:ExactGp",
                                  "fits.Coefficient/1"])
def test_a_v1_name_outside_the_legacy_table_imports_nothing(name: str):
    before = set(sys.modules)
    with pytest.raises(StoreError, match="unknown type"):
        state.decode(blob_of({"format_version": 1, "root": {"$c": name, "f": {}}}))
    assert set(sys.modules) == before


def test_a_v1_legacy_name_decodes():
    node = coefficient_node("rigtool.analysis.fits:Coefficient")
    assert state.decode(blob_of({"format_version": 1, "root": node})).value == 2.0


def test_unknown_and_missing_fields():
    with pytest.raises(StoreError, match="fits.Coefficient/1 has no field 'colour'"):
        state.decode(blob_of({"format_version": 2, "root": coefficient_node(colour="red")}))
    legacy = coefficient_node("rigtool.analysis.fits:Coefficient", colour="red")
    assert state.decode(blob_of({"format_version": 1, "root": legacy})).value == 2.0
    node = coefficient_node()
    del node["f"]["unit"]
    with pytest.raises(StoreError, match="fits.Coefficient/1 lacks field 'unit'"):
        state.decode(blob_of({"format_version": 2, "root": node}))


@pytest.mark.parametrize("version", [0, 3, "2", True, None, 2.0])
def test_an_unknown_format_version_is_named(version: Any):
    with pytest.raises(StoreError, match="format .* this rigtool reads 1 and 2: calibrate again"):
        state.decode(blob_of({"format_version": version, "root": None}))


@pytest.mark.parametrize("stored", ["PK", 3, None, [1]])
def test_a_state_that_is_not_a_blob_is_a_store_error(stored: Any):
    with pytest.raises(StoreError, match="not a blob"):
        state.decode(stored)


def test_plain_values_round_trip():
    obj = {"a": (1, 2.5, None, True), 3.5: [np.arange(4), np.array(["x", "yz"])],
           "o": np.array([Coefficient("C", 1.0, 0.0, 2.0, "N"), None], dtype=object),
           "f": np.asfortranarray(np.arange(6.0).reshape(2, 3)), "s": np.float32(2.5)}
    back = state.decode(state.encode(obj))
    assert back.keys() == obj.keys() and back["a"] == obj["a"] and back["s"] == 2.5
    np.testing.assert_array_equal(back[3.5][1], obj[3.5][1])
    np.testing.assert_array_equal(back["f"], obj["f"])
    assert back["o"].dtype == object and back["o"][0].value == 1.0 and back["o"][1] is None
    back["f"][0, 0] = 9.0  # arrays come back writable


@pytest.mark.parametrize("obj", [np.zeros(2, dtype="datetime64[s]"), np.zeros(2, dtype="S3"),
                                 np.zeros(2, dtype=[("a", "f8")]), {1, 2}, object()])
def test_what_decode_would_refuse_is_not_encoded(obj: Any):
    with pytest.raises(TypeError, match="cannot store"):
        state.encode(obj)


def test_encode_refuses_a_tree_deeper_than_decode_reads():
    deep: Any = 1
    for _ in range(state.MAX_DEPTH + 1):
        deep = [deep]
    with pytest.raises(StoreError, match="deeper than"):
        state.encode(deep)
    deep = deep[0]
    assert state.decode(state.encode(deep)) == deep


# -- nothing is imported by name ------------------------------------------------------------
IMPORT_BY_NAME = re.compile(r"\bimportlib\b|\b__import__\b|\bimport_module\b")
# Modules allowed to use these, each with the reason; none applies them to stored data.
ALLOWED_IMPORT_BY_NAME: dict[str, str] = {
    "rigtool/devices/registry.py": "a fixed table of driver names to rigtool modules, read from "
                                   "the validated rig file's `driver:` name only",
}


def test_no_module_imports_by_name_from_stored_data():
    package = Path(rigtool.__file__).parent
    for path in (package / "artefacts" / "state.py", package / "artefacts" / "state_types.py"):
        assert not IMPORT_BY_NAME.search(path.read_text()), path
    users = {str(p.relative_to(package.parent)) for p in package.rglob("*.py")
             if IMPORT_BY_NAME.search(p.read_text())}
    assert users == set(ALLOWED_IMPORT_BY_NAME)


def _shorter(cal):
    sec = cal.sections[0]
    points = dataclasses.replace(sec.points, command=sec.points.command[:-3])
    return dataclasses.replace(cal, sections=[dataclasses.replace(sec, points=points)])


def _text_commands(cal):
    sec = cal.sections[0]
    text = np.array(["=1+1"] * sec.points.command.size)
    points = dataclasses.replace(sec.points, command=text)
    return dataclasses.replace(cal, sections=[dataclasses.replace(sec, points=points)])


WELL_TYPED_BUT_BROKEN = {
    "no section": lambda cal: dataclasses.replace(cal, sections=[]),
    "a short column": _shorter,
    "text commands": _text_commands,
    "a huge neutral": lambda cal: dataclasses.replace(cal, neutral_command=10.0**300),
    "a negative diameter": lambda cal: dataclasses.replace(cal, propeller_diameter_m=-1e308),
}


@pytest.mark.parametrize("case", WELL_TYPED_BUT_BROKEN, ids=str)
def test_well_typed_but_inconsistent_states_are_refused(calibrated, tmp_path, capsys, case):
    """Field types right, contents unusable: report, export-cal and the API refuse with one
    line (exit 2) instead of failing inside the readers."""
    import rigtool
    from rigtool.errors import DataError

    db = tmp_path / "db.sqlite"
    db.write_bytes(calibrated.read_bytes())
    results = state.decode(_stored_state(db))
    results["calibration"] = WELL_TYPED_BUT_BROKEN[case](results["calibration"])
    conn = sqlite3.connect(db)
    with conn:
        conn.execute("UPDATE calibrations SET state = ?", (state.encode(results),))
    conn.close()
    for argv in (["report", "last"], ["export-cal", "last", "--format", "c-header"]):
        assert main([*argv, "--db", str(db), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert "is inconsistent" in err and "Traceback" not in err and len(err.splitlines()) == 1
    lab = rigtool.open(db)
    with pytest.raises(DataError, match="is inconsistent"):
        lab.calibration(lab.run("last"))
