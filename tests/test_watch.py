"""`rigtool watch`: data bounds, the server's routes and headers, and the page in headless
Chromium following a real sweep over real transports (docs/watch.md)."""

from __future__ import annotations

import html
import json
import re
import shutil
import socket
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.store import Store
from rigtool.watch import Watcher, WatchServer
from rigtool.watch.data import MAX_TRACE, decimate, detail_text, fit_cp
from rigtool.watch.server import HEADERS

from .conftest import PROTOCOLS
from .helpers import sim_process, stop_processes

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="headless Chromium not installed (Debian: apt-get install chromium)")

SIM_PROTOCOL = """\
rigtool_protocol: 1
name: {name}
simulator: {{profile: can-bldc, seed: 3}}
command: {{unit: percent, values: [-60, -45, -30, -15, 0, 15, 30, 45, 60]}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0.2}}
  acquire: {{samples: 300, rate_hz: 1000}}
  rest_s: 0.1
  tare: at_start
limits: {{max_thrust_n: 90, slew_per_s: 400}}
"""

REAL_PROTOCOL = """\
rigtool_protocol: 1
name: watch-e2e
command: {unit: pwm_counts, values: [0, 150, 300, 415, 460], repeats: 3}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 0.6}
  acquire: {samples: 600, rate_hz: 1000}
  rest_s: 0.2
  tare: at_start
limits: {max_thrust_n: 20}
"""


def _get(url: str, method: str = "GET", host: str | None = None) -> tuple[int, dict, bytes]:
    req = urllib.request.Request(url, method=method)
    if host:
        req.add_header("Host", host)
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            return resp.status, dict(resp.headers), resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def _sim_run(tmp_path: Path, name: str = "watch-sim") -> Path:
    protocol = tmp_path / "p.yaml"
    protocol.write_text(SIM_PROTOCOL.format(name=json.dumps(name, ensure_ascii=False)))
    db = tmp_path / "w.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    return db


@pytest.fixture
def served(tmp_path):
    """A finished sim run served on a free loopback port."""
    db = _sim_run(tmp_path)
    server = WatchServer(Watcher(db, "last"), 0)
    server.watcher.start()
    server.serve_in_thread()
    yield server
    server.stop()


# -- data and bounds -----------------------------------------------------------------------
def test_decimate_is_bounded_and_keeps_the_extremes():
    n = 1_000_003
    t = np.arange(n) / 7000.0
    thrust = np.sin(t) + np.where(np.arange(n) == 123_457, 50.0, 0.0)
    chunks = ({"t_s": t[i:i + 65536], "thrust_n": thrust[i:i + 65536],
               "speed_rpm": np.full(min(65536, n - i), np.nan),
               "current_a": np.full(min(65536, n - i), 1.0)} for i in range(0, n, 65536))
    out = decimate(chunks, n)
    assert 0 < len(out["t_s"]) <= MAX_TRACE
    assert np.all(np.diff(out["t_s"]) >= 0)
    assert out["thrust_n"].max() == pytest.approx(thrust.max())
    assert out["thrust_n"].min() == pytest.approx(thrust.min())
    short = decimate(iter([{"t_s": t[:10], "thrust_n": thrust[:10], "speed_rpm": t[:10],
                            "current_a": t[:10]}]), 10)
    assert len(short["t_s"]) == 10


def test_provisional_cp_fit_per_direction():
    n = np.array([-1500.0, -1000, -500, 0, 500, 1000, 1500])
    f = np.where(n > 0, 2e-5, 1.5e-5) * np.abs(n) * n
    fit = fit_cp(n, f)
    assert fit["fwd"]["C_p"] == pytest.approx(2e-5) and fit["rev"]["C_p"] == pytest.approx(1.5e-5)
    assert fit_cp(np.full(3, np.nan), f[:3])["reason"].startswith("no speed")
    assert fit_cp(n[3:5], f[3:5])["fwd"]["C_p"] is None  # too few points yet


