"""Load YAML config files into pydantic models with errors that name file, line and field."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from rigtool.errors import ConfigError
from rigtool.files import MAX_CONFIG_BYTES, read_regular_text

M = TypeVar("M", bound=BaseModel)
Loc = tuple[Any, ...]
MAX_NESTING = 50  # YAML collections inside collections; deeper is refused, not recursed into


class _LineLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (a silent overwrite would change an experiment),
    aliases (`*name`: recursive or exponential documents are not worth the risk) and
    nesting deeper than MAX_NESTING (PyYAML composes recursively)."""

    def compose_node(self, parent, index):  # noqa: ANN001, ANN201 - PyYAML's signature
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, f"YAML aliases (*{event.anchor}) are not supported in rigtool files",
                event.start_mark)
        depth = getattr(self, "_depth", 0)
        if depth >= MAX_NESTING and self.check_event(yaml.CollectionStartEvent):
            raise yaml.composer.ComposerError(
                None, None, f"nested more than {MAX_NESTING} levels deep", self.peek_event().start_mark)
        self._depth = depth + 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth = depth


def _construct_number(loader: _LineLoader, node: yaml.ScalarNode, kind: str) -> Any:
    """An int or float scalar; a value Python refuses (an int of 5000 digits) names its line."""
    construct = getattr(yaml.constructor.SafeConstructor, f"construct_yaml_{kind}")
    try:
        return construct(loader, node)
    except ValueError as exc:
        raise yaml.constructor.ConstructorError(
            None, None, f"number out of range ({' '.join(str(exc).split()[:8])}...)",
            node.start_mark) from None


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, str | int | float | bool) and key is not None:
            raise yaml.constructor.ConstructorError(
                None, None, f"keys must be plain names, not {type(key).__name__}", key_node.start_mark)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (first at line {seen[key]})", key_node.start_mark
            )
        seen[key] = key_node.start_mark.line + 1
    return loader.construct_mapping(node, deep=deep)


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_LineLoader.add_constructor("tag:yaml.org,2002:int", lambda ld, n: _construct_number(ld, n, "int"))
_LineLoader.add_constructor("tag:yaml.org,2002:float", lambda ld, n: _construct_number(ld, n, "float"))


class FieldError(ValueError):
    """A ValueError raised by a model validator that names the field it concerns, so that the
    message points at that field's line (`loc` is relative to the model being validated)."""

    def __init__(self, loc: Loc, message: str) -> None:
        super().__init__(message)
        self.loc = tuple(loc)


def _line_map(node: yaml.Node, loc: Loc, out: dict[Loc, int]) -> None:
    """Record the 1-based line of every key and item, keyed by its path."""
    out.setdefault(loc, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = key_node.value
            out[(*loc, key)] = key_node.start_mark.line + 1
            _line_map(value_node, (*loc, key), out)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _line_map(item, (*loc, i), out)


def read_yaml(path: Path) -> tuple[Any, dict[Loc, int]]:
    """Parse `path`; return the data and a path -> line map. Errors name file and line.

    Only a regular UTF-8 file of at most MAX_CONFIG_BYTES is read (files.py).
    """
    text = read_regular_text(path, MAX_CONFIG_BYTES)
    lines: dict[Loc, int] = {}
    try:
        loader = _LineLoader(text)  # its reader already refuses characters YAML does not allow
        try:
            # Parsed once: the data and the line map from the same nodes (the data first: it
            # refuses the keys that the map could not hold, such as a list).
            node = loader.get_single_node()
            if node is None:
                return None, lines
            data = loader.construct_document(node)
            _line_map(node, (), lines)
            return data, lines
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise ConfigError([f"{where}: YAML syntax error: {problem}"]) from None


def _line_for(loc: Loc, lines: dict[Loc, int]) -> int | None:
    for end in range(len(loc), -1, -1):
        if loc[:end] in lines:
            return lines[loc[:end]]
    return None


def _clean_loc(loc: Loc, data: Any) -> Loc:
    """Drop pydantic's union-tag entries so the location is a path into the YAML data."""
    out: list[Any] = []
    node = data
    for part in loc:
        if isinstance(node, dict) and part in node or isinstance(node, list) and isinstance(part, int) and part < len(node):
            out.append(part)
            node = node[part]
        elif isinstance(node, dict) and isinstance(part, str) and not any(
            c in part for c in "[]()-,"
        ):
            out.append(part)
            node = None
    return tuple(out)


def format_validation_error(path: Path, exc: ValidationError, data: Any, lines: dict[Loc, int],
                            prefix: Loc = ()) -> list[str]:
    """Turn pydantic errors into `file:line: field: problem` lines."""
    problems = []
    for err in exc.errors():
        named = getattr(err.get("ctx", {}).get("error"), "loc", ())
        loc = _clean_loc((*err["loc"], *named), data)
        full = (*prefix, *loc)
        line = _line_for(full, lines)
        field = ".".join(str(p) for p in full) or "(top level)"
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; unknown fields are not ignored)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        elif "input" in err and err["type"] != "model_type" and not isinstance(err["input"], dict):
            msg = f"{msg} (got {_shown(err['input'])})"
        problems.append(f"{path}:{line or '?'}: {field}: {msg}")
    return problems


