"""Column mapping of an imported table: which column is what, units, CSV dialect (YAML or --col)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rigtool.accuracy import SensorAccuracy
from rigtool.config import load_model
from rigtool.errors import UsageError
from rigtool.importers.units import KNOWN_COMMAND_UNITS

FIELDS = ("time", "command", "thrust", "speed", "current", "voltage", "depth", "supply",
          "thrust_std", "n_samples", "torque", "temperature")
FORMATS = ("auto", "timeseries", "points", "steps", "ramp")
# Characters a delimiter may not be: the quote, line ends, and what numbers are written with.
NOT_DELIMITERS = frozenset('"\r\n0123456789.+-eE')
# Mapping field -> the command-line option that sets it, to name it in errors.
OPTIONS = {"columns": "--col", "units": "--unit", "command_unit": "--command-unit",
           "neutral": "--neutral", "format": "--format", "delimiter": "--delimiter",
           "decimal": "--decimal-comma", "settle_s": "--settle-s", "thrust_sign": "--flip-thrust",
           "pole_pairs": "--pole-pairs", "sensor_accuracy": "--sensor-accuracy"}
# --sensor-accuracy keys -> SensorAccuracy fields
ACCURACY_OPTION = {"nonlinearity": "nonlinearity_pct_fs", "hysteresis": "hysteresis_pct_fs",
                   "crosstalk": "crosstalk_pct_fs", "full_scale": "full_scale_n"}
MAX_COLUMN_DIGITS = 6


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Columns(_Strict):
    """Header name (with or without its unit suffix, case-insensitive) or 1-based column number."""

    time: str | int | None = None
    command: str | int | None = None
    thrust: str | int | None = None
    speed: str | int | None = None
    current: str | int | None = None
    voltage: str | int | None = None
    depth: str | int | None = None
    supply: str | int | None = None  # supply voltage set (a voltage sweep); `voltage` is measured
    thrust_std: str | int | None = None
    n_samples: str | int | None = None
    torque: str | int | None = None  # about the thrust axis: C_q (right-hand about forward thrust)
    temperature: str | int | None = None  # kept per point (a `temperature` event), not fitted


class Units(_Strict):
    """Units of mapped columns; they override a unit suffix in the header."""

    time: str | None = None
    thrust: str | None = None
    speed: str | None = None
    current: str | None = None
    voltage: str | None = None
    depth: str | None = None
    supply: str | None = None
    thrust_std: str | None = None
    torque: str | None = None
    temperature: str | None = None


class Mapping(_Strict):
    """How to read one table into a run (the YAML file given to `rigtool import --mapping`)."""

    rigtool_mapping: Literal[1] = 1
    columns: Columns = Field(default_factory=Columns)
    units: Units = Field(default_factory=Units)
    command_unit: str | None = None
    neutral: float | None = Field(default=None, allow_inf_nan=False)
    format: Literal["auto", "timeseries", "points", "steps", "ramp"] = "auto"
    delimiter: str | None = None
    decimal: Literal[".", ","] = "."
    header_row: int | None = Field(default=None, ge=1)
    settle_s: float = Field(default=0.0, ge=0, allow_inf_nan=False)
    thrust_sign: Literal[1, -1] = 1
    pole_pairs: int | None = Field(default=None, ge=1)
    # the force sensor's datasheet accuracy, % of full scale (docs/protocols.md)
    sensor_accuracy: SensorAccuracy | None = None

    @field_validator("delimiter")
    @classmethod
    def _one_char(cls, v: str | None) -> str | None:
        if v is not None and v not in ("\t", "tab") and len(v) != 1:
            raise ValueError("delimiter must be one character (or 'tab')")
        if v is not None and v in NOT_DELIMITERS:
            raise ValueError(f"{v!r} cannot be the delimiter (quote, line end, or part of numbers)")
        return "\t" if v == "tab" else v

    @field_validator("command_unit")
    @classmethod
    def _known_unit(cls, v: str | None) -> str | None:
        """A misspelt unit would import and then fit no command curve, saying nothing."""
        if v is not None and v not in KNOWN_COMMAND_UNITS:
            raise ValueError(f"unknown command unit; known: {' | '.join(KNOWN_COMMAND_UNITS)}")
        return v

    @model_validator(mode="after")
    def _delimiter_not_decimal(self) -> Mapping:
        """A delimiter equal to the decimal mark would split every number in two."""
        if self.delimiter is not None and self.delimiter == self.decimal:
            raise ValueError(f"delimiter {self.delimiter!r} is also the decimal mark")
        return self


def load_mapping(path: str | Path) -> Mapping:
    """Read and validate a mapping YAML file; errors name file, line and field."""
    model, _ = load_model(Path(path), Mapping)
    return model


def _pairs(items: list[str] | None, option: str, allowed: tuple[str, ...]) -> dict[str, str]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not value.strip():
            raise UsageError(f"{option} {item!r}: expected FIELD=VALUE, e.g. {option} thrust=Fz")
        if key not in allowed:
            raise UsageError(f"{option} {item!r}: unknown field {key!r}; known: {', '.join(allowed)}")
        out[key] = value.strip()
    return out


def accuracy_option(text: str | None) -> dict[str, str] | None:
    """`--sensor-accuracy nonlinearity=0.25,hysteresis=0.25,crosstalk=1.5,full_scale=100`
    (% of full scale; full scale in N) as SensorAccuracy fields (None: not given)."""
    if text is None:
        return None
    pairs = _pairs([p for p in text.split(",") if p.strip()], "--sensor-accuracy",
                   tuple(ACCURACY_OPTION))
    if not pairs:
        raise UsageError(f"--sensor-accuracy {text!r}: expected KEY=VALUE pairs, e.g. "
                         "nonlinearity=0.25,hysteresis=0.25,crosstalk=1.5,full_scale=100")
    return {ACCURACY_OPTION[k]: v for k, v in pairs.items()}


def with_overrides(base: Mapping, *, cols: list[str] | None = None,
                   units: list[str] | None = None, **options: object) -> Mapping:
    """`base` with command-line --col/--unit pairs and other options (None = keep) applied."""
    col_map = {k: _column_ref(k, v) for k, v in _pairs(cols, "--col", FIELDS).items()}
    unit_map = _pairs(units, "--unit", tuple(Units.model_fields))
    update: dict[str, object] = {k: v for k, v in options.items() if v is not None}
    data = base.model_dump()
    data["columns"].update(col_map)
    data["units"].update(unit_map)
    data.update(update)
    try:
        return Mapping.model_validate(data)
    except ValidationError as exc:
        raise UsageError(_options_error(exc, update)) from None


def _column_ref(fld: str, value: str) -> str | int:
    """A --col value: a 1-based column number (ASCII digits) or a header name."""
    if not (value.isascii() and value.isdigit()):
        return value
    if len(value) > MAX_COLUMN_DIGITS:
        raise UsageError(f"--col {fld}=<{len(value)} digits>: column number out of range")
    return int(value)


def _options_error(exc: ValidationError, given: dict[str, object]) -> str:
    """Name the command-line option behind each problem, with the value given."""
    lines = []
    for e in exc.errors():
        loc = [str(x) for x in e["loc"]]
        option = OPTIONS.get(loc[0], "--" + loc[0].replace("_", "-")) if loc else "--delimiter"
        shown = f" {given[loc[0]]!r}" if loc and loc[0] in given else ""
        where = f" ({'.'.join(loc[1:])})" if len(loc) > 1 else ""
        lines.append(f"{option}{shown}{where}: {e['msg'].removeprefix('Value error, ')}")
    return "\n".join(lines or [str(exc)])