def test_data_of_a_finished_run(tmp_path):
    db = _sim_run(tmp_path)
    watcher = Watcher(db)
    try:
        watcher.start()
        d = watcher.data()
    finally:
        watcher.close()
    assert d["run"]["status"] == "completed" and d["run"]["ended"]
    assert d["points"]["n_sent"] == 9 and d["progress"]["done"] == 9
    assert d["trace"]["n_samples"] == 300 and d["trace"]["step_idx"] == 8
    assert d["fit"]["provisional"] and "provisional" in d["fit"]["label"]
    assert d["fit"]["fwd"]["C_p"] > 0 and d["fit"]["rev"]["C_p"] > 0
    json.dumps(d, allow_nan=False)
    assert d["database"] == "w.sqlite"  # two servers on one PC: which database this is


def test_event_details_read_as_text_not_json(tmp_path):
    """A tare's six biases read as four significant digits each, not 17-digit JSON floats."""
    db = _sim_run(tmp_path)
    watcher = Watcher(db)
    try:
        watcher.start()
        items = watcher.data()["events"]["items"]
    finally:
        watcher.close()
    tare = next(e["detail"] for e in items if e["kind"] == "tare")
    assert re.search(r"\bbias \[[^\]]+\]", tare) and "{" not in tare and '"' not in tare
    numbers = re.findall(r"[-+]?\d[\d.]*(?:e[-+]?\d+)?", tare)
    assert numbers and all(len(re.sub(r"e.*|[-+.]", "", n).lstrip("0")) <= 4 for n in numbers)
    assert detail_text({"a": {"b": [0.1 + 0.2, None, True]}, "c": "x y"}) == (
        "a {b [0.3, null, true]}; c x y")


def test_sweep_watch_does_not_say_ctrl_c_stops_the_page(tmp_path):
    """Beside a sweep, Ctrl-C stops the sweep: the announcement says the page lasts while the
    sweep runs; `rigtool watch` alone says Ctrl-C stops it."""
    proc = subprocess.run([sys.executable, "-m", "rigtool.cli", "sweep",
                           str(PROTOCOLS / "quick-demo.yaml"), "--sim", "--watch", "0", "--db",
                           str(tmp_path / "s.sqlite")], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stderr.splitlines() if x.startswith("watch the run at"))
    assert line.endswith("(read-only; served while the sweep runs)")
    assert "Ctrl-C stops it" not in proc.stderr


def _running_run(db: Path, name: str, pid: int | None = None) -> str:
    """A run left marked running (its process `pid`, this one by default)."""
    with Store(db) as store:
        run_id = store.create_run(name=name, protocol={}, protocol_path=None, rig={}, plan=[],
                                  metadata={}, seed=1, command_unit="percent",
                                  tool_version="test")
        if pid is not None:
            store.conn.execute("UPDATE runs SET pid = ? WHERE id = ?", (pid, run_id))
    return run_id


def test_following_keeps_the_running_run_and_a_dead_one_shows_interrupted(tmp_path):
    """After an attack: a run created in the same database during a watched sweep took the
    page over, and a sweep killed with -9 showed "running" for ever."""
    db = _sim_run(tmp_path)
    watcher = Watcher(db, follow=True, cache_s=0.0)
    try:
        watcher.start()
        sweep = _running_run(db, "the sweep")
        assert watcher.data()["run"]["id"] == sweep
        assert main(["sweep", str(tmp_path / "p.yaml"), "--sim", "--db", str(db)]) == 0
        assert watcher.data()["run"]["id"] == sweep  # the new, finished run does not take over
    finally:
        watcher.close()
    other = tmp_path / "other"
    other.mkdir()
    db = _sim_run(other)
    watcher = Watcher(db, follow=True, cache_s=0.0)
    try:
        watcher.start()  # open first: the sweep dies while it is watched
        gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)
        dead = _running_run(db, "killed", pid=int(gone.stdout))
        run = watcher.data()["run"]
    finally:
        watcher.close()
    assert run["id"] == dead and run["status"] == "interrupted" and run["ended"]
    assert "gone" in run["stop_reason"]


