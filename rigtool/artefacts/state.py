"""The stored form of a calibration: analysis results as one blob, so `report` and the Python
API use what `calibrate` found instead of recomputing it.

A blob is a zip: `tree.json` ({"format_version": 2, "root": node}) describes the object tree
and array i is the entry `i.npy`. A node is JSON null, a bool, number or string; a list of
nodes; or an object with exactly one of these forms:

- {"$a": i}: array i (bool, integer, float, complex or unicode; never object or structured);
- {"$o": [nodes]}: a one-dimensional object array;
- {"$t": [nodes]}: a tuple;
- {"$d": [[key, value], ...]}: a dict;
- {"$c": tag, "f": {field: node}}: a dataclass, named by its tag in the closed registry of
  rigtool/artefacts/state_types.py ("steady.PointTable/1"). Format 1 (rigtool 0.1) wrote
  "module:qualname" there instead; a fixed table of those names reads it, and nothing is
  ever looked up or loaded by a name read from a blob.

Decoding never unpickles and constructs only registered classes, from their stored fields:
a field the class does not have is an error (the tag's version promises its field set; in
format 1 it is ignored, as rigtool did when it wrote format 1), a missing field with a
default takes it, a missing field without one is an error.

Everything read back is hostile. Sizes are checked before anything is allocated: the zip's
entry count and central directory, each entry's declared size against the caps below and
against the blob's size (ratio), the tree's size and depth, each .npy header (allowed dtype,
shape times item size equal to the entry's size). Any failure is a one-line StoreError that
says to calibrate again. `encode` refuses (StoreError) what `decode` would refuse.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import math
import struct
import tokenize
import types
import typing
import zipfile
import zlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.lib import format as npy

from rigtool.artefacts import state_types
from rigtool.errors import StoreError

FORMAT_VERSION = 2
READS = (1, 2)
_TREE = "tree.json"

MAX_ENTRIES = 20_000  # zip entries (the largest shipped calibration has 337)
MAX_CENTRAL_DIR = MAX_ENTRIES * 128  # bytes; an entry "19999.npy" takes 55
MAX_TOTAL_BYTES = 256 << 20  # uncompressed, all entries (the largest shipped: 0.5 MB)
RATIO_FLOOR_BYTES = 16 << 20  # below this total no ratio applies
MAX_RATIO = 50  # uncompressed total / blob size above the floor (shipped: 1.4 to 3.5)
MAX_TREE_BYTES = 4 << 20  # tree.json (the largest shipped: 70 kB; JSON costs ~25x in objects)
MAX_DEPTH = 64  # nesting of tree nodes (shipped calibrations: 17)
MAX_NDIM = 32
ARRAY_KINDS = frozenset("biufcU")  # bool, int, uint, float, complex, unicode
_CHUNK = 1 << 20
_EOCD = struct.Struct("<4s4H2LH")  # end of central directory record
_EOCD_SIG = b"PK\x05\x06"
_ZIP64_LOCATOR_SIG = b"PK\x06\x07"
_MARKS = ({"$a"}, {"$o"}, {"$t"}, {"$d"}, {"$c", "f"})
# What zipfile, zlib, json and numpy raise on malformed input, and constructors on bad values.
_MALFORMED = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, TypeError,
              LookupError, ArithmeticError, RuntimeError, struct.error)


class _Bad(Exception):
    """A malformed blob, said in one line; decode turns it into a StoreError."""


def encode(obj: Any) -> bytes:
    """`obj` (registered dataclasses, numpy arrays, dicts, lists, tuples, scalars) as a blob."""
    arrays: list[np.ndarray] = []
    text = json.dumps({"format_version": FORMAT_VERSION, "root": _enc(obj, arrays, 0)})
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        zf.writestr(_TREE, text)
        for i, a in enumerate(arrays):
            with zf.open(f"{i}.npy", "w") as fh:
                np.save(fh, a, allow_pickle=False)
    blob = buf.getvalue()
    try:
        _check_layout(blob)
    except _Bad as exc:
        raise StoreError(f"calibration state cannot be stored: {exc}") from None
    return blob


def decode(blob: bytes) -> Any:
    """The object a blob of `encode` holds. StoreError if the blob is not one."""
    if not isinstance(blob, bytes | bytearray | memoryview):
        raise StoreError(f"stored calibration is a {type(blob).__name__}, not a blob: "
                         "calibrate again")
    try:
        return _decode(bytes(blob))
    except _Bad as exc:
        raise StoreError(f"stored calibration is unreadable ({exc}): calibrate again") from None
    except _MALFORMED as exc:
        raise StoreError(f"stored calibration is unreadable ({_one_line(exc)}): "
                         "calibrate again") from None


def _decode(blob: bytes) -> Any:
    """decode's work; _Bad, StoreError or a _MALFORMED error if the blob is not one."""
    declared = _check_directory(blob)
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        infos = _check_entries(zf.infolist(), declared, len(blob))
        version, root = _read_tree(zf, infos[_TREE])
        arrays = [_read_array(zf, infos[f"{i}.npy"]) for i in range(len(infos) - 1)]
    return _Decoder(arrays, version).node(root, 0)


