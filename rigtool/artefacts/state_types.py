"""The closed registry of the types a stored calibration state may hold (rigtool/artefacts/state.py).

A state blob names each dataclass by a stable tag, "<area>.<Name>/<version>", never by its
Python module or class name, so a class can be renamed or moved without making any stored
calibration unreadable. Decoding constructs only the classes in TYPES; nothing else.

Rules for changing a registered class:

- Adding a field with a default keeps the tag: older blobs lack it and get the default.
- Any other change (a field removed, renamed, retyped or given a new meaning; a new field
  without a default) bumps the version in the class's tag. The old tag stays in TYPES, mapped
  to the same class, and UPGRADES maps it to a function that turns the old version's fields
  into the current ones. Encoding writes the highest version of a class.
- A class that can newly appear in a state gets a new tag here; encoding an unregistered
  dataclass is a TypeError, and tests/test_state_blob.py encodes real calibrations.
- Tags are never reused for another meaning and never removed while a release that wrote
  them may have users; tests/fixtures/state holds blobs each release wrote.

LEGACY_V1 maps the "module:qualname" names that format 1 (rigtool 0.1) wrote to tags. It is
a fixed table of strings: those names are history and must not follow later renames.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

from rigtool.analysis import (
    captive,
    curves,
    depth_fits,
    dynamics,
    events,
    fits,
    gp,
    results,
    steady,
    trainset,
)
from rigtool.errors import StoreError
from rigtool.models import betm as model_betm
from rigtool.models import domain

Fields = dict[str, Any]

TYPES: Mapping[str, type] = MappingProxyType({
    "betm.EstimatorErrors/1": results.EstimatorErrors,
    "calibrate.Calibration/1": results.CalibrationResult,
    "captive.CaptiveLaw/1": captive.CaptiveLaw,
    "captive.CaptivePoints/1": captive.CaptivePoints,
    "captive.CaptiveResult/1": captive.CaptiveResult,
    "captive.LiftDrag/1": captive.LiftDrag,
    "calibrate.CalibrationParams/1": results.CalibrationParams,
    "calibrate.DepthSection/1": results.DepthSection,
    "cavitation.CavitationParams/1": results.CavitationParams,
    "cavitation.CavitationResult/1": results.CavitationResult,
    "cavitation.ClassErrors/1": results.ClassErrors,
    "cavitation.Evaluation/1": results.Evaluation,
    "curves.Branch/1": curves.Branch,
    "curves.CommandCurve/1": curves.CommandCurve,
    "curves.CurveParams/1": curves.CurveParams,
    "dynamics.Dynamics/1": dynamics.Dynamics,
    "dynamics.Dynamics/2": dynamics.Dynamics,
    "dynamics.DynamicsModel/1": dynamics.DynamicsModel,
    "dynamics.DynamicsModel/2": dynamics.DynamicsModel,
    "dynamics.StepMetrics/1": dynamics.StepMetrics,
    "dynamics.StepMetrics/2": dynamics.StepMetrics,
    "events.EventParams/1": events.EventParams,
    "events.MatchResult/1": events.MatchResult,
    "fits.Coefficient/1": fits.Coefficient,
    "fits.ZeroLine/1": fits.ZeroLine,
    "gp.GpParams/1": gp.GpParams,
    "model.Betm/1": model_betm.Betm,
    "model.Bounds/1": domain.Bounds,
    "model.Domain/1": domain.Domain,
    "models.FitParams/1": depth_fits.FitParams,
    "quality.Hysteresis/1": results.Hysteresis,
    "quality.Repeatability/1": results.Repeatability,
    "quality.TareDrift/1": results.TareDrift,
    "steady.ChannelStats/1": steady.ChannelStats,
    "steady.PointTable/1": steady.PointTable,
    "steady.SettlingCriterion/1": steady.SettlingCriterion,
    "trainset.TrainingSet/1": trainset.TrainingSet,
    "voltage.VoltageLaw/1": results.VoltageLaw,
    "voltage.VoltagePoint/1": results.VoltagePoint,
})



def _same_fields(fields: Fields) -> Fields:
    """An old version whose fields all kept their meaning; the fields it lacks take their
    defaults (dynamics version 1: no yoerger candidate, reverse ratio, held-out error,
    identification verdict or censored settling; its models were selected by BIC)."""
    return fields


# Fields of an old tag's version -> fields of the class now (see the rules above).
UPGRADES: Mapping[str, Callable[[Fields], Fields]] = MappingProxyType({
    "dynamics.Dynamics/1": _same_fields,
    "dynamics.DynamicsModel/1": _same_fields,
    "dynamics.StepMetrics/1": _same_fields,
})

LEGACY_V1: Mapping[str, str] = MappingProxyType({
    "rigtool.analysis.betm:EstimatorErrors": "betm.EstimatorErrors/1",
    "rigtool.analysis.calibrate:Calibration": "calibrate.Calibration/1",
    "rigtool.analysis.calibrate:CalibrationParams": "calibrate.CalibrationParams/1",
    "rigtool.analysis.calibrate:DepthSection": "calibrate.DepthSection/1",
    "rigtool.analysis.cavitation:CavitationParams": "cavitation.CavitationParams/1",
    "rigtool.analysis.cavitation:CavitationResult": "cavitation.CavitationResult/1",
    "rigtool.analysis.cavitation:ClassErrors": "cavitation.ClassErrors/1",
    "rigtool.analysis.cavitation:Evaluation": "cavitation.Evaluation/1",
    "rigtool.analysis.curves:Branch": "curves.Branch/1",
    "rigtool.analysis.curves:CommandCurve": "curves.CommandCurve/1",
    "rigtool.analysis.curves:CurveParams": "curves.CurveParams/1",
    "rigtool.analysis.dynamics:Dynamics": "dynamics.Dynamics/1",
    "rigtool.analysis.dynamics:DynamicsModel": "dynamics.DynamicsModel/1",
    "rigtool.analysis.dynamics:StepMetrics": "dynamics.StepMetrics/1",
    "rigtool.analysis.events:EventParams": "events.EventParams/1",
    "rigtool.analysis.events:MatchResult": "events.MatchResult/1",
    "rigtool.analysis.fits:Coefficient": "fits.Coefficient/1",
    "rigtool.analysis.fits:ZeroLine": "fits.ZeroLine/1",
    "rigtool.analysis.gp:GpParams": "gp.GpParams/1",
    "rigtool.analysis.models:FitParams": "models.FitParams/1",
    "rigtool.analysis.quality:Hysteresis": "quality.Hysteresis/1",
    "rigtool.analysis.quality:Repeatability": "quality.Repeatability/1",
    "rigtool.analysis.quality:TareDrift": "quality.TareDrift/1",
    "rigtool.analysis.steady:ChannelStats": "steady.ChannelStats/1",
    "rigtool.analysis.steady:PointTable": "steady.PointTable/1",
    "rigtool.analysis.steady:SettlingCriterion": "steady.SettlingCriterion/1",
    "rigtool.analysis.trainset:TrainingSet": "trainset.TrainingSet/1",
    "rigtool.analysis.voltage:VoltageLaw": "voltage.VoltageLaw/1",
    "rigtool.analysis.voltage:VoltagePoint": "voltage.VoltagePoint/1",
    "rigtool.models.betm:Betm": "model.Betm/1",
    "rigtool.models.domain:Bounds": "model.Bounds/1",
    "rigtool.models.domain:Domain": "model.Domain/1",
})


def split_tag(tag: str) -> tuple[str, int]:
    """("area.Name", version) of a well-formed tag; ValueError otherwise."""
    name, sep, version = tag.rpartition("/")
    if not (sep and name and version.isascii() and version.isdigit() and len(version) < 6):
        raise ValueError(f"malformed type tag {tag!r}")
    return name, int(version)


def _current(types: Mapping[str, type]) -> dict[type, str]:
    """The tag each class is written with: its highest version."""
    best: dict[type, tuple[int, str]] = {}
    for tag, cls in types.items():
        version = split_tag(tag)[1]
        if cls not in best or version > best[cls][0]:
            best[cls] = (version, tag)
    return {cls: tag for cls, (_, tag) in best.items()}


def tag_of(cls: type) -> str:
    """The tag encoding writes for `cls`; TypeError if it is not registered."""
    tag = _current(TYPES).get(cls)
    if tag is None:
        raise TypeError(f"{cls.__module__}.{cls.__qualname__} is not a registered state type: "
                        "give it a tag in rigtool/artefacts/state_types.py")
    return tag


def class_of(tag: str) -> type:
    """The class a stored tag names; StoreError naming an unknown tag or version."""
    cls = TYPES.get(tag)
    if cls is not None:
        return cls
    try:
        name, version = split_tag(tag)
    except ValueError:
        raise StoreError(f"stored calibration holds an unknown type {_short(tag)}: "
                         "calibrate again") from None
    known = sorted(split_tag(t)[1] for t in TYPES if split_tag(t)[0] == name)
    if not known:
        raise StoreError(f"stored calibration holds an unknown type {_short(tag)}: "
                         "calibrate again")
    raise StoreError(f"stored calibration holds {name} version {version}, this rigtool reads "
                     f"version {', '.join(map(str, known))}: calibrate again")


def upgrade(tag: str, fields: Fields) -> Fields:
    """`fields` stored under `tag` as fields of the class now."""
    step = UPGRADES.get(tag)
    return fields if step is None else step(fields)


def legacy_tag(name: str) -> str:
    """The tag of a format-1 "module:qualname" name; StoreError if it names no known type."""
    tag = LEGACY_V1.get(name)
    if tag is None:
        raise StoreError(f"stored calibration holds an unknown type {_short(name)}: "
                         "calibrate again")
    return tag


def _short(text: str, limit: int = 80) -> str:
    """repr of stored text, cut to `limit` characters, for one-line messages."""
    r = repr(text)
    return r if len(r) <= limit else r[:limit - 3] + "..."
