"""Upper bounds of the numeric knobs of a simulation, checked before any work, and the projection of long work.

Memory bounds the knobs whose arrays grow with them (:mod:`.budget`); these bound the work: each knob a user
sets (in a scene's ``simulation`` block, a dataset config or on the command line) has the largest value a run
may ask for, about an hour of transport on one core of the reference machine (docs/benchmarks.md) at its
largest, so that no value runs until killed. :func:`check_bounds` refuses a value beyond its bound in one line
naming the field (and the option that sets it), the value, the bound and why; :func:`check_simulation_memory
<datagen.simulation.budget.check_simulation_memory>` calls it after the memory check, so every simulation path
(``simulate``, multi-zone runs, the tolerance loop, dataset samples) checks it before it builds anything.
:func:`projected_work` gives the nominal time of the work that grows with the knobs (light paths, hidden
samples, camera rays), which the commands print when it is long (:data:`LONG_WORK_S`).

docs/reliability.md ("Bounds") lists every bound; tests/test_hostile_round5.py draws each knob up to 1e15.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ConfigError
from ..scene import Scene
from ..timing import EnvelopeAccumulator
from ..timing.accumulator import MAX_FINE_NODES as ACCUMULATOR_MAX_NODES
from ..units import format_duration
from .config import SimulationConfig

__all__ = ["MAX_PATHS", "MAX_SAMPLES", "MAX_CAMERA_RAYS", "MAX_GRID_SIDE", "MAX_GRID_POINTS", "MAX_CHANNELS",
           "MAX_FINE_NODES", "MAX_WORKERS", "MAX_FOV_CELLS", "MAX_TOP_K", "MAX_BATCH", "MAX_CONNECT_SIDE",
           "LONG_WORK_S", "SECONDS_PER", "Knob", "knobs", "check_bounds", "projected_work", "long_work_line"]

MAX_PATHS = 1 << 30
"""Light paths of the order ≥ 3 tracer in one run, ``multibounce.paths`` × laser points (1.07e9: 10–20 min of
tracing at the measured 0.5–1 µs a path)."""

MAX_SAMPLES = 1 << 30
"""Hidden samples of the area sampler (``estimator.samples``) or of the quadrature's secondary
(``estimator.secondary_samples``) × laser points (1.07e9: about 70 min at 4 µs each, nominal)."""

MAX_CAMERA_RAYS = 1 << 34
"""Camera rays of the lookin estimator, lookins × pixels × laser points (1.7e10: about an hour at 0.21 µs each)."""

MAX_GRID_SIDE = 4096
"""Points a side of a lookin grid, a camera, a sensor grid, a FoV or a scan (a 4096 × 4096 scan is 16.8 M laser
points; the largest lab scans are 256 × 256)."""

MAX_GRID_POINTS = 1 << 20
"""Points of one sensor grid, FoV or scan (1024 × 1024)."""

MAX_CHANNELS = 1 << 22
"""Output channels (envelopes) of a capture: laser points × sensor points of an exhaustive scan (4.2 M)."""

MAX_FINE_NODES = ACCUMULATOR_MAX_NODES
"""Nodes of the accumulator's fine time grid per component: ``time.n_bins`` × its oversample (1–34 fine nodes a
bin, from the IRF's width over the bin width) plus the IRF's guard nodes (16.8 M: the 1 km corridor's 1.67 M bins
need 1.67 M)."""

MAX_WORKERS = 256
"""Processes a simulation may start (``workers``): each is a full copy of the run's arrays."""

MAX_FOV_CELLS = 64
"""The quadrature's FoV cells per pixel side when given (``estimator.fov_cells``: 4096 per pixel region)."""

MAX_TOP_K = 1 << 16
"""The optimized secondary's ``top_k`` (pairs kept per lookin and FoV point; a 256 × 256 camera has 65 536)."""

MAX_BATCH = 1 << 20
"""Lookins per batch (``estimator.batch``)."""

MAX_CONNECT_SIDE = 256
"""Stratified connection points per pixel side (``estimator.connect_samples``)."""

LONG_WORK_S = 60.0
"""Projected work (nominal seconds, one core) from which ``simulate`` and ``multizone`` print the projection."""

SECONDS_PER = {"path": 1.0e-6, "sample": 4.0e-6, "camera_ray": 2.1e-7}
"""Nominal seconds of one core per traced light path (measured 0.5 µs on the demo room at orders 3; deeper
orders cost more), per area-sampler hidden sample and per lookin camera ray (the estimators' ``NOMINAL_SECONDS``)."""


