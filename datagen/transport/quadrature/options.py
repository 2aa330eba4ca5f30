"""The hidden-surface quadrature's settings model: the ``estimator: {kind: quadrature, ...}`` block of a
simulation config (:class:`QuadratureOptions`), with its registry hooks (replica, refine, describe)."""
from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from ..base import EstimatorOptions

QUADRATURE_EDGE = 0.02
"""Default sub-triangle edge h (m). On the hidden-square tal captures (0.4 m square 1 m from the wall, 3 mm bins)
it gives 0.13 % (single spot) and 0.22 % (32×32 confocal) relative L2 against the exact answer (docs/tal.md), well
inside their 1 % target."""


class QuadratureOptions(EstimatorOptions):
    """The quadrature's settings (:mod:`datagen.transport.quadrature`).

    Attributes:
        edge: sub-triangles of edge ≤ ``edge`` metres, with exact time binning.
        fov_cells: aperture captures integrate each pixel region with ``fov_cells`` × ``fov_cells`` FoV cells
            (None: cells no larger than the edge).
        grading: r (None: off): hidden triangles are first cut into 4 while longer than r × their distance to the
            scanned points, so sub-triangles near the scan are finer (:mod:`datagen.transport.quadrature.grading`).
        refine_grading: the tolerance loop's finer levels (and the coarse run of the error estimate) scale the
            grading ratio with the edge, so the whole graded split refines by one factor (:meth:`at_edge`); False
            (the default, the v1 suites' setting): only the edge changes, and the pieces near the scan only through
            their floor of 0.4 × the edge.
        secondary_samples: hidden samples per laser point of the area sampler that computes a planned secondary.
    """

    kind: Literal["quadrature"] = "quadrature"
    edge: float = Field(QUADRATURE_EDGE, gt=0.0)
    fov_cells: int | None = Field(None, ge=1)
    grading: float | None = Field(None, gt=0)
    refine_grading: bool = False
    secondary_samples: int = Field(65536, ge=16)

    LEGACY: ClassVar[dict[str, str]] = {"quadrature_edge": "edge", "quadrature_fov": "fov_cells",
                                        "quadrature_grading": "grading", "area_samples": "secondary_samples"}

    def replica(self, replicas: int) -> dict:
        """One of ``replicas`` runs of the Monte Carlo secondary: ``secondary_samples`` / R hidden samples (the
        primary is deterministic and shared, :meth:`Quadrature.run_replicas`)."""
        return {"secondary_samples": max(16, -(-int(self.secondary_samples) // int(replicas)))}

    def refine(self) -> dict:
        """The coarser setting of the error estimate: twice the edge (FoV cells follow it unless fixed; the grading
        ratio too with ``refine_grading``)."""
        return self.at_edge(2.0 * float(self.edge))

    def at_edge(self, edge: float) -> dict:
        """The settings of a level at sub-triangle edge ``edge`` (m) of the tolerance loop
        (:func:`datagen.simulation.simulate_to_tolerance`): the edge, and with ``refine_grading`` the grading ratio
        times edge / ``self.edge``."""
        if self.refine_grading and self.grading is not None:
            return {"edge": float(edge), "grading": float(self.grading) * float(edge) / float(self.edge)}
        return {"edge": float(edge)}

    def describe(self) -> str:
        return f"quadrature edge {self.edge:.4g} m"
