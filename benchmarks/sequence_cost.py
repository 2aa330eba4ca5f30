"""What a capture sequence costs: the 'changes' method against 100 frames simulated one by one, and how close its
frames and their steps come to frames simulated on their own (docs/motion.md, "What a sequence costs").

    python benchmarks/sequence_cost.py [--frames 100] [--only demo rooms] [--split 128] [--no-old]

Two scenes, each with a person-sized walker: ``scene_library/demo_room_walker.yaml`` (the demo room, the lookin
estimator at its 10 × 10 lookins and 60 × 60 pixels, every order) and room 0 of ``configs/rooms/default.yaml`` with
one walker drawn (``motion.walkers: 1``) at ``configs/datasets/default.yaml``'s sampling (the area sampler, its 16384
hidden samples split into :data:`ROOM_REPLICAS` replicas, every order). For each:

0. **Warm-up** (untimed): one frame and a 2-frame sequence, so that neither figure below carries the process's
   one-off costs (numba's compiled kernels loaded from its cache, or compiled; first imports).
1. **One frame**: the scene at the first frame's instant, simulated alone (the unit of cost): the median of
   :data:`UNIT_RUNS` runs, since a single frame's time moves with the machine's load more than a sequence's does.
2. **New**: :func:`datagen.simulation.sequence.simulate_sequence` with ``method="changes"``.
3. **Old**: the same frames each simulated in full (``method="frames"``: 100 independent frames, the cost of a
   sequence made frame by frame).
4. **Frames against frames simulated on their own**: frames 0, F/2 and F−1 of the new method against the same
   instants simulated with :func:`datagen.simulate` under another seed (independent noise); the gap, relative L2 over
   the whole window, is printed beside the bound it should stay within (the two stated Monte Carlo errors in
   quadrature).
5. **A step**: frame F/2 + 1 minus frame F/2 of the new method against the same step of the old method (at full
   sampling and common random numbers: its own error is the smaller), relative to the frame, beside the new
   method's stated step error.

Wall times are one run each, on this machine, one process; the ratios are what the docs quote.
"""
from __future__ import annotations

import argparse
import copy
import math
import time

import numpy as np

import datagen
from datagen.dataset.config import load_dataset_config
from datagen.dataset.rooms import load_room_distribution
from datagen.dataset.sampler import sample_room
from datagen.scene.motion import FrameSpec
from datagen.simulation.sequence import DEFAULT_CHANGE_SPLIT, simulate_sequence

WALKER_FRAMES = {"count": 100, "rate": "10Hz", "exposure": "50ms"}

UNIT_RUNS = 3
"""Runs of one frame whose median is the unit of cost."""

ROOM_REPLICAS = 24
"""Replicas the room's frame splits configs/datasets/default.yaml's 16384 hidden samples into (683 each; a stated
error of 1.5 %): a sequence runs a fixed config. (The dataset's tolerance loop instead adds replicas of 8192 until
1 %: four on this room, 0.85 %, in about the same time.)"""


def _norm(a: np.ndarray) -> float:
    return float(np.sqrt(np.sum(a * a)))


def demo_scene(frames: int):
    scene = datagen.load_scene("scene_library/demo_room_walker.yaml")
    scene.capture = scene.capture.model_copy(update={"frames": scene.capture.frames.model_copy(
        update={"count": frames})})
    return "demo room + walker", scene, datagen.resolve_config(scene)


def room_scene(frames: int):
    dist = load_room_distribution("configs/rooms/default.yaml").with_overrides(
        {"motion": {"walkers": 1, "frames": {**WALKER_FRAMES, "count": frames}}})
    rngs = {k: np.random.default_rng([0, i]) for i, k in enumerate(("geometry", "materials", "sensor", "motion"))}
    scene = sample_room(dist, rngs).scene
    overrides = load_dataset_config("configs/datasets/default.yaml").simulation_overrides()
    config = datagen.resolve_config(scene, overrides)
    return "default.yaml room 0 + walker", scene, config.model_copy(update={"error": config.error.model_copy(
        update={"replicas": ROOM_REPLICAS})})


def _first_frames(scene, count: int):
    """``scene`` with only the first ``count`` frames of its capture."""
    frames = scene.capture.frames.model_copy(update={"count": count})
    out = copy.copy(scene)
    out.capture = scene.capture.model_copy(update={"frames": frames})
    return out


def measure(name: str, scene, config, split: int, old: bool) -> None:
    frames: FrameSpec = scene.capture.frames
    mids = frames.times() + frames.exposure / 2
    n = len(mids)
    datagen.simulate(scene.at(mids[0]), config)                          # warm-up, untimed
    simulate_sequence(_first_frames(scene, 2), config, "changes", split)
    ones = []
    for _ in range(UNIT_RUNS):
        t0 = time.perf_counter()
        datagen.simulate(scene.at(mids[0]), config)
        ones.append(time.perf_counter() - t0)
    one = float(np.median(ones))
    t0 = time.perf_counter()
    new = simulate_sequence(scene, config, "changes", split)
    t_new = time.perf_counter() - t0
    print(f"\n{name}: {n} frames, {config.estimator.kind} {config.estimator.model_dump(exclude={'kind'})}")
    print(f"  one frame {one:.2f} s (median of {', '.join(f'{t:.2f}' for t in ones)}); changes (split {split}) "
          f"{t_new:.1f} s = {t_new / one:.2f} frames ({t_new / one / n:.3f} of a frame per frame)")
    print(f"  stated error per frame: {new.error.min():.2%}..{new.error.max():.2%} (one frame alone: "
          f"{new.attrs['reference_error']:.2%}); Monte Carlo part {new.monte_carlo_error.min():.2%}.."
          f"{new.monte_carlo_error.max():.2%}")
    independent = config.model_copy(update={"seed": config.seed + 1})
    for f in (0, n // 2, n - 1):
        alone = datagen.simulate(scene.at(mids[f]), independent)
        gap = _norm(new.envelopes[f] - alone.envelope) / _norm(alone.envelope)
        bound = math.hypot(new.monte_carlo_error[f], alone.attrs["error"]["monte_carlo"])
        print(f"  frame {f:3d}: gap to a frame simulated alone {gap:.2%}, bound {bound:.2%} "
              f"({'within' if gap <= bound else 'OUTSIDE'})")
    if not old:
        return
    t0 = time.perf_counter()
    full = simulate_sequence(scene, config, "frames")
    t_old = time.perf_counter() - t0
    print(f"  frames one by one {t_old:.1f} s = {t_old / one:.2f} frames; changes cost {t_new / t_old:.3f} of it "
          f"({t_old / t_new:.1f}x faster)")
    f = n // 2
    step_new, step_old = new.envelopes[f + 1] - new.envelopes[f], full.envelopes[f + 1] - full.envelopes[f]
    gap = _norm(step_new - step_old) / _norm(full.envelopes[f])
    print(f"  step {f}->{f + 1}: {_norm(step_old) / _norm(full.envelopes[f]):.3%} of a frame; changes' step off "
          f"the full frames' by {gap:.3%}, stated step error {new.difference_error:.3%}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--only", nargs="*", choices=("demo", "rooms"), default=("demo", "rooms"))
    parser.add_argument("--split", type=int, default=DEFAULT_CHANGE_SPLIT)
    parser.add_argument("--no-old", action="store_true", help="skip the frame-by-frame run (the slow part)")
    args = parser.parse_args()
    for key, make in (("demo", demo_scene), ("rooms", room_scene)):
        if key in args.only:
            measure(*make(args.frames), args.split, not args.no_old)


if __name__ == "__main__":
    main()
