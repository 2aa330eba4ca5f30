"""Tracking baseline for capture sequences: locate the walker in each frame from the frame's difference to the static
background, by backprojection onto the floor plane, as the field's first trackers did (Gariepy et al. 2016).

    python -m examples.track_backprojection data/tracking [--split test] [--input counts] [--png tracks.png]

For each sequence of the split (docs/motion.md; ``configs/datasets/tracking.yaml``): the background is the per-bin
median over the sequence's frames (the walker stands at any one place for a few frames only); a frame's difference
is the frame minus it, smoothed in time by a Gaussian of the IRF's width (one bin at least), its negative part dropped
(the walker adds light where it is), read between bin centres by linear interpolation. Every candidate point p of a
5 cm grid over the L-bend room's floor, at ``--height`` (m), collects the difference of each SPAD pixel k at the round
trip spot → p → y_k (→ sensor when that leg counts), y_k the pixel's centre on the relay wall; the frame's estimate
is the point that collects most. Scores: the distance (m, in the floor
plane) from the walker's true anchor per frame, its mean over each sequence's frames (along the track), the mean and
median over the split, beside the trivial guess (the room's centre). ``--png`` draws the first sequences' tracks,
true and estimated, over the room's plan.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import datagen
from datagen.dataset.config import DatasetConfig
from datagen.dataset.sample_scene import scene_of_sample
from datagen.dataset.sampler import room_floor
from datagen.scene import RayCaster, resolve_capture
from datagen.units import SPEED_OF_LIGHT

GRID_STEP = 0.05
"""Pitch of the floor grid searched, m."""


def floor_grid(room: dict, step: float = GRID_STEP) -> tuple[np.ndarray, np.ndarray]:
    """(xs (a,), ys (b,)) m: the L-bend room's floor (room params of a sample) on a ``step`` grid."""
    x0, x1, y0, y1 = room_floor(room)
    return np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step)


def geometry(path: Path, split: str, index: int, config: DatasetConfig):
    """(spot (3,), pixel centres (P, 3), sensor (3,), laser leg m, count the sensor leg, room params) of a sample."""
    room, _, _ = scene_of_sample(path, split, index)
    scene = room.scene
    caster = RayCaster(scene)
    capture = resolve_capture(scene, caster)
    sim = config.simulation_config(split)
    laser_leg = float(np.linalg.norm(np.subtract(scene.laser.spot, scene.laser.emitter))) if sim.count_laser_leg \
        else 0.0
    pixels = capture.sensor_points().reshape(-1, 3)
    return np.asarray(scene.laser.spot, float), pixels, np.asarray(scene.sensor.position, float), laser_leg, \
        sim.count_sensor_leg, room.params["room"]


