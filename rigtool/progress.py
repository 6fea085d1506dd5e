"""Terminal progress: a live bar with ETA for sweeps, a spinner for analysis stages with a
bar per task the analysis reports (its `ProgressHook`); sparse plain lines (or nothing) when
the output is not a terminal."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, TextIO

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from rigtool.progress_hook import ProgressHook, no_progress
from rigtool.units import unit_label

if TYPE_CHECKING:  # the plan's pydantic models cost 0.25 s to import: not at start-up
    from rigtool.plan import PlanStep


def _live_text(step: PlanStep, unit: str, thrust_n: float | None,
               command: float | None = None) -> str:
    """One progress line: the command (the step's unless given), depth, the supply voltage of
    the pass (when the protocol sets one) and thrust read at it."""
    thrust = "   --   " if thrust_n is None else f"{thrust_n:8.2f}"
    cmd = step.command if command is None else command
    supply = "" if step.voltage_v is None else f"supply {step.voltage_v:5.1f} V  "
    return (f"cmd {cmd:8.2f} {unit_label(unit)}  depth {step.depth_m:5.2f} m  {supply}"
            f"thrust {thrust} N")


class RichReporter:
    """Live progress bar: point i/N, command, depth, live thrust, elapsed and ETA."""

    wants_live = True  # the engine computes live thrust only for reporters that show it

    def __init__(self, console: Console | None = None) -> None:
        self.console = console or Console(stderr=True, markup=False)
        self._progress: Progress | None = None
        self._task = None
        self._unit = ""
        self._last_live = 0.0

    def start(self, run_id: str, n_steps: int, unit: str, done: int = 0) -> None:
        self._unit = unit
        self.console.print(Text.assemble(
            "run ", (run_id, "bold"), f": {n_steps} points "
            "(Ctrl-C finishes the current point and stops; twice stops now)"))
        self._progress = Progress(
            TextColumn("[progress.description]{task.description}"), BarColumn(),
            MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
            console=self.console, transient=False,
        )
        self._progress.start()
        self._task = self._progress.add_task("starting", total=n_steps, completed=done)

    def live(self, step: PlanStep, thrust_n: float | None, command: float) -> None:
        """Show `thrust_n`, just read with `command` sent (ramps, settle and rest included)."""
        now = time.monotonic()
        if self._progress is not None and now - self._last_live > 0.1:
            self._last_live = now
            self._progress.update(self._task,
                                  description=_live_text(step, self._unit, thrust_n, command))

    def step_done(self, step: PlanStep, thrust_n: float | None) -> None:
        if self._progress is not None:
            self._progress.update(self._task, advance=1,
                                  description=_live_text(step, self._unit, thrust_n))

    def note(self, text: str) -> None:
        self.console.print(text, markup=False)

    def finish(self) -> None:
        self.finished = True
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


class PlainReporter:
    """For logs and pipes: a line at start, every tenth of the run, on notes, and at the end."""

    wants_live = False

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        self._n = 0
        self._done = 0
        self._unit = ""
        self._t0 = time.monotonic()
        self._next_report = 0

    def _print(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    def start(self, run_id: str, n_steps: int, unit: str, done: int = 0) -> None:
        self._n, self._done, self._unit = n_steps, done, unit
        self._t0 = time.monotonic()
        self._next_report = done + max(1, n_steps // 10)
        self._print(f"run {run_id}: {n_steps} points")

    def live(self, step: PlanStep, thrust_n: float | None, command: float) -> None:
        return None

    def step_done(self, step: PlanStep, thrust_n: float | None) -> None:
        self._done += 1
        if self._done >= self._next_report or self._done == self._n:
            self._next_report = self._done + max(1, self._n // 10)
            elapsed = time.monotonic() - self._t0
            self._print(f"point {self._done}/{self._n}  {_live_text(step, self._unit, thrust_n)}  "
                        f"elapsed {elapsed:.0f} s")

    def note(self, text: str) -> None:
        self._print(text)

    def finish(self) -> None:
        self.finished = True


class SilentReporter:
    """Reports nothing (tests, library use)."""

    wants_live = False

    def start(self, run_id: str, n_steps: int, unit: str, done: int = 0) -> None:
        return None

    def live(self, step: PlanStep, thrust_n: float | None, command: float) -> None:
        return None

    def step_done(self, step: PlanStep, thrust_n: float | None) -> None:
        return None

    def note(self, text: str) -> None:
        return None

    def finish(self) -> None:
        self.finished = True


def default_reporter() -> RichReporter | PlainReporter:
    """Live bar on a terminal, plain lines when stderr is a pipe or file."""
    return RichReporter() if sys.stderr.isatty() else PlainReporter()


class _TaskBars:
    """A ProgressHook drawing one bar per reported task under the stage's spinner."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.tasks: dict[str, TaskID] = {}

    def __call__(self, task: str, done: int, total: int) -> None:
        if task not in self.tasks:
            self.tasks[task] = self.progress.add_task("  " + task, total=total or None)
        self.progress.update(self.tasks[task], completed=done, total=total or None)


@contextmanager
def stage(text: str, console: Console | None = None) -> Iterator[ProgressHook]:
    """A spinner with the elapsed time while one stage runs, and a bar (done/total, elapsed,
    ETA) for each task the stage reports through the hook it yields; on a terminal only
    (stdout and stderr both: pipes and logs stay quiet; a `console` given is taken at its
    word). The stage's line stays with its duration when it ends."""
    con = console or Console(stderr=True, markup=False, highlight=False)
    if not (con.is_terminal and (console is not None or sys.stdout.isatty())):
        yield no_progress
        return
    t0 = time.monotonic()
    bars = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                    MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                    console=con, transient=True)
    with bars:
        bars.add_task(text + " ...", total=None)
        yield _TaskBars(bars)
    con.print(f"{text}: {time.monotonic() - t0:.1f} s")
