"""rigtool import of .xlsx workbooks laid out like the Blue Robotics T200 public performance
workbook (one sheet per supply voltage), hostile workbooks, and Tyto/RCbenchmark logs that
keep their torque and temperature columns.

Workbooks are built with openpyxl from known coefficients (tests/tabledata.py: C_p per
direction, the current law I = C_n(U) |n|^3 + I_0 with C_n(U) = k U^b, a dead band, speed
proportional to U so thrust grows as U^2), imported and calibrated through the CLI.
"""

from __future__ import annotations

import json
import re
import sqlite3
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import openpyxl
import pytest
from openpyxl.chart import LineChart, Reference

from rigtool.cli import main
from rigtool.importers import workbook
from rigtool.importers.units import G0
from rigtool.store import Store

from .tabledata import HEAD, MakerThruster, rows

VOLTS = (10.0, 12.0, 14.0, 16.0, 18.0, 20.0)
COLUMNS = ("command", "rpm", "current", "voltage", "power", "force", "eff")


@dataclass(frozen=True)
class BookThruster(MakerThruster):
    """A maker's thruster whose current coefficient follows C_n(U) = k U^b (b = -1 physical)."""

    k: float = 3.0
    cn_b: float = -1.0

    def c_law(self, volts: float) -> float:
        """C_n(U), A/(r/min)^3."""
        return (self.max_current_a - self.i0_a) / self.max_rpm**self.k * (
            volts / self.u_ref) ** self.cn_b

    @property
    def law_k(self) -> float:
        """k of C_n(U) = k U^b."""
        return self.c_law(1.0)


def build_book(path: Path, th: MakerThruster, volts: tuple[float, ...] = VOLTS, *,
               names: str = "{:g} V", space: bool = True, readme: bool = True,
               chart: bool = True) -> Path:
    """A T200-style workbook: a notes sheet, one sheet per voltage, a chart sheet."""
    wb = openpyxl.Workbook()
    notes = wb.active
    notes.title = "READ ME FIRST"
    notes.append(["Critical Notes"])
    notes.append(["All input signals from 1100-1500 µs correspond to the REVERSE direction."])
    rng = np.random.default_rng(th.seed)
    for volts_v in volts:
        ws = wb.create_sheet(names.format(volts_v))
        ws.append([(" " if space else "") + h for h in HEAD])
        c = rows(th, volts_v, rng)
        for k in range(c["command"].size):
            ws.append([float(c[key][k]) for key in COLUMNS])
    if not readme:
        wb.remove(notes)
    if chart:
        plot = LineChart()
        plot.add_data(Reference(wb.worksheets[-1], min_col=6, min_row=1, max_row=50),
                      titles_from_data=True)
        wb.create_chartsheet("Thrust chart").add_chart(plot)
    wb.save(path)
    return path


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    status = main(list(args))
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return status, out, err


def _n_runs(db: Path) -> int:
    if not db.exists():
        return 0
    with sqlite3.connect(db) as conn:
        return conn.execute("SELECT count(*) FROM runs").fetchone()[0]


# -- the T200 workbook ---------------------------------------------------------------------------

