"""Analysis stages show a spinner and their duration on a terminal, and nothing in a pipe."""

from __future__ import annotations

import io

from rich.console import Console

from rigtool.progress import stage


def test_terminal_gets_the_stage_and_its_duration():
    buf = io.StringIO()
    with stage("calibrating run X", Console(file=buf, force_terminal=True, width=80)):
        pass
    assert "calibrating run X ..." in buf.getvalue() and "calibrating run X: " in buf.getvalue()


def test_pipe_stays_quiet():
    buf = io.StringIO()
    with stage("calibrating run X", Console(file=buf, force_terminal=False)):
        pass
    assert buf.getvalue() == ""