# -- encoding -------------------------------------------------------------------------------
def _enc(obj: Any, arrays: list[np.ndarray], depth: int) -> Any:
    """The tree node of `obj`; its arrays are appended to `arrays`."""
    if depth > MAX_DEPTH:
        raise StoreError(f"calibration state nests deeper than {MAX_DEPTH}: cannot be stored")
    if obj is None or isinstance(obj, str | bool | int | float):
        return obj
    if isinstance(obj, np.generic):
        return _enc(obj.item(), arrays, depth)
    if isinstance(obj, np.ndarray):
        return _enc_array(obj, arrays, depth)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        tag = state_types.tag_of(type(obj))
        return {"$c": tag, "f": {f.name: _enc(getattr(obj, f.name), arrays, depth + 1)
                                 for f in dataclasses.fields(obj)}}
    if isinstance(obj, tuple):
        return {"$t": [_enc(v, arrays, depth + 1) for v in obj]}
    if isinstance(obj, list):
        return [_enc(v, arrays, depth + 1) for v in obj]
    if isinstance(obj, dict):
        return {"$d": [[_enc(k, arrays, depth + 1), _enc(v, arrays, depth + 1)]
                       for k, v in obj.items()]}
    raise TypeError(f"cannot store a {type(obj).__name__} in a calibration state")


def _enc_array(a: np.ndarray, arrays: list[np.ndarray], depth: int) -> Any:
    """The node of an array: an entry of its own, or its elements for an object array."""
    if a.dtype.kind == "O":
        return {"$o": [_enc(v, arrays, depth + 1) for v in a.tolist()]}
    if a.dtype.kind not in ARRAY_KINDS or a.dtype.fields is not None or a.dtype.itemsize == 0:
        raise TypeError(f"cannot store an array of {a.dtype} in a calibration state")
    arrays.append(a)
    return {"$a": len(arrays) - 1}


# -- the zip --------------------------------------------------------------------------------
def _check_layout(blob: bytes) -> None:
    """_Bad unless the blob's directory, entry names and sizes are within bounds."""
    declared = _check_directory(blob)
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        _check_entries(zf.infolist(), declared, len(blob))


def _check_entries(infos: list[zipfile.ZipInfo], declared: int, blob_size: int
                   ) -> dict[str, zipfile.ZipInfo]:
    """The entries by name, once their count, names and sizes are within bounds."""
    if len(infos) != declared:
        raise _Bad(f"{len(infos)} entries where the archive declares {declared}")
    by_name = {info.filename: info for info in infos}
    expected = {_TREE, *(f"{i}.npy" for i in range(len(infos) - 1))}
    if len(by_name) != len(infos):
        raise _Bad("an entry name repeats")
    if by_name.keys() != expected:
        odd = sorted(by_name.keys() - expected) or sorted(expected - by_name.keys())
        raise _Bad(f"entry {_short(odd[0])} {'unexpected' if odd[0] in by_name else 'missing'}")
    for info in infos:
        _check_entry(info)
    _check_total(sum(info.file_size for info in infos), blob_size)
    return by_name


