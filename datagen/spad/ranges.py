"""Detector randomisation: (low, high) ranges of exposure, ambient rate, dark count rate and PDE, and how a
sample's detector is drawn from them (one definition for :class:`datagen.SPADNoise` on the training device and for
``NLOSDataset(..., noise="resample", detector_ranges=...)`` in the loader).

Each field is fixed (low = high) or uniform on [low, high], drawn per sample from one row of four uniforms
(exposure, ambient_rate, dcr, pde, in that order, whether or not a field is randomised, so the stream layout is
the same for every choice); the laser cycles of a drawn exposure are round(exposure × repetition_rate), at least
1, or the detector's ``n_cycles`` when the exposure is not randomised and the detector counts cycles. The physics
of the drawn detector is docs/physics.md §6.
"""
from __future__ import annotations

from typing import Any

import torch
from pydantic import ValidationError

from .config import DetectorConfig

__all__ = ["RANDOMISED_FIELDS", "detector_range", "detector_ranges", "draw_detector_params", "fixed_cycles"]

RANDOMISED_FIELDS = ("exposure", "ambient_rate", "dcr", "pde")
"""Detector fields that can be drawn per sample from a (low, high) range, in the order of the uniforms."""


def detector_range(det: DetectorConfig, name: str, value: Any, default: float, owner: str = "SPADNoise"
                   ) -> tuple[float, float]:
    """(low, high) from a number, a (low, high) pair or None (``default``), each value validated as the field
    ``name`` of ``det`` (units such as "1ms" accepted).

    Raises:
        ValueError: a value the field refuses, a pair of other than 2 values, or low > high; the message starts
            with ``owner`` and names the field and the value.
    """
    def parse(v: Any) -> float:
        data = det.model_dump() | {name: v} | ({"n_cycles": None} if name == "exposure" else {})
        try:
            return float(getattr(DetectorConfig.model_validate(data), name))
        except ValidationError as exc:
            raise ValueError(f"{owner}: {name}: {exc.errors()[0]['msg']} (got {v!r})") from None

    if value is None:
        return float(default), float(default)
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ValueError(f"{owner}: {name} must be a number or a (low, high) pair, got {value!r}")
        low, high = (parse(v) for v in value)
    else:
        low = high = parse(value)
    if not low <= high:
        raise ValueError(f"{owner}: {name} range must have low <= high, got {value!r}")
    return low, high


def detector_ranges(det: DetectorConfig, values: dict[str, Any], owner: str = "SPADNoise"
                    ) -> dict[str, tuple[float, float]]:
    """(low, high) of every field of :data:`RANDOMISED_FIELDS` (``values`` may omit fields: the detector's own
    value, its exposure from ``n_cycles`` if it counts cycles). ValueError on an unknown field name."""
    unknown = sorted(set(values) - set(RANDOMISED_FIELDS))
    if unknown:
        raise ValueError(f"{owner}: unknown detector field(s) {unknown}; randomisable: {list(RANDOMISED_FIELDS)}")
    defaults = {"exposure": det.exposure if det.exposure is not None else det.cycles / det.repetition_rate,
                "ambient_rate": det.ambient_rate, "dcr": det.dcr, "pde": det.pde}
    return {name: detector_range(det, name, values.get(name), defaults[name], owner) for name in RANDOMISED_FIELDS}


def fixed_cycles(det: DetectorConfig, exposure: Any) -> int | None:
    """The detector's ``n_cycles`` when the exposure is not given (None) and the detector counts cycles, else None."""
    return det.n_cycles if exposure is None and det.n_cycles is not None else None


def draw_detector_params(ranges: dict[str, tuple[float, float]], repetition_rate: float, cycles: int | None,
                         batch: int, generator: torch.Generator | None = None,
                         device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
    """Per-sample detector parameters: ``exposure`` (s), ``ambient_rate`` (Hz), ``dcr`` (Hz), ``pde`` and
    ``cycles`` (laser cycles), each float64 (batch,) on ``device``.

    Always draws (batch, 4) uniforms from ``generator``; ``cycles`` is the fixed count when given (see
    :func:`fixed_cycles`), else round(exposure × repetition_rate), at least 1.
    """
    u = torch.rand((batch, len(RANDOMISED_FIELDS)), generator=generator, dtype=torch.float64, device=device)
    out = {name: ranges[name][0] + (ranges[name][1] - ranges[name][0]) * u[:, k]
           for k, name in enumerate(RANDOMISED_FIELDS)}
    if cycles is not None:
        out["cycles"] = torch.full((batch,), float(cycles), dtype=torch.float64, device=device)
    else:
        out["cycles"] = torch.round(out["exposure"] * repetition_rate).clamp_min(1.0)
    return out