def _shown(value: Any, limit: int = 80) -> str:
    """A value as an error shows it: its repr, cut to `limit` characters (a whole mapping is
    never shown: the field and line already say where)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def locate(path: Path, loc: Loc) -> str:
    """`file:line` of the field at `loc` (or of its nearest parent given), for errors found
    after loading; `file:?` when the file can no longer be read."""
    try:
        _, lines = read_yaml(path)
    except ConfigError:
        lines = {}
    return f"{path}:{_line_for(loc, lines) or '?'}"


_GONE = object()


def _child(value: Any, key: Any) -> Any:
    """What a validated model, mapping or sequence holds under the file's `key` (_GONE where a
    validator reshaped it)."""
    if isinstance(value, BaseModel):
        known = key in type(value).model_fields or key in (value.model_extra or {})
        return getattr(value, key, _GONE) if isinstance(key, str) and known else _GONE
    if isinstance(value, dict):
        return value.get(key, _GONE)
    if isinstance(value, list | tuple) and isinstance(key, int) and key < len(value):
        return value[key]
    return _GONE


def coerced_values(data: Any, value: Any, loc: Loc = ()) -> list[Loc]:
    """Where the file's value is not the kind the model kept: true/false where the model holds
    something else (pydantic's lax mode reads `true` as 1, so `step: true` would sweep in steps
    of one), or a quoted text where it holds a number ('10')."""
    if isinstance(data, bool):
        return [] if value is _GONE or isinstance(value, bool) else [loc]
    if isinstance(data, str):
        number = isinstance(value, int | float) and not isinstance(value, bool)
        return [loc] if number else []
    if isinstance(data, dict):
        items = data.items()
    elif isinstance(data, list):
        items = enumerate(data)
    else:
        return []
    return [bad for key, item in items
            for bad in coerced_values(item, _child(value, key), (*loc, key))]


def coerced_problem(raw: Any) -> str:
    """What is wrong with a value coerced_values found."""
    if isinstance(raw, bool):
        return (f"{str(raw).lower()} is not a value of this field (true/false, yes/no and on/off "
                "only fit yes/no fields; write a number or name)")
    return f"{raw!r} is text where a number belongs (write the number without quotes)"


def load_model(path: Path, model: type[M], context: dict | None = None) -> tuple[M, dict]:
    """Read `path` and validate it as `model`; return the model and the raw data.

    true/false are refused wherever the model wants something else (a number, a name), and
    quoted numbers wherever it wants a number: the file says what it means."""
    data, lines = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError([f"{path}:1: expected a mapping of fields at the top level"])
    try:
        checked = model.model_validate(data, context=context)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(path, exc, data, lines)) from None
    coerced = coerced_values(data, checked)
    if coerced:
        raise ConfigError([
            f"{path}:{_line_for(loc, lines) or '?'}: {'.'.join(str(p) for p in loc)}: "
            f"{coerced_problem(_at(data, loc))}" for loc in coerced])
    return checked, data


def _at(data: Any, loc: Loc) -> Any:
    """The raw value at `loc`."""
    for key in loc:
        data = data[key]
    return data
