"""Baseline for the single-pixel datasets: a small 1-D CNN reads one SPAD histogram per sample and regresses
scene targets; every target is scored against its trivial baseline (the training mean, or the majority class).

    python -m examples.train_single_pixel data/default                        # what the default set teaches
    python -m examples.train_single_pixel data/objects --input subtracted     # objects, empty room subtracted
    python -m examples.train_single_pixel data/default --targets fov_distance --epochs 10 --seed 1

Reads the ``train`` and ``val`` splits (``--train``/``--val`` to change) with :class:`datagen.NLOSDataset` (its
transform receives each sample's params, from which the targets are computed), keeps them in memory and
trains on the CPU. Training counts are fresh SPAD noise every step, drawn in the batch with
:class:`datagen.SPADNoise` from the stored envelope and the split's detector; validation uses the stored
(frozen) counts. Inputs (``--input``):

* ``counts``: log(1 + counts), what a single-pixel SPAD measures;
* ``subtracted``: that and the residual against the empty room, (counts − E_ref)/sqrt(E_ref + 1), with E_ref
  the expected counts of the stored ``reference`` envelope (datasets built with ``store.reference``);
* ``envelope``: the noise-free expected counts (an upper bound: no measurement gives it);
* ``objects``: the hidden objects' own components, noise-free (``store.components``; an oracle showing what
  the objects' light carries once separated from the room's).

Targets (``--targets``, comma separated; ``all`` by default): see :data:`TARGETS`. Prints one row per target:
validation RMSE (or accuracy) of the network, of the trivial baseline, and the ratio.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

import datagen

INPUTS = ("counts", "subtracted", "envelope", "objects")


def _nearest_object(params: dict) -> dict | None:
    """The hidden object whose centre is nearest the FoV centre (None in an empty room)."""
    fov = np.asarray(params["room"]["sensor"]["fov"]["center"])
    objects = params["objects"]
    if not objects:
        return None
    return min(objects, key=lambda o: float(np.linalg.norm(np.asarray(o["center"]) - fov)))


def _onset_ns(envelope: np.ndarray, edges: np.ndarray, level: float = 0.1) -> float:
    """Time (ns) of the first bin where the noise-free envelope reaches ``level`` × its maximum."""
    first = int(np.argmax(envelope >= level * envelope.max()))
    return float(0.5 * (edges[first] + edges[first + 1]) * 1e9)


@dataclass(frozen=True)
class Target:
    unit: str
    kind: str                     # "regression" or "class"
    value: Callable[[dict, dict, np.ndarray], float]   # (arrays, params, time_edges) → value, NaN when undefined


def _room(name: str) -> Callable[[dict, dict, np.ndarray], float]:
    return lambda arrays, params, edges: float(params["room"]["room"][name])


def _nearest(axis: int | None) -> Callable[[dict, dict, np.ndarray], float]:
    def value(arrays, params, edges):
        obj = _nearest_object(params)
        if obj is None:
            return math.nan
        if axis is not None:
            return float(obj["center"][axis])
        return float(np.linalg.norm(np.asarray(obj["center"]) - params["room"]["sensor"]["fov"]["center"]))
    return value


TARGETS: dict[str, Target] = {
    "fov_distance": Target("m", "regression", lambda a, p, e: float(np.linalg.norm(
        np.asarray(p["room"]["sensor"]["position"]) - p["room"]["sensor"]["fov"]["center"]))),
    "first_return": Target("ns", "regression", lambda a, p, e: _onset_ns(a["envelope"].reshape(-1, len(e) - 1)
                                                                          .sum(0), e)),
    "corridor_width": Target("m", "regression", _room("corridor_width")),
    "corridor_length": Target("m", "regression", _room("corridor_length")),
    "room_length": Target("m", "regression", _room("room_length")),
    "room_depth": Target("m", "regression", _room("room_depth")),
    "ceiling": Target("m", "regression", _room("ceiling")),
    "bend_side": Target("", "class", lambda a, p, e: float(p["room"]["room"]["bend_side"] > 0)),
    "object_count": Target("", "class", lambda a, p, e: float(len(p["objects"]))),
    "nearest_object": Target("m", "regression", _nearest(None)),
    "nearest_object_x": Target("m", "regression", _nearest(0)),
    "nearest_object_y": Target("m", "regression", _nearest(1)),
}
"""Scene targets from each sample's params: ``fov_distance`` sensor → FoV centre; ``first_return`` onset of the
hidden-scene return (10 % of the noise-free peak); room dimensions (docs/rooms.md); ``bend_side`` (+y);
``object_count``; ``nearest_object`` distance from the FoV centre to the nearest hidden object's centre, and
that object's x, y (undefined, so left out of loss and score, in rooms without objects)."""


