"""`export --all` keeps the axes of a calibration (issue item 10): _tables/calibrations.pq has
the supply voltage set, the section's role (deep or shallow) and the API's main section, carries the
C_n(U) law of a voltage sweep with its intervals, and docs/sql.md's "C_p forward of every
thruster" returns each thruster's own coefficient, one row per thruster. Through the CLI and
the Python API, on twins and axes the export was not developed on."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pyarrow.parquet as pq
import pytest

import rigtool
from rigtool.cli import main

ROOT = Path(__file__).resolve().parents[1]
DEPTHS, VOLTS = [0.45, 1.2], [13.0, 15.5, 18.0, 21.0]
SWEEP = """\
rigtool_protocol: 1
name: {name}
simulator: {{profile: {profile}, seed: {seed}, overrides: {{feedback: [speed_rpm, current_a,
             voltage_v]}}}}
metadata: {{thruster_id: {thruster}}}
command: {{unit: pulse_us, range: {{start: 1100, stop: 1900, step: 100}}}}
depth: {{unit: m, values: {depths}}}
{voltage}timing:
  settle: {{seconds: 0.4}}
  acquire: {{seconds: 0.4, rate_hz: 400}}
  tare: at_start
limits: {{max_current_a: 80}}
"""


def _sweep(tmp: Path, db: Path, name: str, thruster: str, seed: int, depths: list[float],
           volts: list[float] | None = None) -> str:
    """Sweep a protocol on the ESC twin, calibrate the run, and return its id."""
    voltage = "" if volts is None else f"voltage: {{unit: V, values: {volts}}}\n"
    path = tmp / f"{name}.yaml"
    path.write_text(SWEEP.format(name=name, profile="esc-1100-1900", seed=seed,
                                 thruster=thruster, depths=depths, voltage=voltage))
    assert main(["sweep", str(path), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp / "cal")]) == 0
    with rigtool.open(db) as lab:
        return lab.run("last").id


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A voltage sweep of `bow-1` at a shallow and a deep depth, a later shallow-only run of
    the same thruster, a deep run of `stern-2`, all calibrated, exported with --all."""
    tmp = tmp_path_factory.mktemp("calexport")
    db = tmp / "lab.sqlite"
    ids = {"volts": _sweep(tmp, db, "volts", "bow-1", 4242, DEPTHS, VOLTS),
           "shallow": _sweep(tmp, db, "shallow", "bow-1", 4243, [0.3]),
           "stern": _sweep(tmp, db, "stern", "stern-2", 4244, [0.9])}
    assert main(["export", "--all", "--out", str(tmp / "ds"), "--db", str(db)]) == 0
    table = pq.read_table(tmp / "ds" / "_tables/calibrations.pq")
    return tmp, db, ids, table


def _api(db: Path, run_id: str) -> rigtool.api.Calibration:
    with rigtool.open(db) as lab:
        return lab.calibration(run_id)


def test_every_voltage_and_depth_is_its_own_row_with_a_role(dataset):
    _, db, ids, table = dataset
    assert {"voltage_set_v", "role", "main_section"} <= set(table.column_names)
    assert str(table.schema.field("main_section").type) == "bool"
    cal = table.to_pandas()
    mine = cal[(cal.run_id == ids["volts"]) & (cal.coefficient == "C_p_fwd")]
    pairs = zip(mine.depth_m, mine.voltage_set_v, strict=True)
    assert sorted(pairs) == list(itertools.product(DEPTHS, VOLTS))
    assert dict(zip(mine.depth_m, mine.role, strict=True)) == {0.45: "shallow", 1.2: "deep"}
    sections = cal[cal.voltage_set_v.notna()]
    assert not sections.duplicated(["run_id", "depth_m", "voltage_set_v", "coefficient"]).any()
    api = _api(db, ids["volts"])
    for row in mine.itertuples():
        expected = api.coefficients_at(row.depth_m, row.voltage_set_v)["C_p_fwd"]
        assert (row.value, row.lo, row.hi) == pytest.approx(
            (expected.value, expected.lo, expected.hi), rel=1e-9)
    (main_row,) = mine[mine.main_section].itertuples()
    assert (main_row.depth_m, main_row.voltage_set_v) == (1.2, 15.5)  # the API's default
    assert main_row.value == pytest.approx(api.coefficients["C_p_fwd"].value, rel=1e-9)
    stern = cal[cal.run_id == ids["stern"]]
    assert stern.voltage_set_v.isna().all() and set(stern.role) == {"deep"}
    assert set(cal[cal.run_id == ids["shallow"]].role) == {"shallow"}
    assert stern.main_section.all()


