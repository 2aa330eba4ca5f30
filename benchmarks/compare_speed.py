"""Check that a refactor leaves datagen's speed unchanged: old tree against new tree, interleaved in one run.

What it shows
    Each tree runs its OWN benchmark scripts (``benchmarks/bench_demo_room.py``, ``bench_spad.py``,
    ``bench_dataset.py``) as a subprocess with ``PYTHONPATH=TREE`` and ``cwd=TREE``, so ``import datagen`` (and
    any new module path the tree's scripts import) resolves to that tree. Runs alternate old, new, old, new, …
    within each repeat, so slow drifts of the machine's load hit both trees alike. For every run the wall
    clock and the CPU time (user + system, the subprocess and the children it waited for) of the whole
    subprocess are measured, and the timings the benchmark prints are parsed (throughputs are turned into
    time per item, so for every row lower is better). The table gives, per benchmark row, the median of the
    old and of the new runs, the ratio new/old (> 1: the new code is slower) and the spread (min–max) of the
    runs. It asserts nothing about timings: read the ratios against the spreads (the machine is shared).

How to run it::

    python benchmarks/compare_speed.py --old /work/old --new /work/main --repeat 3
    python benchmarks/compare_speed.py --old /work/old --new /work/old --repeat 1     # sanity: ratios ≈ 1
    python benchmarks/compare_speed.py --old A --new B --only spad,dataset --json times.json

Benchmark modes (fast; about 100 s per tree and repeat on 2 cores, so --repeat 3 takes about 10 minutes):
    demo_room  ``bench_demo_room.py --quick --repeat 1``: the 10×10×60×60 rows (full, optimized, exact ×
               albedo 1 and 0.5), then the exact secondary at 45×45×60×60 on 1 and 2 workers (the script also
               runs the 45×45 full secondary once for its accuracy line: part of the whole-process time only);
    spad       ``bench_spad.py`` (no options; ~40 s);
    dataset    ``bench_dataset.py --samples 16 --workers 2 --skip-big`` (build of 16 default-config samples
               and the loader measurements; ~12 s).
    scan       ``bench_scan.py --skip 1 --samples 3 --no-reference --build 0``: ``make_sample`` of
               ``confocal.yaml`` and ``wall.yaml`` (wall and CPU seconds per sample, mean of 3 after a warm-up) and the
               10 000-triangle torus's confocal captures at 32×32, 64×64 and 128×128 × 512 (wall and CPU seconds;
               numba's threads); a few minutes per tree and repeat. Not part of the default set (``--only scan``).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

BENCHES = {
    "demo_room": ["benchmarks/bench_demo_room.py", "--quick", "--repeat", "1"],
    "spad": ["benchmarks/bench_spad.py"],
    "dataset": ["benchmarks/bench_dataset.py", "--samples", "16", "--workers", "2", "--skip-big"],
    "scan": ["benchmarks/bench_scan.py", "--skip", "1", "--samples", "3", "--no-reference", "--build", "0"],
}


# ------------------------------------------------------------------------------------------------------------
# Parsers of the benchmarks' printed timings: text -> {row name: (value, unit)}; lower is better for all rows
# ------------------------------------------------------------------------------------------------------------
def parse_demo_room(text: str) -> dict:
    rows = {}
    for m in re.finditer(r"^\s*(\S+)\s+(\S+)\s+albedo\s+([\d.]+):\s+([\d.]+)\s+s\b", text, re.M):
        rows[f"{m[1]}x60x60 {m[2]} albedo {m[3]}"] = (float(m[4]), "s")
    for m in re.finditer(r"^\|\s*demo room\s*\|\s*(\d+)\s*\|\s*([\d.]+)\s*\|", text, re.M):
        rows[f"45x45x60x60 exact, {m[1]} worker(s), best"] = (float(m[2]), "s")
    return rows


def parse_spad(text: str) -> dict:
    rows = {}
    for line in text.splitlines():
        m = re.match(r"^(\S.*?)\s{2,}(\S.*?)\s{2,}(\d+\.\d+)(?:\s{2}|$)", line)
        if m:
            rows[f"{m[1]} | {m[2]}"] = (float(m[3]), "s")
    return rows


def parse_dataset(text: str) -> dict:
    rows = {}
    m = re.search(r"^build\s+default config.*?:\s*([\d.]+) samples/s \(([\d.]+) s wall.*?per sample ([\d.]+) s mean",
                  text, re.M)
    if m:
        rows["build: wall of the build (incl. pool start-up)"] = (float(m[2]), "s")
        rows["build: time per sample (1/throughput)"] = (1.0 / float(m[1]), "s")
        rows["build: mean per-sample time in a worker"] = (float(m[3]), "s")
    m = re.search(r"^build\s+([\d.]+) CPU-s per default sample", text, re.M)
    if m:
        rows["build: CPU-s per sample in one process"] = (float(m[1]), "s")
    m = re.search(r"^loader one __getitem__.*?:\s*([\d.]+)\s*µs", text, re.M)
    if m:
        rows["loader: one __getitem__ in the main process"] = (float(m[1]), "µs")
    for m in re.finditer(r"^loader DataLoader.*?noise=(\w+):\s*([\d.]+) samples/s", text, re.M):
        rows[f"loader: DataLoader noise={m[1]}, time per sample (1/throughput)"] = (1e6 / float(m[2]), "µs")
    return rows


def parse_scan(text: str) -> dict:
    rows = {}
    for m in re.finditer(r"^(confocal|wall)\s+([\d.]+) s per sample \(max [\d.]+; CPU ([\d.]+) s\)", text, re.M):
        rows[f"{m[1]}.yaml make_sample: wall s per sample"] = (float(m[2]), "s")
        rows[f"{m[1]}.yaml make_sample: CPU s per sample"] = (float(m[3]), "s")
    for m in re.finditer(r"^\s*(\d+)×(\d+)\s+([\d.]+)\s+([\d.]+)\s+\d+\s+\d+\s+[\d.]+%", text, re.M):
        rows[f"torus {m[1]}×{m[2]} × 512: wall s"] = (float(m[3]), "s")
        rows[f"torus {m[1]}×{m[2]} × 512: CPU s"] = (float(m[4]), "s")
    return rows


PARSERS = {"demo_room": parse_demo_room, "spad": parse_spad, "dataset": parse_dataset, "scan": parse_scan}


# ------------------------------------------------------------------------------------------------------------
def check_tree(tree: Path) -> str:
    """``datagen.__file__`` as the benchmarks will see it; exit if it is not inside ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-c", "import datagen; print(datagen.__file__)"], cwd=tree, env=env,
                         capture_output=True, text=True)
    where = os.path.realpath(out.stdout.strip()) if out.returncode == 0 else ""
    if not where.startswith(os.path.realpath(tree) + os.sep):
        sys.exit(f"with PYTHONPATH={tree}, datagen is imported from {where or '(import failed)'}:\n{out.stderr}")
    return where


