"""Stored text cannot change the structure of a generated vehicle artefact (issue: generated
files are injectable through run names, thruster ids, run ids and stored timestamps).

Hostile and arbitrary Unicode text goes in as run id, run name, thruster id, created timestamp,
command unit, dynamics run and dynamics model name, through every export format. The C
headers compile under strict flags with the macros and symbols of a plain header and hold the
text's UTF-8 bytes; the YAML and XML load to the keys and tags of a plain file with the text
back; the CSV lookup table keeps its rows; no comment changes. The C headers are compiled in
a few batches (each header in its own slot of one translation unit, its names renamed), so
the ~2,500 names take seconds. Then each encoder of rigtool.artefacts.encode on its own.
"""

from __future__ import annotations

import csv
import io
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigtool.analysis.dynamics import Dynamics, DynamicsModel
from rigtool.analysis.fits import Coefficient
from rigtool.artefacts import encode
from rigtool.artefacts.formats import write_vehicle_artefacts
from rigtool.artefacts.vehicle import DynamicsSource, ExportOptions
from rigtool.cli import main
from rigtool.store import Store
from rigtool.workflows import stored_results

CC = shutil.which("gcc") or shutil.which("cc")
FORMATS = ("c-header", "ros2", "gazebo", "csv-lut")
OPTIONS = ExportOptions(joint="prop_joint", namespace="thruster_1")
EXAMPLES = 360  # x 7 texts each = 2,520 generated names, plus the hostile ones below
BATCHES = 4
PROTOCOL = """\
rigtool_protocol: 1
name: plain
simulator: {profile: esc-1100-1900, seed: 41}
metadata: {thruster_id: stern-1, propeller_diameter_m: 0.1, water_density_kg_m3: 1000}
command: {unit: pulse_us, range: {start: 1100, stop: 1900, step: 50}, order: up}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 200, rate_hz: 1000}
  tare: at_start
"""
PLAIN = {"run_id": "20240501T120000000Z-abc123", "run_name": "plain", "thruster_id": "stern-1",
         "created": "2024-05-01T12:00:00+00:00", "command_unit": "pulse_us",
         "dynamics_run": "20240501T130000000Z-def456", "dynamics_model": "two-state"}
HOSTILE = ["*/", "/*", "*/ int PWNED; /*", "*/\n#define PWNED 1\n/*", "??/", "??=", "\\",
           "a\\\nb", "\u202e", "\u2066x\u2069", "--->", "---", "--", "]]>", "<plugin>",
           "</plugin><plugin name='x'>", "<!-- x -->", "&", "&amp;", "&#0;", "\n", "\r", "\r\n",
           "\x85", "\u2028", "\u2029", "\x00", "\x1b[31m", "\x7f", "\x9f", "\ufeff", "\ufffe",
           "\uffff", "\ud800", "\udfff", "\ud83d\ude00", "\U0001f600", '"', "'", "#", ": ",
           "- x", "{", "}", "[", "]", "&anchor", "*alias", "!!python/object", "%", "@", "`",
           "|", ">", "? ", "null", "~", "yes", "1.5", ".nan", "0x1F", "=1+2", "+1", "-1",
           "@SUM(A1)", "\t", "\\x41", "\\u0041", "\\101", "%s%n", "x" * 10_000,
           "\u20ac" * 3_000, "\U0001f600" * 2_500, "\n# PWNED: 1\n" * 400]
TEXT_FIELDS = {"run_id": "source_run", "run_name": "run_name", "thruster_id": "thruster_id",
               "created": "created_utc", "command_unit": "command_unit",
               "dynamics_run": "dynamics_source_run", "dynamics_model": "dynamics_model"}
SURROGATE = re.compile("[\ud800-\udfff]")
XML_CHAR = re.compile("[\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")

text = st.one_of(
    st.text(),  # every category but surrogates
    st.text(st.characters(categories=["Cs"]) | st.characters(), max_size=8),
    st.lists(st.sampled_from(HOSTILE[:-4]) | st.text(max_size=3), max_size=6).map("".join),
)
texts = st.fixed_dictionaries({k: text for k in PLAIN})


def _coef(name: str, value: float, unit: str = "s") -> Coefficient:
    """A fitted value with a nominal interval."""
    return Coefficient(name, value, 0.9 * value, 1.1 * value, unit)


