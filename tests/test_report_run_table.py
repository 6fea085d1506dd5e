"""The report's Run table: the supply voltages of a run with a voltage axis; an imported run
is told nothing about protocol settings that do not apply to it."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

from rigtool.cli import main

VOLTAGE_SWEEP = """\
rigtool_protocol: 1
name: volts
simulator:
  profile: esc-1100-1900
  seed: 77
  overrides: {{feedback: [speed_rpm, current_a, voltage_v]}}
metadata: {{thruster_id: esc-9}}
command: {{unit: pulse_us, range: {{start: 1100, stop: 1900, step: 100}}, order: up}}
depth: {{unit: m, values: [1.0], mode: preset}}
voltage: {{unit: V, values: {volts}, order: {order}, mode: preset, tolerance_frac: 0.2}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{seconds: 0.5, rate_hz: 250}}
  rest_s: 0.1
  tare: per_depth
limits: {{max_thrust_n: 120, max_current_a: 60, slew_per_s: 800}}
"""


class _Rows(HTMLParser):
    """(label, value) rows of the table with id `table_id`."""

    def __init__(self, table_id: str) -> None:
        super().__init__()
        self.table_id, self.inside, self.rows, self.cell = table_id, False, [], None

    def handle_starttag(self, tag: str, attrs: list) -> None:
        if tag == "table" and dict(attrs).get("id") == self.table_id:
            self.inside = True
        elif self.inside and tag == "tr":
            self.rows.append([])
        elif self.inside and tag == "td":
            self.cell = ""

    def handle_endtag(self, tag: str) -> None:
        if tag == "table":
            self.inside = False
        elif self.inside and tag == "td" and self.cell is not None:
            self.rows[-1].append(self.cell.strip())
            self.cell = None

    def handle_data(self, data: str) -> None:
        if self.cell is not None:
            self.cell += data


def _report(tmp: Path, db: str) -> str:
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "out")]) == 0
    assert main(["report", "last", "--db", db, "--out", str(tmp / "out")]) == 0
    return next((tmp / "out").glob("*/report.html")).read_text()


def _run_table(html: str) -> dict[str, str]:
    parser = _Rows("run-metadata")
    parser.feed(html)
    return {row[0]: row[1] for row in parser.rows if len(row) == 2}


def test_run_table_shows_the_supply_voltages_and_their_mode(tmp_path, capsys):
    protocol = tmp_path / "volts.yaml"
    protocol.write_text(VOLTAGE_SWEEP.format(volts="[13.5, 21, 17]", order="down"))
    db = str(tmp_path / "db.sqlite")
    assert main(["sweep", str(protocol), "--sim", "--db", db]) == 0
    rows = _run_table(_report(tmp_path, db))
    volts = rows["supply voltages"]
    assert volts.startswith("21, 17, 13.5 V"), volts
    assert "order down" in volts and "mode preset" in volts and "20 %" in volts


def test_run_without_a_voltage_axis_has_no_voltage_row(tmp_path, capsys):
    protocol = tmp_path / "plain.yaml"
    text = VOLTAGE_SWEEP.format(volts="[16]", order="up")
    protocol.write_text(re.sub(r"voltage: .*\n", "", text))
    db = str(tmp_path / "db.sqlite")
    assert main(["sweep", str(protocol), "--sim", "--db", db]) == 0
    assert "supply voltages" not in _run_table(_report(tmp_path, db))


def test_imported_run_is_not_told_to_set_protocol_timing(tmp_path, capsys):
    rows = ["Time (s),ESC signal (µs),Thrust (kgf)"]
    t = 0.0
    for cmd in range(1100, 1901, 50):
        for _ in range(40):
            x = max(abs(cmd - 1500) - 30, 0) / 370
            rows.append(f"{t:.3f},{cmd},{(1 if cmd > 1500 else -0.8) * 4 * x * x:.5f}")
            t += 0.05
    log = tmp_path / "stand.csv"
    log.write_text("\n".join(rows) + "\n")
    db = str(tmp_path / "db.sqlite")
    assert main(["import", str(log), "--db", db]) == 0
    html = _report(tmp_path, db)
    assert "timing.tare" not in html and "protocol" not in _figure_text(html, "fig-tare-drift")
    assert "an imported run records no tares" in html


def _figure_text(html: str, fig_id: str) -> str:
    """The text of the figure slot `fig_id` (its caption or its note)."""
    start = html.index(f'id="{fig_id}"')
    return html[start:html.index("</figure>", start)] if "</figure>" in html[start:] else ""
