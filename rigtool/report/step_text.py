"""How the report writes a measured step's timings (analysis/dynamics.py StepMetrics): a
settling time censored at the end of its window, timings against an unsettled end left out."""

from __future__ import annotations

import math

from rigtool.analysis.dynamics import StepMetrics


def settling_text(step: StepMetrics) -> str:
    """The settling time as a report shows it (censored at the end of the window)."""
    if step.settled and math.isfinite(step.settling_s):
        return f"{step.settling_s:.3g}"
    if math.isfinite(step.window_s):
        return f"> {step.window_s:.1f} s (not settled in the window)"
    return "not settled in the window"


def measured_text(step: StepMetrics, value: float, scale: float = 1.0, digits: int = 3) -> str:
    """A timing measured against the end of the hold (rise, overshoot): as a number when the
    step settled, else "not measured (not settled)": its end level is not the step's."""
    if not step.settled:
        return "not measured (not settled)"
    return "" if not math.isfinite(value) else f"{scale * value:.{digits}g}"


def end_text(step: StepMetrics) -> str:
    """The thrust at the end of the hold, marked when it is not a settled level."""
    text = f"{step.thrust_to_n:.3g}"
    return text if step.settled else f"{text} (still moving)"