DYNAMICS = Dynamics(
    one_state=DynamicsModel("one-state", _coef("tau_n", 0.2), _coef("delay", 0.01), None, None,
                            0.1, 100),
    two_state=DynamicsModel("two-state", _coef("tau_n", 0.2), _coef("delay", 0.01),
                            _coef("tau_a", 0.6), _coef("g", 0.3, "1"), 0.1, 100),
    selected="two-state", steps=[], levels={}, zero_n=0.0)


@dataclass
class Header:
    """One generated C header and the bytes each text macro must hold."""

    path: Path
    want: dict[str, str] = field(default_factory=dict)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A calibration of a simulated ESC thruster, made once; examples only vary its texts."""
    tmp = tmp_path_factory.mktemp("generated-text")
    (tmp / "p.yaml").write_text(PROTOCOL)
    db = str(tmp / "db.sqlite")
    assert main(["sweep", str(tmp / "p.yaml"), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "cal")]) == 0
    store = Store(db)
    cal = stored_results(store, store.resolve_run_id("last")).calibration
    store.close()
    return cal


def render(cal, out: Path, values: dict[str, str], dynamics: bool) -> dict[str, str]:
    """Every format written with `values` as its texts."""
    hostile = replace(cal, run_id=values["run_id"], run_name=values["run_name"],
                      thruster_id=values["thruster_id"], command_unit=values["command_unit"])
    model = replace(DYNAMICS.two_state, name=values["dynamics_model"])
    source = DynamicsSource(values["dynamics_run"], replace(DYNAMICS, two_state=model))
    paths = write_vehicle_artefacts(hostile, out, FORMATS, values["created"],
                                    source if dynamics else None, OPTIONS)
    files = {fmt: path.read_bytes().decode("utf-8")
             for fmt, path in zip(FORMATS, paths, strict=True)}
    shutil.rmtree(paths[0].parent)
    return files


def stored(value: str) -> str:
    """What a UTF-8 file can hold of `value`: lone surrogates become U+FFFD."""
    return SURROGATE.sub("\ufffd", value)


def shape(doc: object) -> object:
    """The keys of `doc`, recursively, with the type of every value."""
    if isinstance(doc, dict):
        return {k: shape(v) for k, v in doc.items()}
    return [shape(v) for v in doc] if isinstance(doc, list) else type(doc).__name__


def yaml_docs(text: str) -> list[dict]:
    """`text` loaded by PyYAML and, when built, by libyaml (what ROS 2 parses with)."""
    loaders = [yaml.SafeLoader] + ([yaml.CSafeLoader] if hasattr(yaml, "CSafeLoader") else [])
    return [yaml.load(text, Loader=loader) for loader in loaders]


def check_ros2(got: str, plain: str, values: dict[str, str], dynamics: bool) -> None:
    """Same comments, keys and value types as the plain file; the texts load back."""
    assert got.isascii()
    assert got.split("/**:")[0] == plain.split("/**:")[0]
    want = yaml.safe_load(plain)
    params = want["/**"]["ros__parameters"]["rigtool"]
    for key, name in TEXT_FIELDS.items():
        if name in params and (dynamics or not key.startswith("dynamics")):
            params[name] = stored(values[key])
    for doc in yaml_docs(got):
        assert shape(doc) == shape(want)
        assert doc == want


def xml_events(text: str) -> tuple[list[str], ET.Element]:
    """The comments of an XML document and its root element."""
    parser = ET.XMLPullParser(events=("comment", "end"))
    parser.feed(text)
    parser.close()
    comments, root = [], None
    for event, item in parser.read_events():
        if event == "comment":
            comments.append(item.text)
        else:
            root = item
    return comments, root


def check_gazebo(got: str, plain: str, values: dict[str, str]) -> None:
    """Same comments, tags and attributes as the plain file; the texts come back as element
    text, less the characters XML 1.0 cannot hold."""
    assert got.isascii()
    comments, root = xml_events(got)
    plain_comments, plain_root = xml_events(plain)
    assert comments == plain_comments
    assert [(e.tag, e.attrib) for e in root.iter()] == [
        (e.tag, e.attrib) for e in plain_root.iter()]
    want = {f"rigtool_{TEXT_FIELDS[k]}": "".join(XML_CHAR.findall(stored(v)))
            for k, v in values.items()}
    for got_el, plain_el in zip(root.iter(), plain_root.iter(), strict=True):
        assert (got_el.text or "") == want.get(got_el.tag, plain_el.text or "")


def check_csv(got: str, plain: str) -> None:
    """The same header row and rows as the plain table; every other line is a comment, and
    no CR makes a reader see a line the comment did not start."""
    rows = [line for line in got.split("\n") if not line.startswith("# ")]
    assert rows == [line for line in plain.split("\n") if not line.startswith("# ")]
    assert len(rows) > 10 and "\r" not in got


def check_c_lines(got: str, plain: str, header: Header) -> None:
    """Only the text macros' lines differ from the plain header, and only after the name."""
    assert got.isascii()
    got_lines, plain_lines = got.split("\n"), plain.split("\n")
    assert len(got_lines) == len(plain_lines)
    for line, plain_line in zip(got_lines, plain_lines, strict=True):
        if line != plain_line:
            assert plain_line.startswith("#define ")
            name = plain_line.split(" ")[1]
            assert name in header.want and line.startswith(f"#define {name} \"")