def track(frames: np.ndarray, time_edges: np.ndarray, geo, height: float, irf_fwhm: float) -> np.ndarray:
    """(F, 2) m: the walker's estimated floor position in each of ``frames`` (F, ny, nx, T) by backprojection of the
    frames' positive differences to their per-bin median (module docstring)."""
    spot, pixels, sensor, laser_leg, sensor_leg, room = geo
    xs, ys = floor_grid(room)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    points = np.concatenate([grid, np.full((len(grid), 1), height)], axis=1)
    f, t = frames.shape[0], frames.shape[-1]
    x = frames.reshape(f, -1, t).astype(np.float64)
    diff = x - np.median(x, axis=0)
    width = time_edges[1] - time_edges[0]
    sigma = max(irf_fwhm / 2.355, width) / width                     # bins: the IRF's, or one bin at least
    offsets = np.arange(-int(4 * sigma) - 1, int(4 * sigma) + 2)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    diff = np.apply_along_axis(lambda v: np.convolve(v, kernel / kernel.sum(), mode="same"), -1, diff)
    diff = np.maximum(diff, 0.0)
    out_leg = np.linalg.norm(pixels - sensor, axis=1) if sensor_leg else np.zeros(len(pixels))
    path = (laser_leg + np.linalg.norm(points - spot, axis=1)[:, None]
            + np.linalg.norm(points[:, None] - pixels[None], axis=2) + out_leg[None])        # (G, P) m
    at = (path / SPEED_OF_LIGHT - time_edges[0]) / width - 0.5       # fractional bin, from bin centres
    lo = np.floor(at).astype(np.int64)
    frac = at - lo
    inside = (lo >= 0) & (lo + 1 < t)
    lo = np.clip(lo, 0, t - 2)
    score = np.zeros((f, len(points)))
    for k in range(len(pixels)):                                     # linear interpolation between bin centres
        value = diff[:, k, :][:, lo[:, k]] * (1 - frac[:, k]) + diff[:, k, :][:, lo[:, k] + 1] * frac[:, k]
        score += np.where(inside[:, k][None], value, 0.0)
    return grid[np.argmax(score, axis=1)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--split", default="test")
    parser.add_argument("--input", choices=("counts", "envelope"), default="counts")
    parser.add_argument("--height", type=float, default=1.0, help="height of the floor plane searched, m")
    parser.add_argument("--png", type=Path, default=None)
    parser.add_argument("--draw", type=int, default=2, help="sequences drawn in --png")
    args = parser.parse_args()
    ds = datagen.NLOSDataset(args.data, split=args.split, fields=(args.input, "track_position"))
    config = DatasetConfig.model_validate(ds.card["config"])
    irf = config.simulation_config(args.split).irf.fwhm
    errors, trivial, drawn = [], [], []
    for i in range(len(ds)):
        item = ds[i]
        geo = geometry(args.data, args.split, i, config)
        est = track(item[args.input].numpy(), ds.time_edges, geo, args.height, irf)
        true = item["track_position"].numpy()[:, 0, :2]
        err = np.linalg.norm(est - true, axis=1)
        xs, ys = floor_grid(geo[-1])
        centre = np.array([xs.mean(), ys.mean()])
        errors.append(err)
        trivial.append(np.linalg.norm(true - centre, axis=1))
        print(f"{args.split}[{i}]: position error mean {err.mean():.3f} m, median {np.median(err):.3f} m "
              f"(room centre: {trivial[-1].mean():.3f} m)")
        if len(drawn) < args.draw:
            drawn.append((i, true, est))
    err, triv = np.concatenate(errors), np.concatenate(trivial)
    print(f"{args.split}: {len(ds)} sequences, {len(err)} frames from {args.input}: position error mean "
          f"{err.mean():.3f} m, median {np.median(err):.3f} m, along the tracks (mean of the sequences' means) "
          f"{np.mean([e.mean() for e in errors]):.3f} m; room centre {triv.mean():.3f} m")
    if args.png is not None:
        draw(args.data, args.split, drawn, args.png)
        print(f"wrote {args.png}")


def draw(path: Path, split: str, drawn: list, png: Path) -> None:
    """Tracks, true (dots coloured by frame) and estimated (crosses), over each drawn sequence's room plan."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from datagen.plot.sequence import plot_plan

    fig, axes = plt.subplots(1, len(drawn), figsize=(5.5 * len(drawn), 5), squeeze=False)
    for ax, (i, true, est) in zip(axes[0], drawn):
        room, _, _ = scene_of_sample(path, split, i)
        plot_plan(ax, room.scene)
        sc = ax.scatter(true[:, 0], true[:, 1], c=np.arange(len(true)), cmap="viridis", s=14, label="true", zorder=4)
        ax.scatter(est[:, 0], est[:, 1], c=np.arange(len(est)), cmap="viridis", marker="x", s=30,
                   label="estimated", zorder=5)
        ax.set_title(f"{split}[{i}]: mean error {np.linalg.norm(est - true, axis=1).mean():.2f} m")
        ax.legend(fontsize=8, loc="best")
        fig.colorbar(sc, ax=ax, label="frame")
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