def _check_directory(blob: bytes) -> int:
    """The entry count the archive declares, once it and the central directory zipfile would
    parse are within bounds."""
    at = _eocd_offset(blob)
    if at < 0:
        raise _Bad("not a zip archive")
    _, disk, _, here, entries, size, _, _ = _EOCD.unpack_from(blob, at)
    if at >= 20 and blob[at - 20:at - 16] == _ZIP64_LOCATOR_SIG:
        raise _Bad("a zip64 archive")
    if disk != 0 or here != entries:
        raise _Bad("a multi-disk archive")
    if not 1 <= entries <= MAX_ENTRIES or size > MAX_CENTRAL_DIR:
        raise _Bad(f"a central directory of {entries} entries in {size} bytes, at most "
                   f"{MAX_ENTRIES} allowed")
    return entries


def _eocd_offset(blob: bytes) -> int:
    """Where zipfile finds the end of central directory record; -1 if nowhere."""
    n = _EOCD.size
    if len(blob) >= n and blob[-n:-n + 4] == _EOCD_SIG and blob[-2:] == b"\0\0":
        return len(blob) - n
    start = max(0, len(blob) - n - (1 << 16))
    at = blob.rfind(_EOCD_SIG, start)
    return at if 0 <= at <= len(blob) - n else -1


def _check_entry(info: zipfile.ZipInfo) -> None:
    """One entry: plain or deflated, not encrypted, its declared sizes within bounds."""
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise _Bad(f"{_short(info.filename)} uses compression method {info.compress_type}")
    if info.flag_bits & 0x1:
        raise _Bad(f"{_short(info.filename)} is encrypted")
    cap = MAX_TREE_BYTES if info.filename == _TREE else MAX_TOTAL_BYTES
    if info.file_size > cap:
        raise _Bad(f"{_short(info.filename)} expands to {info.file_size} bytes, "
                   f"at most {cap} allowed")


def _check_total(total: int, blob_size: int) -> None:
    """The uncompressed total within the absolute cap and the ratio to the blob's size."""
    cap = min(MAX_TOTAL_BYTES, max(RATIO_FLOOR_BYTES, MAX_RATIO * blob_size))
    if total > cap:
        raise _Bad(f"{blob_size} bytes expand to {total}, at most {cap} allowed")


def _read_exact(fh: Any, name: str, size: int) -> Iterator[bytes]:
    """The next `size` bytes of open entry `fh`, in chunks; its end must follow them."""
    left = size
    while left > 0:
        chunk = fh.read(min(_CHUNK, left))
        if not chunk:
            raise _Bad(f"{_short(name)} is truncated")
        left -= len(chunk)
        yield chunk
    if fh.read(1):
        raise _Bad(f"{_short(name)} is longer than declared")


