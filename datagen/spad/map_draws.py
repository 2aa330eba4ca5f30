"""Per-sample gain and background maps drawn on the training device (docs/detector.md "Direct light, gain and
background maps"): what :class:`datagen.SPADNoise` draws with ``gain_range`` and ``background_bands``, so that a
network trained on simulated scans sees the per-point gain (laser power, focus) and the drifting background of real
captures (the LCT release: the direct and hidden counts vary together 14x over a scan; the background changes 3-4x
in bands of columns).

* :func:`draw_gain_fields`: a smooth random field per sample, bilinear over a GAIN_NODES x GAIN_NODES grid of
  uniforms, mapped to 10**(log10(R)·u) with u rescaled to [0, 1] per sample, then divided by its mean: max/min is the
  stated dynamic range R exactly, the mean 1.
* :func:`draw_background_bands`: the columns cut into ``bands`` contiguous bands at uniformly drawn positions, each
  band at a level 10**(log10(ratio)·v), v uniform, divided by the mean: max/min at most ``ratio``, the mean 1.

Draws come from the caller's ``torch.Generator`` after the detector parameters' uniforms
(:func:`datagen.spad.ranges.draw_detector_params`), so adding them does not change those.
"""
from __future__ import annotations

import math

import torch

__all__ = ["GAIN_NODES", "draw_gain_fields", "draw_background_bands"]

GAIN_NODES = 4
"""The gain field's coarse grid (4 x 4 uniforms, bilinear): smooth over a quarter of the scan, as laser power and
focus drift."""


def draw_gain_fields(shape: tuple[int, int], dynamic_range: float, batch: int,
                     generator: torch.Generator | None = None, device: torch.device | str = "cpu") -> torch.Tensor:
    """(batch, ny, nx) float64 gain maps, each of mean 1 and max/min exactly ``dynamic_range`` (≥ 1; 1: all ones).

    Raises:
        ValueError: ``dynamic_range`` < 1 or not finite, or a shape that is not (ny, nx) of positive sizes.
    """
    if not (math.isfinite(dynamic_range) and dynamic_range >= 1):
        raise ValueError(f"gain_range must be a finite dynamic range >= 1 (max/min), got {dynamic_range!r}")
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"a gain map needs a (ny, nx) scan, got leading shape {tuple(shape)}")
    coarse = torch.rand((batch, 1, GAIN_NODES, GAIN_NODES), generator=generator, dtype=torch.float64, device=device)
    field = torch.nn.functional.interpolate(coarse, size=tuple(shape), mode="bilinear", align_corners=True)[:, 0]
    low = field.amin(dim=(1, 2), keepdim=True)
    span = (field.amax(dim=(1, 2), keepdim=True) - low).clamp_min(1e-300)
    gain = torch.pow(10.0, math.log10(dynamic_range) * (field - low) / span)
    return gain / gain.mean(dim=(1, 2), keepdim=True)


def draw_background_bands(shape: tuple[int, int], ratio: float, bands: int, batch: int,
                          generator: torch.Generator | None = None, device: torch.device | str = "cpu"
                          ) -> torch.Tensor:
    """(batch, ny, nx) float64 background maps in ``bands`` bands of columns, mean 1, max/min ≤ ``ratio``.

    Raises:
        ValueError: ``ratio`` < 1 or not finite, ``bands`` < 1, or a shape that is not (ny, nx).
    """
    if not (math.isfinite(ratio) and ratio >= 1) or int(bands) != bands or bands < 1:
        raise ValueError(f"background_bands must be (ratio >= 1, bands >= 1), got ({ratio!r}, {bands!r})")
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"a background map needs a (ny, nx) scan, got leading shape {tuple(shape)}")
    ny, nx = shape
    cuts = torch.rand((batch, int(bands) - 1), generator=generator, dtype=torch.float64, device=device)
    levels = torch.pow(10.0, math.log10(ratio) * torch.rand((batch, int(bands)), generator=generator,
                                                             dtype=torch.float64, device=device))
    column = (torch.arange(nx, dtype=torch.float64, device=device) + 0.5) / nx
    band = (column[None, :, None] > torch.sort(cuts, dim=1).values[:, None, :]).sum(-1)      # (batch, nx)
    rows = torch.gather(levels, 1, band)
    maps = rows[:, None, :].expand(batch, ny, nx)
    return maps / maps.mean(dim=(1, 2), keepdim=True)
