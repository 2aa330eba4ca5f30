"""Draw the package's real import graph, collapsed to subpackages, as a PNG (so the architecture docs stay true).

What it draws:

- the import graph of the package (``datagen`` by default) as built by grimp from the source tree: every
  ``import`` statement in every module, function-level and ``TYPE_CHECKING`` imports included, external
  packages left out;
- each module collapsed to its layer (the longest matching name of the layer contract, e.g.
  ``datagen.transport.lookin`` → ``datagen.transport``) or, outside the contract, to its top-level subpackage or
  module (``datagen.units``); one box per group, listing the group's modules in small text;
- boxes in rows by layer, top to bottom in the order of the import-linter ``layers`` contract read from
  ``pyproject.toml`` (``[[tool.importlinter.contracts]]`` with ``type = "layers"``; ``|`` separates independent
  siblings of one row, ``:`` siblings that may import each other); the package's own ``__init__`` sits above
  every layer; groups the contract does not name get a row of their own at the bottom;
- one arrow per importing group → imported group, its width growing with the number of module-to-module imports
  behind it (the number is written on it); red arrows break the contract (an import from a lower row into a
  higher one, or between independent siblings), grey dashed ones involve a group outside the contract. The
  offending module-to-module imports are listed under the graph.

Without a layers contract (and without ``--layers``) the rows are inferred from the graph itself (modules that
import nothing at the bottom) and red marks imports that close a cycle.

Run from the repository root::

    python scripts/architecture_diagram.py --out docs/architecture.png [--package datagen]

Options: ``--layers ROW`` (repeatable, top row first, e.g. ``--layers datagen.cli --layers "datagen.io |
datagen.plot"``) replaces the contract; ``--contract NAME`` picks a layers contract by name; ``--root DIR``
analyses the package found in DIR (default: this repository) and ``--pyproject FILE`` reads another contract;
``--check`` exits with status 1 when an arrow is red. Needs ``grimp`` and ``matplotlib`` (``pip install grimp
import-linter``).
"""
from __future__ import annotations

import argparse
import math
import sys
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

TITLE_FONT = 11.0
"""Box titles (points)."""
MODULE_FONT = 8.0
"""Module lists inside boxes (points)."""
LABEL_FONT = 7.5
"""Import counts on arrows and the layer labels (points)."""
MODULES_PER_COLUMN = 7
"""A box lists at most this many modules per column; longer lists wrap into more columns."""
BOX_PAD = 0.12
"""Inner margin of a box (inches)."""
BOX_GAP = 0.45
"""Horizontal space between boxes of one row (inches)."""
ROW_GAP = 1.05
"""Vertical space between rows, where the arrows run (inches)."""
MAX_ROW_WIDTH = 22.0
"""A row wider than this (inches) wraps onto several lines of boxes (same layer)."""
MARGIN = 0.5
"""Outer margin of the figure (inches)."""
LAYER_LABEL_WIDTH = 0.9
"""Left column holding the layer labels (inches)."""
LABEL_OFFSET = 0.32
"""Distance (inches) from an arrow's start to its import count, so the count sits in the gap between rows."""
BOW_CLEARANCE = 2.4
"""An arrow that skips rows bows sideways by about half this (inches), enough to pass beside a typical box."""
MAX_BOW = 0.3
"""Largest arc3 curvature of a bowed arrow."""
MAX_LISTED_VIOLATIONS = 40
"""Offending module-to-module imports listed under the graph (the rest are counted)."""
DPI = 150

COLORS = {"ok": "#4a6f9c", "violation": "#d62728", "outside": "#8c8c8c"}
FILL = {"root": "#f3e9d2", "layer": "#e8eef7", "outside": "#eeeeee"}


@dataclass
class Layers:
    """Rows of the layer order, top first. Each row: (group names, independent siblings?)."""

    rows: list[tuple[list[str], bool]]
    source: str

    def names(self) -> list[str]:
        return [name for row, _ in self.rows for name in row]


