"""What accuracy costs on a scanned capture: the quadrature's edge ladder against the quadrature at a quarter of its
finest edge (``datagen bench accuracy --quadrature-reference``; docs/accuracy.md).

The Monte Carlo reference of :mod:`datagen.analysis.reference` runs the area sampler once per laser point, which a
scan of hundreds of points cannot afford (:func:`datagen.analysis.reference.check_reference_size`). A scan's
reference is then the hidden-surface quadrature itself at a fine edge h_ref. The quadrature's error falls as h²
(docs/performance_history.md, item 29: error / h² within ±15 % from 6 to 12 cm on `wall.yaml` rooms), so against h_ref a
step at 4 h_ref or coarser carries at most ≈ 1/16 of its own error in the reference. The reference states its own
error as ‖P(h_ref) − P(2 h_ref)‖ / 3 (the h² law's estimate of P(h_ref)'s error), from one more run at 2 h_ref.

Every step and the reference run the config's quadrature settings with the edge and a graded config's grading
ratio scaled together (the whole split refines by one factor), and with the FoV cells per pixel side of the
config's own transport (its ``estimator.fov_cells``, else the count its edge gets), so all of them integrate the
pixels alike (one cell per pixel in the scan configs: each target is its laser point). The steps go from
``LADDER_TOP`` × the config's edge down to ``LADDER_BOTTOM`` × h_ref in factors of √2.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ConfigError
from ..scene import RayCaster, Scene, resolve_capture
from ..transport import estimator as transport_estimator
from .accuracy import Ladder, relative_l2, run_estimator
from .reference import Reference

__all__ = ["LADDER_BOTTOM", "LADDER_TOP", "SCAN_LADDER", "quadrature_reference", "scan_benchmark", "scan_ladder"]

SCAN_LADDER = "quadrature"
"""The registered estimator the scan's ladder runs, and the ladder's name in the benchmark's tables."""

LADDER_TOP = 4.0
"""The coarsest step's edge over the config's edge."""

LADDER_BOTTOM = 4.0
"""The finest step's edge over the reference's: against h_ref a step at 4 h_ref carries ≈ 1/16 of its error."""


def _base(config) -> tuple[float, float | None]:
    """(edge m, grading ratio or None) of the config's estimator when it has an edge (the quadrature's options),
    else the quadrature's defaults."""
    est = config.estimator
    if getattr(est, "edge", None) is not None:
        grading = getattr(est, "grading", None)
        return float(est.edge), (None if grading is None else float(grading))
    settings = transport_estimator(SCAN_LADDER).settings_class.from_transport(config.transport_settings())
    return float(settings.edge), None


def _step(edge: float, base_edge: float, grading: float | None, fov_cells: int | None) -> dict:
    step = {"edge": float(edge), "fov_cells": fov_cells}
    if grading is not None:
        step["grading"] = grading * edge / base_edge
    return step


def _fov_cells(scene: Scene, config, caster: RayCaster) -> int | None:
    """FoV cells per pixel side of the config's own transport: its ``estimator.fov_cells`` when it fixes them,
    else the count the quadrature takes at the config's edge (None: not an aperture capture)."""
    edge, _ = _base(config)
    return transport_estimator(SCAN_LADDER).cls.aperture_cells(resolve_capture(scene, caster), edge,
                                                                getattr(config.estimator, "fov_cells", None))


