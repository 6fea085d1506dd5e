"""Every shipped protocol runs sweep -> calibrate -> report through the CLI with exit 0, as a
user would run it on the simulated rig (luo2020-cavitation after its deep base run)."""

from __future__ import annotations

import pytest

from rigtool.cli import main

from .conftest import PROTOCOLS

SHIPPED = sorted(p.stem for p in PROTOCOLS.glob("*.yaml"))
NEEDS = {"luo2020-cavitation": "luo2020-baseline"}  # a deep base run of the same thruster


def test_the_list_is_the_shipped_protocols():
    assert {"quick-demo", "luo2020-baseline", "luo2020-cavitation", "esc-1100-1900",
            "stm32-pwm"} <= set(SHIPPED)


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_sweep_calibrate_report(name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RIGTOOL_DB", str(tmp_path / "rigtool.sqlite"))
    for protocol in filter(None, (NEEDS.get(name), name)):
        assert main(["sweep", str(PROTOCOLS / f"{protocol}.yaml"), "--sim"]) == 0
    assert main(["calibrate", "last"]) == 0
    assert main(["report", "last"]) == 0
    report = capsys.readouterr().out.strip().splitlines()[-1]
    assert report.endswith("report.html") and (tmp_path / report).is_file()
    if name in NEEDS:
        assert 'id="cavitation"' in (tmp_path / report).read_text()
