"""A stored calibration state is hostile input: zip bombs, lying .npy headers, deep or
malformed trees and bit flips come out as a one-line StoreError, within 10 s and 1 GiB."""

from __future__ import annotations

import functools
import io
import json
import os
import resource
import struct
import subprocess
import sys
import time
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from rigtool.artefacts import state, state_types
from rigtool.errors import StoreError

from .hostile import MEMORY_LIMIT
from .state_fixtures import FIXTURES

TIME_LIMIT_S = 10  # CPU seconds of one decode
MIB = 1 << 20
ZERO_MIB = bytes(MIB)
SMALL = [FIXTURES / f"{p}-v{v}.blob" for p in ("quick-demo", "dynamics-steps-esc") for v in (1, 2)]
FUZZ = settings(derandomize=True, max_examples=400, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])


def outcome(blob: Any) -> str:
    """"ok" or "error" for decoding `blob`; anything but a one-line StoreError fails."""
    started = time.process_time()
    try:
        state.decode(blob)
        return "ok"
    except StoreError as exc:
        message = str(exc)
        assert "\n" not in message and message.endswith("calibrate again"), message
        return "error"
    finally:
        assert time.process_time() - started < TIME_LIMIT_S


# -- building hostile zips ------------------------------------------------------------------
def tree(root: Any, version: int = 2) -> bytes:
    """tree.json text of `root`."""
    return json.dumps({"format_version": version, "root": root}).encode()


def npy_header(descr: Any = "<f8", shape: Any = (1,), fortran: Any = False,
               version: tuple[int, int] = (1, 0)) -> bytes:
    """An .npy header that claims `descr` and `shape`, whatever follows it."""
    text = repr({"descr": descr, "fortran_order": fortran, "shape": shape})
    length = "<H" if version == (1, 0) else "<I"
    lead = 8 + struct.calcsize(length)
    text += " " * (63 - (lead + len(text)) % 64) + "\n"
    return b"\x93NUMPY" + bytes(version) + struct.pack(length, len(text)) + text.encode("latin1")