@dataclass
class Group:
    name: str
    modules: list[str]
    row: int
    kind: str                           # "root", "layer" or "outside"
    x: float = 0.0                      # lower-left corner and size, inches
    y: float = 0.0
    w: float = 0.0
    h: float = 0.0
    title_h: float = 0.0
    columns: list[list[str]] = field(default_factory=list)
    column_w: list[float] = field(default_factory=list)
    line_h: float = 0.0

    @property
    def cx(self) -> float:
        return self.x + self.w / 2


# -- layer contract ------------------------------------------------------------------------------------------

def parse_row(text: str) -> tuple[list[str], bool]:
    """One entry of import-linter's ``layers`` list: names separated by ``|`` (independent) or ``:`` (not)."""
    independent = ":" not in text
    parts = text.replace(":", "|").split("|")
    names = [p.strip().strip("()").strip() for p in parts if p.strip()]
    return names, independent


def read_contract(pyproject: Path, name: str | None) -> Layers | None:
    """The ``layers`` contract of ``pyproject`` (the one called ``name``, else the first), or None."""
    if not pyproject.is_file():
        return None
    data = tomllib.loads(pyproject.read_text())
    contracts = data.get("tool", {}).get("importlinter", {}).get("contracts", [])
    layered = [c for c in contracts if c.get("type") == "layers"]
    if name is not None:
        layered = [c for c in layered if c.get("name") == name]
        if not layered:
            raise SystemExit(f"error: {pyproject} has no layers contract named {name!r}")
    if not layered:
        return None
    contract = layered[0]
    containers = contract.get("containers") or [""]
    rows = []
    for entry in contract.get("layers", []):
        names, independent = parse_row(entry)
        rows.append(([f"{c}.{n}" if c else n for c in containers for n in names], independent))
    return Layers(rows, f"{pyproject.name}: contract {contract.get('name', '(unnamed)')!r}")


# -- graph ---------------------------------------------------------------------------------------------------

def build_graph(package: str, root: Path):
    """grimp's graph of ``package`` as found under ``root`` (every import, no cache written)."""
    import grimp

    sys.path.insert(0, str(root))
    try:
        return grimp.build_graph(package, include_external_packages=False, exclude_type_checking_imports=False,
                                 cache_dir=None)
    finally:
        sys.path.remove(str(root))


def group_of(module: str, package: str, layer_names: list[str]) -> str:
    """The layer a module belongs to (longest matching name), else its top-level subpackage or module."""
    best = ""
    for name in layer_names:
        if (module == name or module.startswith(name + ".")) and len(name) > len(best):
            best = name
    if best:
        return best
    parts = module.split(".")
    return package if len(parts) == 1 else ".".join(parts[:2])


def collapse(graph, package: str, layer_names: list[str]):
    """Groups → modules, and (importer group, imported group) → list of (importer, imported) module pairs."""
    members: dict[str, list[str]] = defaultdict(list)
    edges: dict[tuple[str, str], list[tuple[str, str]]] = defaultdict(list)
    for module in sorted(graph.modules):
        members[group_of(module, package, layer_names)].append(module)
    for module in sorted(graph.modules):
        a = group_of(module, package, layer_names)
        for imported in sorted(graph.find_modules_directly_imported_by(module)):
            b = group_of(imported, package, layer_names)
            if a != b:
                edges[(a, b)].append((module, imported))
    return dict(members), dict(edges)


def infer_layers(groups: list[str], edges, package: str) -> tuple[Layers, set[tuple[str, str]]]:
    """Rows from the graph: strongly connected groups share a row, groups importing nothing sit at the bottom.
    Returns the layers and the group edges inside a cycle."""
    succ = defaultdict(set)
    for a, b in edges:
        succ[a].add(b)
    index, low, stack, on_stack, comp = {}, {}, [], set(), {}
    counter = [0]

    def strongconnect(v):                                        # Tarjan (groups are few: recursion is fine)
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in succ[v]:
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp[w] = v
                if w == v:
                    break

    for g in sorted(groups):
        if g not in index:
            strongconnect(g)
    height: dict[str, int] = {}

    def h(c):                                                    # longest path down the condensation
        if c not in height:
            height[c] = 0
            below = {comp[b] for a in groups if comp[a] == c for b in succ[a] if comp[b] != c}
            height[c] = 1 + max((h(d) for d in below), default=-1)
        return height[c]

    top = max(h(comp[g]) for g in groups)
    rows: dict[int, list[str]] = defaultdict(list)
    for g in sorted(groups):
        if g != package:
            rows[top - h(comp[g])].append(g)
    cyclic = {(a, b) for a, b in edges if comp[a] == comp[b]}
    ordered = [(rows[i], False) for i in sorted(rows)]
    return Layers(ordered, "no layers contract: rows inferred from the graph"), cyclic


