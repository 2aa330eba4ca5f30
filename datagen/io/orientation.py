"""One orientation for every confocal scan datagen reads, writes or simulates (docs/capture_io.md, "Orientation").

datagen's order: a scan's envelope is (ny, nx, T); row iy grows up the wall (v) and column ix along u, which is to
the right as seen from the wall looking into the hidden scene (u = n × z, v = u × n, n the wall normal on the hidden
side; docs/physics.md §1). Drawn with ``origin="lower"`` a scan, its reconstruction and its wall-view labels show the
hidden scene as the wall sees it: a sign whose text faces the wall reads as it does in a photograph taken from there.

The Stanford LCT release (O'Toole, Lindell & Wetzstein, Nature 555, 338 (2018)) stores ``rect_data(i, j, t)``. Its
script ``cnlos_reconstruction.m`` permutes the array to (t, j, i), reverses the i axis and draws the maximum over t
with ``imagesc`` (row 1 at the top): in its "Front view" j runs down the picture and i from right to left, and in
that view the exit sign's text and arrow and the "S U" letters read correctly. So datagen's (iy, ix) is
(N_j − 1 − j, N_i − 1 − i): the file's array transposed and reversed along both axes (its anti-transpose, which is
its own inverse). Seen by the scanner facing the wall, i runs left to right and j top to bottom.

The grid is the release's: ``linspace(−width, width, N)`` along each axis (pitch 2·width/(N − 1)), on a vertical
wall in datagen's world frame (z up): the plane y = 0 with the hidden side at +y, u = +x, v = +z. The files record
no frame; this one puts the scan where a datagen scene of the same set-up would (docs/capture_io.md).
"""
from __future__ import annotations

import numpy as np

from ..errors import DatasetError

__all__ = ["LCT_WALL_NORMAL", "lct_to_scan", "scan_to_lct", "lct_scan_points", "lct_half_width", "square_pitch"]

LCT_WALL_NORMAL = np.array([0.0, 1.0, 0.0])
"""Wall normal (on the hidden side) of an imported LCT / f-k capture: the wall is the plane y = 0, u = +x, v = +z."""


def lct_to_scan(a: np.ndarray) -> np.ndarray:
    """The LCT release's ``rect_data``-ordered array (N_i, N_j, ...) in datagen's scan order (ny, nx, ...) =
    (N_j, N_i, ...): ``out[iy, ix] = a[N_i − 1 − ix, N_j − 1 − iy]`` (module docstring). A view, any dtype."""
    return np.swapaxes(np.asarray(a), 0, 1)[::-1, ::-1]


def scan_to_lct(a: np.ndarray) -> np.ndarray:
    """datagen's scan-ordered array (ny, nx, ...) in the LCT release's ``rect_data`` order (nx, ny, ...), the inverse
    of :func:`lct_to_scan` (the same anti-transpose): a C-contiguous copy, the dtype kept."""
    return np.ascontiguousarray(np.swapaxes(np.asarray(a), 0, 1)[::-1, ::-1])


def lct_scan_points(half_width: float, shape: tuple[int, int]) -> np.ndarray:
    """(ny, nx, 3) float64 scan points (m) of an LCT / f-k file in datagen's order and frame: column ix at
    u = ``linspace(−w, w, nx)[ix]`` (+x), row iy at v = ``linspace(−w, w, ny)[iy]`` (+z), on the plane y = 0
    (the release's grid, ``w`` = its ``width``, pitch 2·w/(N − 1))."""
    ny, nx = shape
    gv, gu = np.meshgrid(np.linspace(-half_width, half_width, ny), np.linspace(-half_width, half_width, nx),
                         indexing="ij")
    return np.stack([gu, np.zeros_like(gu), gv], axis=-1)


def lct_half_width(pitch: float, n: int) -> float:
    """The LCT ``width`` (m) of an N-point scan axis of pitch ``pitch`` m: pitch·(N − 1)/2, so that the release's
    ``linspace(−width, width, N)`` is that grid."""
    return float(pitch) * (int(n) - 1) / 2


def square_pitch(points: np.ndarray, fmt: str) -> float:
    """Pitch (m) of an N × N grid of points (N, N, 3) with equal spacing along rows and columns (what LCT / f-k
    files can describe).

    Raises:
        DatasetError: the grid is not square, has fewer than 2 points per side, or its pitches differ (the message
            names ``fmt`` and what the grid is).
    """
    ny, nx = points.shape[:2]
    if ny != nx or nx < 2:
        raise DatasetError(f"{fmt} files hold an N × N scan; the result's grid is {ny} × {nx}")
    du = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    dv = np.linalg.norm(np.diff(points, axis=0), axis=-1)
    pitch = float(du.mean())
    if not (np.allclose(du, pitch, rtol=1e-6) and np.allclose(dv, pitch, rtol=1e-6)):
        raise DatasetError(f"{fmt} files hold a grid of one pitch in both directions; the result's pitches are "
                           f"{float(du.mean()):.6g} m and {float(dv.mean()):.6g} m")
    return pitch