@dataclass(frozen=True)
class Knob:
    """One bounded quantity of a run: the ``field`` that sets it (and the command-line ``option``), its ``value``
    as given (a grid "64x64", a count, a product "1e+06 x 4096 laser points"), the ``amount`` compared with the
    ``bound``, the ``unit`` it counts and what the bound means (``why``). ``memory``: the memory estimate counts
    it too (:mod:`.budget`), and names it first when it cannot fit; ``todo``: what to do (default: lower it)."""

    field: str
    value: str
    amount: float
    bound: float
    unit: str
    why: str
    option: str | None = None
    memory: bool = True
    todo: str | None = None

    def message(self, where: str) -> str:
        name = f"{self.field} ({self.option})" if self.option else self.field
        unit = f" {self.unit}" if self.unit else ""
        try:
            plain = float(self.value) == self.amount
        except ValueError:
            plain = False
        verb = "has" if self.unit.endswith("a side") else "makes"
        what = (f"{self.value} is above its bound of {self.bound:.4g}{unit}" if plain else
                f"{self.value} {verb} {self.amount:.4g}{unit}, above the bound of {self.bound:.4g}")
        return f"{where}{name} {what} ({self.why}): {self.todo or 'lower ' + self.field}"


def _grid(v) -> str:
    return "x".join(str(int(n)) for n in v)


def _lasers(scene: Scene) -> int:
    cap = scene.capture
    return math.prod(cap.laser_grid.points) if cap is not None and cap.type != "single" else 1


def knobs(scene: Scene, config: SimulationConfig) -> list[Knob]:
    """Every bounded knob of ``scene`` under ``config``, with its value and bound (those that do not apply, such
    as another estimator's, are left out)."""
    lasers = _lasers(scene)
    per = f" x {lasers} laser points" if lasers > 1 else ""
    est = config.estimator
    _, over, left, right = EnvelopeAccumulator.fine_grid(config.time, config.irf)
    guard = left + right > config.time.n_bins * over       # the IRF's guard nodes dominate: the IRF is the cause
    value = (f"(sigma {config.irf.sigma:.3g} s, {left + right} guard nodes)" if guard else
             f"{config.time.n_bins} ({over} fine nodes a bin)")
    out = [Knob("irf" if guard else "time.n_bins", value, config.time.n_bins * over + left + right, MAX_FINE_NODES,
                "fine time nodes", "the accumulator's fine grid, 128 MiB per component",
                todo=("narrow the irf" if guard else "lower time.n_bins") + " or widen time.bin_width"),
           Knob("workers", str(config.workers), config.workers, MAX_WORKERS, "processes",
                "each holds a copy of the run", "--workers", memory=False)]
    if config.multibounce.paths is not None:
        out.append(Knob("multibounce.paths", f"{config.multibounce.paths}{per}", config.multibounce.paths * lasers,
                        MAX_PATHS, "light paths", "10-20 min of tracing at about 1 µs a path", memory=False))
    for field, option in (("samples", "--samples"), ("secondary_samples", None)):
        n = getattr(est, field, None)
        if isinstance(n, int):
            out.append(Knob(f"estimator.{field}", f"{n}{per}", n * lasers, MAX_SAMPLES, "hidden samples",
                            "about 70 min at 4 µs each", option))
    for field, option in (("lookins", "--lookins"), ("pixels", "--pixels")):
        grid = getattr(est, field, None)
        if grid is not None:
            out.append(Knob(f"estimator.{field}", _grid(grid), max(grid), MAX_GRID_SIDE, "a side",
                            f"{MAX_GRID_SIDE} a side", option))
    if getattr(est, "lookins", None) is not None and getattr(est, "pixels", None) is not None:
        rays = math.prod(est.lookins) * math.prod(est.pixels) * lasers
        out.append(Knob("estimator.lookins", f"{_grid(est.lookins)} x pixels {_grid(est.pixels)}{per}", rays,
                        MAX_CAMERA_RAYS, "camera rays", "about an hour at 0.21 µs each", "--lookins"))
    for field, bound in (("top_k", MAX_TOP_K), ("batch", MAX_BATCH)):
        n = getattr(est, field, None)
        if isinstance(n, int):
            out.append(Knob(f"estimator.{field}", str(n), n, bound, "", "more changes nothing but the memory",
                            "--top-k" if field == "top_k" else None, memory=False))
    connect = getattr(est, "connect_samples", None)
    if connect is not None:
        out.append(Knob("estimator.connect_samples", _grid(connect), max(connect), MAX_CONNECT_SIDE, "a side",
                        f"{MAX_CONNECT_SIDE} a side", memory=False))
    cells = getattr(est, "fov_cells", None)
    if isinstance(cells, int) and not isinstance(cells, bool):
        out.append(Knob("estimator.fov_cells", str(cells), cells, MAX_FOV_CELLS, "a pixel side",
                        f"{MAX_FOV_CELLS ** 2} FoV points per pixel region", memory=False))
    out += _grids(scene, lasers)
    return out