@pytest.mark.parametrize(("seed", "cn_b", "names", "space", "readme"), [
    (9401, -1.0, "{:g} V", True, True),  # the public workbook's layout
    (9402, -0.8, "T200 {:g}V", False, False),  # b is fitted, not assumed
])
def test_workbook_imports_in_one_command_and_calibrates_per_voltage(
        tmp_path: Path, capsys, seed: int, cn_b: float, names: str, space: bool,
        readme: bool) -> None:
    """Each sheet's voltage becomes the supply axis: C_p, C_n, I_0 and the dead band per
    voltage, and the C_n(U) law across them, come back within their tolerances."""
    th = BookThruster(seed=seed, cn_b=cn_b, current_step=0.01, force_step_kgf=0.001)
    book = build_book(tmp_path / "T200.xlsx", th, names=names, space=space, readme=readme)
    db, out_dir = tmp_path / "r.sqlite", tmp_path / "cal"
    status, out, err = _cli(capsys, "import", str(book), "--db", str(db))
    assert status == 0, err
    assert "1206 row(s) read, 0 skipped -> 1206 point(s) (xlsx, points, pulse_us)" in out
    assert "note: sheet 'Thrust chart': a chart sheet: skipped" in out
    assert ("note: sheet 'READ ME FIRST': no command and thrust columns" in out) == readme
    store = Store(db)
    run_id = store.resolve_run_id("last")
    sheets = store.run(run_id)["rig"]["import"]["sheets"]
    assert [s["supply_v"] for s in sheets] == [[v] for v in VOLTS]
    assert {s["supply_from"] for s in sheets} == {"sheet name"}
    assert {s["voltage_set_v"] for s in store.steps(run_id)} == set(VOLTS)

    assert _cli(capsys, "calibrate", "last", "--db", str(db), "--out", str(out_dir))[0] == 0
    doc = json.loads((out_dir / run_id / "calibration.json").read_text())
    by_volts = {d["supply_voltage_v"]: d for d in doc["depths"]}
    assert sorted(by_volts) == list(VOLTS)
    for volts_v, section in by_volts.items():
        c = section["coefficients"]
        assert c["C_p_fwd"]["value"] == pytest.approx(th.cp_fwd, rel=0.01), volts_v
        assert c["C_p_rev"]["value"] == pytest.approx(th.cp_rev, rel=0.01), volts_v
        assert c["C_n"]["value"] == pytest.approx(th.c_law(volts_v), rel=0.01), volts_v
        assert c["I_0"]["value"] == pytest.approx(th.i0_a, abs=0.01), volts_v
        ((lo, hi),) = section["command_curve"]["dead_zones"]
        assert abs(lo - (1500 - th.deadband_us)) <= th.step_us, (volts_v, lo)
        assert abs(hi - (1500 + th.deadband_us)) <= th.step_us, (volts_v, hi)
    (law,) = doc["voltage_laws"]
    b = law["b"]
    assert b["lo"] <= cn_b <= b["hi"] and abs(b["value"] - cn_b) < 0.01, b
    assert law["k"]["value"] == pytest.approx(th.law_k, rel=0.02)
    assert law["cp_consistent"]


def test_thrust_in_kgf_becomes_newtons(tmp_path: Path, capsys) -> None:
    """`Force (Kg f)` is read in kgf and stored in N with g = 9.80665."""
    th = BookThruster(seed=9403, noise=0.0)
    book = build_book(tmp_path / "b.xlsx", th, (16.0,), readme=False, chart=False)
    db = tmp_path / "r.sqlite"
    assert _cli(capsys, "import", str(book), "--db", str(db))[0] == 0
    store = Store(db)
    steps = store.steps(store.resolve_run_id("last"))
    kgf = rows(th, 16.0, np.random.default_rng(th.seed))["force"]
    assert [s["thrust_all_mean_n"] for s in steps] == pytest.approx((kgf * G0).tolist(), abs=1e-12)
    assert G0 == 9.80665


def test_a_workbook_under_a_csv_name_is_still_a_workbook(tmp_path: Path, capsys) -> None:
    book = build_book(tmp_path / "b.xlsx", BookThruster(seed=9404), (12.0, 16.0))
    renamed = book.rename(tmp_path / "b.csv")
    status, out, err = _cli(capsys, "import", str(renamed), "--db", str(tmp_path / "r.sqlite"))
    assert status == 0 and "(xlsx, points, pulse_us)" in out, err


@pytest.mark.parametrize(("name", "volts"), [
    ("10 V", 10.0), ("12V", 12.0), ("14.8 V", 14.8), ("T200 16V", 16.0), ("16 volts", 16.0),
    ("14,8 V", 14.8), ("READ ME FIRST", None), ("Sheet1", None), ("10-20V", None),
    ("10 V and 12 V", None), ("0 V", None), ("V16", None),
])
def test_supply_voltage_from_the_sheet_name(name: str, volts: float | None) -> None:
    assert workbook.voltage_from_name(name) == volts


# -- hostile workbooks ---------------------------------------------------------------------------

