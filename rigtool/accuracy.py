"""A force sensor's declared accuracy: one model for rig files and `rigtool import`."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field


class SensorAccuracy(BaseModel):
    """The force sensor's datasheet accuracy on the thrust axis, in % of its full scale: what
    no scatter shows, carried into the systematic part of every thrust coefficient's interval
    (`full_scale_n` None: the largest thrust of the run stands for the full scale)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    full_scale_n: Annotated[float, Field(gt=0, le=1e7)] | None = None
    nonlinearity_pct_fs: Annotated[float, Field(ge=0, le=100)] = 0.0
    hysteresis_pct_fs: Annotated[float, Field(ge=0, le=100)] = 0.0
    crosstalk_pct_fs: Annotated[float, Field(ge=0, le=100)] = 0.0