def check_all(files: dict[str, str], plain: dict[str, str], values: dict[str, str],
              dynamics: bool, header: Header) -> None:
    """Every format against the plain rendering with the same dynamics."""
    check_ros2(files["ros2"], plain["ros2"], values, dynamics)
    check_gazebo(files["gazebo"], plain["gazebo"],
                 values if dynamics else {k: v for k, v in values.items()
                                          if not k.startswith("dynamics")})
    check_csv(files["csv-lut"], plain["csv-lut"])
    check_c_lines(files["c-header"], plain["c-header"], header)
    header.path.write_text(files["c-header"], encoding="ascii")


def c_macros(values: dict[str, str], dynamics: bool) -> dict[str, str]:
    """The C macro of each text and the text it holds."""
    names = {k: f"RIGTOOL_{v.upper()}" for k, v in TEXT_FIELDS.items()}
    names["dynamics_run"] = "RIGTOOL_DYNAMICS_RUN"
    return {names[k]: v for k, v in values.items() if dynamics or not k.startswith("dynamics")}


def test_hostile_and_arbitrary_text_in_every_format(base, tmp_path):
    """~2,500 names through every format (checked in Python as they are written), then all
    the headers through the C compiler in a few translation units."""
    out, hdr = tmp_path / "out", tmp_path / "headers"
    hdr.mkdir()
    plain = {d: render(base, out, PLAIN, d) for d in (False, True)}
    headers: list[Header] = []

    def one(values: dict[str, str], dynamics: bool) -> None:
        header = Header(hdr / f"h{len(headers)}.h", c_macros(values, dynamics))
        check_all(render(base, out, values, dynamics), plain[dynamics], values, dynamics,
                  header)
        headers.append(header)

    for i, hostile in enumerate(HOSTILE):
        one(dict.fromkeys(PLAIN, hostile), dynamics=i % 2 == 0)
    one(dict.fromkeys(PLAIN, "".join(HOSTILE[:-4])), dynamics=True)

    @settings(derandomize=True, max_examples=EXAMPLES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(values=texts, dynamics=st.booleans())
    def arbitrary(values: dict[str, str], dynamics: bool) -> None:
        one(values, dynamics)

    arbitrary()
    assert len(headers) >= EXAMPLES + len(HOSTILE)
    if CC is not None:
        compile_headers(tmp_path, plain[True]["c-header"], headers)


# -- the C side ---------------------------------------------------------------------------

def _flags() -> list[str]:
    """Strict C99, plus a warning on any bidirectional control where the compiler has it."""
    strict = ["-std=c99", "-Wall", "-Werror", "-pedantic"]
    probe = subprocess.run([CC, *strict, "-Wbidi-chars=any", "-x", "c", "-fsyntax-only", "-"],
                           input="int x;\n", capture_output=True, text=True)
    return strict + (["-Wbidi-chars=any"] if probe.returncode == 0 else [])


def _run(*args: str | Path, cwd: Path) -> str:
    """Run a tool; its stdout, or the failure with its stderr."""
    done = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[:4000]
    return done.stdout


def _defined(obj: Path, cwd: Path) -> set[str]:
    """The symbols an object file defines."""
    return {line.split()[-1] for line in _run("nm", "--defined-only", obj, cwd=cwd).splitlines()}


def _macro_names(source: Path, flags: list[str], cwd: Path) -> set[str]:
    """The macros defined at the end of a translation unit."""
    dump = _run(CC, *flags, "-E", "-dM", source, cwd=cwd)
    return {line.split()[1].split("(")[0] for line in dump.splitlines()}


def unit_source(headers: list[Header], plain: str) -> str:
    """One translation unit holding every header in a slot of its own: the header's names
    renamed per slot, each text macro copied into an array, every macro undefined after.
    main prints each array as `slot macro hex-bytes`."""
    macros = re.findall(r"^#define (\w+)", plain, re.M)
    names = sorted(set(re.findall(r"\brigtool_[a-z_]+\b", plain)))
    lines = ["#include <stdio.h>", "#include <stddef.h>"]
    checks = []
    for slot, header in enumerate(headers):
        lines += [f"#define {n} {n}_s{slot}" for n in names]
        lines.append(f'#include "{header.path.name}"')
        for k, macro in enumerate(header.want):
            lines.append(f"static const char rigtool_check_{slot}_{k}[] = {macro};")
            checks.append(f'{{"{slot} {macro}", rigtool_check_{slot}_{k}, '
                          f"sizeof rigtool_check_{slot}_{k}}}")
        lines += [f"#undef {m}" for m in macros + names]
    lines += ["struct rigtool_check { const char *name; const char *data; size_t size; };",
              "static const struct rigtool_check rigtool_checks[] = {",
              ",\n".join(checks), "};",
              "int main(void)", "{", "    size_t i, j;",
              "    for (i = 0; i < sizeof rigtool_checks / sizeof rigtool_checks[0]; ++i) {",
              '        printf("%s ", rigtool_checks[i].name);',
              "        for (j = 0; j + 1 < rigtool_checks[i].size; ++j)",
              '            printf("%02x", (unsigned char)rigtool_checks[i].data[j]);',
              '        printf("\\n");', "    }", "    return 0;", "}", ""]
    return "\n".join(lines)


def build_unit(folder: Path, name: str, headers: list[Header], plain: str,
               flags: list[str]) -> tuple[set[str], set[str], str]:
    """Compile, list and run one translation unit: (symbols, macros, output)."""
    source = folder / f"{name}.c"
    source.write_text(unit_source(headers, plain), encoding="ascii")
    _run(CC, *flags, "-c", source.name, "-o", f"{name}.o", cwd=folder)
    _run(CC, f"{name}.o", "-o", name, "-lm", cwd=folder)
    return (_defined(folder / f"{name}.o", folder), _macro_names(source, flags, folder),
            _run(folder / name, cwd=folder))


def c_bytes_ok(got: bytes, value: str) -> bool:
    """The literal holds the text's UTF-8, or (past the C99 literal limit) the longest start
    of it that ends at a character boundary."""
    whole = stored(value).encode("utf-8")
    if len(whole) <= encode.C_STRING_MAX_BYTES:
        return got == whole
    cut = whole[:encode.C_STRING_MAX_BYTES]
    return got == cut[:len(cut.decode("utf-8", "ignore").encode("utf-8"))]


def compile_headers(tmp: Path, plain: str, headers: list[Header]) -> None:
    """Every header compiles in strict C99, adds the plain header's symbols and macros only,
    and its text macros hold the expected bytes."""
    folder = headers[0].path.parent
    (folder / "plain.h").write_text(plain, encoding="ascii")
    flags = _flags()
    reference = Header(folder / "plain.h", c_macros(PLAIN, dynamics=True))
    ref_symbols, ref_macros, ref_output = build_unit(folder, "reference", [reference], plain,
                                                     flags)
    assert ref_output == "".join(f"0 {m} {v.encode().hex()}\n" for m, v in reference.want.items())
    per_slot = {s[:-3] for s in ref_symbols if s.endswith("_s0")}
    fixed = {s for s in ref_symbols if not s.endswith("_s0") and "_check_" not in s}
    assert per_slot >= {"rigtool_lut_thrust", "rigtool_test_command"}
    parts = [part for part in (headers[i::BATCHES] for i in range(BATCHES)) if part]
    with ThreadPoolExecutor(max_workers=2) as pool:
        built = list(pool.map(lambda i: build_unit(folder, f"unit{i}", parts[i], plain, flags),
                              range(len(parts))))
    for part, (symbols, macros, output) in zip(parts, built, strict=True):
        assert macros == ref_macros
        assert symbols == fixed | {
            f"{s}_s{slot}" for slot in range(len(part)) for s in per_slot} | {
            f"rigtool_check_{slot}_{k}" for slot, h in enumerate(part) for k in range(len(h.want))}
        rows = [line.split(" ") for line in output.splitlines()]
        assert len(rows) == sum(len(h.want) for h in part)
        for slot, macro, hexdata in rows:
            value = part[int(slot)].want[macro]
            assert c_bytes_ok(bytes.fromhex(hexdata), value), (macro, value[:200])


# -- each encoder on its own ---------------------------------------------------------------

any_text = st.text(st.characters(categories=["Cs"]) | st.characters()) | st.sampled_from(HOSTILE)
FAST = settings(derandomize=True, max_examples=400, deadline=None, database=None)


def c_literal_bytes(literal: str) -> bytes:
    """The bytes of a C string literal that uses only printable ASCII and \\ooo, \\\\, \\",
    \\? escapes (anything else fails the match)."""
    assert literal[0] == literal[-1] == '"'
    tokens = re.findall(r'\\[0-7]{3}|\\[\\"?]|[ !#-/0-Z\[\]-~^_`a-z{|}]', literal[1:-1])
    assert "".join(tokens) == literal[1:-1]
    return bytes(int(t[1:], 8) if len(t) == 4 else ord(t[-1]) for t in tokens)


@FAST
@given(value=any_text)
def test_c_string_is_printable_ascii_with_safe_escapes(value):
    literal = encode.c_string(value)
    assert "??" not in literal and c_bytes_ok(c_literal_bytes(literal), value)
    assert encode.c_string_bytes(value) == c_literal_bytes(literal)


@FAST
@given(value=any_text, prefix=st.sampled_from(["rigtool_", "RIGTOOL_", "rigtool_lut_"]))
def test_c_identifier_is_allow_listed_and_never_reserved(value, prefix):
    name = encode.c_identifier(value, prefix)
    assert re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name) and name.startswith(prefix)
    assert len(name) <= encode.C_IDENTIFIER_MAX
    assert name != encode.c_identifier(value + "\x00", prefix)


