"""The stored form of a calibration: analysis results as one blob, so `report` and the Python
API use what `calibrate` found instead of recomputing it.

A blob is a zip: `tree.json` describes the object tree and each numpy array is its own .npy
entry. Decoding never unpickles; it rebuilds only dataclasses
defined in rigtool modules, by calling their constructors with the stored fields.
"""

from __future__ import annotations

import dataclasses
import importlib
import io
import json
import zipfile
from typing import Any

import numpy as np

from rigtool.errors import StoreError

FORMAT_VERSION = 1
_TREE = "tree.json"


def encode(obj: Any) -> bytes:
    """`obj` (dataclasses, numpy arrays, dicts, lists, tuples, scalars) as a blob."""
    arrays: list[np.ndarray] = []
    tree = {"format_version": FORMAT_VERSION, "root": _enc(obj, arrays)}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        zf.writestr(_TREE, json.dumps(tree))
        for i, a in enumerate(arrays):
            with zf.open(f"{i}.npy", "w") as fh:
                np.save(fh, a, allow_pickle=False)
    return buf.getvalue()


def decode(blob: bytes) -> Any:
    """The object a blob of `encode` holds. StoreError if the blob is not one."""
    try:
        with zipfile.ZipFile(io.BytesIO(blob)) as zf:
            tree = json.loads(zf.read(_TREE))
            if tree.get("format_version") != FORMAT_VERSION:
                raise StoreError(f"stored calibration has format {tree.get('format_version')!r}"
                                 f", this rigtool reads {FORMAT_VERSION}: calibrate again")
            n = len([name for name in zf.namelist() if name.endswith(".npy")])
            arrays = [np.load(io.BytesIO(zf.read(f"{i}.npy")), allow_pickle=False)
                      for i in range(n)]
        return _dec(tree["root"], arrays)
    except (zipfile.BadZipFile, KeyError, ValueError, TypeError, ImportError,
            AttributeError) as exc:
        raise StoreError(f"stored calibration is unreadable ({exc}): calibrate again") from exc


def _enc(obj: Any, arrays: list[np.ndarray]) -> Any:
    if obj is None or isinstance(obj, str | bool | int | float):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "O":
            return {"$o": [_enc(v, arrays) for v in obj.tolist()]}
        arrays.append(obj)
        return {"$a": len(arrays) - 1}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        cls = type(obj)
        fields = {f.name: _enc(getattr(obj, f.name), arrays) for f in dataclasses.fields(obj)}
        return {"$c": f"{cls.__module__}:{cls.__qualname__}", "f": fields}
    if isinstance(obj, tuple):
        return {"$t": [_enc(v, arrays) for v in obj]}
    if isinstance(obj, list):
        return [_enc(v, arrays) for v in obj]
    if isinstance(obj, dict):
        return {"$d": [[_enc(k, arrays), _enc(v, arrays)] for k, v in obj.items()]}
    raise TypeError(f"cannot store a {type(obj).__name__} in a calibration state")


def _dec(node: Any, arrays: list[np.ndarray]) -> Any:
    if isinstance(node, list):
        return [_dec(v, arrays) for v in node]
    if not isinstance(node, dict):
        return node
    if "$a" in node:
        return arrays[node["$a"]]
    if "$o" in node:
        out = np.empty(len(node["$o"]), dtype=object)
        out[:] = [_dec(v, arrays) for v in node["$o"]]
        return out
    if "$t" in node:
        return tuple(_dec(v, arrays) for v in node["$t"])
    if "$d" in node:
        return {_dec(k, arrays): _dec(v, arrays) for k, v in node["$d"]}
    cls = _dataclass(node["$c"])
    values = {k: _dec(v, arrays) for k, v in node["f"].items()}
    fields = {f.name: f for f in dataclasses.fields(cls)}
    obj = cls(**{k: v for k, v in values.items() if k in fields and fields[k].init})
    for k, v in values.items():
        if k in fields and not fields[k].init:
            object.__setattr__(obj, k, v)
    return obj


def _dataclass(name: str) -> type:
    """The rigtool dataclass `module:qualname` names; nothing else is ever constructed."""
    module, _, qualname = name.partition(":")
    if module != "rigtool" and not module.startswith("rigtool."):
        raise ValueError(f"stored class {name!r} is not rigtool's")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise ValueError(f"stored class {name!r} is not a rigtool dataclass")
    return obj
