"""The result of a detector fit (:func:`datagen.spad.fit.fit_detector`): values, uncertainties, intervals,
goodness of fit, and the fitted detector as a ``configs/detectors`` YAML."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..timing.irf import Irf
from .config import DetectorConfig

__all__ = ["UNITS", "DetectorFit"]

UNITS = {"signal": "photons/cycle", "position": "s", "jitter_sigma": "s", "diffusion_tail": "s",
          "diffusion_fraction": "", "background_rate": "Hz", "dead_time": "s", "afterpulse_probability": "",
          "tail": "s", "tail_weight": "", "tail2": "s", "tail2_weight": "", "tail_delay": "s"}
"""Unit of each fit parameter, as :meth:`DetectorFit.summary` prints it."""


@dataclass
class DetectorFit:
    """Result of :func:`datagen.spad.fit.fit_detector`.

    Attributes:
        model, irf: the histogram model and IRF shape fitted.
        values: parameter → maximum-likelihood value (SI: s, Hz; ``signal`` photons per cycle).
        errors: parameter → 1σ uncertainty (delta method from the inverse Fisher information); fixed ones absent.
        intervals: parameter → (low, high) 95 % interval of that parameter alone (symmetric in the fit
            coordinates: log or logit).
        joint_intervals: parameter → (low, high) simultaneous 95 % intervals: all fitted parameters inside theirs
            at once with probability ≥ 95 % (Bonferroni over the k fitted parameters, :func:`joint_z`): the ones to
            read when the question is whether every parameter is right.
        fixed: parameters held at a given value.
        identifiable: parameter → False when the data do not constrain it (see :attr:`messages`).
        messages: one line per parameter that is not identifiable.
        deviance, pearson_chi2, dof, p_value: goodness of fit (Poisson deviance, Pearson χ², degrees of freedom,
            the χ² p-value of the deviance).
        expected: float64 (bins,) best-fit expected histogram; config: the fitted :class:`DetectorConfig`.
        settings: what the fit was told (bin width, repetition rate, cycles, t_start, pulse_sigma).
        irf_model: a two-tail fit's IRF (:class:`~datagen.timing.irf.Irf` of kind ``two_tail``, core = laser pulse
            and jitter), else None.
    """

    model: str
    irf: str
    values: dict[str, float]
    errors: dict[str, float]
    intervals: dict[str, tuple[float, float]]
    joint_intervals: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    identifiable: dict[str, bool]
    messages: list[str]
    deviance: float
    pearson_chi2: float
    dof: int
    p_value: float
    expected: np.ndarray
    config: DetectorConfig
    settings: dict = field(default_factory=dict)
    irf_model: Irf | None = None

    def summary(self) -> str:
        """Human-readable table: value ± 1σ [95 % interval; simultaneous 95 % interval] per parameter, then the
        goodness of fit."""
        lines = [f"model {self.model}, IRF {self.irf}"]
        for name, value in self.values.items():
            unit = UNITS.get(name, "")
            if name in self.fixed:
                lines.append(f"  {name:<20s} {value:.6g} {unit} (fixed)")
                continue
            lo, hi = self.intervals[name]
            jlo, jhi = self.joint_intervals[name]
            flag = "" if self.identifiable[name] else "  NOT IDENTIFIABLE"
            lines.append(f"  {name:<20s} {value:.6g} ± {self.errors[name]:.3g} {unit} "
                         f"[95 %: {lo:.6g}, {hi:.6g}; all jointly: {jlo:.6g}, {jhi:.6g}]{flag}")
        lines.append(f"  goodness of fit: deviance {self.deviance:.1f}, Pearson chi2 {self.pearson_chi2:.1f} on "
                     f"{self.dof} dof (p = {self.p_value:.3g}; chi2/dof {self.pearson_chi2 / self.dof:.3g})")
        if self.irf_model is not None:
            from .fit_two_tail import response_fwhm
            lines.append(f"  IRF: core FWHM {self.irf_model.fwhm * 1e12:.1f} ps (laser pulse and jitter), whole "
                         f"response FWHM {response_fwhm(self.irf_model) * 1e12:.1f} ps, mean delay "
                         f"{self.irf_model.mean * 1e12:.1f} ps")
        if self.settings.get("covariance") == "sandwich":
            lines.append(f"  intervals: sandwich (quasi-likelihood score variance from "
                         f"{self.settings['sandwich_replicates']} histograms of {self.settings['sandwich_cycles']} "
                         f"cycles simulated from the fit, seed {self.settings['seed']})")
        return "\n".join(lines)

    def detector_yaml(self) -> str:
        """The fitted detector as a ``configs/detectors`` YAML (:meth:`DetectorConfig.from_yaml` reads it). A
        two-tail fit writes ``detector:`` and ``irf:`` blocks, the keys of a scene file's ``simulation`` block
        (docs/detector.md "detector.yaml")."""
        c = self.config
        rows = [
            "# Detector fitted by maximum likelihood to a measured histogram (datagen fit-detector;",
            "# datagen.spad.fit). Background is the total avalanche rate before pile-up, written as dcr",
            "# (pde * ambient_rate + dcr is what a histogram measures).",
            f"model: {c.model}",
            f"repetition_rate: {c.repetition_rate!r}",
            f"n_cycles: {c.cycles}",
            f"bin_width: {c.bin_width!r}",
            f"t_start: {c.t_start!r}",
            f"dcr: {c.dcr!r}",
            "ambient_rate: 0.0",
            f"jitter_sigma: {c.jitter!r}",
            f"diffusion_tail: {c.diffusion_tail!r}",
            f"diffusion_fraction: {c.diffusion_fraction!r}",
        ]
        if c.model == "free_running":
            rows.append(f"dead_time: {c.dead_time!r}")
            if "afterpulse_probability" in self.values:
                rows.append(f"afterpulse_probability: {c.afterpulse_probability!r}")
                rows.append(f"afterpulse_time_constant: {c.afterpulse_time_constant!r}")
        rows.append("# fit (value, 1 sigma, 95 % interval, simultaneous 95 % interval of all parameters"
                    + (", sandwich covariance):" if self.settings.get("covariance") == "sandwich" else "):"))
        for name, value in self.values.items():
            if name in self.fixed:
                rows.append(f"#   {name}: {value!r} (fixed)")
            else:
                lo, hi = self.intervals[name]
                jlo, jhi = self.joint_intervals[name]
                rows.append(f"#   {name}: {value!r} +- {self.errors[name]:.3g} [{lo:.6g}, {hi:.6g}] "
                            f"[{jlo:.6g}, {jhi:.6g}]"
                            + ("" if self.identifiable[name] else " not identifiable"))
        rows.append(f"#   deviance {self.deviance:.2f} on {self.dof} dof, p = {self.p_value:.3g}")
        if self.irf_model is not None:
            head = [r for r in rows if r.startswith("#")][:3]
            body = ["  " + r for r in rows[3:] if not r.startswith("#")]
            rows = head + ["detector:"] + body + ["irf:"] + [f"  {k}: {v!r}" for k, v in
                                                              self.irf_model.model_dump().items()] + \
                [r for r in rows[3:] if r.startswith("#")]
        return "\n".join(rows) + "\n"

    def write_yaml(self, path: str | Path) -> Path:
        """Write :meth:`detector_yaml` to ``path`` and check it loads (:meth:`DetectorConfig.from_yaml`)."""
        path = Path(path)
        path.write_text(self.detector_yaml())
        DetectorConfig.from_yaml(path)
        return path
