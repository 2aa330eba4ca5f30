"""Resource estimate before allocating: refuse a simulation whose largest arrays cannot fit in memory.

:func:`simulation_memory` adds up, from the scene and the config alone (nothing is allocated), the arrays that
grow with the inputs — the accumulator's fine grid and the result arrays (components × channels × time
bins), the lookin grid, the camera rays of one slice (pixels per lookin) and the full secondary's pairs
(pixels²), the capture's laser and sensor grids, the area sampler's hidden samples and the quadrature's
sub-triangles (edge) — each with the field that sets it. :func:`check_simulation_memory` compares the total with the memory available to this process
(:func:`available_memory`) and raises :class:`ResourceError` naming the dominant field, its value and both
figures in GiB, then checks every knob's bound of work (:mod:`.bounds`). ``simulate`` and
``simulate_to_tolerance`` call it before building anything
(:func:`datagen.simulation.run.run_transport`); dataset builds add their shard buffers
(:mod:`datagen.dataset.build`).

The estimators' own terms come from their registry entries (:attr:`datagen.transport.base.EstimatorEntry.memory`, beside
each estimator's code). The byte counts per element are upper estimates of the arrays they hold at once (read off the
code, and measured for the secondary's pairs): a setting refused here would have failed with a MemoryError (or
the kernel's out-of-memory killer) after minutes of work, while the repository's scenes and configs estimate
at most a few hundred MiB (the demo room at its default 10×10×60×60, full secondary: 131 MiB).
"""
from __future__ import annotations

import math
from pathlib import Path

from ..errors import ResourceError
from ..scene import Scene
from ..timing import EnvelopeAccumulator
from ..transport import estimator
from ..transport.base import TARGET_BYTES
from .bounds import check_bounds
from .config import SimulationConfig

GIB = float(1 << 30)

ACCUMULATOR_COPIES = 2
"""Fine-grid copies an accumulator holds at once (histogram, and the convolution's output)."""

RESULT_COPIES = 2
"""Copies of the (components + envelope + counts + rates) × channels × bins result arrays alive at once."""


def available_memory() -> int | None:
    """Bytes this process may still allocate: ``MemAvailable`` of /proc/meminfo, lowered by a cgroup v2
    memory limit when one is set; psutil's estimate elsewhere; None when unknown (no check)."""
    found = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    if found is None:
        try:
            import psutil
            found = int(psutil.virtual_memory().available)
        except Exception:  # noqa: BLE001 - psutil missing or unsupported: no estimate
            return None
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
            found = min(found, max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    return found


def _capture_counts(scene: Scene) -> tuple[int, int, int, tuple[str, str]]:
    """(laser points L, sensor points S, output channels, (field, value) of the largest grid)."""
    cap, fov = scene.capture, scene.sensor.fov
    if cap is not None and cap.type == "confocal":
        n = math.prod(cap.laser_grid.points)
        return n, n, n, ("capture.laser_grid.points", "x".join(map(str, cap.laser_grid.points)))
    if cap is not None and cap.sensor_grid is not None:
        sensor, s_field = math.prod(cap.sensor_grid.points), ("capture.sensor_grid.points",
                                                              "x".join(map(str, cap.sensor_grid.points)))
    else:
        pixels = fov.pixels if fov is not None else (1, 1)
        sensor, s_field = math.prod(pixels), ("sensor.fov.pixels", "x".join(map(str, pixels)))
    if cap is not None and cap.type == "exhaustive":
        lasers = math.prod(cap.laser_grid.points)
        field = s_field if sensor >= lasers else ("capture.laser_grid.points", "x".join(map(str, cap.laser_grid.points)))
        return lasers, sensor, lasers * sensor, field
    return 1, sensor, sensor, s_field


def simulation_memory(scene: Scene, config: SimulationConfig) -> list[tuple[str, str, float]]:
    """The arrays a simulation of ``scene`` under ``config`` holds at its peak, estimated without allocating.

    Returns:
        (field, value, bytes) per term, largest first: field is the config or scene field that sets the term
        (``time.n_bins``, ``estimator.lookins``, ``sensor.fov.pixels``, ``estimator.edge``, …). The shared
        arrays are counted here, the estimator's own by its registry entry
        (:attr:`datagen.transport.base.EstimatorEntry.memory`).
    """
    lasers, sensors, channels, grid_field = _capture_counts(scene)
    primary = len(scene.component_names()) if config.split_components else 1
    n_components = primary + 2                                  # + secondary, first_bounce
    _, over, left, right = EnvelopeAccumulator.fine_grid(config.time, config.irf)
    n_fine = config.time.n_bins * over + left + right
    n_bins = config.time.n_bins
    grid = grid_field if channels > n_bins else ("time.n_bins", f"{n_bins} bins × {channels} channel(s)")
    fine = (grid[0], f"{grid[1]} ({over} fine nodes per bin, {n_components} components)")
    if left + right > n_bins * over:   # the IRF's guard nodes dominate: its width over the fine step is the cause
        tail = f", tail {config.irf.tail:.3g} s" if config.irf.tail else ""
        step = config.time.bin_width / over
        fine = ("irf", f"(sigma {config.irf.sigma:.3g} s{tail}) over fine steps of {step:.3g} s (time.bin_width / "
                       f"{over}) adds {left + right:.3g} guard nodes to the {n_bins} bins,")
    terms = [(*fine, 8.0 * ACCUMULATOR_COPIES * n_components * channels * n_fine),
             (grid[0], f"{grid[1]} (results)", 8.0 * RESULT_COPIES * (n_components + 3) * channels * n_bins),
             (grid_field[0], grid_field[1], float(TARGET_BYTES) * (lasers + sensors))]
    memory = estimator(config.estimator.kind).memory        # the estimator's own arrays (its registry entry)
    if memory is not None:
        terms += memory(scene, config, lasers, sensors)
    return sorted(terms, key=lambda t: -t[2])


RAISE_TO_SHRINK = ("estimator.edge",)
"""Fields whose memory falls as they grow (the hint says "raise", not "lower")."""

HINTS = {"irf": "narrow the irf or widen time.bin_width"}
"""Hints for terms that two fields set."""


def check_memory(needed: float, field: str, value: str, where: str = "") -> None:
    """Refuse ``needed`` bytes beyond :func:`available_memory` (no check when it is unknown).

    Raises:
        ResourceError: "``where``field value needs about X GiB … Y GiB available: lower field".
    """
    available = available_memory()
    if available is not None and needed > available:
        hint = HINTS.get(field, f"{'raise' if field in RAISE_TO_SHRINK else 'lower'} {field}")
        raise ResourceError(f"{where}{field} {value} needs about {needed / GIB:.3g} GiB of memory, more than the "
                            f"{available / GIB:.3g} GiB available: {hint}")


def check_simulation_memory(scene: Scene, config: SimulationConfig) -> float:
    """Estimate the simulation's memory (:func:`simulation_memory`) and refuse it when it exceeds the memory
    available; returns the estimate in bytes.

    Raises:
        ResourceError: naming the scene file, the dominant field, its value and both figures in GiB;
        ConfigError: a knob beyond its bound of work (:func:`datagen.simulation.bounds.check_bounds`).
    """
    check_bounds(scene, config, memory=False)    # the knobs of work alone (light paths, workers, …) first
    terms = simulation_memory(scene, config)
    total = sum(t[2] for t in terms)
    field, value, _ = terms[0]
    where = f"{scene.source} (simulation): " if scene.source else "simulation: "
    check_memory(total, field, value, where)
    check_bounds(scene, config, memory=True)     # then those memory counted too: the bound of their work
    return total