def test_an_ended_run_is_read_once_and_queued_requests_share_a_read(tmp_path):
    db = _sim_run(tmp_path)
    now = [0.0]
    watcher = Watcher(db, "last", cache_s=0.5, clock=lambda: now[0])
    try:
        watcher.start()
        first = watcher.data()
        now[0] = 1e6  # long after: the run has ended, so nothing is read again
        assert watcher.data() is first
    finally:
        watcher.close()


# -- server: routes, headers, nothing writes --------------------------------------------------
def test_routes_headers_and_refusals(served, tmp_path):
    url = served.url
    code, headers, body = _get(url)
    assert code == 200 and b"<script src=\"/app.js\"" in body
    assert headers["Content-Security-Policy"].startswith("default-src 'self'")
    assert headers["X-Content-Type-Options"] == "nosniff"
    code, headers, body = _get(url + "data")
    assert code == 200 and headers["Content-Type"].startswith("application/json")
    assert json.loads(body)["run"]["name"] == "watch-sim"
    for path in ("data/../../etc/passwd", "static/app.js", "..%2f..%2fpyproject.toml", "x",
                 "uPlot.iife.min.js/", "favicon.ico"):
        assert _get(url + path)[0] == 404, path
    for method in ("POST", "PUT", "DELETE", "PATCH", "OPTIONS"):
        assert _get(url + "data", method)[0] == 404
    assert _get(url + "data", host="attacker.example")[0] == 404  # DNS rebinding
    code, headers, _ = _get(url + "data", "PROPFIND")  # the server's own error page
    assert code == 501 and headers["Content-Security-Policy"].startswith("default-src 'self'")
    assert _get(url + "uPlot.LICENSE")[2].startswith(b"The MIT License")
    before = (tmp_path / "w.sqlite").stat().st_mtime_ns
    for _ in range(3):
        _get(url + "data")
    assert (tmp_path / "w.sqlite").stat().st_mtime_ns == before


def _raw(url: str, request: bytes) -> bytes:
    """Send `request` as it is on a raw socket; everything the server answers."""
    host, port = url.split("//")[1].rstrip("/").rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.sendall(request)
        answer = b""
        while chunk := sock.recv(65536):
            answer += chunk
    return answer


@pytest.mark.parametrize("request_line", [b"GET / HTTP/9x", b"GET / FTP/1.0", b"GET /",
                                          b"GET / HTTP/1.1.1", b"GET / HTTP/"])
def test_every_error_page_carries_the_security_headers(served, request_line):
    """Issue 49: a request with an unparsable HTTP version was answered as HTTP/0.9, an
    error page with no status line and none of the headers docs/watch.md promises."""
    answer = _raw(served.url, request_line + b"\r\nHost: localhost\r\n\r\n")
    head = answer.split(b"\r\n\r\n", 1)[0].decode("latin-1")
    assert re.match(r"HTTP/1\.[01] (200|400|404|505) ", head), answer[:200]
    for name, value in HEADERS.items():
        assert f"\r\n{name}: {value}\r\n" in head + "\r\n", (name, head)


def test_a_port_in_use_is_named(tmp_path, capsys):
    db = _sim_run(tmp_path)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        capsys.readouterr()
        assert main(["watch", "--db", str(db), "--port", str(port)]) == 1
    assert f"127.0.0.1:{port}" in capsys.readouterr().err


def test_static_files_ship_as_package_data():
    text = (ROOT / "pyproject.toml").read_text()
    assert '"rigtool.watch" = ["static/*"]' in text
    static = ROOT / "rigtool" / "watch" / "static"
    for name in ("index.html", "app.js", "app.css", "uPlot.iife.min.js", "uPlot.min.css",
                 "uPlot.LICENSE"):
        assert (static / name).is_file()
    page = (static / "index.html").read_text()
    assert "<script>" not in page and "http" not in page.replace("http-equiv", "")  # no CDN
    assert "innerHTML" not in (static / "app.js").read_text()


