"""Notebook displays of the Python API: `Lab`, `Run`, `Calibration`, tables and values have a
short `__repr__` and an escaped, bounded `_repr_html_`; a notebook executed by nbclient on a
real kernel shows them as HTML."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

import rigtool
from rigtool.api import PANDAS_HINT, Columns, Records, Value
from rigtool.cli import main

from .conftest import PROTOCOLS, copy_db

HOSTILE = '<script>alert("x")</script> & <img src=x onerror=alert(1)>'
MAX_REPR = 300  # characters of any text repr
MAX_HTML = 20_000  # characters of any HTML display


@pytest.fixture(scope="module")
def lab_folder(tmp_path_factory, shipped_sweep) -> tuple[Path, Path]:
    """A quick-demo run, and a run whose name and thruster id are markup, both calibrated."""
    tmp = tmp_path_factory.mktemp("display")
    db = copy_db(shipped_sweep("quick-demo"), tmp / "lab.sqlite")
    text = (PROTOCOLS / "quick-demo.yaml").read_text()
    hostile = text.replace("name: quick-demo", f"name: {json.dumps(HOSTILE)}").replace(
        "thruster_id: demo", f"thruster_id: {json.dumps(HOSTILE)}").replace(
        "range: {start: -100, stop: 100, step: 10}", "range: {start: -100, stop: 100, step: 50}")
    assert hostile != text
    (tmp / "hostile.yaml").write_text(hostile)
    assert main(["sweep", str(tmp / "hostile.yaml"), "--sim", "--db", str(db)]) == 0
    for ref in ("quick-demo", "last"):
        run_id = _run_id(db, ref)
        assert main(["calibrate", run_id, "--db", str(db), "--out", str(tmp / "cal")]) == 0
    return db, tmp / "cal"


def _run_id(db: Path, ref: str) -> str:
    with rigtool.open(db) as lab:
        if ref == "last":
            return lab.run("last").id
        return next(r["id"] for r in lab.runs() if r["name"] == ref)


def _bounded(obj: object) -> str:
    text, page = repr(obj), obj._repr_html_()
    assert len(text) <= MAX_REPR and "\n" not in text, text
    assert len(page) <= MAX_HTML, len(page)
    return page


def test_points_show_their_size_not_every_value(lab_folder):
    db, _ = lab_folder
    with rigtool.open(db) as lab:
        points = lab.run(_run_id(db, "quick-demo")).points()
        page = _bounded(points)
    n_rows = len(points["step_idx"])
    assert n_rows == 42 and repr(points).startswith(f"<rigtool table: {n_rows} rows × ")
    assert f"{n_rows} rows × {len(points)} columns" in page
    assert page.count("<tr>") == 1 + 11  # the header, 5 + 5 rows and the gap between


def test_large_and_wide_tables_stay_bounded():
    wide = Columns({f"c{i}": np.arange(100_000.0) for i in range(200)})
    page = _bounded(wide)
    assert "100000 rows × 200 columns (160 not shown)" in page
    long_text = Records([{"detail": "x" * 100_000}] * 1000)
    assert "x" * 100 not in _bounded(long_text)


def test_hostile_names_are_escaped_everywhere(lab_folder):
    db, cal_dir = lab_folder
    with rigtool.open(db) as lab:
        run = lab.run("last")
        cal = rigtool.load_calibration(cal_dir / run.id)
        pages = [_bounded(x) for x in (lab, run, lab.runs(), run.events(), cal,
                                       lab.calibration(run))]
    assert HOSTILE in repr(run)  # text reprs show the name as it is
    for page in pages[:3]:
        assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; &lt;img" in page
    assert "&lt;script&gt;" in pages[4]  # the thruster id
    for page in pages:
        assert "<script" not in page and "<img" not in page and "onerror=" not in page.replace(
            "&lt;img src=x onerror=", "")


def test_values_and_calibrations(lab_folder):
    db, cal_dir = lab_folder
    cal = rigtool.load_calibration(cal_dir / _run_id(db, "quick-demo"))
    value = cal.coefficients["C_p_fwd"]
    assert re.fullmatch(r"<rigtool value C_p_fwd = \S+ \[\S+, \S+\] N/\(r/min\)\^2>", repr(value))
    assert _bounded(value).startswith("<code>C_p_fwd = ")
    page = _bounded(cal)
    assert "C_p_fwd" in page and "coefficients of the deepest section" in page
    assert str(Value("x", 1.0, float("nan"), float("nan"), "")) == "1"


def test_the_pandas_hint_works_from_a_clone():
    assert "pip install pandas" in PANDAS_HINT and "pip install -e '.[pandas]'" in PANDAS_HINT


def test_an_executed_notebook_shows_the_html_displays(lab_folder):
    """nbclient runs the notebook on an ipykernel, as Jupyter would; each display's HTML is
    among the cell's outputs."""
    nbformat = pytest.importorskip("nbformat", reason="nbformat not installed (pip install "
                                   "nbclient ipykernel)")
    nbclient = pytest.importorskip("nbclient", reason="nbclient not installed (pip install "
                                   "nbclient ipykernel)")
    pytest.importorskip("ipykernel", reason="ipykernel not installed (pip install ipykernel)")
    db, cal_dir = lab_folder
    run_id = _run_id(db, "quick-demo")
    cells = ["import rigtool", f"lab = rigtool.open({str(db)!r})\nlab",
             f"run = lab.run({run_id!r})\nrun", "run.points()", "lab.runs()",
             f"cal = rigtool.load_calibration({str(cal_dir / run_id)!r})\ncal",
             "cal.coefficients['C_p_fwd']"]
    book = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    nbclient.NotebookClient(book, timeout=120, kernel_name="python3").execute()
    shown = [[o["data"] for o in cell.outputs if o.get("output_type") == "execute_result"]
             for cell in book.cells]
    assert shown[0] == []
    wants = ["rigtool lab lab.sqlite", "rigtool run quick-demo", "42 rows ×", "rigtool records: 2 rows",
             f"rigtool calibration of run {run_id}", "C_p_fwd = "]
    for (data,), want in zip(shown[1:], wants, strict=True):
        assert want in data["text/html"] and len(data["text/html"]) <= MAX_HTML
        assert len(data["text/plain"]) <= MAX_REPR