def test_c_identifier_refuses_a_prefix_outside_rigtool():
    for prefix in ("", "_", "_Rig", "E", "str", "int", "1rigtool_", "rigtool"):
        with pytest.raises(ValueError):
            encode.c_identifier("x", prefix)
    assert encode.c_identifier("lut_thrust", "rigtool_") == "rigtool_lut_thrust"


@FAST
@given(value=any_text)
def test_yaml_string_is_one_ascii_line_that_loads_back(value):
    scalar = encode.yaml_string(value)
    assert scalar.isascii() and scalar.isprintable() and scalar[0] == scalar[-1] == '"'
    for doc in yaml_docs(f"# {scalar}\nkey: {scalar}\nafter: 1\n"):
        assert doc == {"key": stored(value), "after": 1}


@FAST
@given(value=any_text)
def test_xml_text_loads_back_as_text_and_attribute(value):
    escaped = encode.xml_text(value)
    assert escaped.isascii() and escaped.isprintable()
    root = ET.fromstring(f'<a b="{escaped}" c=\'{escaped}\'>{escaped}<d/></a>')
    want = "".join(XML_CHAR.findall(stored(value)))
    assert [e.tag for e in root.iter()] == ["a", "d"]
    assert (root.text or "") == root.attrib["b"] == root.attrib["c"] == want


@FAST
@given(value=any_text)
def test_csv_field_is_one_field_and_never_a_formula(value):
    cell = encode.csv_field(value)
    rows = list(csv.reader(io.StringIO(f"{cell},next\r\n"), strict=True))
    assert len(rows) == 1 and len(rows[0]) == 2 and rows[0][1] == "next"
    want = stored(value)
    assert rows[0][0] == ("'" + want if want[:1] in ("=", "+", "-", "@", "\t", "\r") else want)