def load_split(path, split: str, targets: list[str], inp: str, limit: int | None = None) -> dict[str, torch.Tensor]:
    """In-memory arrays of the first ``limit`` (default all) samples of one split: envelope, counts, optional
    reference/objects, targets (N, len(targets))."""
    fields = ["envelope", "counts"] + (["reference"] if inp == "subtracted" else []) + (
        ["components", "object_count"] if inp == "objects" else [])
    probe = datagen.NLOSDataset(path, split=split, fields=("envelope",))
    edges = probe.time_edges

    def with_targets(item, params):
        arrays = {k: v.numpy() for k, v in item.items()}
        item["targets"] = torch.tensor([TARGETS[t].value(arrays, params, edges) for t in targets],
                                       dtype=torch.float64)
        return item

    ds = datagen.NLOSDataset(path, split=split, fields=fields, transform=with_targets)
    items = [ds[i] for i in range(min(len(ds), limit or len(ds)))]
    out = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    out["envelope"] = out["envelope"].reshape(len(items), -1, out["envelope"].shape[-1]).sum(1)   # pixels summed
    out["counts"] = out["counts"].reshape(len(items), -1, out["counts"].shape[-1]).sum(1).double()
    if "reference" in out:
        out["reference"] = out["reference"].reshape(len(items), -1, out["reference"].shape[-1]).sum(1)
    if "components" in out:       # slots room, object_0 … object_{K-1}, secondary, first_bounce
        k = ds.card["config"]["labels"].get("max_objects", 8)
        comp = out.pop("components")
        out["objects"] = comp[:, 1:1 + k].reshape(len(items), k, -1, comp.shape[-1]).sum(dim=(1, 2))
    return out


class Net(torch.nn.Module):
    """1-D CNN: five stride-2 convolutions (channels 16→64), then two linear layers; ≈ 0.3 M parameters at
    1536 bins. Input (B, C, T) standardised features, output (B, targets)."""

    def __init__(self, channels: int, bins: int, outputs: int):
        super().__init__()
        layers, c = [], channels
        for width in (16, 32, 32, 64, 64):
            layers += [torch.nn.Conv1d(c, width, 5, stride=2, padding=2), torch.nn.GELU()]
            c = width
        self.features = torch.nn.Sequential(*layers)
        length = bins
        for _ in range(5):
            length = (length + 1) // 2
        self.head = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(c * length, 64), torch.nn.GELU(),
                                        torch.nn.Linear(64, outputs))

    def forward(self, x):
        return self.head(self.features(x))


def features(inp: str, counts: torch.Tensor, data: dict, rows, noise, params) -> torch.Tensor:
    """(B, C, T) float32 network input for ``inp`` (unstandardised)."""
    if inp == "envelope":
        return torch.log1p(noise.expected(data["envelope"][rows])).float()[:, None]
    if inp == "objects":
        return torch.log1p(noise.expected(data["objects"][rows], params) - noise.expected(
            torch.zeros_like(data["objects"][rows]), params)).float()[:, None]
    x = torch.log1p(counts)[:, None]
    if inp == "subtracted":
        ref = noise.expected(data["reference"][rows], params)
        x = torch.cat([x, ((counts - ref) / torch.sqrt(ref + 1.0))[:, None]], dim=1)
    return x.float()


@dataclass
class Result:
    target: str
    unit: str
    kind: str
    model: float
    trivial: float
    count: int

    @property
    def ratio(self) -> float:
        return self.model / self.trivial if self.kind == "regression" else self.model - self.trivial


