"""Vehicle-simulator parameter blocks from vehicle_model.json, one module per consumer
(docs/vehicle-formats.md).

Each module has FILE (the file name it writes; None where the consumer takes no block),
FOLLOWS (the consumer source and commit it follows), `needs(model, options)` (why it cannot
render: a list of reasons naming the parameter or option) and `render(model, options)` (the
block's text). `model` is a checked document (`rigtool.artefacts.vehicle_model.validate_model`).
`write_hydro_formats` checks every requested format's needs before it writes any file.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from rigtool.artefacts.hydro_formats import gz_hydrodynamics, stonefish, uuv_fossen
from rigtool.artefacts.hydro_formats.common import HydroOptions
from rigtool.artefacts.write import write_all
from rigtool.errors import UsageError

__all__ = ["HYDRO_FORMATS", "HydroOptions", "check_hydro_formats", "write_hydro_formats"]

HYDRO_FORMATS: dict[str, ModuleType] = {
    "gz-hydrodynamics": gz_hydrodynamics, "uuv-fossen": uuv_fossen, "stonefish": stonefish}


def check_hydro_formats(formats: Sequence[str], model: dict[str, Any],
                        options: HydroOptions) -> None:
    """UsageError naming every unknown format and every missing prerequisite."""
    unknown = sorted(set(formats) - set(HYDRO_FORMATS))
    if unknown:
        raise UsageError(f"unknown vehicle format(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(HYDRO_FORMATS)}")
    missing = [f"{fmt}: {reason}" for fmt in dict.fromkeys(formats)
               for reason in HYDRO_FORMATS[fmt].needs(model, options)]
    if missing:
        raise UsageError("nothing written, because\n  " + "\n  ".join(missing))


def write_hydro_formats(model: dict[str, Any], folder: str | Path, formats: Sequence[str],
                        options: HydroOptions) -> list[Path]:
    """Write the requested blocks into `folder` and return their paths, or write nothing and
    raise UsageError when any lacks what it needs."""
    check_hydro_formats(formats, model, options)
    folder = Path(folder)
    return write_all({folder / HYDRO_FORMATS[fmt].FILE: HYDRO_FORMATS[fmt].render(model, options)
                      for fmt in dict.fromkeys(formats)})
