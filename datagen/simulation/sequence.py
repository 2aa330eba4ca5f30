"""Capture sequences of scenes whose objects move: one envelope and one SPAD histogram per frame (docs/motion.md).

:func:`simulate_sequence` simulates the frames of ``scene.capture.frames`` (:class:`~datagen.scene.motion.FrameSpec`)
for a scene with moving objects (:meth:`~datagen.scene.Scene.with_motion`). Each frame is the scene at the middle of
the frame's exposure; a scanned capture visits its points one after another during the exposure, so its points are
simulated in ``slots`` groups of consecutive points, each group at its middle time (motion during the scan).

Two methods give the same frames in expectation:

- ``"frames"``: every frame (and slot) simulated in full with :func:`~datagen.simulation.simulate` and the config's
  seed: the random numbers are shared across frames (common random numbers), so light that does not change from
  frame to frame carries the same error in every frame and a difference of two frames is nearly free of it.
- ``"changes"`` (default): the sequence costs what changes. The first frame's scene (the reference) is simulated
  once at the config's sampling; every frame adds only the *change* from the reference, estimated with
  ``1 / change_split`` of that sampling in one run on the frame's scene and on the reference with the same random
  streams (common random numbers: every path that meets neither the moving object nor its shadow cancels to the bit).
  Frame f = reference + change_f, unbiased but for the bins where a noisy change takes an empty bin below zero, which
  are set to zero (``attrs["clamped"]``: the largest such negative sum of a frame, over the frame's L2 norm). Its
  stated error is the reference's error and the change's, added in quadrature. The change's is read from a second,
  independent run of the same size on every :data:`SPREAD_EVERY`-th frame and the frame after it (and on the
  reference): the spread of the two, pooled over those frames (docs/motion.md, "The two methods, and what a frame's
  error is").

Every frame of ``"frames"`` and every change of ``"changes"`` run with ``common_random_numbers``
(:class:`~datagen.simulation.SimulationConfig`): every path draws from a slot of its own, so that paths line up from
frame to frame. The reference of ``"changes"`` runs with the config as given: it meets no other frame's paths (the
changes subtract their own run of the reference), so it is the first frame simulated on its own, to the bit, and
costs no more. Random streams, children of a root (``SeedSequence(seed)``, or a dataset sample's): the reference and
the ``"frames"`` method take (``STREAM_SAMPLING``,), as :func:`~datagen.simulation.simulate` does; every frame's
change is replica 0 of a run on (``STREAM_CHANGES``,), its second run replica 1; frame f's detector noise takes
(``STREAM_NOISE``, f): independent in every frame, as a real detector's is.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from ..scene import RayCaster, Scene, resolve_capture
from ..scene.motion import object_anchor, posed_vertices, velocity_at
from ..transport import estimator
from .config import STREAM_NOISE, STREAM_SAMPLING, SimulationConfig, resolve_config
from .detection import detector_counts
from .run import Planned, Replicas, simulate_runs

STREAM_CHANGES = 3
"""Spawn-key entry of the change's random stream under the sequence's root (the sampling stream is 0, the noise 1)."""

CONFIDENCE_Z = 1.96
"""Two-sided 95 % normal quantile: the change's stated error is a 95 % bound, as the reference's is."""

DEFAULT_CHANGE_SPLIT = 128
"""The change of a frame is estimated with 1/128 of the reference's sampling (in one run): in the demo room a
frame's stated error then stays a few per cent above a single frame's (docs/motion.md gives the measured cost and
errors, ``python benchmarks/sequence_cost.py``)."""

SPREAD_EVERY = 10
"""Every 10th frame (1, 11, 21, …) and the frame after it run the change a second time (replica 1): a fifth of the
frames, whose two runs' spread is the change's error (pooled over them) and, the pairs being consecutive, a step's.
Each such frame costs a second run; fewer would leave the pooled spread to a handful of frames."""


@dataclass
class SequenceResult:
    """Output of :func:`simulate_sequence`.

    Attributes:
        time_edges: (T+1,) float64 s.
        frame_times: (F,) float64 s: each frame's start.
        envelopes: (F, *channel_shape, T) float64 expected detected photons per pulse per bin of each frame.
        counts: (F, *channel_shape, T) int64 SPAD histogram of each frame over its exposure.
        error: (F,) float64 stated relative L2 error of each frame's envelope (95 % bound; docs/motion.md): the
            reference's stated error (light left out included) and the change's, in quadrature.
        monte_carlo_error: (F,) float64: the same without the parts every frame shares with the reference (the
            orders left out, the smoothing): the noise of each frame's estimate.
        difference_error: stated relative L2 error of a difference of two frames, relative to the frame (95 %).
        positions, velocities: (F, M, 3) float64 m and m/s of the M moving objects' anchors at each frame's middle.
        boxes: (F, M, 2, 3) float64 m: their axis-aligned bounding boxes (min, max corners) then.
        moving: the M moving objects' names.
        attrs: JSON-able metadata (method, change_split, slots, seconds, the reference's error and attrs).
    """

    time_edges: np.ndarray
    frame_times: np.ndarray
    envelopes: np.ndarray
    counts: np.ndarray
    error: np.ndarray
    monte_carlo_error: np.ndarray
    difference_error: float
    positions: np.ndarray
    velocities: np.ndarray
    boxes: np.ndarray
    moving: list[str]
    attrs: dict = field(default_factory=dict)


def change_config(config: SimulationConfig, split: int, tracer_paths: int | None = None) -> SimulationConfig:
    """``config`` with ``1/split`` of its sampling in one replica, a frame's change: the estimator's own split (its
    registry entry's ``replica`` hook, the rule its replicas use) and ``tracer_paths`` / ``split`` light paths per
    laser point of the order ≥ 3 tracer (``tracer_paths``: what the reference traced in all its replicas). Its
    ``error.replicas`` is 1, below what a user's config may ask (2): the config is the change's own, and its second
    replica, run on some frames only, gives the spread (:func:`simulate_sequence`).

    Raises:
        SceneError: a deterministic estimator (one refined, not only replicated: the quadrature): at a coarser
            setting its change would carry another bias than the reference.
    """
    entry = estimator(config.estimator.kind)
    if entry.replica is None or entry.refine is not None:
        raise SceneError(f"method 'changes' needs a Monte Carlo estimator; {config.estimator.kind!r} is "
                         "deterministic: use method 'frames' (docs/motion.md)")
    small = config.with_estimator(**entry.replica(config.estimator, split))
    update = {"error": small.error.model_copy(update={"replicas": 1})}
    if tracer_paths is not None:
        paths = max(1, -(-tracer_paths // split))
        update["multibounce"] = small.multibounce.model_copy(update={"paths": paths})
    return small.model_copy(update=update)


def _change_run(scene: Scene, config: SimulationConfig, root: np.random.SeedSequence, plan, second: bool
                ) -> tuple[np.ndarray, np.ndarray | None]:
    """The binned envelopes ((n_channels, n_bins) each) of replicas 0 and, when ``second``, 1 of ``scene`` at the
    change's ``config`` (stream: ``root``'s child (STREAM_CHANGES,); None for replica 1 when not ``second``), each
    with one replica of the tracer when it is planned, under the reference's effect ``plan`` (every frame's change is
    made under the same decisions, so that the streams line up)."""
    if not config.split_components:
        scene = scene.with_summed_primary()
    caster = RayCaster(scene)
    runs = Replicas(scene, config, _rng(root, STREAM_CHANGES),                  # (the reference's memory checked)
                    Planned(scene, caster, resolve_capture(scene, caster), plan), memory_checked=True)
    runs.run(1, tracer_target=1, min_tracer=1)
    first = _replica_total(runs)
    if not second:
        return first, None
    runs.run(1, tracer_target=2, min_tracer=1)
    return first, _replica_total(runs) - first


def _replica_total(runs: Replicas) -> np.ndarray:
    """(n_channels, n_bins) the sum over the replicas run so far of their envelopes (components summed), orders
    1–2 and the tracer's: read from their sums (each replica's envelope binned once, as it was added), not from the
    total, which would bin every component again."""
    parts = [runs.sums] + ([runs.tracer_sums] if runs.tracer is not None else [])
    return sum(p.mean() * p.count for p in parts)


def _spread_frames(n_frames: int) -> np.ndarray:
    """(F,) bool: the frames whose change runs twice: frame 0 (the reference's, whose change is zero) and, for
    :data:`SPREAD_EVERY` = k, frames 1 + j·k and 2 + j·k (pairs of consecutive frames, for the steps' spread)."""
    f = np.arange(n_frames)
    return (f == 0) | ((f - 1) % SPREAD_EVERY < 2)


def _rng(root: np.random.SeedSequence, *key: int) -> np.random.Generator:
    """The generator of ``root``'s child ``key``: SeedSequence(root's entropy, spawn_key=root's key + ``key``)."""
    return np.random.default_rng(np.random.SeedSequence(root.entropy, spawn_key=tuple(root.spawn_key) + key))


def _slot_times(scene: Scene, config: SimulationConfig, slots: int | None):
    """(F, S) slot times s, and (S, P) bool: which of the P scan points each slot holds (P = 1 unscanned)."""
    frames = scene.capture.frames
    spec = scene.capture
    if spec.type == "single":
        return (frames.times() + frames.exposure / 2)[:, None], np.ones((1, 1), dtype=bool)
    grid = spec.laser_grid.points
    shape = (grid[1], grid[0])                       # (ny, nx): rows of nx points
    n = shape[0] * shape[1]
    point_t = frames.point_times(n, shape)           # (F, P)
    rank = np.argsort(np.argsort(point_t[0]))        # visit rank of each point
    slots = n if slots is None else max(1, min(int(slots), n))
    slot_of = rank * slots // n
    holds = slot_of[None, :] == np.arange(slots)[:, None]
    times = np.stack([point_t[:, h].mean(axis=1) for h in holds], axis=1)
    return times, holds


def _frame_from_slots(slot_envelopes: list[np.ndarray], holds: np.ndarray) -> np.ndarray:
    """One frame's envelope: each scan point's channels from the simulation at its slot's time."""
    if len(slot_envelopes) == 1:
        return slot_envelopes[0]
    out = np.empty_like(slot_envelopes[0])
    flat_out = out.reshape((holds.shape[1], -1))
    for env, h in zip(slot_envelopes, holds):
        flat_out[h] = env.reshape((holds.shape[1], -1))[h]
    return out


def _labels(scene: Scene, times: np.ndarray):
    names = list(scene.moving)
    pos = np.zeros((len(times), len(names), 3))
    vel = np.zeros_like(pos)
    box = np.zeros((len(times), len(names), 2, 3))
    for j, name in enumerate(names):
        m = scene.moving[name]
        pos[:, j] = m.motion.pose(times, object_anchor(m.vertices))[0]
        vel[:, j] = velocity_at(m.motion, m.vertices, times)
        posed = posed_vertices(m.motion, m.vertices, times)
        box[:, j, 0], box[:, j, 1] = posed.min(axis=1), posed.max(axis=1)
    return names, pos, vel, box


def simulate_sequence(scene: Scene, config: SimulationConfig | None = None, method: str = "changes",
                      change_split: int = DEFAULT_CHANGE_SPLIT, slots: int | None = None,
                      streams: np.random.SeedSequence | None = None) -> SequenceResult:
    """Simulate every frame of ``scene.capture.frames`` (module docstring: the two methods and their errors).

    Args:
        scene: a scene with a ``frames`` block in its capture (moving objects optional: without them every frame
            is the same scene).
        config: as for :func:`~datagen.simulation.simulate`; the detector's exposure is replaced by the frame's
            (per scan point: the frame's exposure over the points).
        method: "changes" (default) or "frames".
        change_split: the change's sampling is 1/``change_split`` of the config's ("changes").
        slots: groups of consecutive scan points simulated at one time (scanned captures; default: one per point).
        streams: the root of the sequence's random streams (default ``SeedSequence(config.seed)``: the reference
            then draws what :func:`~datagen.simulation.simulate` draws); dataset builds pass the sample's.
    Returns:
        :class:`SequenceResult`.
    Raises:
        SceneError: no ``frames`` block, an unknown method, or "changes" with a deterministic estimator.
    """
    if scene.capture is None or scene.capture.frames is None:
        raise SceneError(f"{scene.source or scene.name}: capture.frames is missing: a sequence needs frames "
                         "(count, rate, exposure; docs/motion.md)")
    if method not in ("changes", "frames"):
        raise SceneError(f"sequence method {method!r}: expected 'changes' or 'frames'")
    alone = config or resolve_config(scene)                                 # the reference's ("changes")
    config = alone.model_copy(update={"error": alone.error.model_copy(       # paths line up from frame to frame
        update={"common_random_numbers": True})})
    t0 = time.perf_counter()
    frames = scene.capture.frames
    times, holds = _slot_times(scene, config, slots)
    n_frames, n_slots = times.shape
    root = streams if streams is not None else np.random.SeedSequence(config.seed)
    ref = scene.at(times[0, 0])
    first, runs = simulate_runs(ref, config if method == "frames" else alone,
                                sampling_rng=_rng(root, STREAM_SAMPLING))
    ref_error = float(first.attrs["error"]["rel_l2"])
    ref_noise = float(first.attrs["error"].get("monte_carlo") or 0.0)
    envelopes = np.empty((n_frames,) + first.envelope.shape)
    var, step_var, negative = np.zeros(n_frames), np.zeros(n_frames), np.zeros(n_frames)
    if method == "frames":
        for f in range(n_frames):
            envelopes[f] = _frame_from_slots([first.envelope if (f, s) == (0, 0) else
                                              simulate_runs(scene.at(times[f, s]), config,
                                                            sampling_rng=_rng(root, STREAM_SAMPLING))[0].envelope
                                              for s in range(n_slots)], holds)
    else:
        small = change_config(config, change_split, runs.tracer_paths_run() if runs.tracer is not None else None)
        shape = first.envelope.shape
        spread = _spread_frames(n_frames)
        base = [b.reshape(shape) for b in _change_run(ref, small, root, runs.plan, True)]
        reference = first.envelope
        prev = None
        for f in range(n_frames):
            parts = []
            for s in range(n_slots):
                if (f, s) == (0, 0):
                    parts.append((np.zeros_like(reference), np.zeros_like(reference)))
                    continue
                runs_f = _change_run(scene.at(times[f, s]), small, root, runs.plan, bool(spread[f]))
                parts.append(tuple(None if run is None else run.reshape(shape) - base[r]
                                   for r, run in enumerate(runs_f)))
            d0 = _frame_from_slots([p[0] for p in parts], holds)
            envelopes[f] = reference + d0
            negative[f] = -float(envelopes[f][envelopes[f] < 0].sum())
            np.maximum(envelopes[f], 0.0, out=envelopes[f])     # a noisy change below an empty bin: no light
            d1 = _frame_from_slots([p[1] for p in parts], holds) if spread[f] else None
            if d1 is not None:
                var[f] = float(np.sum((d0 - d1) ** 2)) / 2.0   # the variance of one run, summed over bins
                if prev is not None:                           # that of the step from the frame before
                    step_var[f] = float(np.sum(((d0 - prev[0]) - (d1 - prev[1])) ** 2)) / 2.0
            prev = (d0, d1) if d1 is not None else None
    norms = np.linalg.norm(envelopes.reshape(n_frames, -1), axis=1)
    steps = np.linalg.norm(np.diff(envelopes, axis=0).reshape(n_frames - 1, envelopes[0].size), axis=1) / norms[:-1]
    changes = method == "changes" and n_frames > 1          # "frames": every frame carries the reference's error
    pooled = math.sqrt(var[1:][spread[1:]].mean()) if changes else 0.0
    change_error = CONFIDENCE_Z * pooled / np.maximum(norms, np.finfo(float).tiny)
    change_error[0] = 0.0                                   # frame 0 is the reference
    error, noise = np.hypot(ref_error, change_error), np.hypot(ref_noise, change_error)
    stepped = spread[1:] & spread[:-1] if changes else None     # steps between two frames run twice
    difference_error = (float(CONFIDENCE_Z * math.sqrt(step_var[1:][stepped].mean()) / norms.mean()) if changes
                        else float("nan"))
    detector = dict(config.detector)
    detector["exposure"] = frames.exposure / holds.shape[1]
    frame_config = config.model_copy(update={"detector": detector})
    counts = np.empty(envelopes.shape, dtype=np.int64)
    for f in range(n_frames):
        frame_noise = _rng(root, STREAM_NOISE, f)
        counts[f] = detector_counts(envelopes[f], frame_config, first.attrs["plan"], frame_noise)[0]
    names, pos, vel, box = _labels(scene, frames.times() + frames.exposure / 2)
    attrs = {"method": method, "change_split": change_split if method == "changes" else None, "slots": n_slots,
             "frames": frames.model_dump(mode="json"), "seconds": time.perf_counter() - t0,
             "reference_error": ref_error, "mean_step": float(steps.mean()) if steps.size else 0.0,
             "clamped": float(negative.max() / max(float(norms.max()), np.finfo(float).tiny)),
             "reference": first.attrs}
    return SequenceResult(first.time_edges, frames.times(), envelopes, counts, error, noise, difference_error, pos,
                          vel, box, names, attrs)