# -- tree.json ------------------------------------------------------------------------------
def _read_tree(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> tuple[int, Any]:
    """(format version, root node) of tree.json."""
    with zf.open(info) as fh:
        text = b"".join(_read_exact(fh, info.filename, info.file_size))
    try:
        tree = json.loads(text)
    except RecursionError:
        raise _Bad(f"tree nests deeper than {MAX_DEPTH}") from None
    if not isinstance(tree, dict) or tree.keys() != {"format_version", "root"}:
        raise _Bad("tree.json is not a state tree")
    version = tree["format_version"]
    if type(version) is not int or version not in READS:
        raise StoreError(f"stored calibration has format {_short(version)}, this rigtool "
                         f"reads {' and '.join(map(str, READS))}: calibrate again")
    return version, tree["root"]


# -- arrays ---------------------------------------------------------------------------------
def _read_array(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    """Array entry `info`, its header checked against its size before allocation."""
    with zf.open(info) as fh:
        shape, fortran, dtype = _npy_header(fh, info.filename)
        size = info.file_size - fh.tell()
        count = math.prod(shape)
        if count * dtype.itemsize != size:
            raise _Bad(f"{info.filename} declares {shape} of {dtype} in {size} bytes")
        buf = bytearray(size)
        view, pos = memoryview(buf), 0
        for chunk in _read_exact(fh, info.filename, size):
            view[pos:pos + len(chunk)] = chunk
            pos += len(chunk)
    flat = np.frombuffer(buf, dtype=dtype, count=count)
    return flat.reshape(shape, order="F" if fortran else "C")


def _npy_header(fh: Any, name: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, Fortran order, dtype) of an .npy header, within the allowed kinds and sizes."""
    version = npy.read_magic(fh)
    if version not in ((1, 0), (2, 0)):
        raise _Bad(f"{name} has .npy format {version}")
    read = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
    try:
        shape, fortran, dtype = read(fh, max_header_size=4096)
    except (SyntaxError, tokenize.TokenError):  # from numpy's fallback for Python 2 headers
        raise _Bad(f"{name} has an unreadable .npy header") from None
    if (dtype.kind not in ARRAY_KINDS or dtype.fields is not None or dtype.subdtype is not None
            or dtype.itemsize == 0):
        raise _Bad(f"{name} holds {_short(str(dtype))}, not an allowed dtype")
    if len(shape) > MAX_NDIM or any(type(n) is not int or n < 0 for n in shape):
        raise _Bad(f"{name} has shape {_short(str(shape))}")
    return shape, bool(fortran), dtype


# -- nodes ----------------------------------------------------------------------------------
class _Decoder:
    """Tree nodes back to objects, given the blob's arrays and format version."""

    def __init__(self, arrays: list[np.ndarray], version: int) -> None:
        self.arrays = arrays
        self.version = version

    def node(self, node: Any, depth: int) -> Any:
        """The object `node` stands for."""
        if depth > MAX_DEPTH:
            raise _Bad(f"tree nests deeper than {MAX_DEPTH}")
        if node is None or isinstance(node, str | bool | int | float):
            return node
        if isinstance(node, list):
            return self.items(node, depth)
        if not isinstance(node, dict) or set(node) not in _MARKS:
            raise _Bad(f"unexpected node {_short(node)}")
        if "$a" in node:
            return self.array(node["$a"])
        if "$c" in node:
            return self.dataclass(node["$c"], node["f"], depth)
        if "$t" in node:
            return tuple(self.items(node["$t"], depth))
        if "$o" in node:
            return _objects(self.items(node["$o"], depth))
        return self.mapping(node["$d"], depth)

    def items(self, nodes: Any, depth: int) -> list[Any]:
        """The objects of a list of nodes one level down."""
        if not isinstance(nodes, list):
            raise _Bad(f"{_short(nodes)} where a list belongs")
        return [self.node(v, depth + 1) for v in nodes]

    def array(self, index: Any) -> np.ndarray:
        """Array `index` of the blob."""
        if type(index) is not int or not 0 <= index < len(self.arrays):
            raise _Bad(f"array index {_short(index)} of {len(self.arrays)}")
        return self.arrays[index]

    def mapping(self, pairs: Any, depth: int) -> dict:
        """A dict from [key, value] pair nodes."""
        if not isinstance(pairs, list):
            raise _Bad(f"{_short(pairs)} where a list of [key, value] pairs belongs")
        out = {}
        for pair in pairs:
            if not (isinstance(pair, list) and len(pair) == 2):
                raise _Bad(f"dict entry {_short(pair)} is not a [key, value] pair")
            key, value = self.items(pair, depth)
            try:
                out[key] = value
            except TypeError:
                raise _Bad(f"dict key {_short(key)} is not hashable") from None
        return out

    def dataclass(self, name: Any, stored: Any, depth: int) -> Any:
        """The registered dataclass that `name` tags, built from its `stored` field nodes."""
        if not isinstance(name, str) or not isinstance(stored, dict):
            raise _Bad(f"dataclass node of {_short(name)} with fields {_short(stored)}")
        tag = state_types.legacy_tag(name) if self.version == 1 else name
        cls = state_types.class_of(tag)
        values = {k: self.node(v, depth + 1) for k, v in stored.items()}
        return _construct(cls, tag, state_types.upgrade(tag, values), strict=self.version > 1)


def _objects(values: list[Any]) -> np.ndarray:
    """A one-dimensional object array of `values`."""
    out = np.empty(len(values), dtype=object)
    for i, v in enumerate(values):
        out[i] = v
    return out


def _construct(cls: type, tag: str, values: dict[str, Any], *, strict: bool) -> Any:
    """An instance of `cls` from its fields: a missing required one fails, and so does an
    unknown one when `strict` (format 1 ignored those)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(values.keys() - fields.keys())
    if unknown and strict:
        raise _Bad(f"{tag} has no field {_short(unknown[0])}")
    values = {k: v for k, v in values.items() if k in fields}
    missing = [f.name for f in fields.values() if f.init and f.name not in values
               and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise _Bad(f"{tag} lacks field {missing[0]!r}")
    hints = _hints(cls)
    for k, v in values.items():
        if not _conforms(v, hints.get(k, Any)):
            raise _Bad(f"{tag} field {k!r} holds {_short(v)}, not {_hint_name(hints[k])}")
    obj = cls(**{k: v for k, v in values.items() if fields[k].init})
    for k, v in values.items():
        if not fields[k].init:
            object.__setattr__(obj, k, v)
    return obj


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """The resolved field annotations of a registered class."""
    return typing.get_type_hints(cls)


def _conforms(value: Any, hint: Any) -> bool:
    """Whether a decoded value fits a field's annotation (containers checked item by item;
    an int passes for a float, as JSON writes whole floats)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_conforms(value, h) for h in args)
    if hint is float:
        return isinstance(value, int | float)
    if origin is None:
        if hint is type(None) or _unstored(hint):
            return value is None  # an unregistered class is never encoded: stored as None
        return not isinstance(hint, type) or isinstance(value, hint)
    if not isinstance(value, origin):
        return False
    if origin is list and args:
        return all(_conforms(v, args[0]) for v in value)
    if origin is dict and args:
        return all(_conforms(k, args[0]) and _conforms(v, args[1]) for k, v in value.items())
    if origin is tuple and args:
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_conforms(v, args[0]) for v in value)
        return len(args) == len(value) and all(map(_conforms, value, args))
    return True


def _unstored(hint: Any) -> bool:
    """A dataclass the registry does not hold (a fitted GP the state leaves out)."""
    return dataclasses.is_dataclass(hint) and hint not in _REGISTERED


_REGISTERED = frozenset(state_types.TYPES.values())


def _hint_name(hint: Any) -> str:
    """An annotation as a short text for messages."""
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _short(value: Any, limit: int = 60) -> str:
    """A repr of stored data for one-line messages: containers by size, text cut short."""
    if isinstance(value, dict):
        keys = [repr(str(k)[:20]) for k in list(value)[:4]]
        text = f"{{{', '.join(keys)}{', ...' if len(value) > 4 else ''}}}"
    elif isinstance(value, list | tuple):
        text = f"<{type(value).__name__} of {len(value)}>"
    else:
        text = repr(value[:limit] if isinstance(value, str) else value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _one_line(exc: BaseException) -> str:
    """The type and first line of an exception's message, cut short."""
    lines = str(exc).splitlines()
    text = f"{type(exc).__name__}: {lines[0] if lines else ''}"
    return text if len(text) <= 160 else text[:157] + "..."