def scan_ladder(scene: Scene, config, reference_edge: float | None = None,
                caster: RayCaster | None = None) -> tuple[Ladder, dict]:
    """The quadrature ladder of a scan and the settings of its reference (module doc).

    Args:
        scene, config: the capture and its :class:`~datagen.simulation.SimulationConfig`.
        reference_edge: h_ref, metres (default a quarter of the config's edge).
    Returns:
        (the :class:`~datagen.analysis.accuracy.Ladder` named :data:`SCAN_LADDER`, coarsest step first; the reference's
        step: quadrature settings at h_ref).
    Raises:
        ConfigError: ``reference_edge`` not > 0, or so coarse that no step lies at ``LADDER_BOTTOM`` × it or above
            ``LADDER_TOP`` × the config's edge.
    """
    edge, grading = _base(config)
    h_ref = edge / 4.0 if reference_edge is None else float(reference_edge)
    if not (math.isfinite(h_ref) and h_ref > 0):
        raise ConfigError(f"--reference-edge must be a length > 0 in metres, got {reference_edge!r}")
    top, bottom = LADDER_TOP * edge, LADDER_BOTTOM * h_ref
    if bottom > top:
        raise ConfigError(f"--reference-edge {h_ref:g} m: the finest step ({LADDER_BOTTOM:g} × it = {bottom:g} m) "
                          f"would be coarser than the coarsest ({LADDER_TOP:g} × the config's edge {edge:g} m); give "
                          f"at most {top / LADDER_BOTTOM:g} m")
    cells = _fov_cells(scene, config, caster or RayCaster(scene))
    count = int(math.floor(2.0 * math.log2(top / bottom) + 1e-9)) + 1
    steps = tuple(_step(top * 2.0 ** (-i / 2), edge, grading, cells) for i in range(count))   # even i: exact
    ladder = Ladder(SCAN_LADDER, "hidden-surface quadrature", SCAN_LADDER, steps,
                    lambda s: s["edge"] ** -2.0, lambda s: f"h={s['edge']:.3g} m")
    return ladder, _step(h_ref, edge, grading, cells)


def quadrature_reference(scene: Scene, config, step: dict, caster: RayCaster | None = None) -> Reference:
    """The quadrature at the reference's settings ``step`` (:func:`scan_ladder`), with its own error estimate
    ‖P(h_ref) − P(2 h_ref)‖ / 3 from one more run at twice the edge (and grading ratio).

    Returns:
        :class:`~datagen.analysis.reference.Reference`: envelope channel_shape + (n_bins,) float64 photons per pulse
        per bin; ``error_estimate`` {"rel_l2": the estimate, "total", "peak_time": nan}; ``replicas`` 1;
        ``converged`` True; ``seconds`` both runs' wall time; ``settings`` the step, the estimate's method.
    """
    caster = caster or RayCaster(scene)
    ladder = Ladder(SCAN_LADDER, "", SCAN_LADDER, (step,), lambda s: 1.0, lambda s: "")
    t0 = time.perf_counter()
    env, _ = run_estimator(scene, config, ladder, step, caster)
    coarse_step = {**step, "edge": 2.0 * step["edge"]}
    if step.get("grading") is not None:
        coarse_step["grading"] = 2.0 * step["grading"]
    coarse, _ = run_estimator(scene, config, ladder, coarse_step, caster)
    rel = relative_l2(env, coarse) / 3.0
    info = {"sampler": "quadrature", **step, "method": "‖P(h) − P(2h)‖ / 3 (h² law), relative L2 over bins above "
                                                      "1 % of the peak"}
    return Reference(env, {}, np.asarray(config.time.edges), {"rel_l2": rel, "total": float("nan"),
                                                              "peak_time": float("nan")},
                     info, time.perf_counter() - t0, 1, True)


def scan_benchmark(scene: Scene, config, reference_edge: float | None, caster: RayCaster) -> tuple[Reference, dict]:
    """What ``--quadrature-reference`` runs a scan against: (its reference, :func:`quadrature_reference` at
    :func:`scan_ladder`'s reference settings (edge in ``settings["edge"]``); the ladder table
    {:data:`SCAN_LADDER`: the ladder} for :func:`datagen.analysis.accuracy.run_accuracy`). Raises as
    :func:`scan_ladder`."""
    ladder, step = scan_ladder(scene, config, reference_edge, caster)
    return quadrature_reference(scene, config, step, caster), {SCAN_LADDER: ladder}