def _grids(scene: Scene, lasers: int) -> list[Knob]:
    """The scene's sensor grid, FoV and scan: points a side, points, and channels."""
    cap, out = scene.capture, []
    grids = [("sensor.fov.pixels", scene.sensor.fov.pixels)] if scene.sensor.fov is not None else []
    if cap is not None:
        grids += [(f"capture.{name}.points", g.points) for name, g in (("sensor_grid", cap.sensor_grid),
                                                                         ("laser_grid", cap.laser_grid))
                  if g is not None]
    for field, points in grids:
        out.append(Knob(field, _grid(points), max(points), MAX_GRID_SIDE, "points a side", f"{MAX_GRID_SIDE} a side"))
        out.append(Knob(field, _grid(points), math.prod(points), MAX_GRID_POINTS, "points",
                        f"{MAX_GRID_POINTS} points, 1024 x 1024"))
    if cap is not None and cap.type == "exhaustive" and cap.sensor_grid is not None:
        channels = lasers * math.prod(cap.sensor_grid.points)
        out.append(Knob("capture.sensor_grid.points", f"{_grid(cap.sensor_grid.points)} x {lasers} laser points",
                        channels, MAX_CHANNELS, "channels", "4.2 M envelopes"))
    return out


def check_bounds(scene: Scene, config: SimulationConfig, memory: bool | None = None) -> None:
    """Refuse a knob beyond its bound (:func:`knobs`) before any work; ``memory``: only the knobs whose
    :attr:`Knob.memory` is that (None: every knob).

    Raises:
        ConfigError: one line naming the scene file, the field (and its option), the value, the bound and why.
    """
    where = f"{scene.source} (simulation): " if scene.source else "simulation: "
    for knob in knobs(scene, config):
        if memory in (None, knob.memory) and not knob.amount <= knob.bound:
            raise ConfigError(knob.message(where))


def projected_work(scene: Scene, config: SimulationConfig) -> tuple[float, str]:
    """(nominal seconds on one core, what they are) of the work that grows with the knobs: the area sampler's
    hidden samples (and the quadrature's secondary's), the lookin estimator's camera rays, and the light paths when orders ≥ 3 may be traced
    (``orders`` ≥ 3 or "auto") (:data:`SECONDS_PER`); (0, "") when none applies. The quadrature's work grows with
    its edge, which memory bounds (:mod:`.budget`)."""
    lasers, est, parts = _lasers(scene), config.estimator, []
    orders = config.orders_setting()
    tracer = orders == "auto" or orders >= 3
    per = f" x {lasers} laser points" if lasers > 1 else ""
    for field in ("samples", "secondary_samples"):
        n = getattr(est, field, None)
        secondary = config.secondary != "none" and config.effects.get("secondary", True) is not False
        if isinstance(n, int) and (field == "samples" or secondary):
            parts.append((n * lasers * SECONDS_PER["sample"], f"estimator.{field} {n:g}{per}"))
    if getattr(est, "lookins", None) is not None and getattr(est, "pixels", None) is not None:
        rays = math.prod(est.lookins) * math.prod(est.pixels) * lasers
        parts.append((rays * SECONDS_PER["camera_ray"], f"estimator.lookins {_grid(est.lookins)} x pixels "
                                                        f"{_grid(est.pixels)}{per}"))
    if tracer:
        paths = config.tracer_paths(lasers) * lasers
        parts.append((paths * SECONDS_PER["path"], f"multibounce.paths {config.tracer_paths(lasers):g}{per}"))
    if not parts:
        return 0.0, ""
    seconds = sum(s for s, _ in parts)
    return seconds, " and ".join(what for t, what in sorted(parts, reverse=True) if t >= 0.1 * seconds)


def long_work_line(scene: Scene, config: SimulationConfig) -> str | None:
    """The line a command prints before long work (projected beyond :data:`LONG_WORK_S`), else None."""
    seconds, what = projected_work(scene, config)
    if seconds <= LONG_WORK_S:
        return None
    return (f"{what} project about {format_duration(seconds)} of transport on one core (nominal; the progress bar "
            "follows the run): lower them for a faster run")
