"""`import rigtool.rig` (and the CLI, the sweep and the API) loads no pyserial, python-can or
cantools: the drivers import them when they open a port or a bus, so a dry run, `show` or a
notebook starts without them (issue: clear rooms)."""

from __future__ import annotations

import subprocess
import sys


def test_importing_the_rig_loads_no_transport_library():
    code = ("import sys, rigtool.rig, rigtool.cli, rigtool.sweep, rigtool.api\n"
            "rigtool.cli.build_parser()\n"  # every command's options, as `rigtool X --help`
            "print(sorted(m for m in ('serial', 'can', 'cantools') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