def _small_book(path: Path, name: str = "16 V", cells: dict[str, object] | None = None) -> Path:
    """One sheet, PWM and force, 41 rows; `cells` overrides cells by reference (`B7`)."""
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = name
    ws.append(["PWM (µs)", "Force (Kg f)"])
    for c in range(1100, 1901, 20):
        ws.append([c, (c - 1500) / 100.0])
    for ref, value in (cells or {}).items():
        ws[ref] = value
    wb.save(path)
    return path


def _rezip(src: Path, dst: Path, edit) -> Path:
    """Copy the archive `src` to `dst`, passing each member's bytes through edit(name, data)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            zout.writestr(item, edit(item.filename, zin.read(item.filename)))
    return dst


def _sheet_xml(edit):
    return lambda name, data: edit(data) if name.startswith("xl/worksheets/") else data


def _refused(capsys, tmp_path: Path, path: Path, *words: str, options: tuple = ()) -> str:
    """Import `path`: exit status 2, every word in the one error, nothing stored."""
    db = tmp_path / "refused.sqlite"
    status, _, err = _cli(capsys, "import", str(path), "--db", str(db), *options)
    assert status == 2, err
    for word in words:
        assert word in err, (word, err)
    assert _n_runs(db) == 0
    return err


def test_dimension_claims_and_far_cells_are_not_trusted(tmp_path: Path, capsys) -> None:
    """A sheet claiming A1:XFD1048576 with a cell at XFD1048576 reads only what it holds."""
    far = b'<row r="1048576"><c r="XFD1048576" t="n"><v>1</v></c></row></sheetData>'
    book = _rezip(_small_book(tmp_path / "ok.xlsx"), tmp_path / "claims.xlsx", _sheet_xml(
        lambda d: re.sub(rb'<dimension ref="[^"]*"', b'<dimension ref="A1:XFD1048576"', d)
        .replace(b"</sheetData>", far)))
    status, out, err = _cli(capsys, "import", str(book), "--db", str(tmp_path / "r.sqlite"))
    assert status == 0 and "41 row(s) read, 0 skipped -> 41 point(s)" in out, err


def test_rows_beyond_the_bounds_are_refused(tmp_path: Path, capsys, monkeypatch) -> None:
    book = _small_book(tmp_path / "b.xlsx", cells={"A900": 1500, "B900": 0.0})
    monkeypatch.setattr(workbook, "MAX_SCANNED_ROWS", 500)
    _refused(capsys, tmp_path, book, "more than 500 rows (empty ones counted)")
    monkeypatch.setattr(workbook, "MAX_SCANNED_ROWS", 10_000)
    monkeypatch.setattr(workbook, "MAX_ROWS", 20)
    _refused(capsys, tmp_path, book, "more than 20 rows of data")


@pytest.mark.parametrize(("bound", "value", "words"), [
    ("MAX_UNPACKED_BYTES", 2000, "unpacks to"),
    ("MAX_SHEETS", 1, "2 sheets, more than the 1"),
    ("MAX_MEMBERS", 3, "parts in the archive"),
])
def test_archive_bounds(tmp_path: Path, capsys, monkeypatch, bound: str, value: int,
                        words: str) -> None:
    book = build_book(tmp_path / "b.xlsx", BookThruster(seed=9405), (12.0, 16.0), readme=False,
                      chart=False)
    monkeypatch.setattr(workbook, bound, value)
    _refused(capsys, tmp_path, book, words)


def test_formula_without_a_stored_result_is_refused(tmp_path: Path, capsys) -> None:
    """openpyxl writes formulas without results, as a script would: rigtool evaluates none."""
    formulas = {f"B{r}": f"=(A{r}-1500)/100" for r in range(2, 43)}
    book = _small_book(tmp_path / "f.xlsx", cells=formulas)
    _refused(capsys, tmp_path, book, "sheet '16 V'", "B2 ('=(A2-1500)/100')", "and 36 more",
             "formula with no stored result")


def test_text_in_numeric_cells(tmp_path: Path, capsys) -> None:
    """One text cell skips its row, reported by sheet and row (--strict: nothing imported);
    a command column of text leaves no row: refused."""
    book = _small_book(tmp_path / "t.xlsx", cells={"B7": "abc"})
    db = tmp_path / "r.sqlite"
    status, out, err = _cli(capsys, "import", str(book), "--db", str(db))
    assert status == 0 and f"{book}['16 V']:7: thrust: 'abc' is not a number" in err
    assert "40 row(s) read, 1 skipped -> 40 point(s)" in out
    _refused(capsys, tmp_path, book, "1 unreadable cell(s), nothing imported (--strict)",
             options=("--strict",))
    text = _small_book(tmp_path / "t2.xlsx", cells={f"A{r}": "n/a" for r in range(2, 43)})
    _refused(capsys, tmp_path, text, "no readable data rows", "command: 'n/a' is not a number")


def test_a_data_sheet_without_a_voltage_is_refused(tmp_path: Path, capsys) -> None:
    book = _small_book(tmp_path / "s.xlsx", name="Sheet1")
    _refused(capsys, tmp_path, book, "sheet 'Sheet1' holds data but its name gives no supply "
             "voltage", "`Supply Voltage (V)` column")


def test_a_supply_column_in_the_sheet_wins_over_its_name(tmp_path: Path, capsys) -> None:
    book = _small_book(tmp_path / "s.xlsx", name="Sheet1",
                       cells={"C1": "Supply Voltage (V)", **{f"C{r}": 14.0 for r in range(2, 43)}})
    db = tmp_path / "r.sqlite"
    assert _cli(capsys, "import", str(book), "--db", str(db))[0] == 0
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert {s["voltage_set_v"] for s in store.steps(run_id)} == {14.0}
    (sheet,) = store.run(run_id)["rig"]["import"]["sheets"]
    assert sheet["supply_from"] == "column 'Supply Voltage (V)'"


def test_no_sheets_or_no_data_sheet(tmp_path: Path, capsys) -> None:
    ok = _small_book(tmp_path / "ok.xlsx")
    empty = _rezip(ok, tmp_path / "zero.xlsx", lambda n, d: re.sub(
        rb"<sheets>.*</sheets>", b"<sheets/>", d) if n == "xl/workbook.xml" else d)
    _refused(capsys, tmp_path, empty, "the workbook has no sheets")
    wb = openpyxl.Workbook()
    wb.active.append(["just", "notes"])
    wb.active.title = "Notes"
    wb.save(tmp_path / "notes.xlsx")
    _refused(capsys, tmp_path, tmp_path / "notes.xlsx", "no sheet holds a table with command "
             "and thrust columns", "sheet 'Notes': no command and thrust columns")


@pytest.mark.parametrize(("content", "words"), [
    (b"PWM (us),Force (kgf)\n1500,0\n1600,1\n", "not an .xlsx workbook (a text file? name it .csv)"),
    (bytes(range(256)) * 8, "not an .xlsx workbook (not a ZIP archive)"),
    (None, "not a readable .xlsx workbook"),  # a ZIP archive, but not a workbook
    (b"", "not an .xlsx workbook"),
])
def test_a_file_that_is_not_a_workbook(tmp_path: Path, capsys, content: bytes | None,
                                       words: str) -> None:
    path = tmp_path / "renamed.xlsx"
    if content is None:
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("readme.txt", "not a workbook")
    else:
        path.write_bytes(content)
    _refused(capsys, tmp_path, path, words)


def test_an_old_xls_workbook_is_named(tmp_path: Path, capsys) -> None:
    path = tmp_path / "old.xls"
    path.write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504))
    _refused(capsys, tmp_path, path, "an old Excel .xls workbook", "save it as .xlsx")


def test_missing_openpyxl_is_a_one_line_usage_error(tmp_path: Path, capsys, monkeypatch) -> None:
    book = _small_book(tmp_path / "b.xlsx")
    monkeypatch.setitem(sys.modules, "openpyxl", None)  # `import openpyxl` raises ImportError
    err = _refused(capsys, tmp_path, book, "reading .xlsx workbooks needs openpyxl: "
                   "pip install 'rigtool[xlsx]'")
    assert err.strip().count("\n") == 0


# -- Tyto/RCbenchmark logs with torque and temperature --------------------------------------------

@dataclass(frozen=True)
class TytoRun:
    """A Tyto/RCbenchmark time series of a thruster with known C_p and C_q per direction."""

    cp_fwd: float = 3.0e-6  # N/(r/min)^2
    cp_rev: float = 2.4e-6
    cq_fwd: float = 6.0e-8  # N m/(r/min)^2
    cq_rev: float = 5.0e-8
    max_rpm: float = 3500.0
    deadband_us: float = 25.0
    hold_s: float = 2.0
    rate_hz: float = 20.0
    torque_noise: float = 0.0005  # N m
    seed: int = 0

    def speed(self, command: float) -> float:
        offset = command - 1500.0
        beyond = max(abs(offset) - self.deadband_us, 0.0) / (400.0 - self.deadband_us)
        return float(np.sign(offset)) * self.max_rpm * beyond**0.9


TORQUE_UNITS = {"N·m": 1.0, "lbf·in": 0.1129848290276167}
TEMPERATURE_UNITS = {"°C": (1.0, 0.0), "°F": (1.8, 32.0)}  # reading = °C * a + b


def tyto_log(run: TytoRun, torque_unit: str, temperature_unit: str) -> tuple[str, list[float]]:
    """The log text and the true mean temperature (°C) of each command's rows."""
    rng = np.random.default_rng(run.seed)
    head = ["Time (s)", "ESC signal (µs)", "Servo 1 (µs)", "AccX (g)", f"Torque ({torque_unit})",
            "Thrust (kgf)", "Voltage (V)", "Current (A)", "Motor Electrical Speed (RPM)",
            "Motor Optical Speed (RPM)", "Electrical Power (W)", f"Temp0 ({temperature_unit})",
            "App message"]
    lines = [",".join(head) + ","]
    scale_t, shift_t = TEMPERATURE_UNITS[temperature_unit]
    t, means = 0.0, []
    for cmd in np.arange(1100.0, 1901.0, 25.0):
        n = run.speed(cmd)
        cp, cq = (run.cp_fwd, run.cq_fwd) if n >= 0 else (run.cp_rev, run.cq_rev)
        temps = []
        for _ in range(int(run.hold_s * run.rate_hz)):
            f = cp * abs(n) * n + rng.normal(0, 0.02)
            q = cq * abs(n) * n + rng.normal(0, 1) * run.torque_noise
            cur = 0.1 + 4e-10 * abs(n) ** 3 + rng.normal(0, 0.02)
            temp = 20.0 + 0.02 * t + rng.normal(0, 0.05)
            temps.append(temp)
            lines.append(",".join([
                f"{t:.3f}", f"{cmd:.0f}", "1500", "0.01", f"{q / TORQUE_UNITS[torque_unit]:.6f}",
                f"{f / G0:.6f}", "16.0", f"{cur:.3f}", f"{7 * abs(n):.0f}", f"{abs(n):.1f}",
                f"{16 * cur:.2f}", f"{temp * scale_t + shift_t:.4f}", ""]) + ",")
            t += 1 / run.rate_hz
        means.append(float(np.mean(temps)))
    return "\n".join(lines) + "\n", means


