"""Bytes per sample of the scan configs under each codec the store supports (issue 30). Plain script::

    python benchmarks/bench_storage.py --config wall --samples 2            # samples made here (make_sample; their
                                                                            # CPU seconds are printed too)
    python benchmarks/bench_storage.py --dataset data/wall128 --samples 4   # samples of a built dataset

For each sample (train 0, 1, …) it encodes, with numcodecs (the codecs zarr's ``BloscCodec`` / ``ZstdCodec`` wrap,
so the bytes are those of a stored inner chunk up to a 16-byte Blosc header), the envelope (float32), the counts
(int64 and, where they fit, uint16 / uint32: ``store.counts_dtype``) and the labels (every other numeric field the
sample stores, summed), and reports per codec the mean compressed bytes per sample and the encode / decode time
of the envelope (median ms, one thread). Codecs: Blosc lz4 and Blosc zstd with byte or bit shuffle (``store.
compression`` "lz4" / "blosc-zstd", ``store.shuffle``), plain zstd, none; level ``--level`` (the store's default 5).
A decode is checked to return the same bytes. The machine is shared: times are for comparison within one run.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from datagen.dataset import NLOSDataset, load_dataset_config, make_sample  # noqa: E402

NOT_LABELS = ("envelope", "counts", "envelope_error", "params", "photons_per_pulse", "components", "reference")


def codecs(level: int) -> dict:
    """name → numcodecs codec (None: raw bytes), in the store's vocabulary."""
    import numcodecs
    out = {}
    for cname, label in (("lz4", "lz4"), ("zstd", "blosc-zstd")):
        for shuffle, sname in ((numcodecs.Blosc.SHUFFLE, "byte"), (numcodecs.Blosc.BITSHUFFLE, "bit")):
            out[f"{label}/{sname}"] = numcodecs.Blosc(cname=cname, clevel=min(level, 9), shuffle=shuffle)
    out["zstd"] = numcodecs.Zstd(level=level)
    out["none"] = None
    return out


def samples_of(args) -> list[dict[str, np.ndarray]]:
    """Sample arrays in the stored layout (counts as stored, widened to int64 by the loader)."""
    if args.dataset:
        ds = NLOSDataset(args.dataset, split=args.split)
        fields = [f for f in ds.card["splits"][args.split]["fields"] if f != "params"]
        ds = NLOSDataset(args.dataset, split=args.split, fields=fields)
        return [ds.read(i) for i in range(min(args.samples, len(ds)))]
    config = load_dataset_config(ROOT / f"configs/datasets/{args.config}.yaml")
    make_sample(config, [s for s in config.splits if s != args.split][-1], 0)   # warm-up: numba cache load
    out, cpu = [], []
    for i in range(args.samples):
        t = time.process_time()
        arrays = make_sample(config, args.split, i).arrays
        cpu.append(time.process_time() - t)
        out.append({k: v for k, v in arrays.items() if k != "params"})
    print(f"make_sample CPU s (this process, every thread) of {args.split} 0–{args.samples - 1}: "
          + ", ".join(f"{c:.2f}" for c in cpu) + f"; mean {np.mean(cpu):.2f}")
    return out


def timed_ms(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t))
    return statistics.median(times)


def measure(samples: list[dict], level: int, reps: int) -> list[dict]:
    rows = []
    for name, codec in codecs(level).items():
        def enc(a, codec=codec):
            a = np.ascontiguousarray(a)
            return codec.encode(a) if codec is not None else a.tobytes()
        sizes = {"envelope": [], "counts int64": [], "counts uint32": [], "counts uint16": [], "labels": []}
        t_enc, t_dec = [], []
        for s in samples:
            env = np.asarray(s["envelope"], dtype=np.float32)
            raw = enc(env)
            sizes["envelope"].append(len(raw))
            if codec is not None:
                t_enc.append(timed_ms(lambda: codec.encode(env), reps))
                t_dec.append(timed_ms(lambda: codec.decode(raw), reps))
                assert np.array_equal(np.frombuffer(codec.decode(raw), np.float32).reshape(env.shape), env)
            counts = np.asarray(s["counts"])
            for dt in ("int64", "uint32", "uint16"):
                if counts.max() <= np.iinfo(dt).max:
                    sizes[f"counts {dt}"].append(len(enc(counts.astype(dt))))
            sizes["labels"].append(sum(len(enc(np.asarray(v))) for k, v in s.items()
                                       if k not in NOT_LABELS and np.asarray(v).dtype != object))
        rows.append({"codec": name, **{k: (float(np.mean(v)) if v else float("nan")) for k, v in sizes.items()},
                     "encode_ms": statistics.median(t_enc) if t_enc else 0.0,
                     "decode_ms": statistics.median(t_dec) if t_dec else 0.0})
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--config", default="wall", help="a config of configs/datasets (samples made here)")
    parser.add_argument("--dataset", default=None, help="a built dataset (its samples are read instead)")
    parser.add_argument("--split", default="train")
    parser.add_argument("--samples", type=int, default=2)
    parser.add_argument("--level", type=int, default=5)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args(argv)
    samples = samples_of(args)
    env = samples[0]["envelope"]
    print(f"{args.dataset or args.config}: {len(samples)} samples of {args.split}, envelope {env.shape} "
          f"({env.size * 4 / 2**20:.1f} MiB float32), max count {max(int(s['counts'].max()) for s in samples)}")
    print(f"{'codec':<16}{'envelope':>12}{'counts i64':>12}{'u32':>10}{'u16':>10}{'labels':>10}"
          f"{'enc ms':>9}{'dec ms':>9}   (bytes per sample; times for the envelope)")
    for r in measure(samples, args.level, args.reps):
        print(f"{r['codec']:<16}{r['envelope']:>12.0f}{r['counts int64']:>12.0f}{r['counts uint32']:>10.0f}"
              f"{r['counts uint16']:>10.0f}{r['labels']:>10.0f}{r['encode_ms']:>9.1f}{r['decode_ms']:>9.1f}")


if __name__ == "__main__":
    main()
