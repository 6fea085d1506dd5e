"""ROS 2 parameter files: values in YAML flow style that rclcpp's parser reads back as the
same type, and never an empty list (rclcpp cannot type one; such a key is left out)."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence

from rigtool.artefacts.encode import yaml_string

Value = str | float | int | bool | Sequence[float] | Sequence[str]


def yaml_float(x: float) -> str:
    """`x` as PyYAML writes a float (.nan, .inf, a point before any exponent): a float again."""
    if not math.isfinite(x):
        return ".nan" if math.isnan(x) else (".inf" if x > 0 else "-.inf")
    text = repr(float(x))
    return text.replace("e", ".0e", 1) if "." not in text and "e" in text else text


def yaml_value(value: Value) -> str:
    """A parameter value: text through yaml_string, booleans, integers, floats, lists."""
    if isinstance(value, str):
        return yaml_string(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, Sequence):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    return yaml_float(float(value))


def yaml_entries(params: Mapping[str, Value], indent: str) -> str:
    """`key: value` lines; an empty list is left out; a list of numbers wraps at 100
    columns, text never."""
    lines = []
    for key, value in params.items():
        if isinstance(value, Sequence) and not isinstance(value, str) and not len(value):
            continue
        line = f"{indent}{key}: {yaml_value(value)}"
        if isinstance(value, Sequence) and not isinstance(value, str):
            line = textwrap.fill(line, width=100, subsequent_indent=indent + "  ",
                                 break_long_words=False, break_on_hyphens=False)
        lines.append(line + "\n")
    return "".join(lines)


def comment(lines: Sequence[str]) -> str:
    """YAML comment lines (callers pass no stored text)."""
    return "".join(f"# {line}\n" for line in lines)