def npy_bytes(a: np.ndarray) -> bytes:
    """`a` saved as .npy."""
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def zip_of(entries: dict[str, bytes] | list[tuple[str, bytes]],
           method: int = zipfile.ZIP_DEFLATED) -> bytes:
    """A zip of (name, content) entries written by zipfile."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for name, data in (entries.items() if isinstance(entries, dict) else entries):
            zf.writestr(name, data)
    return buf.getvalue()


def blob(root: Any, *arrays: bytes, version: int = 2) -> bytes:
    """A state blob of tree `root` and .npy entries `arrays` (raw bytes)."""
    return zip_of({"tree.json": tree(root, version),
                   **{f"{i}.npy": a for i, a in enumerate(arrays)}})


@functools.lru_cache
def zeros_deflated(head: bytes, mib: int) -> tuple[bytes, int, int]:
    """(raw deflate stream, CRC-32, size) of `head` then `mib` MiB of zeros, built from one
    compressed MiB repeated: 2 GiB costs 2 MB and no compression time."""
    co = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = co.compress(head) + co.flush(zlib.Z_FULL_FLUSH)
    block = co.compress(ZERO_MIB) + co.flush(zlib.Z_FULL_FLUSH)
    crc = zlib.crc32(head)
    for _ in range(mib):
        crc = zlib.crc32(ZERO_MIB, crc)
    return first + block * mib + co.flush(), crc, len(head) + mib * MIB


def raw_zip(entries: list[tuple[str, bytes, int, int, int]], *, prefix: bytes = b"",
            flags: int = 0, method: int | None = None) -> bytes:
    """A zip of (name, stored bytes, CRC-32, declared size, compression method) entries,
    written by hand so that nothing has to be compressed or checked."""
    body, directory = bytearray(), bytearray()
    for name, data, crc, size, entry_method in entries:
        m = entry_method if method is None else method
        raw = name.encode()
        directory += struct.pack("<4s4B4HL2L5H2L", b"PK\x01\x02", 20, 3, 20, 0, flags, m, 0,
                                 33, crc, len(data), size, len(raw), 0, 0, 0, 0, 0, len(body))
        directory += raw
        body += struct.pack("<4s2B4HL2L2H", b"PK\x03\x04", 20, 0, flags, m, 0, 33, crc,
                            len(data), size, len(raw), 0) + raw + data
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, len(entries), len(entries),
                      len(directory), len(body), 0)
    return prefix + bytes(body + directory) + end


def tree_entry(root: Any = "array") -> tuple[str, bytes, int, int, int]:
    """A raw_zip entry of tree.json, stored; its root {"$a": 0} unless given."""
    text = tree({"$a": 0} if root == "array" else root)
    return ("tree.json", text, zlib.crc32(text), len(text), zipfile.ZIP_STORED)


def bomb_entry(name: str, head: bytes, mib: int) -> tuple[str, bytes, int, int, int]:
    """A raw_zip entry of `head` and `mib` MiB of zeros, deflated, its size declared truly."""
    data, crc, size = zeros_deflated(head, mib)
    return (name, data, crc, size, zipfile.ZIP_DEFLATED)


def small_zip() -> bytes:
    """A valid state blob of one array."""
    return blob({"$a": 0}, npy_bytes(np.arange(3.0)))


def with_eocd(data: bytes, **fields: int) -> bytes:
    """`data` with fields of its end-of-central-directory record replaced."""
    names = ("sig", "disk", "disk_cd", "n_here", "n_total", "size", "offset", "comment")
    values = dict(zip(names, struct.unpack("<4s4H2LH", data[-22:]), strict=True))
    values.update(fields)
    return data[:-22] + struct.pack("<4s4H2LH", *values.values())


@functools.lru_cache
def handcrafted() -> dict[str, bytes]:
    """Hostile blobs by name; those named ok-* are the largest the bounds allow."""
    empty = npy_bytes(np.zeros(0))
    many = [(f"{i}.npy", empty) for i in range(state.MAX_ENTRIES)]
    deep_lists = "[" * 100_000 + "]" * 100_000
    deep_tuples = '{"$t": [' * 100_000 + "]}" * 100_000
    lying = zeros_deflated(npy_header("<f8", (1,)), 2048)
    cases = {
        # 2 MB of deflate expanding to 2 GiB, its sizes declared truly
        "bomb-npy-2gib": raw_zip([tree_entry(), bomb_entry("0.npy", npy_header(
            "<f8", ((2 << 30) // 8,)), 2048)]),
        "bomb-tree-2gib": raw_zip([bomb_entry("tree.json", b"[", 2048)]),
        "bomb-many-entries": raw_zip([tree_entry([{"$a": i} for i in range(200)])]
                                     + [bomb_entry(f"{i}.npy", b"", 12) for i in range(200)]),
        "bomb-ratio-20mib": raw_zip([tree_entry(), bomb_entry("0.npy", npy_header(
            "<f8", (20 * MIB // 8,)), 20)]),
        "bomb-lying-size": raw_zip([tree_entry(), ("0.npy", lying[0], lying[1], 100, 8)]),
        "npy-claims-1e12": blob({"$a": 0}, npy_header("<f8", (10**12,)) + bytes(16)),
        "npy-claims-1e12-2d": blob({"$a": 0}, npy_header("<f8", (10**6, 10**6)) + bytes(16)),
        "npy-overflowing-shape": blob({"$a": 0}, npy_header("<f8", (2**62, 2**62)) + bytes(16)),
        "npy-huge-itemsize": blob({"$a": 0}, npy_header("<U2000000000", (1,)) + bytes(16)),
        "tree-deep-lists": zip_of({"tree.json": f'{{"format_version": 2, "root": {deep_lists}}}'}),
        "tree-deep-tuples": zip_of({"tree.json": f'{{"format_version": 2, "root": {deep_tuples}}}'}),
        "tree-5mib": zip_of({"tree.json": tree(" " * (5 * MIB))}),
        "entries-too-many": zip_of([("tree.json", tree(None)), *many], zipfile.ZIP_STORED),
        "eocd-claims-a-huge-directory": with_eocd(small_zip(), n_here=65535, n_total=65535,
                                                  size=400 * MIB),
        "zip64-locator": (lambda z: z[:-22] + b"PK\x06\x07" + bytes(16) + z[-22:])(small_zip()),
    }
    # nearly the largest total allowed: 255 MiB of array in a blob padded to the ratio
    f8 = npy_header("<f8", (255 * MIB // 8,))
    cases["ok-cap-255mib"] = raw_zip([tree_entry(), bomb_entry("0.npy", f8, 255)],
                                     prefix=bytes(256 * MIB // state.MAX_RATIO + MIB))
    cases["ok-max-entries"] = zip_of(
        [("tree.json", tree([{"$a": i} for i in range(state.MAX_ENTRIES - 1)])), *many[:-1]],
        zipfile.ZIP_STORED)
    cases["ok-4mib-of-lists"] = zip_of({"tree.json": tree([[]] * (4 * MIB // 4 - 20))})
    return cases


RUNNER = """
import json, sys, time
from pathlib import Path
from rigtool.artefacts import state
from rigtool.errors import StoreError
for path in sorted(Path(sys.argv[1]).glob("*.blob")):
    data = path.read_bytes()
    started = time.process_time()
    try:
        state.decode(data)
        result, message = "ok", ""
    except StoreError as exc:
        result, message = "StoreError", str(exc)
    except BaseException as exc:
        result, message = type(exc).__name__, str(exc)[:300]
    del data
    print(json.dumps({"case": path.stem, "outcome": result, "message": message,
                      "seconds": time.process_time() - started}), flush=True)
