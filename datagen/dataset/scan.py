"""Scanned captures in room distributions: a laser grid over a rectangle of the relay wall (``capture.scan``).

Most NLOS reconstruction networks and every classical baseline (backprojection, LCT, f-k, phasor fields) take
a *scan*: the transient L(t) per laser point over a grid on the relay wall (docs/datasets.md, "Scanned
captures"). :class:`ScanDist` is the ``capture.scan`` block of a room distribution; :func:`draw_scan` draws one
scan from it with the sensor stream and :func:`scan_capture` turns it into the scene's
:class:`~datagen.scene.CaptureSpec` (the tal scan types, docs/physics.md §8):

- ``confocal``: the laser visits each point of an nx × ny grid (cell centres of a w × h rectangle) and the
  sensor images the same point (with the aperture convention: the grid cell around it). Envelope (ny, nx, T).
- ``exhaustive``: every laser point × every point of a sensor grid (``sensor``: its own rectangle and points;
  1 × 1 is a single sensor point, a small pixel region). Envelope (ly, lx, ny, nx, T).
- ``exhaustive`` with ``flood`` (:class:`FloodScan`): a flood-illuminated multi-zone sensor (docs/multizone.md):
  the laser grid is the flood's quadrature nodes, the sensor grid the zones, and a sample stores the zones'
  envelope and counts (Z_y, Z_x, T) (:mod:`datagen.dataset.zones`).

Axis order on the wall: u = n × z (the wall's horizontal tangent, +y for the relay wall x = relay_x facing −x)
and v = u × n (up, +z); grid point (iy, ix) is center + ((ix + ½)/nx − ½)·w·u + ((iy + ½)/ny − ½)·h·v, so
row iy grows upward and column ix along u (plot with ``origin="lower"``). The time window (``n_bins``,
``bin_width``, ``t_start``) is the dataset's ``simulation.time``; confocal set-ups usually leave both the
emitter → wall and the wall → sensor legs out of it (``count_sensor_leg: false``), so t = (|x − p| + |x − p|)/c.

The rectangle's centre is placed by fractions of the free space on the wall's corridor end (the part the
emitter and sensor see): ``lateral`` ∈ [−1, 1] of the horizontal slack (w_wall − 2·edge_margin − w)/2 and
``height`` ∈ [0, 1] of the vertical slack, so every value keeps the rectangle ``edge_margin`` inside the wall.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import field_validator, model_validator

from ..scene import CaptureSpec
from ..scene.flood import FloodProfile
from ..scene.parts import check_counts
from .ranges import Model, Positive, Range, Signed, Unit


class GridDist(Model):
    """A grid on the relay wall: rectangle ``width`` × ``height`` (m, uniform ranges; ``height: width`` draws a
    square, the height equal to the drawn width), ``points`` (nx, ny) fixed, centre at fractions ``lateral``
    (−1..1) and ``height_frac`` (0..1) of the free space (module doc)."""

    width: Positive = Range(min=1.0, max=1.0)
    height: Positive | Literal["width"] = Range(min=1.0, max=1.0)
    points: tuple[int, int] = (32, 32)
    lateral: Signed = Range(min=0.0, max=0.0)
    height_frac: Unit = Range(min=0.5, max=0.5)

    @field_validator("points")
    @classmethod
    def _points(cls, v: tuple[int, int]) -> tuple[int, int]:
        return check_counts(v, "point counts")

    @property
    def square(self) -> bool:
        """Whether the rectangle is a square (``height: width``)."""
        return self.height == "width"

    @property
    def height_range(self) -> Range:
        """The range the height is drawn from (the width's when square)."""
        return self.width if self.square else self.height


class FloodScan(Model):
    """``capture.scan.flood``: the exhaustive scan's laser grid is a flood's quadrature nodes, lit with the
    emitter's ``profile`` (:class:`~datagen.scene.flood.FloodProfile`); a sample stores the zones' histograms."""

    profile: FloodProfile = FloodProfile()


class ScanDist(GridDist):
    """``capture.scan``: the laser grid (``type`` confocal or exhaustive), its rectangle and points, the
    sensor grid of exhaustive scans (``sensor``; 1 × 1 points: a single sensor point) and the ``convention``
    (``aperture``: expected detected photons per pulse; ``point_radiance``: tal / mitransient's radiance);
    ``flood`` (exhaustive, aperture): the laser grid is a flood's nodes and the sensor grid its zones."""

    type: Literal["confocal", "exhaustive"] = "confocal"
    sensor: GridDist | None = None
    convention: Literal["aperture", "point_radiance"] = "aperture"
    flood: FloodScan | None = None

    @model_validator(mode="after")
    def _sensor(self) -> "ScanDist":
        if self.type == "confocal" and self.sensor is not None:
            raise ValueError("a confocal scan images its own laser points; drop sensor (or use type exhaustive)")
        if self.type == "exhaustive" and self.sensor is None:
            raise ValueError("an exhaustive scan needs a sensor grid (points [1, 1] for a single sensor point)")
        if self.flood is not None and (self.type != "exhaustive" or self.convention != "aperture"):
            raise ValueError(f"flood: a flood's zones are an exhaustive scan's sensor grid with the aperture "
                             f"convention, got type {self.type!r}, convention {self.convention!r}")
        return self

    @property
    def shape(self) -> tuple[int, ...]:
        """Leading axes of the envelope: (ny, nx) confocal, (ly, lx, ny, nx) exhaustive."""
        lx, ly = self.points
        if self.type == "confocal":
            return (ly, lx)
        sx, sy = self.sensor.points
        return (ly, lx, sy, sx)


def _draw_grid(grid: GridDist, rng: np.random.Generator, relay_x: float, wall_width: float, ceiling: float,
               margin: float) -> dict:
    """Rectangle of ``grid`` on the wall's corridor end: 4 uniforms (width, height, lateral, height_frac); a square
    still draws the height's uniform, so the stream is the same whichever the shape."""
    w, h = grid.width.draw(rng.random()), grid.height_range.draw(rng.random())
    if grid.square:
        h = w
    lateral, up = grid.lateral.draw(rng.random()), grid.height_frac.draw(rng.random())
    cy = lateral * 0.5 * (wall_width - 2 * margin - w)
    cz = margin + h / 2 + up * (ceiling - 2 * margin - h)
    return {"center": [float(relay_x), float(cy), float(cz)], "size": [float(w), float(h)],
            "points": list(grid.points)}


def draw_scan(scan: ScanDist, rng: np.random.Generator, relay_x: float, wall_width: float, ceiling: float,
              margin: float) -> dict:
    """One scan drawn with the sensor stream: {type, convention, laser_grid {center, size, points},
    sensor_grid (exhaustive) or None}; 4 uniforms per grid, laser grid first."""
    laser = _draw_grid(scan, rng, relay_x, wall_width, ceiling, margin)
    sensor = _draw_grid(scan.sensor, rng, relay_x, wall_width, ceiling, margin) if scan.sensor else None
    return {"type": scan.type, "convention": scan.convention, "laser_grid": laser, "sensor_grid": sensor}


def scan_capture(drawn: dict) -> CaptureSpec:
    """The scene's :class:`~datagen.scene.CaptureSpec` of a drawn scan."""
    data = {"type": drawn["type"], "convention": drawn["convention"], "laser_grid": drawn["laser_grid"]}
    if drawn.get("sensor_grid") is not None:
        data["sensor_grid"] = drawn["sensor_grid"]
    return CaptureSpec.model_validate(data)


def rectangle_corners(grid: dict) -> list[list[float]]:
    """(4, 3) corners, in order, of a drawn grid's rectangle on the relay wall x = const (u = +y, v = +z)."""
    x, cy, cz = grid["center"]
    w, h = grid["size"]
    return [[x, cy + a * w / 2, cz + b * h / 2] for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]


def scan_fits(scan: ScanDist, wall_width: float, ceiling: float, margin: float) -> list[tuple[str, str]]:
    """(field, problem) for every grid of ``scan`` that does not fit the narrowest wall / lowest ceiling."""
    out = []
    grids = [("capture.scan", scan)] + ([("capture.scan.sensor", scan.sensor)] if scan.sensor else [])
    for name, grid in grids:
        if grid.width.max > wall_width - 2 * margin:
            out.append((f"{name}.width.max", f"{grid.width.max} m does not fit the narrowest relay wall "
                        f"({wall_width} m minus 2 × edge_margin {margin} m)"))
        if grid.height_range.max > ceiling - 2 * margin:
            field = f"{name}.width.max (height: width)" if grid.square else f"{name}.height.max"
            out.append((field, f"{grid.height_range.max} m does not fit under the lowest ceiling "
                        f"({ceiling} m minus 2 × edge_margin {margin} m)"))
    return out

