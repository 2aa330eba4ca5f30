"""The hidden-surface quadrature's settings model: the ``estimator: {kind: quadrature, ...}`` block of a
simulation config (:class:`QuadratureOptions`), with its registry hooks (replica, refine, describe)."""
from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import Field

from ..base import EstimatorOptions

QUADRATURE_EDGE = 0.02
"""Default sub-triangle edge h (m). On the hidden-square tal captures (0.4 m square 1 m from the wall, 3 mm bins)
it gives 0.13 % (single spot) and 0.22 % (32×32 confocal) relative L2 against the exact answer (docs/tal.md), well
inside their 1 % target."""


SCAN_FOV_CELLS = 1
"""FoV cells per pixel side of a scanned capture whose config leaves ``fov_cells`` unset: one, the pixel's midpoint (a
scan point is the detector's focus, as in the field's renderers), at every edge of the tolerance loop. Following the
edge instead (``fov_cells: edge``, what the v1 benchmark suites were built with), a sample refined below the pixel
pitch switched to 2 × 2 cells, a different capture at 18 times the cost (docs/scans.md, "Fix the FoV cells of a scan
config")."""


def fov_cells_per_side(fov_cells: int | str | None, scanned: bool, pixel_side: float, edge: float) -> int:
    """FoV cells per pixel side for a ``fov_cells`` setting (an int, "edge" or None), a capture that is ``scanned``
    (more than one laser point) or not, its pixel side (m) and the sub-triangle edge (m): the int; "edge" (and None
    on a single-spot capture) ceil(pixel side / edge), at least 1 (not capped here); None on a scan
    :data:`SCAN_FOV_CELLS`."""
    if isinstance(fov_cells, int) and not isinstance(fov_cells, bool):
        return int(fov_cells)
    if fov_cells is None and scanned:
        return SCAN_FOV_CELLS
    return max(1, math.ceil(pixel_side / edge - 1e-9))


class QuadratureOptions(EstimatorOptions):
    """The quadrature's settings (:mod:`datagen.transport.quadrature`).

    Attributes:
        edge: sub-triangles of edge ≤ ``edge`` metres, with exact time binning.
        fov_cells: aperture captures integrate each pixel region with ``fov_cells`` × ``fov_cells`` FoV cells
            (None: cells no larger than the edge, and on a scanned capture :data:`SCAN_FOV_CELLS` at every edge;
            "edge": cells no larger than the edge on scans too).
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
    fov_cells: Annotated[int, Field(ge=1)] | Literal["edge"] | None = None
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