def train(path, targets: list[str] | None = None, inp: str = "counts", epochs: int = 30, batch: int = 64,
          seed: int = 0, train_split: str = "train", val_split: str = "val", lr: float = 2e-3,
          limit: int | None = None, log: Callable[[str], None] | None = print) -> list[Result]:
    """Train the baseline and score it; see the module doc. Returns one :class:`Result` per target."""
    targets = list(TARGETS) if targets in (None, ["all"]) else targets
    torch.manual_seed(seed)
    t0 = time.perf_counter()
    tr, va = load_split(path, train_split, targets, inp, limit), load_split(path, val_split, targets, inp)
    noise = datagen.NLOSDataset(path, split=train_split, fields=("envelope",)).spad_noise(dtype=torch.float64)
    gen = torch.Generator().manual_seed(seed)
    y_tr, y_va = tr["targets"], va["targets"]
    mean = torch.nanmean(y_tr, dim=0)
    std = torch.sqrt(torch.nanmean((y_tr - mean) ** 2, dim=0)).clamp_min(1e-9)
    fixed = noise.draw_params(1)
    n_tr = len(y_tr)

    def batch_input(data, rows, fresh: bool):
        if fresh:
            counts, params = noise.sample(data["envelope"][rows], gen)
        else:
            counts, params = data["counts"][rows], {k: v.expand(len(rows)) for k, v in fixed.items()}
        return features(inp, counts, data, rows, noise, params)

    with torch.no_grad():
        sample = batch_input(tr, torch.arange(min(n_tr, 256)), True)
        x_mean, x_std = sample.mean(dim=(0, 2), keepdim=True), sample.std(dim=(0, 2), keepdim=True) + 1e-6
    net = Net(sample.shape[1], sample.shape[2], len(targets))
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    steps = epochs * math.ceil(n_tr / batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps)
    for epoch in range(epochs):
        net.train()
        order = torch.randperm(n_tr, generator=gen)
        for start in range(0, n_tr, batch):
            rows = order[start:start + batch]
            x = (batch_input(tr, rows, True) - x_mean) / x_std
            z = ((y_tr[rows] - mean) / std).float()
            known = ~torch.isnan(z)
            loss = ((net(x) - torch.nan_to_num(z)) ** 2)[known].mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        if log and (epoch + 1) % max(1, epochs // 5) == 0:
            log(f"  epoch {epoch + 1}/{epochs}: train loss {loss.item():.3f} ({time.perf_counter() - t0:.0f} s)")
    net.eval()
    with torch.no_grad():
        rows = torch.arange(len(y_va))
        pred = torch.cat([net((batch_input(va, rows[s:s + 256], False) - x_mean) / x_std)
                          for s in range(0, len(rows), 256)]).double() * std + mean
    results = []
    for j, name in enumerate(targets):
        t = TARGETS[name]
        known = ~torch.isnan(y_va[:, j])
        truth, guess = y_va[known, j], pred[known, j]
        if t.kind == "class":
            classes = torch.unique(y_tr[~torch.isnan(y_tr[:, j]), j])
            snapped = classes[torch.argmin((guess[:, None] - classes[None]).abs(), dim=1)]
            majority = torch.mode(y_tr[~torch.isnan(y_tr[:, j]), j]).values
            results.append(Result(name, "accuracy", t.kind, (snapped == truth).double().mean().item(),
                                  (truth == majority).double().mean().item(), int(known.sum())))
        else:
            results.append(Result(name, t.unit, t.kind, torch.sqrt(((guess - truth) ** 2).mean()).item(),
                                  torch.sqrt(((mean[j] - truth) ** 2).mean()).item(), int(known.sum())))
    return results


def table(results: list[Result]) -> str:
    lines = [f"{'target':18s} {'metric':>14s} {'network':>9s} {'trivial':>9s}  {'network/trivial (RMSE) or gain':>8s}"]
    for r in results:
        metric = f"RMSE {r.unit}" if r.kind == "regression" else "accuracy"
        ratio = f"{r.ratio:.2f}" if r.kind == "regression" else f"{r.ratio:+.3f}"
        lines.append(f"{r.target:18s} {metric:>14s} {r.model:9.3f} {r.trivial:9.3f}  {ratio:>8s}   (n={r.count})")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", help="dataset directory (datagen build ... --out DATA)")
    parser.add_argument("--input", choices=INPUTS, default="counts")
    parser.add_argument("--targets", default="all", help=f"comma-separated, from: {', '.join(TARGETS)}")
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--train", default="train")
    parser.add_argument("--val", default="val")
    parser.add_argument("--limit", type=int, help="use only the first LIMIT training samples")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    targets = args.targets.split(",")
    unknown = [t for t in targets if t not in TARGETS and t != "all"]
    if unknown:
        parser.error(f"unknown targets {unknown}; known: {', '.join(TARGETS)}")
    results = train(args.data, targets, args.input, args.epochs, args.batch, args.seed, args.train, args.val,
                    limit=args.limit)
    print(table(results))
    if args.json:
        with open(args.json, "w") as f:
            json.dump([r.__dict__ for r in results], f, indent=1)


if __name__ == "__main__":
    main()
