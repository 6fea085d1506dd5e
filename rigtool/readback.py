"""Checks on everything rigtool reads back: bounded JSON, value shapes and caps.

A run database, a merge source or a calibration folder may be damaged, hand-edited or
crafted. Every JSON text is size-capped and counted before it is parsed, every parsed
document is walked with a depth limit and checked against the shape its readers use, and
every stored column value is checked for its type and range. A failed check raises
`Invalid`, whose message names the field; the caller adds the file or run.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from rigtool.spool import SAMPLES_PER_CHUNK
from rigtool.units import THRUST_LAWS

MAX_JSON_DEPTH = 64  # nesting of any stored or read-back JSON document
MAX_JSON_BYTES = 16 << 20  # one JSON field or calibration.json
MAX_PLAN_JSON_BYTES = 128 << 20  # a run's plan: about 80 bytes per point
MAX_JSON_CONTAINERS = 2_000_000  # `{` and `[` in one document, counted before parsing
MAX_JSON_SEPARATORS = 16_000_000  # `,` in one document (about the number of values)
MAX_TEXT = 64 << 10  # a text column (names, reasons, paths, timestamps)
MAX_ID_TEXT = 256  # run ids, statuses, units, directions, event kinds
MAX_STORED_POINTS = 1_000_000  # points of one run (protocols allow 100 000; imports more)
MAX_STORED_EVENTS = 1_000_000  # events of one run
MAX_EVENT_BYTES = 256 << 20  # detail JSON of all of one run's events
MAX_STORED_CALIBRATIONS = 10_000  # calibration records of one run
MAX_MERGE_RUNS = 100_000  # runs of one merge source
MAX_STATE_BYTES = 64 << 20  # one stored calibration state blob
MAX_SAMPLES_PER_POINT = 100_000_000  # as rigtool.bounds (not imported: it needs pydantic)
MAX_COMMAND = 1e10  # as rigtool.bounds
MAX_SEED = 2**32 - 1  # as rigtool.bounds
MAX_BLOCK_BYTES = SAMPLES_PER_CHUNK * 8  # one float64 column block
MAX_CHUNK = MAX_SAMPLES_PER_POINT // SAMPLES_PER_CHUNK + 1  # highest block number of a point
MAX_NUMBER_TEXT = 64  # characters of a stored number written as text (24 at most)
MAX_PID = 2**31 - 1
INT64 = 2**63
_SHOWN = 40


class Invalid(ValueError):
    """A read-back value is not what rigtool wrote; the message names the field (the path
    into a JSON document is added as the error leaves each level)."""

    def __init__(self, problem: str, path: tuple[str | int, ...] = ()) -> None:
        super().__init__(problem)
        self.problem = problem
        self.path = path

    def at(self, key: str | int) -> Invalid:
        """The same problem, one level further out (inside `key`)."""
        return Invalid(self.problem, (key, *self.path))

    def __str__(self) -> str:
        where = "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in self.path)
        return f"{where.lstrip('.')}: {self.problem}" if where else self.problem


def show(value: object) -> str:
    """A short, one-line description of a bad value for an error message."""
    if isinstance(value, bytes | bytearray | memoryview):
        return f"a {len(value):,}-byte blob"
    if isinstance(value, dict | list):
        return f"a JSON {'object' if isinstance(value, dict) else 'array'}"
    text = repr(value)
    return text if len(text) <= _SHOWN else f"{text[:_SHOWN - 5]}...{text[-1]}"


def brief(exc: BaseException | str, limit: int = 200) -> str:
    """An exception or text on one line, cut to `limit` characters."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


# -- JSON -------------------------------------------------------------------------------------