def test_watch_cli_usage_errors(tmp_path, capsys):
    assert main(["watch", "--db", str(tmp_path / "none.sqlite"), "--port", "0"]) == 2
    assert "no run database" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["watch", "--port", "70000"])


# -- the page in headless Chromium --------------------------------------------------------
def _chromium(url: str, *extra: str, budget_ms: int = 3000) -> str:
    """Chromium's DOM of `url` after `budget_ms` of virtual time (the page polls meanwhile)."""
    out = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--no-first-run", "--disable-extensions", "--window-size=1300,1100",
         f"--virtual-time-budget={budget_ms}", *extra, url],
        capture_output=True, text=True, timeout=90)
    return out.stdout


def _dom(url: str) -> str:
    return _chromium(url, "--dump-dom")


def _attr(dom: str, element_id: str, attr: str) -> str:
    tag = re.search(rf'<[^>]*\bid="{element_id}"[^>]*>', dom)
    assert tag, f"#{element_id} not in the page"
    value = re.search(rf'\b{attr}="([^"]*)"', tag.group(0))
    return html.unescape(value.group(1)) if value else ""


def _text(dom: str, element_id: str) -> str:
    m = re.search(rf'<(\w+)[^>]*\bid="{element_id}"[^>]*>(.*?)</\1>', dom, re.S)
    assert m, f"#{element_id} not in the page"
    return html.unescape(re.sub(r"<[^>]+>", "", m.group(2)))


