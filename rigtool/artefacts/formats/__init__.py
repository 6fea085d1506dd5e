"""Vehicle and simulator artefacts, one module per consumer (docs/artefacts.md).

Each module has FILE (the file name it writes), FOLLOWS (the consumer version whose source it
follows), `needs(x)` (what is missing for it: a list of reasons naming the field and where it
comes from) and `render(x)` (the file's text). `write_vehicle_artefacts` checks every requested
format's needs before it writes any file: all or nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from rigtool.analysis.results import CalibrationResult
from rigtool.artefacts.formats import (
    ardupilot,
    auv_controllers,
    c_header,
    csv_lut,
    gazebo,
    px4,
    ros2,
    stonefish,
    thruster_manager,
    uuv,
)
from rigtool.artefacts.vehicle import DynamicsSource, ExportInput, ExportOptions, deepest
from rigtool.artefacts.write import write_all
from rigtool.errors import RigtoolError, UsageError
from rigtool.outpaths import run_folder

MODULES: dict[str, ModuleType] = {
    "c-header": c_header, "ros2": ros2, "gazebo": gazebo, "csv-lut": csv_lut,
    "ardupilot": ardupilot, "px4": px4, "uuv": uuv, "stonefish": stonefish,
    "thruster-manager": thruster_manager, "auv-controllers": auv_controllers}
FORMATS: dict[str, str] = {name: m.FILE for name, m in MODULES.items()}


def export_input(cal: CalibrationResult, created_utc: str, dynamics: DynamicsSource | None = None,
                 options: ExportOptions | None = None) -> ExportInput:
    """What the artefacts of `cal` are made of (the deepest section)."""
    return ExportInput(cal, deepest(cal), created_utc, dynamics, options or ExportOptions())


def check_formats(formats: Sequence[str], x: ExportInput) -> None:
    """UsageError naming every missing prerequisite of every requested format."""
    unknown = sorted(set(formats) - set(MODULES))
    if unknown:
        raise UsageError(f"unknown export format(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(MODULES)}")
    missing = [f"{fmt}: {reason}" for fmt in dict.fromkeys(formats)
               for reason in MODULES[fmt].needs(x)]
    if missing:
        raise UsageError(f"run {x.cal.run_id}: nothing exported, because\n  "
                         + "\n  ".join(missing))


def write_vehicle_artefacts(cal: CalibrationResult, out_dir: str | Path, formats: Sequence[str],
                            created_utc: str, dynamics: DynamicsSource | None = None,
                            options: ExportOptions | None = None) -> list[Path]:
    """Write the requested formats into `out_dir`/<run-id>/ and return their paths, or write
    nothing and raise UsageError when any format lacks what it needs."""
    x = export_input(cal, created_utc, dynamics, options)
    check_formats(formats, x)
    texts = {MODULES[fmt].FILE: MODULES[fmt].render(x) for fmt in dict.fromkeys(formats)}
    folder = run_folder(out_dir, cal.run_id)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        return write_all({folder / name: text for name, text in texts.items()})
    except OSError as exc:
        raise RigtoolError(f"run {cal.run_id}: nothing exported: cannot write into {folder} "
                        f"({exc})") from exc


def remove_exports(folder: Path) -> None:
    """Remove the vehicle artefacts an earlier calibration left in `folder` (a new calibration
    makes them wrong); inverse_lut.csv is calibrate's own and stays."""
    for name in set(FORMATS.values()) - {csv_lut.FILE}:
        (folder / name).unlink(missing_ok=True)