def run_bench(tree: Path, name: str, timeout: float, log_dir: Path | None, tag: str) -> dict:
    """Run one benchmark of ``tree`` in a subprocess; wall, CPU and parsed rows."""
    argv = BENCHES[name]
    env = {**os.environ, "PYTHONPATH": str(tree)}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, *argv], cwd=tree, env=env, capture_output=True, text=True,
                              timeout=timeout)
        rc, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as exc:
        rc, stdout, stderr = -999, exc.stdout or "", f"timeout after {timeout} s"
        stdout = stdout.decode() if isinstance(stdout, bytes) else stdout
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if log_dir is not None:
        (log_dir / f"{tag}.stdout").write_text(stdout)
        (log_dir / f"{tag}.stderr").write_text(stderr)
    rows = {"(whole subprocess) wall": (wall, "s"), "(whole subprocess) CPU user+sys": (cpu, "s")}
    if rc == 0:
        rows.update(PARSERS[name](stdout))
    return {"returncode": rc, "rows": rows, "load_before": load, "stderr_tail": stderr[-2000:] if rc else ""}


def _fmt(value: float) -> str:
    return f"{value:.4g}"


def report(results: list[dict], benches: list[str]) -> None:
    """Print the table: benchmark row, unit, old/new median, ratio new/old, min–max of each side, n."""
    lines = []
    for bench in benches:
        order = []
        for r in results:
            if r["bench"] == bench:
                order += [k for k in r["rows"] if k not in order]
        for row in order:
            vals = {side: [r["rows"][row][0] for r in results if r["bench"] == bench and r["side"] == side
                           and row in r["rows"]] for side in ("old", "new")}
            unit = next(r["rows"][row][1] for r in results if r["bench"] == bench and row in r["rows"])
            cells = [f"{bench}: {row}", unit]
            med = {}
            for side in ("old", "new"):
                med[side] = statistics.median(vals[side]) if vals[side] else None
                cells.append(_fmt(med[side]) if med[side] is not None else "-")
            cells.append(f"{med['new'] / med['old']:.3f}" if med["old"] and med["new"] is not None else "-")
            for side in ("old", "new"):
                v = vals[side]
                cells.append(f"{_fmt(min(v))}–{_fmt(max(v))}" if len(v) > 1 else (_fmt(v[0]) if v else "-"))
            cells.append(f"{len(vals['old'])}/{len(vals['new'])}")
            lines.append(cells)
    header = ["benchmark row", "unit", "old median", "new median", "new/old", "old min–max", "new min–max",
              "n old/new"]
    widths = [max(len(str(c[i])) for c in lines + [header]) for i in range(len(header))]
    fmt = lambda cells: "  ".join(str(c).ljust(w) if i < 2 else str(c).rjust(w)   # noqa: E731
                                  for i, (c, w) in enumerate(zip(cells, widths)))
    print(fmt(header))
    print("  ".join("-" * w for w in widths))
    for cells in lines:
        print(fmt(cells))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", type=Path, required=True, help="source tree before the change")
    parser.add_argument("--new", type=Path, required=True, help="source tree after the change")
    parser.add_argument("--repeat", type=int, default=3, help="runs per tree and benchmark (alternating)")
    parser.add_argument("--only", default=None, help=f"comma-separated subset of {','.join(BENCHES)}")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds per benchmark subprocess")
    parser.add_argument("--json", type=Path, default=None, help="also write every run's numbers here")
    parser.add_argument("--logs", type=Path, default=None, help="directory for each run's stdout/stderr")
    args = parser.parse_args(argv)
    benches = [b.strip() for b in args.only.split(",")] if args.only else [b for b in BENCHES if b != "scan"]
    unknown = [b for b in benches if b not in BENCHES]
    if unknown:
        sys.exit(f"unknown benchmark(s) {unknown}; known: {list(BENCHES)}")
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    for side, tree in trees.items():
        print(f"{side}: {tree} (datagen from {check_tree(tree)})")
    if args.logs:
        args.logs.mkdir(parents=True, exist_ok=True)
    print(f"{os.cpu_count()} cores, python {sys.version.split()[0]}, load average {os.getloadavg()[0]:.2f}; "
          f"{args.repeat} repeat(s) of {', '.join(benches)}, old and new alternating")
    results = []
    t_start = time.perf_counter()
    for rep in range(args.repeat):
        for bench in benches:
            for side in ("old", "new"):
                tag = f"r{rep + 1}_{bench}_{side}"
                res = run_bench(trees[side], bench, args.timeout, args.logs, tag)
                res.update(bench=bench, side=side, repeat=rep + 1)
                results.append(res)
                wall = res["rows"]["(whole subprocess) wall"][0]
                status = "ok" if res["returncode"] == 0 else f"FAILED (exit {res['returncode']})"
                print(f"[repeat {rep + 1}/{args.repeat}] {bench:<9} {side}: {status}, {wall:.1f} s wall, "
                      f"{len(res['rows']) - 2} parsed rows, load before {res['load_before']:.2f}", flush=True)
                if res["returncode"] != 0:
                    print("    " + res["stderr_tail"].strip().replace("\n", "\n    "))
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s\n")
    report(results, benches)
    loads = [r["load_before"] for r in results]
    print(f"\nload average before the runs: {min(loads):.2f}–{max(loads):.2f} on {os.cpu_count()} cores"
          + (" (the machine was busy: expect noisier ratios)" if max(loads) > 0.5 * (os.cpu_count() or 1) else ""))
    failed = [f"{r['bench']} {r['side']} (repeat {r['repeat']})" for r in results if r["returncode"] != 0]
    if failed:
        print("failed runs: " + ", ".join(failed))
    if args.json:
        args.json.write_text(json.dumps({"trees": {k: str(v) for k, v in trees.items()}, "runs": results},
                                        indent=1))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