def _url_from(proc: subprocess.Popen) -> str:
    """The page address a `watch` or `sweep --watch` process prints on stderr."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        m = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
        if m:
            return m.group(1)
        assert line or proc.poll() is None, "no watch address printed"
    raise AssertionError("no watch address printed")


def _stored(db: Path) -> int:
    with Store(db, read_only=True) as store:
        return len(store.steps(store.resolve_run_id("last")))


@pytest.mark.slow
@needs_chromium
def test_page_follows_a_real_sweep_to_its_end(tmp_path):
    """Sweep over TCP/UDP with `--watch`, and `rigtool watch` beside it: the plotted points
    grow, the trace moves to the newest point, and the page says how the run ended."""
    rig = tmp_path / "sim-rig.yaml"
    with sim_process(rig, "stm32-pwm", stdout=subprocess.DEVNULL):
        protocol = tmp_path / "p.yaml"
        protocol.write_text(REAL_PROTOCOL)
        db = tmp_path / "e2e.sqlite"
        sweep = watch = None
        try:
            sweep = subprocess.Popen(
                [sys.executable, "-m", "rigtool.cli", "sweep", str(protocol), "--rig", str(rig),
                 "--db", str(db), "--watch", "0"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                text=True)
            in_sweep = _url_from(sweep)
            deadline = time.monotonic() + 60
            while _stored_or_zero(db) < 2:
                assert time.monotonic() < deadline and sweep.poll() is None, "no points stored"
                time.sleep(0.2)
            code, _, body = _get(in_sweep + "data")  # the server inside the sweep process
            assert code == 200 and json.loads(body)["run"]["status"] == "running"
            watch = subprocess.Popen(
                [sys.executable, "-m", "rigtool.cli", "watch", "--db", str(db), "--port", "0"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                text=True)
            url = _url_from(watch)
            first = _dom(url)
            count1 = int(_attr(first, "npoints", "data-count"))
            step1 = _attr(first, "trace-info", "data-step")
            assert count1 >= 2 and step1 != ""
            assert _attr(first, "ended", "hidden") is not None and "run ended" not in _text(first, "ended")
            target = _stored(db) + 2
            while _stored(db) < target:
                assert time.monotonic() < deadline + 60 and sweep.poll() is None, "sweep stalled"
                time.sleep(0.2)
            # the server may answer from its cache for a while (longer on a loaded machine:
            # it bounds its own share of the CPU, rigtool/watch/data.py): look again
            for _ in range(5):
                second = _dom(url)
                count2 = int(_attr(second, "npoints", "data-count"))
                if count2 > count1:
                    break
                time.sleep(1.0)
            step2 = _attr(second, "trace-info", "data-step")
            assert count2 > count1, (count1, count2)
            assert int(step2) > int(step1)
            assert _text(second, "state") in ("rest", "settling", "acquiring", "finishing")
            assert sweep.wait(timeout=120) == 0
            end = _dom(url)
            assert "run ended: completed" in _text(end, "ended")
            assert int(_attr(end, "npoints", "data-count")) == 15
            assert _text(end, "progress-text").startswith("15 / 15")
            _chromium(url, f"--screenshot={tmp_path / 'watch.png'}")
            assert (tmp_path / "watch.png").stat().st_size > 10_000
        finally:
            stop_processes(sweep, watch)
        assert watch.returncode in (0, -15)


def _stored_or_zero(db: Path) -> int:
    try:
        return _stored(db)
    except Exception:  # noqa: BLE001 - the sweep has not created its run yet
        return 0


HOSTILE_NAME = ('<script>document.title="PWNED"</script><img src=x onerror="document.title='
                '\'PWNED\'"> & "quotes" \u00dcn\u00efc\u00f8d\u00e9 \u2603 \U0001d54f \u202eRTL')
HOSTILE_DETAIL = '</td><td><b>bold</b><iframe src="javascript:alert(1)"></iframe> \u2028\u0000'


@needs_chromium
def test_hostile_text_is_shown_literally(tmp_path):
    db = _sim_run(tmp_path, HOSTILE_NAME.replace("\u202e", ""))
    with Store(db) as store:
        run_id = store.resolve_run_id("last")
    with sqlite3.connect(db) as con:  # a protocol refuses U+202E; a merged database may hold it
        con.execute("UPDATE runs SET name = ?, protocol_json = json_set(protocol_json, '$.name', "
                    "?) WHERE id = ?", (HOSTILE_NAME, HOSTILE_NAME, run_id))
    con.close()
    with Store(db) as store:
        store.add_event(run_id, "warning", {"message": HOSTILE_DETAIL}, t_s=1.0, step_idx=2)
        store.add_event(run_id, "<svg onload=alert(1)>", {"x": HOSTILE_NAME}, t_s=2.0)
    watcher = Watcher(db)
    server = WatchServer(watcher, 0)
    watcher.start()
    server.serve_in_thread()
    try:
        dom = _dom(server.url)
    finally:
        server.stop()
    assert _text(dom, "run-name") == HOSTILE_NAME.replace("\u0000", "")
    events = _text(dom, "events")
    assert "<svg onload=alert(1)>" in events and "</td><td><b>bold</b><iframe" in events
    assert "\u2603" in events and "\U0001d54f" in events
    title = re.search(r"<title>(.*?)</title>", dom, re.S).group(1)
    assert html.unescape(title).startswith("completed · <script>document.title=")  # no script ran
    assert "<img" not in dom and "<iframe" not in dom and "<svg" not in dom and "<b>" not in dom
    assert dom.count("<script") == 2  # uPlot and app.js only


@needs_chromium
def test_page_names_its_database_and_keeps_one_time_zone(served):
    """The page names the database file and the run, says its times are UTC and shows no
    local clock, and draws thrust, speed and current each on a chart of its own."""
    dom = _dom(server_url := served.url)
    assert _text(dom, "db-name") == "w.sqlite" and _text(dom, "run-name") == "watch-sim"
    assert "times in UTC" in dom and re.search(r"updated \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC",
                                                 _text(dom, "conn")), server_url
    assert not re.search(r"\d:\d\d:\d\d\s?[AP]M", dom)
    assert "w.sqlite" in html.unescape(re.search(r"<title>(.*?)</title>", dom, re.S).group(1))
    charts = re.findall(r'<div id="trace-(\w+)"><div class="uplot', dom)
    assert charts == ["thrust_n", "speed_rpm", "current_a"]