# -- layout --------------------------------------------------------------------------------------------------

def measure(fig, text: str, size: float, weight: str = "normal") -> tuple[float, float]:
    t = fig.text(0, 0, text, fontsize=size, fontweight=weight)
    bb = t.get_window_extent(fig.canvas.get_renderer())
    t.remove()
    return bb.width / fig.dpi, bb.height / fig.dpi


def size_box(fig, g: Group, package: str) -> None:
    names = []
    for m in g.modules:
        rel = m[len(g.name) + 1:] if m.startswith(g.name + ".") else ("__init__" if m == g.name else m)
        names.append(rel)
    if names == ["__init__"] and g.name != package:
        names = ["(module)"]
    names.sort(key=lambda n: (n != "__init__", n))
    title_w, g.title_h = measure(fig, g.name, TITLE_FONT, "bold")
    _, g.line_h = measure(fig, "Ag", MODULE_FONT)
    g.line_h *= 1.18
    n_cols = max(1, math.ceil(len(names) / MODULES_PER_COLUMN))
    per = math.ceil(len(names) / n_cols)
    g.columns = [names[i * per:(i + 1) * per] for i in range(n_cols)]
    g.column_w = [max(measure(fig, n, MODULE_FONT)[0] for n in col) if col else 0.0 for col in g.columns]
    body_w = sum(g.column_w) + 0.25 * (n_cols - 1)
    lines = max(len(c) for c in g.columns)
    g.w = max(title_w, body_w, 1.2) + 2 * BOX_PAD
    g.h = BOX_PAD + g.title_h + 0.08 + lines * g.line_h + BOX_PAD


def order_rows(rows: list[list[Group]], edges) -> None:
    """Barycentre sweeps: each row sorted by the mean position of its neighbours in the other rows."""
    pos = {g.name: i for row in rows for i, g in enumerate(row)}
    nbrs = defaultdict(list)
    for a, b in edges:
        nbrs[a].append(b)
        nbrs[b].append(a)
    for _ in range(4):
        for row in rows[1:] + rows[::-1]:
            keyed = []
            for i, g in enumerate(row):
                others = [pos[n] for n in nbrs[g.name] if n in pos and n not in {x.name for x in row}]
                keyed.append((sum(others) / len(others) if others else i, i, g))
            keyed.sort(key=lambda k: (k[0], k[1]))
            row[:] = [k[2] for k in keyed]
            for i, g in enumerate(row):
                pos[g.name] = i


def wrap(row: list[Group]) -> list[list[Group]]:
    lines, current, width = [], [], 0.0
    for g in row:
        if current and width + BOX_GAP + g.w > MAX_ROW_WIDTH:
            lines.append(current)
            current, width = [], 0.0
        width += (BOX_GAP if current else 0.0) + g.w
        current.append(g)
    return lines + ([current] if current else [])


# -- drawing -------------------------------------------------------------------------------------------------

