"""Value ranges of the room distributions: uniform ranges, integer counts and their bounded variants.

A :class:`Range` is uniform over [min, max] (a bare number or a [min, max] pair in YAML); :class:`CountRange` is
uniform over the integers {min, …, max}. The annotated variants (:data:`Positive`, :data:`NonNegative`,
:data:`Unit`, :data:`Signed`, :data:`Fraction`) add bounds that pydantic checks when a distribution is loaded
(:mod:`datagen.dataset.rooms`, :mod:`datagen.dataset.scan`).
"""
from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator


class Model(BaseModel):
    """Frozen pydantic model that rejects unknown fields (every block of a room distribution)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Range(Model):
    """Uniform range [min, max]; a bare number means min = max (a fixed value)."""

    min: float
    max: float

    @model_validator(mode="before")
    @classmethod
    def _scalar(cls, v: Any) -> Any:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return {"min": v, "max": v}
        if isinstance(v, (list, tuple)) and len(v) == 2:
            return {"min": v[0], "max": v[1]}
        return v

    @model_validator(mode="after")
    def _ordered(self) -> "Range":
        if not (math.isfinite(self.min) and math.isfinite(self.max)):
            raise ValueError(f"min and max must be finite, got min {self.min}, max {self.max}")
        if self.min > self.max:
            raise ValueError(f"min ({self.min}) must be <= max ({self.max})")
        return self

    def draw(self, u: float) -> float:
        """The value at quantile ``u`` ∈ [0, 1) of the uniform distribution."""
        return float(self.min + u * (self.max - self.min))

    def draw_log(self, u: float) -> float:
        """The value at quantile ``u`` ∈ [0, 1) of the log-uniform distribution on [min, max] (min > 0: for
        quantities that span decades, e.g. a Phong exponent, a retroreflective lobe width, an attenuation)."""
        lo, hi = math.log(self.min), math.log(self.max)
        return float(math.exp(lo + u * (hi - lo)))

    def contains(self, x: float, tol: float = 1e-9) -> bool:
        return self.min - tol <= x <= self.max + tol


class CountRange(Model):
    """Integer count, uniform over {min, …, max}; a bare integer means exactly that many."""

    min: int = Field(0, ge=0)
    max: int = Field(0, ge=0)

    @model_validator(mode="before")
    @classmethod
    def _scalar(cls, v: Any) -> Any:
        if isinstance(v, int) and not isinstance(v, bool):
            return {"min": v, "max": v}
        return v

    @model_validator(mode="after")
    def _ordered(self) -> "CountRange":
        if self.min > self.max:
            raise ValueError(f"min ({self.min}) must be <= max ({self.max})")
        return self


def _bounded(lo: float | None, hi: float | None, strict_lo: bool = False):
    def check(r: Range) -> Range:
        if lo is not None and (r.min <= lo if strict_lo else r.min < lo):
            raise ValueError(f"min must be {'>' if strict_lo else '>='} {lo}, got {r.min}")
        if hi is not None and r.max > hi:
            raise ValueError(f"max must be <= {hi}, got {r.max}")
        return r
    return AfterValidator(check)


Positive = Annotated[Range, _bounded(0.0, None, strict_lo=True)]
NonNegative = Annotated[Range, _bounded(0.0, None)]
Unit = Annotated[Range, _bounded(0.0, 1.0)]
Signed = Annotated[Range, _bounded(-1.0, 1.0)]
Fraction = Annotated[Range, _bounded(0.0, 1.0, strict_lo=True)]
