"""Detector configuration: :class:`DetectorConfig` (pydantic, immutable, SI units) and its YAML presets
(``configs/detectors/*.yaml``).  Durations may be written ``"50ns"``, rates ``"20MHz"`` / ``"100cps"``."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import (BaseModel, ConfigDict, Field, ValidationError, field_validator, model_serializer,
                      model_validator)

from ..errors import ConfigError
from ..timing.irf import FWHM_PER_SIGMA
from ..units import parse_duration, parse_rate
from .maps import MAP_FIELDS, DirectLight, maps_relative_to, read_map
from .models import ModelName, detector_model, model_names

__all__ = [
    "FWHM_PER_SIGMA",
    "ModelName",
    "DeadTimeKind",
    "DetectorConfig",
    "MAX_CYCLES",
]


DeadTimeKind = Literal["none", "synchronous", "free_running"]

MAX_CYCLES = 1 << 62
"""Most laser cycles one exposure may hold (4.6e18): counts are int64 (9.2e18) and no bin can count more
detections than there are cycles in the synchronous models."""


def _duration(value: Any) -> Any:
    if value is None or isinstance(value, (list, tuple)):
        return value
    return parse_duration(value)


class DetectorConfig(BaseModel):
    """SPAD/TCSPC detector description (SI units; durations may be strings such as ``"50ns"``, rates such
    as ``"20MHz"``).  Immutable.

    Fields:
        pde: photon detection efficiency in [0, 1].  Only used to thin ``ambient_rate``: the transport
            envelope already contains the PDE (docs/physics.md §2).
        dcr: dark count rate in Hz (≥ 0).
        ambient_rate: ambient photons arriving at the detector per second, before the PDE (≥ 0).
        repetition_rate: laser repetition rate in Hz (> 0); the period is ``1/repetition_rate``.
        exposure / n_cycles: exposure time in s, or number of laser cycles.  Exactly one is given;
            :attr:`cycles` resolves ``n_cycles = round(exposure·repetition_rate)``.
        bin_width: nominal TDC bin width in s (> 0).
        bin_widths: optional true per-bin widths in s (TDC differential non-linearity); fixes the number of
            bins.  Background per bin and the gate use these widths; jitter kernels use ``bin_width``.
        t_start: time of the left edge of bin 0 within the laser cycle, s (default 0).
        gate: optional ``[start, stop]`` in s (same clock as ``t_start``): the SPAD is armed only inside;
            all avalanches (signal, ambient, dark, afterpulses) outside are suppressed.
        dead_time: SPAD dead time τ in s (default 0).
        dead_time_kind: ``"none" | "synchronous" | "free_running"``.  Derived from ``model`` when omitted
            (poisson → none, pile_up/multi_stop → synchronous, free_running → free_running); an
            inconsistent explicit value is an error.
        paralyzable: paralyzable dead time (arrivals during the dead time extend it).  Only with
            ``model="free_running"`` (and for the counter functions).
        afterpulse_probability: probability that an avalanche is followed by an afterpulse, in [0, 1).
        afterpulse_time_constant: afterpulses occur at ``t + dead_time + Exp(afterpulse_time_constant)``.
        crosstalk_probability: probability that an avalanche triggers a prompt avalanche in one of its
            4-neighbours (chosen uniformly among those inside the array), in [0, 1).
        jitter_sigma / jitter_fwhm: Gaussian avalanche + electronic + TDC jitter, applied AFTER pile-up.
            At most one is given.
        diffusion_tail: exponential time constant (s) of the SPAD diffusion tail, applied BEFORE pile-up.
        diffusion_fraction: fraction of detections in the diffusion tail (default 1: the low-flux IRF is
            the ex-Gaussian ``exponnorm``; < 1 gives a Gaussian core plus a tail).
        model: ``"poisson" | "pile_up" | "multi_stop" | "free_running"`` (see :mod:`datagen.spad`).
        markov_oversample: cells per TDC bin of the free-running Markov chain (default: automatic, per pixel from
            its brightest bin).
        direct: the direct light off each scan point attenuated by a stated factor until a stated time after its
            direct return (:class:`~datagen.spad.maps.DirectLight`, ``{attenuation: 1e-4, until: 300ps}``);
            applied by the simulation to the envelope (docs/detector.md). Default: none.
        gain_map / background_map: (ny, nx) per-scan-point factors on the light and on the background rate, inline
            or a ``.npy`` path (:func:`~datagen.spad.maps.read_map`; relative to the YAML that names it). Default:
            none (1 everywhere).

    Raises:
        pydantic.ValidationError (a ValueError): unknown field, bad value or inconsistent combination;
            the message names the field and the value.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    pde: float = Field(1.0, ge=0.0, le=1.0)
    dcr: float = Field(0.0, ge=0.0)
    ambient_rate: float = Field(0.0, ge=0.0)
    repetition_rate: float = Field(gt=0.0)
    exposure: float | None = Field(None, gt=0.0)
    n_cycles: int | None = Field(None, ge=1, le=MAX_CYCLES)
    bin_width: float = Field(gt=0.0)
    bin_widths: tuple[float, ...] | None = None
    t_start: float = Field(0.0, ge=0.0)
    gate: tuple[float, float] | None = None
    dead_time: float = Field(0.0, ge=0.0)
    dead_time_kind: DeadTimeKind | None = None
    paralyzable: bool = False
    afterpulse_probability: float = Field(0.0, ge=0.0, lt=1.0)
    afterpulse_time_constant: float = Field(0.0, ge=0.0)
    crosstalk_probability: float = Field(0.0, ge=0.0, lt=1.0)
    jitter_sigma: float | None = Field(None, ge=0.0)
    jitter_fwhm: float | None = Field(None, ge=0.0)
    diffusion_tail: float = Field(0.0, ge=0.0)
    diffusion_fraction: float = Field(1.0, ge=0.0, le=1.0)
    model: ModelName = "pile_up"
    markov_oversample: int | None = Field(None, ge=1)
    direct: DirectLight | None = None
    gain_map: tuple[tuple[float, ...], ...] | None = None
    background_map: tuple[tuple[float, ...], ...] | None = None

    @field_validator("gain_map", "background_map", mode="before")
    @classmethod
    def _read_map(cls, value: Any, info) -> Any:
        return None if value is None else read_map(value, info.field_name)

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        data = handler(self)
        if isinstance(data, dict):                        # detectors without them dump as before
            for key in ("direct",) + MAP_FIELDS:
                if data.get(key) is None:
                    data.pop(key, None)
        return data

    def scan_map(self, field: str) -> np.ndarray | None:
        """``gain_map`` or ``background_map`` as float64 (ny, nx), or None when not set."""
        value = getattr(self, field)
        return None if value is None else np.asarray(value, dtype=np.float64)

    # ---- parsing at the boundary ------------------------------------------------------------------
    @field_validator("exposure", "bin_width", "t_start", "dead_time", "afterpulse_time_constant",
                     "jitter_sigma", "jitter_fwhm", "diffusion_tail", mode="before")
    @classmethod
    def _parse_durations(cls, value: Any) -> Any:
        return _duration(value)

    @field_validator("bin_widths", "gate", mode="before")
    @classmethod
    def _parse_duration_lists(cls, value: Any) -> Any:
        if value is None:
            return None
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise ValueError(f"expected a list of durations, got {value!r}")
        return [parse_duration(v) for v in value]

    @field_validator("dcr", "ambient_rate", "repetition_rate", mode="before")
    @classmethod
    def _parse_rates(cls, value: Any) -> Any:
        return parse_rate(value)

    @field_validator("n_cycles", mode="before")
    @classmethod
    def _parse_cycles(cls, value: Any) -> Any:
        if value is None or isinstance(value, bool):
            return value
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise ValueError(f"n_cycles must be an integer, got {value!r}") from None
        if isinstance(value, float):
            if not math.isfinite(value) or value != round(value):
                raise ValueError(f"n_cycles must be an integer, got {value!r}")
            return int(round(value))
        return value

    @field_validator("bin_widths")
    @classmethod
    def _check_widths(cls, value: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if value is not None:
            if len(value) == 0:
                raise ValueError("bin_widths must not be empty")
            bad = [w for w in value if not (math.isfinite(w) and w > 0)]
            if bad:
                raise ValueError(f"bin_widths must be finite and > 0, got {bad[0]!r}")
        return value

    @model_validator(mode="after")
    def _check_consistency(self) -> "DetectorConfig":
        if (self.exposure is None) == (self.n_cycles is None):
            raise ValueError(f"give exactly one of exposure or n_cycles (got exposure={self.exposure!r}, "
                             f"n_cycles={self.n_cycles!r})")
        if self.exposure is not None and self.exposure * self.repetition_rate > MAX_CYCLES:
            raise ValueError(f"exposure={self.exposure!r} s at repetition_rate={self.repetition_rate!r} Hz is "
                             f"{self.exposure * self.repetition_rate:.3g} laser cycles, more than {MAX_CYCLES:.3g} "
                             "(int64 counts): shorten the exposure")
        if self.exposure is not None and round(self.exposure * self.repetition_rate) < 1:
            raise ValueError(f"exposure={self.exposure!r} s at repetition_rate={self.repetition_rate!r} Hz is "
                             "less than one laser cycle")
        if self.jitter_sigma is not None and self.jitter_fwhm is not None:
            raise ValueError(f"give at most one of jitter_sigma={self.jitter_sigma!r} and "
                             f"jitter_fwhm={self.jitter_fwhm!r}")
        if self.gate is not None:
            if len(self.gate) != 2 or not self.gate[0] < self.gate[1]:
                raise ValueError(f"gate must be [start, stop] with start < stop, got {list(self.gate)!r}")
        if self.t_start >= self.period:
            raise ValueError(f"t_start={self.t_start!r} s must be inside the laser period {self.period!r} s")
        model = detector_model(self.model)                  # what the model supports: its registry entry

        def models(effect: str) -> str:
            return " or ".join(f"model={name!r}" for name in model_names(**{effect: True}))

        if self.dead_time_kind is not None and self.dead_time_kind != model.dead_time:
            raise ValueError(f"dead_time_kind={self.dead_time_kind!r} is inconsistent with model={self.model!r} "
                             f"(which implies {model.dead_time!r})")
        if self.paralyzable and not model.paralyzable:
            raise ValueError(f"paralyzable=True is only modelled for {models('paralyzable')}, got model={self.model!r}")
        if self.afterpulse_probability > 0:
            if not model.afterpulsing or self.paralyzable:
                raise ValueError(f"afterpulse_probability={self.afterpulse_probability!r} needs "
                                 f"{models('afterpulsing')} with a non-paralyzable dead time (got model={self.model!r}, "
                                 f"paralyzable={self.paralyzable!r})")
        if self.crosstalk_probability > 0 and not model.crosstalk:
            raise ValueError(f"crosstalk_probability={self.crosstalk_probability!r} is only simulated for "
                             f"{models('crosstalk')}, got model={self.model!r}")
        return self

    # ---- derived quantities -----------------------------------------------------------------------
    @property
    def cycles(self) -> int:
        """Number of laser cycles in the exposure (``n_cycles`` or ``round(exposure·repetition_rate)``)."""
        if self.n_cycles is not None:
            return int(self.n_cycles)
        return int(round(self.exposure * self.repetition_rate))

    @property
    def period(self) -> float:
        """Laser period in s."""
        return 1.0 / self.repetition_rate

    @property
    def resolved_dead_time_kind(self) -> str:
        """``dead_time_kind``, derived from ``model`` when it was not given."""
        return self.dead_time_kind or detector_model(self.model).dead_time

    @property
    def jitter(self) -> float:
        """Gaussian after-pile-up jitter σ in s (0 when none is configured)."""
        if self.jitter_sigma is not None:
            return float(self.jitter_sigma)
        if self.jitter_fwhm is not None:
            return float(self.jitter_fwhm) / FWHM_PER_SIGMA
        return 0.0

    @property
    def background_rate(self) -> float:
        """Background avalanches per second before pile-up: ``pde·ambient_rate + dcr``."""
        return self.pde * self.ambient_rate + self.dcr

    def widths(self, n_bins: int) -> np.ndarray:
        """True bin widths in s, float64 shape (n_bins,).  Raises ValueError if ``bin_widths`` has another length."""
        if self.bin_widths is not None:
            if len(self.bin_widths) != n_bins:
                raise ValueError(f"bin_widths has {len(self.bin_widths)} entries but the data have {n_bins} bins")
            return np.asarray(self.bin_widths, dtype=np.float64)
        return np.full(n_bins, self.bin_width, dtype=np.float64)

    def bin_edges(self, n_bins: int) -> np.ndarray:
        """Bin edges within the laser cycle in s, float64 shape (n_bins + 1,), starting at ``t_start``."""
        edges = np.empty(n_bins + 1, dtype=np.float64)
        edges[0] = self.t_start
        np.cumsum(self.widths(n_bins), out=edges[1:])
        edges[1:] += self.t_start
        return edges

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> "DetectorConfig":
        """Read a preset such as ``configs/detectors/cmos_spad_array.yaml``.

        The file holds a mapping of the fields above, or a ``detector:`` block beside an optional ``irf:`` block (the
        keys of a scene file's ``simulation`` block, as ``datagen fit-detector --irf two_tail`` and
        ``datagen estimate-capture`` write them; the ``irf:`` block is the simulation's, read by
        :class:`~datagen.timing.irf.Irf`, and is not checked here).

        Raises:
            ConfigError (a ValueError): the file cannot be read or parsed, or a field is unknown or invalid; the
                message names the file, the field and the offending value.
        """
        from ..scene.load import read_yaml  # bounded in size and alias expansion

        path = Path(path)
        try:
            data = read_yaml(path, "detector config", ConfigError)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read detector config: {exc}") from None
        if isinstance(data, dict) and "detector" in data and set(data) <= {"detector", "irf"}:
            data = data["detector"]
        if isinstance(data, dict):                         # map paths are relative to this file
            data = maps_relative_to(data, path.parent)
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a mapping of detector fields, got {type(data).__name__}")
        try:
            return cls(**data)
        except ValidationError as exc:
            from ..scene.load import short_repr
            problems = []
            for err in exc.errors():
                field = ".".join(str(p) for p in err["loc"]) or "(config)"
                problems.append(f"field {field!r}: {err['msg']} (value: {short_repr(err.get('input'))})")
            raise ConfigError(f"{path}: invalid detector config: " + "; ".join(problems)) from None
