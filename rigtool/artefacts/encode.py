"""Text that enters a generated file, encoded for that file's grammar: one function per grammar.

Every run name, run id, thruster id, timestamp, unit or other stored text a writer puts into a
generated file goes through one of these, and only into a value (a C string literal, a YAML
quoted scalar, XML element text or attribute value, a CSV field), never into a comment:
comment syntax (`*/`, `-->`, a line break after `#`) has no escape. The encoders give ASCII
only, so no bidirectional control, line-break character or byte-order mark reaches a file raw.

Lone surrogates (not Unicode scalar values, so no UTF-8 file can hold them) become U+FFFD in
every grammar; the other losses are stated per function. rigtool.artefacts.vehicle uses
c_string, yaml_string and xml_text; the CSV writers (rigtool.artefacts.write, rigtool.export)
use csv_safe_text; c_identifier and csv_field are for a writer that derives a C name from text or
writes a CSV field itself.
"""

from __future__ import annotations

import hashlib
import re

REPLACEMENT = "\ufffd"
C_STRING_MAX_BYTES = 4094  # C99 guarantees string literals of 4095 bytes with the final NUL
C_IDENTIFIER_MAX = 63  # significant initial characters of a macro name or internal identifier
_SURROGATE = re.compile("[\ud800-\udfff]")
_C_PREFIX = re.compile(r"(rigtool|RIGTOOL)_[A-Za-z0-9_]*")
_C_UNSAFE = re.compile(r"[^A-Za-z0-9_]")
_XML_FORBIDDEN = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")
_XML_REFERENCE = re.compile("[^\x20-\x7e]|[&<>\"']")
_XML_NAMED = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&apos;"}
_YAML_ESCAPE = re.compile('[^\x20-\x7e]|["\\\\]')
_CSV_FORMULA = ("=", "+", "-", "@", "\t", "\r")


def scalar_text(text: str) -> str:
    """`text` with each lone surrogate replaced by U+FFFD (what a UTF-8 file can hold)."""
    return _SURROGATE.sub(REPLACEMENT, text)


def _c_byte(byte: int) -> str:
    """One byte inside a C string literal: printable ASCII, `\\"?` escaped, else octal."""
    char = chr(byte)
    if char in '\\"?':
        return "\\" + char
    return char if 0x20 <= byte <= 0x7E else f"\\{byte:03o}"


_C_BYTES = [_c_byte(b) for b in range(256)]


def c_string_bytes(text: str) -> bytes:
    """The bytes `c_string(text)` holds: the UTF-8 of `text`, cut at a character boundary
    to at most C_STRING_MAX_BYTES (the longest literal every C99 compiler must accept)."""
    data = scalar_text(text).encode("utf-8")
    if len(data) <= C_STRING_MAX_BYTES:
        return data
    return data[:C_STRING_MAX_BYTES].decode("utf-8", "ignore").encode("utf-8")


def c_string(text: str) -> str:
    """`text` as a C99 string literal, quotes included, of `c_string_bytes(text)`: printable
    ASCII as it is but `\\`, `"` and `?` (trigraphs) escaped, every other byte (controls,
    NUL, non-ASCII UTF-8) as a three-digit octal escape, which no following digit extends."""
    return '"' + "".join(_C_BYTES[b] for b in c_string_bytes(text)) + '"'


def c_identifier(text: str, prefix: str = "rigtool_") -> str:
    """`text` as a C identifier or macro name: `prefix` (rigtool_... or RIGTOOL_..., outside
    every reserved name space) then `text` with characters other than [A-Za-z0-9_] as `_`; a
    changed or over-long name ends in a hash of `text` (so two texts that differ only in
    characters outside the allow-list still get two names)."""
    if not _C_PREFIX.fullmatch(prefix):
        raise ValueError(f"C identifier prefix {prefix!r} is not rigtool_... or RIGTOOL_...")
    name = prefix + _C_UNSAFE.sub("_", text)
    if name == prefix + text and len(name) <= C_IDENTIFIER_MAX:
        return name
    digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return name[:C_IDENTIFIER_MAX - len(digest) - 1] + "_" + digest


def yaml_string(text: str) -> str:
    """`text` as a YAML double-quoted scalar in printable ASCII: `"` and `\\` escaped, every
    other character outside U+0020..U+007E (tab, every line break: LF, CR, U+0085, U+2028,
    U+2029; C0/C1 controls, BOM, bidi controls, all non-ASCII) as \\xHH, \\uHHHH or
    \\UHHHHHHHH, so it loads back as `scalar_text(text)` and never ends its line."""
    return '"' + _YAML_ESCAPE.sub(_yaml_escape, scalar_text(text)) + '"'


def _yaml_escape(match: re.Match[str]) -> str:
    """One YAML double-quoted escape sequence for the matched character."""
    code = ord(match.group())
    if match.group() in '"\\':
        return "\\" + match.group()
    return f"\\x{code:02x}" if code < 0x100 else (
        f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")


def xml_text(text: str) -> str:
    """`text` as XML 1.0 element content or a quoted attribute value, in ASCII: `& < > " '`
    as named entities, tab, LF, CR and every non-ASCII character as numeric references (they
    survive line-end and attribute normalisation); characters XML 1.0 forbids (C0 controls
    but tab, LF and CR; U+FFFE, U+FFFF) are left out."""
    return _XML_REFERENCE.sub(_xml_reference, _XML_FORBIDDEN.sub("", scalar_text(text)))


def _xml_reference(match: re.Match[str]) -> str:
    """The entity or numeric character reference for the matched character."""
    char = match.group()
    return _XML_NAMED.get(char) or f"&#x{ord(char):x};"


def csv_safe_text(text: str) -> str:
    """`text` as spreadsheet-safe CSV text (quoting left to the writer): lone surrogates
    replaced, and a leading = + - @ tab or CR (a formula to a spreadsheet) behind a `'`."""
    field = scalar_text(text)
    return "'" + field if field.startswith(_CSV_FORMULA) else field


def csv_field(text: str) -> str:
    """`text` as one RFC 4180 CSV field: a text a spreadsheet would run as a formula (first
    character = + - @ tab or CR) gets a leading `'`; a field holding a comma, quote, CR or
    LF is quoted, with quotes doubled."""
    field = csv_safe_text(text)
    if any(c in field for c in ',"\r\n'):
        return '"' + field.replace('"', '""') + '"'
    return field