@pytest.mark.parametrize(("torque_unit", "temperature_unit"), [("N·m", "°C"), ("lbf·in", "°F")])
def test_tyto_log_keeps_torque_and_temperature(tmp_path: Path, capsys, torque_unit: str,
                                               temperature_unit: str) -> None:
    """Torque goes to the run's torque channel (C_q per direction within 2 % of the truth);
    temperature is kept per point in `temperature` events, in °C."""
    run = TytoRun(seed=9410)
    text, truth_c = tyto_log(run, torque_unit, temperature_unit)
    log, db, out_dir = tmp_path / "tyto.csv", tmp_path / "r.sqlite", tmp_path / "cal"
    log.write_text(text, encoding="utf-8")
    status, out, err = _cli(capsys, "import", str(log), "--db", str(db))
    assert status == 0 and "(rcbenchmark, timeseries, pulse_us)" in out, err
    store = Store(db)
    run_id = store.resolve_run_id("last")
    record = store.run(run_id)
    assert record["rig"]["resolved"]["thrust"] == {"channel": "fx", "sign": 1}
    columns = record["rig"]["import"]["columns"]
    assert columns["torque"]["header"] == f"Torque ({torque_unit})"
    assert columns["temperature"]["header"] == f"Temp0 ({temperature_unit})"

    assert _cli(capsys, "calibrate", "last", "--db", str(db), "--out", str(out_dir))[0] == 0
    doc = json.loads((out_dir / run_id / "calibration.json").read_text())
    (section,) = doc["depths"]
    coef = section["coefficients"]
    assert coef["C_q_fwd"]["value"] == pytest.approx(run.cq_fwd, rel=0.02)
    assert coef["C_q_rev"]["value"] == pytest.approx(run.cq_rev, rel=0.02)
    assert coef["C_p_fwd"]["value"] == pytest.approx(run.cp_fwd, rel=0.02)

    events = store.events(run_id, "temperature")
    assert len(events) == 1
    detail = events[0]["detail"]
    assert detail["unit"] == "°C" and detail["step_idx"] == list(range(len(truth_c)))
    assert detail["mean_c"] == pytest.approx(truth_c, abs=2e-3)
    assert all(lo <= m <= hi for lo, m, hi in zip(detail["min_c"], detail["mean_c"],
                                                   detail["max_c"], strict=True))