try:
    bytearray(2 << 30)
    print(json.dumps({"case": "control", "outcome": "allocated"}))
except MemoryError:
    print(json.dumps({"case": "control", "outcome": "MemoryError"}))
"""


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def test_handcrafted_blobs_fail_cleanly_within_time_and_memory(tmp_path):
    """In a subprocess of 1 GiB address space: each hostile blob is a one-line StoreError in
    under 10 CPU s (CPU, not wall time: a loaded machine must not fail it); the largest blobs the bounds allow decode; 2 GiB cannot be allocated there."""
    cases = handcrafted()
    for name, data in cases.items():
        (tmp_path / f"{name}.blob").write_bytes(data)
    assert len(cases["bomb-npy-2gib"]) < 3 * MIB
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", RUNNER, str(tmp_path)], capture_output=True,
                          text=True, timeout=120, env=env, preexec_fn=_limit_memory)
    assert done.returncode == 0, done.stderr[-2000:]
    results = {r["case"]: r for r in map(json.loads, done.stdout.splitlines())}
    assert results.pop("control")["outcome"] == "MemoryError"
    assert results.keys() == cases.keys()
    for name, r in results.items():
        assert r["outcome"] == ("ok" if name.startswith("ok-") else "StoreError"), r
        assert r["seconds"] < TIME_LIMIT_S, r
        assert "\n" not in r["message"] and (r["outcome"] == "ok"
                                             or r["message"].endswith("calibrate again")), r


def test_bombs_are_refused_before_anything_is_allocated():
    import tracemalloc

    cases = handcrafted()
    for name in ("bomb-npy-2gib", "bomb-tree-2gib", "bomb-many-entries", "bomb-ratio-20mib",
                 "npy-claims-1e12", "npy-overflowing-shape", "eocd-claims-a-huge-directory"):
        tracemalloc.start()
        try:
            assert outcome(cases[name]) == "error", name
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 16 * MIB, (name, peak)


def test_the_deflate_builder_is_honest():
    data, crc, size = zeros_deflated(b"head", 3)
    out = zlib.decompress(data, -15)
    assert out == b"head" + bytes(3 * MIB) and zlib.crc32(out) == crc and size == len(out)


# -- one malformed part at a time -----------------------------------------------------------
ARRAY = npy_bytes(np.arange(3.0))


@pytest.mark.parametrize("root", [
    {"$a": -1}, {"$a": 1}, {"$a": 10**30}, {"$a": 1.0}, {"$a": True}, {"$a": "0"}, {"$a": None},
    {"$a": [0]}, {"$d": "x"}, {"$d": [[1]]}, {"$d": [[1, 2, 3]]}, {"$d": [1]}, {"$d": [None]},
    {"$d": [[[1], 2]]}, {"$d": [[{"$d": []}, 2]]}, {"$d": [[{"$a": 0}, 2]]}, {"$d": {}},
    {"$c": 5, "f": {}}, {"$c": "fits.Coefficient/1", "f": []}, {"$c": "fits.Coefficient/1"},
    {"$c": "fits.Coefficient/1", "f": {"name": "x"}}, {"$c": ["x"], "f": {}},
    {"$c": "x" * 10**6, "f": {}}, {"$c": "steady.PointTable/99999999", "f": {}},
    {"$c": "fits.Coefficient/1", "f": {"name": 1, "value": 1, "lo": 1, "hi": 1, "unit": 1,
                                       "x\ny": 2}},
    {"$o": 3}, {"$t": {}}, {"$o": None}, {"foo": 1}, {}, {"$a": 0, "$t": []},
    {"$c": "fits.Coefficient/1", "f": {}, "x": 1}, [{"$t": [{"bad": 1}]}],
])
def test_malformed_nodes(root: Any):
    assert outcome(blob(root, ARRAY)) == "error"


def test_nesting_just_past_the_bound():
    deep: Any = None
    for _ in range(state.MAX_DEPTH + 1):
        deep = [deep]
    assert outcome(blob(deep)) == "error"
    assert outcome(blob(deep[0])) == "ok"


@pytest.mark.parametrize("text", [
    b"", b"not json", b"\xff\xfe\x00", b"[1, 2", b'{"format_version": 2}', b"[]", b"null",
    b'{"format_version": 2, "root": null, "extra": 1}',
    b'{"format_version": 2, "root": ' + b"9" * 5000 + b"}",
    b'{"format_version": 2, "root": {"$a": ' + b"9" * 4000 + b"}}",
    b'{"format_version": 1e400, "root": null}',
])
def test_malformed_tree_json(text: bytes):
    assert outcome(zip_of({"tree.json": text, "0.npy": ARRAY})) == "error"


@pytest.mark.parametrize("entry", [
    npy_header("|O", (1,)) + bytes(8),
    npy_header([("a", "<f8")], (1,)) + bytes(8),
    npy_header("<f8", (-1,)) + bytes(8),
    npy_header("<f8", (1, -1)) + bytes(8),
    npy_header("<f8", (2,)) + bytes(8),
    npy_header("<f8", (1,)) + bytes(16),
    npy_header("<f8", (1,)),
    npy_header("<f8", (1.5,)) + bytes(8),
    npy_header("<f8", "(1,)") + bytes(8),
    npy_header("<f8", (1,) * 40) + bytes(8),
    npy_header("<f8", (1,), fortran="yes") + bytes(8),
    npy_header("V8", (1,)) + bytes(8),
    npy_header("<M8[s]", (1,)) + bytes(8),
    npy_header("S8", (1,)) + bytes(8),
    npy_header("<U0", (1,)),
    npy_header("nonsense", (1,)) + bytes(8),
    npy_header(("<f8", (2,)), (1,)) + bytes(16),
    npy_header("<f8", (1,), version=(2, 0))[:-1] + bytes(8),
    b"\x93NUMPY\x03\x00" + npy_header()[8:] + bytes(8),
    b"\x93NUMPY\x01\x00\xff\xff" + b"{" * 65535 + bytes(8),
    b"\x93NUMPY\x01\x00\x20\x00" + b"(" * 31 + b"\n" + bytes(8),
    b"NOTNUMPY" + bytes(64),
    b"",
])
def test_malformed_npy_entries(entry: bytes):
    assert outcome(blob({"$a": 0}, entry)) == "error"


def test_an_honest_npy_of_each_allowed_kind_decodes():
    for a in (np.array([True]), np.arange(3, dtype="<i4"), np.arange(3, dtype=">u2"),
              np.ones(2, "<c16"), np.array(["ab"]), np.zeros((0, 3)),
              np.asfortranarray(np.ones((2, 3)))):
        np.testing.assert_array_equal(state.decode(blob({"$a": 0}, npy_bytes(a))), a)


@pytest.mark.parametrize("build", [
    lambda: b"", lambda: b"PK", lambda: b"PK\x05\x06" + bytes(18), lambda: bytes(1000),
    lambda: bytes(range(256)) * 100,
    lambda: zip_of({"tree.json": tree(None), "0.npy": ARRAY, "../evil": b""}),
    lambda: zip_of({"tree.json": tree(None), "1.npy": ARRAY}),
    lambda: zip_of({"tree.json": tree(None), "00.npy": ARRAY}),
    lambda: zip_of({"0.npy": ARRAY}),
    lambda: raw_zip([tree_entry(None), tree_entry(None)]),
    lambda: zip_of({"tree.json": tree(None), "0.npy": ARRAY}, zipfile.ZIP_BZIP2),
    lambda: zip_of({"tree.json": tree(None), "0.npy": ARRAY}, zipfile.ZIP_LZMA),
    lambda: raw_zip([tree_entry(None)], flags=0x1),
    lambda: raw_zip([tree_entry(None)], method=99),
    lambda: raw_zip([("tree.json", b"garbage", 0, 7, zipfile.ZIP_DEFLATED)]),
    lambda: raw_zip([("tree.json", tree(None), 12345, len(tree(None)), 0)]),
    lambda: raw_zip([("tree.json", tree(None), zlib.crc32(tree(None)), 10**6, 0)]),
    lambda: raw_zip([("tree.json", tree(None), zlib.crc32(tree(None)), 3, 0)]),
    lambda: small_zip()[:-30],
    lambda: small_zip()[:100] + small_zip()[101:],
    lambda: with_eocd(small_zip(), offset=2**31),
    lambda: with_eocd(small_zip(), size=1),
    lambda: with_eocd(small_zip(), n_total=0, n_here=0),
    lambda: zip_of({"tree.json": tree({"$c": "rigtool.__main__:X", "f": {}}, 1)}),
])
def test_malformed_zips(build):
    assert outcome(build()) == "error"


@pytest.mark.parametrize("path", SMALL, ids=lambda p: p.stem)
def test_every_truncation_of_a_fixture_fails(path: Path):
    data = path.read_bytes()
    for end in range(0, len(data), max(1, len(data) // 300)):
        assert outcome(data[:end]) == "error"


# -- fuzz -----------------------------------------------------------------------------------
@functools.lru_cache
def _fixture(i: int) -> bytes:
    return SMALL[i].read_bytes()


@functools.lru_cache
def _entries(i: int) -> tuple[tuple[str, bytes], ...]:
    with zipfile.ZipFile(io.BytesIO(_fixture(i))) as zf:
        return tuple((info.filename, zf.read(info)) for info in zf.infolist())


def _mutate(data: bytes, edits: list[tuple[int, int, int]]) -> bytes:
    """`data` with each (position, operation, byte) edit: 0 xor, 1 insert, 2 delete."""
    out = bytearray(data)
    for pos, op, value in edits:
        at = pos % (len(out) + 1)
        if op == 0 and at < len(out):
            out[at] ^= value or 1
        elif op == 1:
            out.insert(at, value)
        elif at < len(out):
            del out[at]
    return bytes(out)


EDITS = st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 2), st.integers(0, 255)),
                 min_size=1, max_size=6)


@FUZZ
@given(st.integers(0, len(SMALL) - 1), EDITS)
def test_fuzz_bit_flipped_fixtures(i: int, edits):
    event(outcome(_mutate(_fixture(i), edits)))


@FUZZ
@given(st.integers(0, len(SMALL) - 1), EDITS)
def test_fuzz_flipped_central_directory(i: int, edits):
    data = _fixture(i)
    start = zipfile.ZipFile(io.BytesIO(data)).start_dir
    tail = _mutate(data[start:], [(p % (len(data) - start), op, v) for p, op, v in edits])
    event(outcome(data[:start] + tail))


@FUZZ
@given(st.integers(0, len(SMALL) - 1), st.integers(0, 80), EDITS)
def test_fuzz_edited_entries_with_valid_checksums(i: int, which: int, edits):
    """Edits inside tree.json or an .npy entry, rezipped so the zip layer accepts them."""
    entries = list(_entries(i))
    name, data = entries[which % len(entries)]
    entries[which % len(entries)] = (name, _mutate(data, [(p % 200 if name != "tree.json"
                                                          else p, op, v) for p, op, v in edits]))
    event(outcome(zip_of(entries, zipfile.ZIP_STORED)))


TAGS = sorted(state_types.TYPES) + sorted(state_types.LEGACY_V1) + ["x/1", "fits.Coefficient/2"]
FIELD_NAMES = ["name", "value", "lo", "hi", "unit", "n", "r2", "x", "offset_n", "drift_n_per_s",
               "t_ref_s", "source", "cov"]
SCALARS = (st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats()
           | st.text(max_size=4) | st.sampled_from(TAGS))


def _extend(children: st.SearchStrategy) -> st.SearchStrategy:
    marks = st.sampled_from(["$a", "$o", "$t", "$d", "$c", "f", "x"])
    return (st.lists(children, max_size=4)
            | st.dictionaries(marks, children, max_size=3)
            | st.builds(lambda v: {"$a": v}, st.integers(-2, 4) | children)
            | st.builds(lambda v: {"$t": v}, st.lists(children, max_size=3))
            | st.builds(lambda v: {"$o": v}, st.lists(children, max_size=3))
            | st.builds(lambda v: {"$d": v}, st.lists(st.lists(children, min_size=1, max_size=3),
                                                      max_size=3))
            | st.builds(lambda t, f: {"$c": t, "f": f}, st.sampled_from(TAGS),
                        st.dictionaries(st.sampled_from(FIELD_NAMES), children, max_size=8)))


NODES = st.recursive(SCALARS, _extend, max_leaves=40)


@FUZZ
@given(st.sampled_from([1, 2]), NODES)
def test_fuzz_generated_trees(version: int, root: Any):
    event(outcome(blob(root, ARRAY, npy_bytes(np.array(["a", "bc"])), version=version)))


@FUZZ
@given(st.sampled_from(["<f8", "|b1", "<i8", "<U3", "|O", "<f8x", "V3", 5, ("<f8", (2,))]),
       st.one_of(st.lists(st.integers(-3, 2**40), max_size=4).map(tuple),
                 st.text("(),1-x ", max_size=4)),
       st.booleans(), st.integers(0, 64))
def test_fuzz_npy_headers(descr: Any, shape: Any, fortran: bool, n_data: int):
    event(outcome(blob({"$a": 0}, npy_header(descr, shape, fortran) + bytes(n_data))))


def _retyped(blob: bytes, value: object) -> bytes:
    """`blob` with the first float field of its first Coefficient set to `value`."""
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        entries = {name: zf.read(name) for name in zf.namelist()}
    tree = json.loads(entries["tree.json"])
    stack = [tree["root"]]
    while stack:
        node = stack.pop()
        if isinstance(node, dict) and node.get("$c", "").startswith("fits.Coefficient"):
            node["f"]["value"] = value
            break
        stack.extend(node.values() if isinstance(node, dict) else
                     node if isinstance(node, list) else [])
    else:
        raise AssertionError("no Coefficient in the fixture")
    entries["tree.json"] = json.dumps(tree).encode()
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return out.getvalue()


@pytest.mark.parametrize("value", ["abc", [1.0], {"$t": [1.0, 2.0]}, None])
def test_a_field_of_the_wrong_type_is_refused_naming_it(value):
    blob = (FIXTURES / "quick-demo-v2.blob").read_bytes()
    with pytest.raises(StoreError, match=r"fits\.Coefficient/1 field 'value' holds"):
        state.decode(_retyped(blob, value))
    assert state.decode(_retyped(blob, 3)) is not None  # a whole number is a float in JSON
