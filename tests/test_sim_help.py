"""`rigtool sim --help` offers the sensor personalities and thruster profiles from their one
list each (sim/personalities.py SENSORS, thruster_profiles.PROFILES), not a copy in the help text."""

from __future__ import annotations

import pytest

from rigtool.cli import main
from rigtool.sim.personalities import SENSORS
from rigtool.thruster_profiles import PROFILES


def test_sim_help_lists_every_personality_and_profile(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["sim", "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert " | ".join(SENSORS) in text and " | ".join(PROFILES) in text


def test_an_unknown_personality_names_the_list(capsys):
    assert main(["sim", "--sensor", "load-cell"]) == 2
    assert ", ".join(SENSORS) in capsys.readouterr().err