def draw(members, edges, layers: Layers, status: dict, package: str, out: Path, title: str, what: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    scratch = plt.figure(dpi=DPI)

    def measure_width(text, size):
        return measure(scratch, text, size)[0]

    row_of = {}
    kinds = {}
    rows_spec: list[list[str]] = []
    if package in members:
        rows_spec.append([package])
        row_of[package], kinds[package] = 0, "root"
    for names, _ in layers.rows:
        present = [n for n in names if n in members]
        if present:
            for n in present:
                row_of[n], kinds[n] = len(rows_spec), "layer"
            rows_spec.append(present)
    outside = sorted(n for n in members if n not in row_of)
    if outside:
        for n in outside:
            row_of[n], kinds[n] = len(rows_spec), "outside"
        rows_spec.append(outside)
    groups = {n: Group(n, members[n], row_of[n], kinds[n]) for n in members}
    for g in groups.values():
        size_box(scratch, g, package)

    rows = [[groups[n] for n in spec] for spec in rows_spec]
    order_rows(rows, edges)
    lines = [(r, line) for r, row in enumerate(rows) for line in wrap(row)]
    widths = [sum(g.w for g in line) + BOX_GAP * (len(line) - 1) for _, line in lines]
    title_w = max(measure_width(line, TITLE_FONT + 1) for line in title.split("\n"))
    content_w = max(widths + [8.0, title_w - LAYER_LABEL_WIDTH])
    violations = sorted((a, b) for (a, b), s in status.items() if s == "violation")
    listed = [(m, i) for e in violations for m, i in edges[e]]
    small_h = 0.16                                                # footer line height, inches
    footer_lines = 3 + (min(len(listed), MAX_LISTED_VIOLATIONS) + (len(listed) > MAX_LISTED_VIOLATIONS)
                        + 1 if listed else 0)
    footer_h = footer_lines * small_h + 0.3
    heights = [max(g.h for g in line) for _, line in lines]
    graph_h = sum(heights) + ROW_GAP * (len(lines) - 1)
    fig_w = content_w + LAYER_LABEL_WIDTH + 2 * MARGIN
    fig_h = graph_h + 2 * MARGIN + 0.8 + footer_h
    plt.close(scratch)
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=DPI)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, fig_w)
    ax.set_ylim(0, fig_h)
    ax.axis("off")

    # place boxes: rows top-down, each line centred
    y_top = fig_h - MARGIN - 0.8
    row_band: dict[int, list[float]] = {}
    for (r, line), width, height in zip(lines, widths, heights):
        x = MARGIN + LAYER_LABEL_WIDTH + (content_w - width) / 2
        for g in line:
            g.x, g.y = x, y_top - height + (height - g.h) / 2
            x += g.w + BOX_GAP
        row_band.setdefault(r, [y_top, y_top - height])[1] = y_top - height
        y_top -= height + ROW_GAP
    for r, (top, bottom) in row_band.items():
        kind = rows[r][0].kind
        number = r + (0 if package in members else 1)                  # row 0 is the package's __init__
        label = {"root": "package", "outside": "outside\ncontract"}.get(kind, f"layer {number}")
        ax.text(MARGIN, (top + bottom) / 2, label, fontsize=LABEL_FONT, color="#666666", va="center", ha="left")

    # arrows: ports spread along the box edges, ordered by the other end's x
    ports_out = defaultdict(list)
    ports_in = defaultdict(list)
    for (a, b) in edges:
        ga, gb = groups[a], groups[b]
        if ga.row == gb.row and abs(ga.y - gb.y) < 1e-9:
            continue
        down = ga.y > gb.y
        ports_out[(a, "bottom" if down else "top")].append((gb.cx, b))
        ports_in[(b, "top" if down else "bottom")].append((ga.cx, a))

    def port(name, side, other, table):
        g = groups[name]
        ends = sorted(table[(name, side)])
        i = [o for _, o in ends].index(other)
        frac = 0.5 if len(ends) == 1 else 0.15 + 0.7 * i / (len(ends) - 1)
        return g.x + frac * g.w, (g.y if side == "bottom" else g.y + g.h)

    centre_x = MARGIN + LAYER_LABEL_WIDTH + content_w / 2
    bowed: list[tuple[str, str]] = []
    for (a, b), pairs in sorted(edges.items(), key=lambda kv: status[kv[0]] == "violation"):
        ga, gb = groups[a], groups[b]
        s = status[(a, b)]
        n = len(pairs)
        lw = 0.7 + 0.9 * math.log2(n)
        color = COLORS[s]
        style = dict(arrowstyle="-|>", mutation_scale=9 + 2 * math.log2(n), lw=lw, color=color,
                     linestyle="--" if s == "outside" else "-", alpha=0.95 if s == "violation" else 0.75,
                     zorder=3 if s == "violation" else 1, shrinkA=0, shrinkB=1)
        if ga.row == gb.row and abs(ga.y - gb.y) < 1e-9:              # same line: arc over the boxes
            left = ga.cx < gb.cx
            p0 = (ga.x + (ga.w if left else 0), ga.y + 0.7 * ga.h)
            p1 = (gb.x + (0 if left else gb.w), gb.y + 0.7 * gb.h)
            arrow = FancyArrowPatch(p0, p1, connectionstyle="arc3,rad=-0.35", **style)
            mid = ((p0[0] + p1[0]) / 2, max(p0[1], p1[1]) + 0.18 * abs(p1[0] - p0[0]))
        else:
            down = ga.y > gb.y
            p0 = port(a, "bottom" if down else "top", b, ports_out)
            p1 = port(b, "top" if down else "bottom", a, ports_in)
            length = math.hypot(p1[0] - p0[0], p1[1] - p0[1])
            rad = 0.0
            if abs(ga.row - gb.row) > 1:
                # an edge skipping rows bows sideways, away from the middle of the figure, so that it passes
                # beside the boxes in between rather than behind them
                if s != "violation":
                    style["alpha"] = 0.55
                side = (p0[0] + p1[0]) / 2 - centre_x
                if abs(side) < 0.3:
                    side = -1.0 if len(bowed) % 2 else 1.0
                bowed.append((a, b))
                towards_right = side > 0
                # arc3 bends to the right of the direction of travel for rad > 0
                travel_down = p1[1] < p0[1]
                rad = min(MAX_BOW, BOW_CLEARANCE / max(length, 1e-9))
                rad = rad if (towards_right != travel_down) else -rad
            arrow = FancyArrowPatch(p0, p1, connectionstyle=f"arc3,rad={rad}", **style)
            t = min(0.5, LABEL_OFFSET / max(length, 1e-9))           # in the gap just below (above) the importer
            mid = (p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1]))
        ax.add_patch(arrow)
        ax.text(*mid, str(n), fontsize=LABEL_FONT, color=color, ha="center", va="center", zorder=4,
                fontweight="bold" if s == "violation" else "normal",
                bbox=dict(boxstyle="round,pad=0.12", fc="white", ec="none", alpha=0.85))

    for g in groups.values():
        ax.add_patch(FancyBboxPatch((g.x, g.y), g.w, g.h, boxstyle="round,pad=0,rounding_size=0.08",
                                    fc=FILL[g.kind], ec="#33415c" if g.kind != "outside" else "#888888",
                                    lw=1.2, zorder=2))
        ax.text(g.cx, g.y + g.h - BOX_PAD, g.name, fontsize=TITLE_FONT, fontweight="bold", ha="center",
                va="top", zorder=5)
        x = g.cx - (sum(g.column_w) + 0.25 * (len(g.columns) - 1)) / 2
        for col, cw in zip(g.columns, g.column_w):
            for i, name in enumerate(col):
                ax.text(x, g.y + g.h - BOX_PAD - g.title_h - 0.08 - (i + 0.5) * g.line_h, name,
                        fontsize=MODULE_FONT, color="#333333", ha="left", va="center", zorder=5)
            x += cw + 0.25

    ax.text(fig_w / 2, fig_h - MARGIN * 0.6, title, fontsize=TITLE_FONT + 1, ha="center", va="top",
            linespacing=1.5)
    handles = [Line2D([], [], color=COLORS["ok"], lw=1.5, label="import (number = module-to-module imports)"),
               Line2D([], [], color=COLORS["violation"], lw=2.0, label=what.replace("close", "closes")
                      .replace("break", "breaks"))]
    if "outside" in status.values():
        handles.append(Line2D([], [], color=COLORS["outside"], lw=1.5, ls="--",
                              label="involves a group outside the contract"))
    fig.legend(handles=handles, loc="lower left", bbox_to_anchor=(MARGIN / fig_w, (MARGIN * 0.5) / fig_h),
               fontsize=LABEL_FONT + 0.5, frameon=False, ncol=3)
    if listed:
        text = [f"{len(listed)} module-to-module import(s) {what}:"]
        text += [f"  {m}  →  {i}" for m, i in listed[:MAX_LISTED_VIOLATIONS]]
        if len(listed) > MAX_LISTED_VIOLATIONS:
            text.append(f"  … and {len(listed) - MAX_LISTED_VIOLATIONS} more")
        ax.text(MARGIN, MARGIN * 0.5 + 0.35, "\n".join(text), fontsize=LABEL_FONT, color=COLORS["violation"],
                ha="left", va="bottom", family="monospace", linespacing=1.35)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)
    plt.close(fig)