def test_a_torque_column_of_zeros_is_not_a_measurement(tmp_path: Path, capsys) -> None:
    """A stand without a torque cell may log `Torque (N·m)` as 0: no C_q of zero from it."""
    text, _ = tyto_log(TytoRun(seed=9411, cq_fwd=0.0, cq_rev=0.0, torque_noise=0.0), "N·m", "°C")
    log, db, out_dir = tmp_path / "tyto.csv", tmp_path / "r.sqlite", tmp_path / "cal"
    log.write_text(text, encoding="utf-8")
    status, _, err = _cli(capsys, "import", str(log), "--db", str(db))
    assert status == 0
    assert "torque column 'Torque (N·m)' holds only zeros or empty cells: not measured" in err
    assert _cli(capsys, "calibrate", "last", "--db", str(db), "--out", str(out_dir))[0] == 0
    run_id = Store(db).resolve_run_id("last")
    doc = json.loads((out_dir / run_id / "calibration.json").read_text())
    assert not any(k.startswith("C_q") for k in doc["depths"][0]["coefficients"])


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_a_command_beyond_what_the_store_takes_is_a_bad_row(tmp_path: Path, capsys,
                                                            suffix: str) -> None:
    """A command cell of -1e308 was stored, and the run could then not be read back: it is
    now a skipped row naming the bound, in a CSV and in a workbook alike."""
    table = [["PWM (µs)", "Force (Kg f)"], [1500, 0.0], [1600, 0.5], [-1e308, 1.0],
             [1700, 1.0], [1800, 1.5]]
    path = tmp_path / f"t{suffix}"
    if suffix == ".csv":
        path.write_text("\n".join(",".join(str(v) for v in r) for r in table) + "\n")
    else:
        book = openpyxl.Workbook()
        book.active.title = "16 V"
        for r in table:
            book.active.append(r)
        book.save(path)
    db = str(tmp_path / "db.sqlite")
    assert main(["import", str(path), "--db", db]) == 0
    assert "outside the commands rigtool stores" in capsys.readouterr().err
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "cal")]) == 0


def test_numbers_right_of_a_sheets_table_keep_their_rows(tmp_path: Path, capsys) -> None:
    """A sum or a note right of a sheet's table is common in workbooks; cells there have fixed
    places, so (unlike a delimited line with numbers past its header) the row is read."""
    th = BookThruster(seed=9404, noise=0.0)
    book = build_book(tmp_path / "b.xlsx", th, (16.0,), readme=False, chart=False)
    wb = openpyxl.load_workbook(book)
    ws = wb.worksheets[0]
    ws.cell(row=3, column=len(HEAD) + 2, value=123.4)
    wb.save(book)
    db = tmp_path / "r.sqlite"
    status, out, err = _cli(capsys, "import", str(book), "--db", str(db))
    assert status == 0 and "skipped" not in out.replace("0 skipped", ""), (out, err)
    store = Store(db)
    kgf = rows(th, 16.0, np.random.default_rng(th.seed))["force"]
    assert len(store.steps(store.resolve_run_id("last"))) == kgf.size
