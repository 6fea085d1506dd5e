"""HTML report: self-contained, expected figures and tables, warnings, PWM vs speed-feedback runs."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import time
from html.parser import HTMLParser
from pathlib import Path

import pytest

from rigtool.analysis.calibrate import calibrate_run
from rigtool.progress import SilentReporter
from rigtool.report import write_report
from rigtool.report.html import fmt_num, fmt_unit
from rigtool.run_warnings import group_by_depth
from rigtool.store import Store
from rigtool.sweep import resolve, run_sweep
from rigtool.workflows import calibrate, report

CAN_PROTOCOL = """\
rigtool_protocol: 1
name: report-can
description: Small up-down sweep for the report tests.
simulator: {{profile: can-bldc, seed: 7}}
metadata:
  thruster_id: T-report
  operator: pytest
  notes: report test run
  propeller_diameter_m: 0.2
  water_density_kg_m3: 1000
command:
  unit: percent
  range: {{start: {start}, stop: 100, step: 25}}
  order: up-down
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{samples: 150, rate_hz: 500}}
  rest_s: 0.1
  tare: {tare}
limits:
  max_thrust_n: {max_thrust}
  slew_per_s: 400
"""

PWM_PROTOCOL = """\
rigtool_protocol: 1
name: report-pwm
simulator: {profile: stm32-pwm, seed: 2017}
metadata: {thruster_id: stern-1}
command:
  unit: pwm_counts
  range: {start: 400, stop: 460, step: 1}
depth: {unit: cm, values: [30]}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 100, rate_hz: 250}
  rest_s: 0.1
  tare: at_start
limits:
  max_thrust_n: 10
"""

SPEED_FIGURES = ("command-curve", "inverse-map", "thrust-speed", "current-speed", "hysteresis",
                 "spread", "time-series", "tare-drift")


class _Page(HTMLParser):
    """Collects tags with their attributes, and the text."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data: str) -> None:
        self.text.append(data)

    def by_attr(self, name: str) -> dict[str, dict[str, str | None]]:
        return {a[name]: a for _, a in self.tags if a.get(name)}  # type: ignore[misc]


def _parse(path: Path) -> tuple[str, _Page]:
    html = path.read_text(encoding="utf-8")
    page = _Page()
    page.feed(html)
    return html, page


def _sweep(tmp: Path, name: str, text: str) -> tuple[Store, str]:
    protocol = tmp / f"{name}.yaml"
    protocol.write_text(text)
    store = Store(tmp / f"{name}.sqlite")
    outcome = run_sweep(resolve(protocol, sim=True), store, SilentReporter())
    return store, outcome.run_id


@pytest.fixture(scope="module")
def can_report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Store, str]:
    tmp = tmp_path_factory.mktemp("can")
    store, run_id = _sweep(tmp, "can", CAN_PROTOCOL.format(start=-100, tare="per_point", max_thrust=90))
    calibrate(store, run_id, tmp / "out")
    return report(store, run_id, tmp / "out"), store, run_id


@pytest.fixture(scope="module")
def pwm_report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Store, str]:
    tmp = tmp_path_factory.mktemp("pwm")
    store, run_id = _sweep(tmp, "pwm", PWM_PROTOCOL)
    calibrate(store, run_id, tmp / "out")
    return report(store, run_id, tmp / "out"), store, run_id


def test_report_is_self_contained(can_report):
    path, _, run_id = can_report
    assert path.name == "report.html" and path.parent.name == run_id
    html, page = _parse(path)
    links = [(tag, key, value) for tag, attrs in page.tags for key, value in attrs.items()
             if key in ("src", "href", "srcset", "data", "action", "poster")]
    assert links, "figures are embedded as <img src=data:...>"
    for tag, key, value in links:
        assert value and (value.startswith("data:") or value.startswith("#")), (tag, key)
    assert not re.search(r"https?://", html)
    assert not [t for t, a in page.tags if t in ("script", "link", "iframe", "object", "embed")]
    assert "url(" not in html and "@import" not in html
    assert "@page" in html and "size: A4" in html and "page-break-inside: avoid" in html


def test_speed_feedback_run_has_every_figure_and_the_coefficient_table(can_report):
    path, _, run_id = can_report
    html, page = _parse(path)
    figures = page.by_attr("data-figure")
    assert set(SPEED_FIGURES) <= set(figures), sorted(figures)
    imgs = [a for t, a in page.tags if t == "img"]
    assert len(imgs) >= len(SPEED_FIGURES)
    assert all(a["src"].startswith("data:image/svg+xml;base64,") and a.get("alt") for a in imgs)
    ids = page.by_attr("id")
    for key in ("warnings", "run-metadata", "protocol", "coefficients-1", "features-1",
                "fig-thrust-speed", "fig-command-curve", "fig-tare-drift"):
        assert key in ids, key
    text = " ".join(page.text)
    for word in ("C_p_fwd", "C_p_rev", "C_n", "I_0", "K_T_fwd", "95 % interval", "R²", "RMS",
                 run_id, "T-report", "pytest", "report test run", "hysteresis max"):
        assert word in text, word
    assert "tare_drift" in text