# -- main ----------------------------------------------------------------------------------------------------

def classify(edges, layers: Layers, package: str, cyclic: set | None) -> dict:
    """'ok', 'violation' or 'outside' for every group edge."""
    index, independent = {}, {}
    for r, (names, indep) in enumerate(layers.rows):
        for n in names:
            index[n], independent[n] = r, indep
    index[package] = -1                                            # the package's __init__ is above every layer
    status = {}
    for a, b in edges:
        if cyclic is not None:
            status[(a, b)] = "violation" if (a, b) in cyclic else "ok"
        elif a not in index or b not in index:
            status[(a, b)] = "outside"
        elif index[a] > index[b] or (index[a] == index[b] and independent.get(a, False)):
            status[(a, b)] = "violation"
        else:
            status[(a, b)] = "ok"
    return status


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="PNG to write (e.g. docs/architecture.png)")
    parser.add_argument("--package", default="datagen", help="top-level package to analyse (default: datagen)")
    parser.add_argument("--root", type=Path, default=REPO, help="directory holding the package (default: the repo)")
    parser.add_argument("--pyproject", type=Path, default=None, help="file with the layers contract "
                        "(default: ROOT/pyproject.toml)")
    parser.add_argument("--contract", default=None, help="name of the layers contract (default: the first)")
    parser.add_argument("--layers", action="append", default=None, metavar="ROW",
                        help='one row of the layer order, top first, e.g. "datagen.io | datagen.plot" '
                             "(repeat; replaces the contract)")
    parser.add_argument("--check", action="store_true", help="exit 1 when an arrow is red")
    args = parser.parse_args(argv)

    root = args.root.resolve()
    if not (root / args.package).is_dir() and not (root / f"{args.package}.py").is_file():
        parser.error(f"no package {args.package!r} under {root}")
    if args.layers:
        layers = Layers([parse_row(r) for r in args.layers], "layers from --layers")
    else:
        layers = read_contract(args.pyproject or root / "pyproject.toml", args.contract)
    graph = build_graph(args.package, root)
    members, edges = collapse(graph, args.package, layers.names() if layers else [])
    cyclic = None
    if layers is None:
        layers, cyclic = infer_layers(sorted(members), edges, args.package)
    status = classify(edges, layers, args.package, cyclic)
    n_imports = sum(len(v) for v in edges.values())
    bad = sum(len(edges[e]) for e, s in status.items() if s == "violation")
    what = "close a cycle" if cyclic is not None else "break the layer order"
    title = (f"Import graph of {args.package}: {len(graph.modules)} modules in {len(members)} groups, "
             f"{n_imports} imports between groups, {bad} of them {what}\n{layers.source}")
    draw(members, edges, layers, status, args.package, args.out, title, what)
    print(f"wrote {args.out}: {len(members)} groups, {len(edges)} group edges ({n_imports} module imports), "
          f"{sum(s == 'violation' for s in status.values())} red ({bad} module imports that {what}), "
          f"{sum(s == 'outside' for s in status.values())} outside the contract")
    for (a, b), s in sorted(status.items()):
        if s == "violation":
            for m, i in edges[(a, b)]:
                print(f"  {m} -> {i}")
    return 1 if args.check and bad else 0


if __name__ == "__main__":
    sys.exit(main())
