"""What accuracy costs over many rooms: the estimator ladders on N rooms (e.g. a dataset's samples), each
against its own converged reference, summarised per setting as median and p95 over the rooms
(``datagen bench accuracy --dataset CONFIG --samples N``; docs/accuracy.md).

The whole run stays within one wall-time ``budget``: room k of N gets the time left divided by the rooms left;
within a room the reference (:func:`datagen.analysis.reference.converged_reference`, cached, so a later call
resumes it) may take ``reference_share`` of that, the ladders (:func:`datagen.analysis.accuracy.run_accuracy`)
the rest. A reference that did not reach ``rel_tol`` is reported with the error it reached; a room whose
reference has fewer than 2 replicas is skipped and reported. The rooms come in as (name, scene, simulation
config) triples: this module does not know where they were drawn (the command line draws them with
:func:`datagen.dataset.sample_setup`).
"""
from __future__ import annotations

import csv
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..scene import RayCaster, Scene
from .accuracy import LADDERS, AccuracyRow, loglog_axes, run_accuracy, save_loglog
from .reference import REFERENCE_SAMPLES, Reference, converged_reference
from .scan_accuracy import SCAN_LADDER, scan_benchmark

__all__ = ["RoomRow", "SettingSummary", "format_rooms_table", "plot_rooms", "run_rooms_accuracy", "summarize",
           "write_rooms_csv"]


@dataclass
class RoomRow:
    """One ladder step on one room: the room's name, its reference's own error estimate and the step's row."""

    room: str
    reference_error: float
    row: AccuracyRow


@dataclass
class SettingSummary:
    """One (estimator, setting) over the rooms it ran on: count, wall seconds and rel L2 error (median, p95)."""

    estimator: str
    setting: str
    rooms: int
    seconds_median: float
    seconds_p95: float
    rel_l2_median: float
    rel_l2_p95: float
    rel_l2_max: float


def run_rooms_accuracy(rooms: list[tuple[str, Scene, object]], budget: float,
                       estimators: tuple[str, ...] | None = None, rel_tol: float = 3e-3,
                       cache_dir: str | Path | None = None, reference_share: float = 0.5,
                       reference_samples: int = REFERENCE_SAMPLES, seed: int = 0,
                       echo: Callable[[str], None] | None = None, scan_reference: bool = False,
                       reference_edge: float | None = None) -> tuple[list[RoomRow], list[Reference]]:
    """The accuracy ladders on every room within ``budget`` wall seconds in all (module docstring).

    Args:
        rooms: (name, scene, :class:`~datagen.simulation.SimulationConfig`) per room.
        budget: wall seconds for everything (references included), > 0.
        estimators: names of :data:`datagen.analysis.accuracy.LADDERS` (default all).
        rel_tol: target of each reference's error estimate; cache_dir: the references' cache.
        reference_share: most of a room's share of the budget its reference may take, in (0, 1].
        echo: called with a line per reference and per finished step.
        scan_reference: False, the Monte Carlo reference; True, a scan's: the quadrature's ladder against the
            quadrature at ``reference_edge``, default a quarter of the config's edge
            (:mod:`datagen.analysis.scan_accuracy`; ``estimators`` is then that ladder alone).
    Returns:
        (rows of every room, in run order; the references used).
    Raises:
        ConfigError: no rooms, budget ≤ 0, reference_share outside (0, 1], unknown estimators.
    """
    if not rooms:
        raise ConfigError("no rooms to benchmark (give --samples >= 1)")
    if not budget > 0:
        raise ConfigError(f"budget must be > 0 seconds, got {budget!r}")
    if not 0 < reference_share <= 1:
        raise ConfigError(f"reference_share must be in (0, 1], got {reference_share!r}")
    end = time.perf_counter() + budget
    rows: list[RoomRow] = []
    references: list[Reference] = []
    for k, (name, scene, config) in enumerate(rooms):
        share = (end - time.perf_counter()) / (len(rooms) - k)
        if share <= 0:
            if echo is not None:
                echo(f"{name}: skipped (budget spent)")
            continue
        t0 = time.perf_counter()
        table, caster = None, None
        if scan_reference:
            caster = RayCaster(scene)                   # one BVH for the reference and the ladder
            ref, table = scan_benchmark(scene, config, reference_edge, caster)
            if echo is not None:
                echo(f"{name}: reference quadrature h = {ref.settings['edge']:.3g} m ({ref.seconds:.1f} s), error "
                     f"estimate {ref.error_estimate['rel_l2']:.2e}")
        else:
            ref = converged_reference(scene, config, rel_tol=rel_tol, cache_dir=cache_dir,
                                      samples=reference_samples, max_seconds=reference_share * share, min_replicas=2)
            if echo is not None:
                status = "converged" if ref.converged else f"NOT converged to {rel_tol:g}"
                echo(f"{name}: reference {ref.replicas} replicas, error estimate {ref.error_estimate['rel_l2']:.2e} "
                     f"({status})")
        if table is None and ref.replicas < 2:        # a Monte Carlo reference without its own error
            continue
        references.append(ref)
        left = min(share - (time.perf_counter() - t0), end - time.perf_counter())
        if left <= 0:
            continue
        for row in run_accuracy(scene, ref, config, budget=left, seed=seed, echo=echo, caster=caster,
                                ladder_table=table, estimators=(SCAN_LADDER,) if table else estimators):
            rows.append(RoomRow(name, ref.error_estimate["rel_l2"], row))
    return rows, references