def test_the_voltage_law_rows_carry_k_and_b_with_intervals(dataset):
    _, db, ids, table = dataset
    cal = table.to_pandas()
    laws = cal[cal.coefficient.str.startswith("C_n_law_")]
    assert set(laws.run_id) == {ids["volts"]} and laws.voltage_set_v.isna().all()
    assert sorted(zip(laws.depth_m, laws.coefficient, strict=True)) == sorted(itertools.product(
        DEPTHS, ["C_n_law_b", "C_n_law_k", "C_n_law_k_inverse"]))
    assert ((laws.lo < laws.value) & (laws.value < laws.hi)).all()
    api = _api(db, ids["volts"])
    for law in api.voltage_laws:
        rows = laws[laws.depth_m == law["depth_m"]].set_index("coefficient")
        for term in ("k", "b", "k_inverse"):
            assert rows.loc[f"C_n_law_{term}", "value"] == pytest.approx(law[term]["value"],
                                                                         rel=1e-9)
            assert rows.loc[f"C_n_law_{term}", "unit"] == law[term]["unit"]
        assert rows.main_section.all() == (law["depth_m"] == 1.2)
    main = laws[laws.main_section].set_index("coefficient")["value"]
    assert main["C_n_law_k"] * 15.5 ** main["C_n_law_b"] == pytest.approx(
        api.current_coefficient(15.5), rel=1e-9)
    assert -1.4 < main["C_n_law_b"] < -0.6  # C_n ~ 1/U on the twin


def _own_coefficients(dataset) -> tuple[dict, int]:
    """What the pandas form of the documented query gives: thruster -> (run, value, role)."""
    tmp, _, _, _ = dataset
    (code,) = [c for c in re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "sql.md").read_text(),
                                     re.S) if "own = " in c]
    scope: dict = {}
    exec(compile(code.replace("DIR", str(tmp / "ds")), "docs/sql.md", "exec"), scope)
    own = scope["own"]
    return {r.thruster_id: (r.run_id, r.value, r.depth_m, r.voltage_set_v)
            for r in own.itertuples()}, len(own)


def _expected(dataset) -> dict:
    """Each thruster's own C_p_fwd as the API gives it for its deep run."""
    _, db, ids, _ = dataset
    return {"bow-1": (ids["volts"], _api(db, ids["volts"]).coefficients["C_p_fwd"].value,
                      1.2, 15.5),
            "stern-2": (ids["stern"], _api(db, ids["stern"]).coefficients["C_p_fwd"].value,
                        0.9, None)}


def _same(got: dict, expected: dict) -> None:
    assert got.keys() == expected.keys()
    for thruster, (run_id, value, depth, volts) in expected.items():
        g = got[thruster]
        assert g[0] == run_id and g[1] == pytest.approx(value, rel=1e-9) and g[2] == depth
        assert (volts is None and g[3] != g[3]) or g[3] == volts  # NaN: no voltage axis


def test_the_documented_query_gives_each_thrusters_own_coefficient(dataset):
    got, rows = _own_coefficients(dataset)
    assert rows == 2  # one row per thruster, none of the shallow run's
    _same(got, _expected(dataset))


def test_the_documented_duckdb_query_agrees(dataset):
    duckdb = pytest.importorskip("duckdb")
    tmp = dataset[0]
    text = (ROOT / "docs" / "sql.md").read_text()
    sql = re.search(r"(SELECT thruster_id, rig, run_id, depth_m.*?;)", text, re.S).group(1)
    con = duckdb.connect()
    cur = con.execute(sql.replace("DIR", str(tmp / "ds")))
    names = [d[0] for d in cur.description]
    rows = [dict(zip(names, r, strict=True)) for r in cur.fetchall()]
    assert len(rows) == 2
    _same({r["thruster_id"]: (r["run_id"], r["c_p_fwd"], r["depth_m"],
                              float("nan") if r["voltage_set_v"] is None
                              else r["voltage_set_v"]) for r in rows}, _expected(dataset))
