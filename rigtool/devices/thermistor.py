"""An NTC thermistor read through a voltage divider on an ADC: counts to degrees Celsius.

The rig file gives the divider (series resistor, which side the thermistor is on, the ADC's
full-scale count) and one model: Beta (`beta_k`, `r0_ohm` at `t0_c`) or Steinhart-Hart
(1/T = a + b ln R + c (ln R)^3, T in kelvin). A count at either rail (open or shorted
thermistor) converts to NaN: no temperature, never a made-up one.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from rigtool.bounds import MAX_SCALE

KELVIN = 273.15
PositiveOhm = Annotated[float, Field(gt=0, le=MAX_SCALE, allow_inf_nan=False)]
Coefficient = Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)]  # 1/K per ln(ohm)^k


class Thermistor(BaseModel):
    """`thermistor:` in a rig file: divider and Beta or Steinhart-Hart model."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    adc_max: int = Field(4095, ge=1, le=2**32 - 1)  # the count at the supply rail
    series_ohm: PositiveOhm = 10_000.0
    position: Literal["low", "high"] = "low"  # low: thermistor from the ADC pin to ground
    beta_k: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] | None = None
    r0_ohm: PositiveOhm = 10_000.0  # resistance at t0_c (Beta model)
    t0_c: Annotated[float, Field(gt=-KELVIN, le=1_000, allow_inf_nan=False)] = 25.0
    steinhart_hart: tuple[Coefficient, Coefficient, Coefficient] | None = None  # a, b, c

    @model_validator(mode="after")
    def _one_model(self) -> Thermistor:
        if (self.beta_k is None) == (self.steinhart_hart is None):
            raise ValueError("give exactly one model: `beta_k` (with r0_ohm, t0_c) or "
                             "`steinhart_hart: [a, b, c]`")
        if self.steinhart_hart is not None:
            a, b, c = self.steinhart_hart
            if b <= 0 or c < 0 or a + b * np.log(self.series_ohm) <= 0:
                raise ValueError("steinhart_hart: need b > 0, c >= 0 and a positive 1/T near "
                                 "the series resistance (check the coefficients' order a, b, c)")
        return self

    def resistance_ohm(self, counts: np.ndarray) -> np.ndarray:
        """Thermistor resistance for ADC counts; NaN at or beyond the rails."""
        x = np.asarray(counts, dtype=float) / self.adc_max
        inside = (x > 0) & (x < 1)
        x = np.where(inside, x, np.nan)
        ratio = x / (1 - x) if self.position == "low" else (1 - x) / x
        return self.series_ohm * ratio

    def temperature_c(self, counts: np.ndarray) -> np.ndarray:
        """Degrees Celsius for ADC counts (NaN for an open or shorted thermistor)."""
        ln_r = np.log(self.resistance_ohm(counts))
        if self.beta_k is not None:
            inv_t = 1 / (self.t0_c + KELVIN) + (ln_r - np.log(self.r0_ohm)) / self.beta_k
        else:
            a, b, c = self.steinhart_hart  # type: ignore[misc]
            inv_t = a + b * ln_r + c * ln_r**3
        with np.errstate(divide="ignore", invalid="ignore"):
            t = 1 / inv_t - KELVIN
        return np.where(np.isfinite(t) & (inv_t > 0), t, np.nan)

    def counts(self, temperature_c: float) -> int:
        """The ADC count this thermistor gives at `temperature_c` (Beta model; for twins)."""
        if self.beta_k is None:
            raise ValueError("counts() needs the Beta model")
        r = self.r0_ohm * np.exp(self.beta_k * (1 / (temperature_c + KELVIN)
                                                - 1 / (self.t0_c + KELVIN)))
        x = r / (r + self.series_ohm) if self.position == "low" else self.series_ohm / (r + self.series_ohm)
        return int(np.clip(round(x * self.adc_max), 0, self.adc_max))