def parse_json(text: object, max_chars: int = MAX_JSON_BYTES) -> Any:
    """`text` parsed as JSON, refused before parsing if too long or holding too many values."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise Invalid(f"not UTF-8 text (byte 0x{text[exc.start]:02x} at offset "
                          f"{exc.start})") from None
    if not isinstance(text, str):
        raise Invalid(f"expected JSON text, found {show(text)}")
    if len(text) > max_chars:
        raise Invalid(f"{len(text):,} characters of JSON; the limit is {max_chars:,}")
    if text.count("{") + text.count("[") > MAX_JSON_CONTAINERS:
        raise Invalid(f"more than {MAX_JSON_CONTAINERS:,} JSON objects and arrays")
    if text.count(",") > MAX_JSON_SEPARATORS:
        raise Invalid(f"more than {MAX_JSON_SEPARATORS:,} JSON values")
    try:
        return json.loads(text)
    except RecursionError:
        raise Invalid(f"JSON nested more than {MAX_JSON_DEPTH} levels") from None
    except ValueError as exc:
        raise Invalid(f"not valid JSON ({exc})") from None


def parse_document(text: object, shape: Shape, max_chars: int = MAX_JSON_BYTES) -> Any:
    """`text` parsed as JSON and checked against `shape` (depth included)."""
    value = parse_json(text, max_chars)
    shape.check(value)
    return value


# -- shapes -----------------------------------------------------------------------------------

def _deeper(depth: int) -> int:
    """One level further down a JSON document; Invalid past MAX_JSON_DEPTH."""
    if depth >= MAX_JSON_DEPTH:
        raise Invalid(f"JSON nested more than {MAX_JSON_DEPTH} levels")
    return depth + 1


class Shape:
    """What a parsed JSON value must look like; `check` raises Invalid naming the path."""

    def check(self, value: Any, depth: int = 0) -> None:
        """Raise Invalid unless `value` (`depth` levels down) fits."""
        raise NotImplementedError


class _Anything(Shape):
    """Any JSON value, walked without recursion to enforce the depth limit."""

    def check(self, value: Any, depth: int = 0) -> None:
        """Refuse only nesting deeper than MAX_JSON_DEPTH."""
        stack = [(value, depth)]
        while stack:
            item, level = stack.pop()
            if isinstance(item, dict | list):
                level = _deeper(level)
                stack.extend((v, level) for v in (item.values() if isinstance(item, dict)
                                                   else item))


_KINDS = {"string": (str,), "integer": (int,), "number": (int, float), "finite": (int, float),
          "positive": (int, float), "scalar": (str, int, float, bool)}
_NAMES = {"string": "a string", "integer": "an integer", "number": "a number",
          "finite": "a finite number", "positive": "a finite number above 0",
          "scalar": "a string or number"}


@dataclass(frozen=True)
class _Scalar(Shape):
    """A JSON string, integer, number or scalar of any of these kinds."""

    kind: str

    def check(self, value: Any, depth: int = 0) -> None:
        """Refuse a value of another kind, or an integer outside int64 range."""
        if not isinstance(value, _KINDS[self.kind]) or (
                isinstance(value, bool) and self.kind != "scalar"):
            raise Invalid(f"expected {_NAMES[self.kind]}, found {show(value)}")
        if isinstance(value, int) and not -INT64 <= value < INT64:
            raise Invalid(f"integer {show(value)} is out of range")
        if self.kind in ("finite", "positive") and not math.isfinite(value) or (
                self.kind == "positive" and not value > 0):
            raise Invalid(f"expected {_NAMES[self.kind]}, found {show(value)}")


@dataclass(frozen=True)
class Opt(Shape):
    """null, or a value of `inner`."""

    inner: Shape

    def check(self, value: Any, depth: int = 0) -> None:
        """Accept None; check anything else against `inner`."""
        if value is not None:
            self.inner.check(value, depth)


@dataclass(frozen=True)
class ListOf(Shape):
    """A JSON array whose items all fit `item`."""

    item: Shape

    def check(self, value: Any, depth: int = 0) -> None:
        """Refuse a non-array or any misfit item."""
        if not isinstance(value, list):
            raise Invalid(f"expected an array, found {show(value)}")
        level = _deeper(depth)
        for i, v in enumerate(value):
            try:
                self.item.check(v, level)
            except Invalid as exc:
                raise exc.at(i) from None


@dataclass(frozen=True)
class MapOf(Shape):
    """A JSON object whose values all fit `value`."""

    value: Shape

    def check(self, value: Any, depth: int = 0) -> None:
        """Refuse a non-object or any misfit value."""
        if not isinstance(value, dict):
            raise Invalid(f"expected an object, found {show(value)}")
        level = _deeper(depth)
        for k, v in value.items():
            try:
                self.value.check(v, level)
            except Invalid as exc:
                raise exc.at(k) from None


@dataclass(frozen=True)
class Obj(Shape):
    """A JSON object with these fields (those in `required` must be present); any other
    field must fit `rest`."""

    fields: dict[str, Shape]
    required: tuple[str, ...] = ()
    rest: Shape = field(default_factory=_Anything)

    def check(self, value: Any, depth: int = 0) -> None:
        """Refuse a non-object, a missing required field or a misfit field."""
        if not isinstance(value, dict):
            raise Invalid(f"expected an object, found {show(value)}")
        level = _deeper(depth)
        for name in self.required:
            if name not in value:
                raise Invalid(f"field {name!r} is missing")
        for k, v in value.items():
            try:
                self.fields.get(k, self.rest).check(v, level)
            except Invalid as exc:
                raise exc.at(k) from None


@dataclass(frozen=True)
class AnyOf(Shape):
    """A value fitting one of `shapes` (the first one's complaint is reported)."""

    shapes: tuple[Shape, ...]

    def check(self, value: Any, depth: int = 0) -> None:
        """Accept a value any of the shapes accepts."""
        problems = []
        for shape in self.shapes:
            try:
                shape.check(value, depth)
                return
            except Invalid as exc:
                problems.append(exc)
        raise problems[0]


ANY = _Anything()
STR = _Scalar("string")
INT = _Scalar("integer")
NUM = _Scalar("number")
FINITE = _Scalar("finite")  # NaN and Infinity are JSON to json.loads, never written here
POSITIVE = _Scalar("positive")
SCALAR = _Scalar("scalar")

# What the readers of stored runs use (report, analysis, show, export, resume).
METADATA = Obj({"thruster_id": Opt(SCALAR), "propeller_diameter_m": Opt(POSITIVE),
                "water_density_kg_m3": Opt(POSITIVE), "extra": Opt(MapOf(ANY))})
PROTOCOL = Obj({"name": Opt(STR), "description": Opt(STR), "metadata": Opt(METADATA),
                "command": Opt(Obj({"unit": Opt(STR), "neutral": Opt(NUM)}))})
AXIS = Obj({"channel": Opt(SCALAR), "sign": Opt(SCALAR)})
ACCURACY = Obj({k: Opt(FINITE) for k in ("full_scale_n", "nonlinearity_pct_fs",
                                          "hysteresis_pct_fs", "crosstalk_pct_fs")})
RIG = Obj({"name": Opt(STR), "thrust": Opt(AXIS), "sensor_accuracy": Opt(ACCURACY),
           "import": Opt(Obj({"sensor_accuracy": Opt(ACCURACY)})),
           "resolved": Opt(Obj({"kind": Opt(STR), "profile": Opt(SCALAR), "thrust": Opt(AXIS)}))})
PLAN = ListOf(Obj({"idx": INT, "command": FINITE, "depth_m": Opt(FINITE), "repeat": INT,
                   "direction": STR, "voltage_v": Opt(FINITE)}))
ACTUATOR = Obj({"command_unit": STR, "neutral": FINITE, "command_min": FINITE,
                "command_max": FINITE,
                "feedback": Opt(ListOf(STR))},
               required=("command_unit", "neutral", "command_min", "command_max"))
COUNTERS = MapOf(MapOf(NUM))
COEFFICIENT = Obj({"value": Opt(NUM), "lo": Opt(NUM), "hi": Opt(NUM), "unit": Opt(STR),
                   "n": Opt(INT), "r2": Opt(NUM)})
SUMMARY = Obj({
    "depths": Opt(ListOf(Obj({"depth_m": Opt(NUM), "supply_voltage_v": Opt(NUM),
                              "coefficients": Opt(MapOf(COEFFICIENT))}))),
    "voltage_laws": Opt(ListOf(Obj({"depth_m": Opt(NUM), "k": Opt(COEFFICIENT),
                                    "b": Opt(COEFFICIENT), "k_inverse": Opt(COEFFICIENT)}))),
    "analysis": Opt(Obj({"deep_depth_m": Opt(NUM)})),
})
_INTERVAL = Obj({"t_start_s": NUM, "t_end_s": NUM})
EVENT_DETAILS: dict[str, Shape] = {
    "tare": Obj({"bias": Opt(ListOf(Opt(NUM)))}),
    "sim.ventilation": Obj(_INTERVAL.fields, required=("t_start_s", "t_end_s")),
}
EVENT_DETAIL = MapOf(ANY)


# -- stored column values ---------------------------------------------------------------------

@dataclass(frozen=True)
class Column:
    """What one stored column may hold: SQLite type, NULL or not, range, size, JSON shape."""

    kind: str  # "int", "real", "text", "blob" or "json"
    null: bool = False
    lo: float = -math.inf
    hi: float = math.inf
    finite: bool = False
    max_len: int = MAX_TEXT
    shape: Shape | None = None
    choices: tuple[str, ...] = ()

    def check(self, value: Any) -> Any:
        """`value` (JSON parsed), or Invalid saying what is wrong with it."""
        if value is None:
            if self.null:
                return None
            raise Invalid("missing (NULL)")
        if self.kind == "int":
            return self._number(value, int)
        if self.kind == "real":
            return self._number(value, int | float)
        if self.kind == "blob":
            if not isinstance(value, bytes):
                raise Invalid(f"expected a blob, found {show(value)}")
            if len(value) > self.max_len:
                raise Invalid(f"a {len(value):,}-byte blob; the limit is {self.max_len:,}")
            return value
        if not isinstance(value, str):
            raise Invalid(f"expected text, found {show(value)}")
        if self.kind == "json":
            return parse_document(value, self.shape or ANY, self.max_len)
        if len(value) > self.max_len:
            raise Invalid(f"{len(value):,} characters; the limit is {self.max_len:,}")
        if self.choices and value not in self.choices:
            raise Invalid(f"{show(value)} is not one of {', '.join(self.choices)}")
        return value

    def _number(self, value: Any, kind: Any) -> Any:
        """`value` if it is a number of `kind` (bools are not) inside the column's range."""
        if isinstance(value, bool) or not isinstance(value, kind):
            name = "an integer" if kind is int else "a number"
            raise Invalid(f"expected {name}, found {show(value)}")
        if isinstance(value, float) and math.isnan(value) or self.finite and not math.isfinite(
                value):
            raise Invalid(f"{show(value)} is not a finite number")
        if not self.lo <= value <= self.hi:
            raise Invalid(f"{show(value)} is outside {self.lo:g} .. {self.hi:g}")
        return value

    def length_cap(self) -> int:
        """The most characters or bytes the column may hold (a number's as text)."""
        return MAX_NUMBER_TEXT if self.kind in ("int", "real") else self.max_len

    def bad_sql(self, name: str) -> str:
        """SQL true where column `name` holds a value of the wrong type, range or length."""
        terms = [f"typeof({name}) NOT IN ({_SQL_TYPES[self.kind]})",
                 f"length({name}) > {self.length_cap()}"]
        if self.lo > -math.inf:
            terms.append(f"{name} < {self.lo!r}")
        if self.hi < math.inf:
            terms.append(f"{name} > {self.hi!r}")
        if self.finite:
            terms.append(f"{name} IN (9e999, -9e999)")
        if self.choices:
            terms.append(f"{name} NOT IN ({', '.join(repr(c) for c in self.choices)})")
        either = " OR ".join(terms)
        if self.null:
            return f"({name} IS NOT NULL AND ({either}))"
        return f"({name} IS NULL OR {either})"


_SQL_TYPES = {"int": "'integer'", "real": "'integer', 'real'", "text": "'text'",
              "json": "'text'", "blob": "'blob'"}


def _text(max_len: int = MAX_TEXT, null: bool = False) -> Column:
    """A text column of at most `max_len` characters."""
    return Column("text", null=null, max_len=max_len)


def _json(shape: Shape, null: bool = False, max_len: int = MAX_JSON_BYTES) -> Column:
    """A JSON text column whose document must fit `shape`."""
    return Column("json", null=null, shape=shape, max_len=max_len)


_ROWID = Column("int", lo=1, hi=INT64 - 1)
_TIME = Column("real", finite=True)
_STAT = Column("real", null=True, finite=True)  # a point's summary of finite samples

RUN_COLUMNS: dict[str, Column] = {
    "id": _text(MAX_ID_TEXT), "name": _text(), "status": Column(
        "text", max_len=MAX_ID_TEXT,
        choices=("running", "completed", "aborted", "failed", "interrupted")),
    "created_utc": _text(MAX_ID_TEXT), "finished_utc": _text(MAX_ID_TEXT, null=True),
    "tool_version": _text(MAX_ID_TEXT), "host": _text(), "pid": Column("int", lo=0, hi=MAX_PID),
    "seed": Column("int", null=True, lo=0, hi=MAX_SEED), "protocol_path": _text(null=True),
    "protocol_json": _json(PROTOCOL), "rig_json": _json(RIG),
    "plan_json": _json(PLAN, max_len=MAX_PLAN_JSON_BYTES), "metadata_json": _json(METADATA),
    "n_planned": Column("int", lo=0, hi=MAX_STORED_POINTS), "command_unit": _text(MAX_ID_TEXT),
    "stop_reason": _text(null=True), "actuator_json": _json(ACTUATOR, null=True),
    "started_utc": _text(MAX_ID_TEXT, null=True),
}
STEP_COLUMNS: dict[str, Column] = {
    "id": _ROWID, "run_id": _text(MAX_ID_TEXT),
    "idx": Column("int", lo=0, hi=MAX_STORED_POINTS - 1),
    "command": Column("real", finite=True, lo=-MAX_COMMAND, hi=MAX_COMMAND),
    "command_unit": _text(MAX_ID_TEXT), "depth_m": Column("real", null=True, finite=True),
    "repeat": Column("int", lo=0, hi=MAX_PID), "direction": _text(MAX_ID_TEXT),
    "t_start_s": _TIME, "t_acquire_s": _TIME, "t_end_s": _TIME, "settle_s": _TIME,
    "settled": Column("int", lo=0, hi=1), "rate_hz": Column("real", finite=True, lo=0),
    "status": _text(MAX_ID_TEXT), "n": Column("int", lo=0, hi=MAX_SAMPLES_PER_POINT),
    **{f"{ch}_all_{stat}_{u}": _STAT for ch, u in (("thrust", "n"), ("speed", "rpm"),
                                                    ("current", "a"))
       for stat in ("mean", "std", "min", "max")},  # as rigtool.store.records.stat_column
    "counters_json": _json(COUNTERS, null=True, max_len=1 << 20),
    "voltage_set_v": Column("real", null=True, finite=True),
}
EVENT_COLUMNS: dict[str, Column] = {
    "id": _ROWID, "run_id": _text(MAX_ID_TEXT), "t_s": Column("real", null=True, finite=True),
    "kind": _text(MAX_ID_TEXT), "step_idx": Column("int", null=True, lo=-INT64, hi=INT64 - 1),
    "detail_json": _json(EVENT_DETAIL),
}
CALIBRATION_COLUMNS: dict[str, Column] = {
    "id": _ROWID, "run_id": _text(MAX_ID_TEXT), "created_utc": _text(MAX_ID_TEXT),
    "tool_version": _text(MAX_ID_TEXT), "out_dir": _text(), "summary_json": _json(SUMMARY),
    "state": Column("blob", null=True, max_len=MAX_STATE_BYTES),
}


def event_detail(kind: str, detail: Any) -> Any:
    """Check a parsed event detail against the shape its readers expect for `kind`."""
    EVENT_DETAILS.get(kind, EVENT_DETAIL).check(detail)
    return detail


# -- calibration folders ----------------------------------------------------------------------

CALIBRATION_FORMAT = "rigtool-calibration"  # as rigtool.artefacts.calibration.FORMAT
_LAW_TERM = Obj({"value": Opt(NUM)})
VOLTAGE_LAW = Obj({"depth_m": Opt(NUM), "k": _LAW_TERM, "b": _LAW_TERM}, required=("k", "b"))
DYNAMICS_MODEL = Obj({"tau_n": COEFFICIENT, "delay": COEFFICIENT, "tau_a": Opt(COEFFICIENT),
                      "g": Opt(COEFFICIENT)}, required=("tau_n", "delay"),
                     rest=AnyOf((COEFFICIENT, Opt(SCALAR))))
DYNAMICS = Obj({"selected": STR, "models": MapOf(Opt(DYNAMICS_MODEL)),
                "levels": ListOf(Obj({"command": NUM, "thrust_n": Opt(NUM)},
                                     required=("command", "thrust_n")))},
               required=("selected", "models", "levels"))
THRUST_LAW = Obj({"family": STR, "params": MapOf(NUM)}, required=("family", "params"))
CALIBRATION_DOCUMENT = Obj({
    "format": STR, "format_version": INT,
    "source": Opt(Obj({"run_id": Opt(STR), "command_unit": Opt(STR),
                       "neutral_command": Opt(NUM)})),
    "warnings": Opt(ListOf(STR)),
    "depths": Opt(ListOf(Obj({"depth_m": Opt(NUM), "supply_voltage_v": Opt(NUM),
                              "coefficients": Opt(MapOf(COEFFICIENT)),
                              "thrust_law": Opt(MapOf(THRUST_LAW))}))),
    "voltage_laws": Opt(ListOf(VOLTAGE_LAW)), "dynamics": Opt(DYNAMICS),
}, required=("format",))


def calibration_document(document: Any) -> dict:
    """A parsed calibration.json checked against what the API reads from it."""
    CALIBRATION_DOCUMENT.check(document)
    if document["format"] != CALIBRATION_FORMAT:
        raise Invalid(f"format: {show(document['format'])} is not {CALIBRATION_FORMAT!r}")
    for i, depth in enumerate(document.get("depths") or []):
        for key, law in (depth.get("thrust_law") or {}).items():
            need = THRUST_LAWS.get(law["family"])
            if key not in ("fwd", "rev") or need is None or sorted(need) != sorted(law["params"]):
                raise Invalid(f"depths[{i}].thrust_law.{show(key)}: not a known law with its "
                              f"parameters ({show(law['family'])})")
    dynamics = document.get("dynamics")
    if dynamics is not None and dynamics["models"].get(dynamics["selected"]) is None:
        raise Invalid(f"dynamics.selected: no model {show(dynamics['selected'])} in "
                      "dynamics.models")
    return document