def test_pwm_run_has_command_curve_with_dead_zone_and_no_speed_figure(pwm_report):
    path, store, run_id = pwm_report
    _, page = _parse(path)
    figures = page.by_attr("data-figure")
    omitted = page.by_attr("data-omitted")
    assert {"command-curve", "inverse-map", "spread", "time-series"} <= set(figures)
    assert "thrust-speed" not in figures and "current-speed" not in figures
    assert "thrust-speed" in omitted
    text = " ".join(page.text)
    assert "No propeller speed feedback" in text
    curve = calibrate_run(store, run_id).sections[0].curve
    assert curve is not None and curve.dead_zones
    lo, hi = curve.dead_zones[0]
    assert f"{lo:g} .. {hi:g} PWM counts" in text
    assert "break-away" in text and "inverted" in text


def test_aborted_run_reports_its_warnings(tmp_path):
    text = CAN_PROTOCOL.format(start=0, tare="at_start", max_thrust=35)
    store, run_id = _sweep(tmp_path, "abort", text)
    assert store.run(run_id)["status"] == "aborted" and store.steps(run_id)
    calibrate(store, run_id, tmp_path / "out")
    _, page = _parse(report(store, run_id, tmp_path / "out"))
    warnings = " ".join(page.text)
    assert "Warnings (" in warnings
    assert "Run aborted: limit trip" in warnings and "limit_trip at t =" in warnings
    assert "run status is 'aborted'" in warnings
    assert "command-curve" in page.by_attr("data-figure")


def test_run_without_points_still_reports(tmp_path):
    store = Store(tmp_path / "empty.sqlite")
    run_id = store.create_run(name="empty", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=None, command_unit="percent",
                              tool_version="test")
    store.finish_run(run_id, "failed", "no rig")
    html, page = _parse(report(store, run_id, tmp_path / "out"))
    assert "Run failed: no rig" in html and "nothing to calibrate" in html
    assert not page.by_attr("data-figure")


def test_png_output_and_given_calibration(can_report, tmp_path):
    _, store, run_id = can_report
    cal = calibrate_run(store, run_id)
    start = time.perf_counter()
    path = write_report(store, run_id, tmp_path, cal, image_format="png")
    assert time.perf_counter() - start < 20
    _, page = _parse(path)
    assert all(a["src"].startswith("data:image/png;base64,") for t, a in page.tags if t == "img")


def test_number_and_unit_formatting():
    assert fmt_num(1.926e-5) == "1.9260×10<sup>−5</sup>"
    assert fmt_num(0.5) == "0.5" and fmt_num(-2.25) == "−2.25"
    assert fmt_num(float("nan")) == "–" and fmt_num(None) == "–"
    assert fmt_unit("N/(r/min)^2") == "N/(r/min)<sup>2</sup>"
    assert fmt_unit("N/A^(2/3)") == "N/A<sup>2/3</sup>"


def test_warnings_repeated_at_several_depths_are_merged():
    merged = group_by_depth(["drift", "0.2 m: few points", "0.3 m: few points", "0.3 m: poor"],
                            ["0.2 m", "0.3 m"])
    assert merged == ["drift", "0.2 m, 0.3 m: few points", "0.3 m: poor"]


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
MEASURE = ("<script>document.body.dataset.widths = JSON.stringify([...document.querySelectorAll("
           "'table')].map(t => [t.id, t.getBoundingClientRect().width, "
           "t.parentElement.clientWidth]))</script></body>")


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (Debian: "
                    "apt-get install chromium)")
@pytest.mark.parametrize("window", [1300, 760])
def test_tables_keep_to_their_column_in_chromium(can_report, tmp_path, window):
    """Every table, the coefficient tables too, is laid out within its column (as Chromium
    lays the page out; the measuring script is added to a copy, the report has none)."""
    path, _, _ = can_report
    copy = tmp_path / "measured.html"
    copy.write_text(path.read_text().replace("</body>", MEASURE))
    dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                          "--hide-scrollbars", f"--window-size={window},900", "--dump-dom",
                          copy.as_uri()], capture_output=True, text=True, timeout=90).stdout
    found = re.search(r'data-widths="([^"]*)"', dom)
    assert found, dom[-2000:]
    widths = json.loads(html.unescape(found.group(1)))
    assert any(name.startswith("coefficients-") for name, _, _ in widths)
    assert [(n, w, c) for n, w, c in widths if w > c + 0.5] == []


def test_protocol_settings_are_open_so_they_print(can_report):
    """A closed <details> does not print: the protocol settings are open."""
    path, _, _ = can_report
    tag = re.search(r'<details[^>]*id="protocol"[^>]*>', path.read_text())
    assert tag and re.search(r"\bopen\b", tag.group(0))