def summarize(rows: list[RoomRow]) -> list[SettingSummary]:
    """Per (estimator, setting), in ladder order: rooms, median and p95 of wall seconds and rel L2 error."""
    groups: dict[tuple[str, str], list[AccuracyRow]] = {}
    for r in rows:
        groups.setdefault((r.row.estimator, r.row.setting), []).append(r.row)
    order = {name: i for i, name in enumerate(LADDERS)}
    out = []
    for (estimator, setting), group in groups.items():
        t = np.array([g.seconds for g in group])
        e = np.array([g.rel_l2 for g in group])
        out.append(SettingSummary(estimator, setting, len(group), float(np.median(t)), float(np.percentile(t, 95)),
                                  float(np.median(e)), float(np.percentile(e, 95)), float(e.max())))
    seen = {key: i for i, key in enumerate(groups)}       # run order: a ladder's steps as they ran

    def step(s: SettingSummary) -> int:
        ladder = LADDERS.get(s.estimator)
        names = [ladder.describe(st) for st in ladder.ladder] if ladder is not None else []
        return names.index(s.setting) if s.setting in names else len(names) + seen[(s.estimator, s.setting)]

    return sorted(out, key=lambda s: (order.get(s.estimator, len(order)), step(s), s.seconds_median))


def write_rooms_csv(rows: list[RoomRow], summary: list[SettingSummary], path: str | Path) -> Path:
    """CSV with one line per (room, step) (kind "room") and one per setting (kind "summary": median and p95)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kind", "room", "estimator", "setting", "rooms", "seconds", "seconds_p95", "rel_l2", "rel_l2_p95",
                    "rel_l2_max", "total", "peak_time", "reference_error"])
        for r in rows:
            w.writerow(["room", r.room, r.row.estimator, r.row.setting, 1, f"{r.row.seconds:.6g}", "",
                        f"{r.row.rel_l2:.6g}", "", "", f"{r.row.total:.6g}", f"{r.row.peak_time:.6g}",
                        f"{r.reference_error:.6g}"])
        for s in summary:
            w.writerow(["summary", "", s.estimator, s.setting, s.rooms, f"{s.seconds_median:.6g}",
                        f"{s.seconds_p95:.6g}", f"{s.rel_l2_median:.6g}", f"{s.rel_l2_p95:.6g}",
                        f"{s.rel_l2_max:.6g}", "", "", ""])
    return path


def plot_rooms(summary: list[SettingSummary], path: str | Path, title: str = "") -> Path:
    """Log-log PNG: median rel L2 error against median wall time per setting, one curve per estimator, the
    p95 error over the rooms as the top of each error bar, the 1 % line dotted."""
    fig, ax = loglog_axes()
    for name in dict.fromkeys(s.estimator for s in summary):
        sel = [s for s in summary if s.estimator == name]
        t = np.array([s.seconds_median for s in sel])
        med = np.maximum([s.rel_l2_median for s in sel], 1e-12)
        p95 = np.maximum([s.rel_l2_p95 for s in sel], med)
        ax.errorbar(t, med, yerr=[np.zeros_like(med), p95 - med], fmt="o-", ms=4, capsize=2,
                    label=LADDERS[name].label if name in LADDERS else name)
    ax.axhline(0.01, color="gray", ls=":", label="1 %")
    return save_loglog(fig, ax, path, "wall time per room (s, median)",
                       "relative L2 error of L(t): median, bar to p95", title or "accuracy vs time over rooms")


def format_rooms_table(summary: list[SettingSummary]) -> str:
    """Markdown table: estimator, setting, rooms, wall time (median, p95), rel L2 error (median, p95)."""
    lines = ["| estimator | setting | rooms | time median (s) | time p95 (s) | rel L2 median | rel L2 p95 |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for s in summary:
        lines.append(f"| {s.estimator} | {s.setting} | {s.rooms} | {s.seconds_median:.3f} | {s.seconds_p95:.3f} | "
                     f"{s.rel_l2_median:.2e} | {s.rel_l2_p95:.2e} |")
    return "\n".join(lines)
