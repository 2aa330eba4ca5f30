"""The package's shape: no import cycle, no module using another module's private name, layers in order, a small
public surface.

The layer contract itself is checked by import-linter (``lint-imports``, configured in pyproject.toml and run by
scripts/test.sh); these tests check what it does not: cycles *inside* a layer (function-level imports
included) and private names used across modules.
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import re
import types
from pathlib import Path

import pytest
from conftest import parse_python

PACKAGE = Path(__file__).resolve().parents[1] / "datagen"

LIBRARY_PRIVATES = {"_replace", "_asdict", "_fields", "_make", "_field_defaults", "_exit"}
"""Documented underscore names of the standard library (namedtuple; ``os._exit``), not private to any datagen
module."""


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _resolve(module: str, is_package: bool, level: int, target: str | None) -> str:
    """Absolute module name of a relative import ``from {'.' * level}{target} import …`` inside ``module``."""
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[:len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _import_graph() -> dict[str, set[str]]:
    """module → datagen modules it imports anywhere (function-level and TYPE_CHECKING imports included)."""
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = parse_python(path)
        is_package = path.name == "__init__.py"
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(name, is_package, node.level, node.module) if node.level else node.module or ""
                # ``from package import submodule`` imports the submodule; else it imports ``base``
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            for t in targets:
                while t and t not in modules:                       # a name inside a module → the module
                    t = t.rpartition(".")[0]
                if t.startswith("datagen") and t != name:
                    graph[name].add(t)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_import_graph_has_no_cycle():
    graph = _import_graph()
    assert len(graph) > 40 and sum(len(v) for v in graph.values()) > 100      # the scan found the package
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _defined_names(tree: ast.AST) -> set[str]:
    """Every name a module defines or binds (functions, classes, methods, attributes, variables, arguments)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.split(".")[0])
    return names


def private_uses(path: Path) -> list[str]:
    """``file:line name`` for every private name (``_x``, not dunder) of another module used in ``path``: imported
    (``from m import _x``) or reached as an attribute (``m._x``, ``obj._x``) when ``path`` does not define it."""
    tree = parse_python(path)
    own = _defined_names(tree)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            out += [f"{path.name}:{node.lineno} {a.name}" for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")]
        elif isinstance(node, ast.Attribute):
            name = node.attr
            if (name.startswith("_") and not name.startswith("__") and name not in own
                    and name not in LIBRARY_PRIVATES):
                out.append(f"{path.name}:{node.lineno} {name}")
    return out


def test_no_module_uses_another_modules_private_name():
    uses = [u for path in _modules().values() for u in private_uses(path)]
    assert uses == []


@pytest.mark.parametrize("folder", ["tests", "benchmarks"])
def test_tests_and_benchmarks_use_only_public_names(folder):
    root = PACKAGE.parent / folder
    uses = [u for path in sorted(root.rglob("*.py")) for u in private_uses(path)]
    assert uses == []


def test_the_private_name_scan_sees_a_violation(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from datagen.transport.physics import _secret\nx = other._helper(1)\nself._mine = 2\n")
    assert private_uses(bad) == ["bad.py:1 _secret", "bad.py:2 _helper"]


MODULE_LINES_MAX = 600
"""Longest module, in lines (the architecture issue's bound: larger modules are split by what they do)."""


def test_modules_stay_small():
    long = {name: n for name, path in _modules().items() if (n := len(path.read_text().splitlines())) > MODULE_LINES_MAX}
    assert long == {}


PUBLIC_NAMES_MAX = 120
"""Most names ``datagen/__init__.py`` and the subpackages' ``__all__`` lists may export together: a public surface a
user can hold in their head (docs/architecture.md). Internals are imported from their module."""


def _public_surface() -> dict[str, list[str]]:
    """``__all__`` of ``datagen`` and of each subpackage (every folder of ``datagen/`` with an ``__init__.py``)."""
    names = ["datagen"] + [f"datagen.{p.parent.name}" for p in sorted(PACKAGE.glob("*/__init__.py"))]
    return {name: list(getattr(importlib.import_module(name), "__all__", ["<no __all__>"])) for name in names}


def unresolved(module: types.ModuleType) -> list[str]:
    """Names of ``module.__all__`` that are listed twice or that ``getattr`` does not find (lazy names included)."""
    names = list(module.__all__)
    twice = sorted({n for n in names if names.count(n) > 1})
    return twice + [n for n in names if not hasattr(module, n)]


def test_the_public_surface_stays_small():
    surface = _public_surface()
    assert len(surface) == 13 and all("<no __all__>" not in names for names in surface.values())
    sizes = {name: len(names) for name, names in surface.items()}
    assert sum(sizes.values()) <= PUBLIC_NAMES_MAX, sizes


def test_every_exported_name_resolves():
    bad = {name: u for name in _public_surface() if (u := unresolved(importlib.import_module(name)))}
    assert bad == {}


def test_the_export_check_sees_a_missing_name():
    module = types.ModuleType("fake")
    module.__all__ = ["here", "gone", "here"]
    module.here = 1
    assert unresolved(module) == ["here", "gone"]


def test_import_datagen_and_its_dataset_loader_stay_light():
    """``import datagen`` and ``datagen.NLOSDataset`` in a fresh interpreter: neither numba, Embree, the simulator,
    the transport nor the planner is imported (a training script that reads a dataset pays for none of them), and
    ``import datagen`` alone does not import torch; the kernel cache and threading layer are still set up (through
    numba's environment variables, read when numba loads)."""
    import subprocess
    import sys
    code = ("import sys, json, os; import datagen; light = sorted(m for m in ('torch', 'numba') if m in sys.modules); "
            "datagen.NLOSDataset; heavy = ('numba', 'embreex', 'datagen.simulation.run', 'datagen.transport', "
            "'datagen.planner', 'datagen.scene.raycast', 'datagen.scene.materials'); "
            "print(json.dumps({'light': light, 'loaded': [m for m in heavy if m in sys.modules], "
            "'cache': os.environ.get('NUMBA_CACHE_DIR', ''), 'layer': os.environ.get('NUMBA_THREADING_LAYER_PRIORITY')}))")
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("NUMBA_")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    import json
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["light"] == [] and got["loaded"] == [], got
    assert "numba-" in got["cache"] and got["layer"] == "omp tbb workqueue"
    # and a simulation in a fresh interpreter still finds numba's threading layer and the kernel cache set
    code = ("import datagen, numba; s = datagen.load_scene('scene_library/demo_room.yaml'); "
            "print(numba.config.CACHE_DIR, numba.config.THREADING_LAYER_PRIORITY)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert "numba-" in out.stdout and "['omp', 'tbb', 'workqueue']" in out.stdout, out.stdout


def _unnamed_modules(package: Path) -> dict[str, list[str]]:
    """package folder → its modules and subpackages that its ``__init__`` docstring does not name as ``:mod:``."""
    import re
    out = {}
    for init in sorted(package.rglob("__init__.py")):
        folder = init.parent
        doc = ast.get_docstring(parse_python(init)) or ""
        refs = re.findall(r":mod:`~?([\w.]+)`", doc)
        named = {r.rstrip(".").split(".")[-1] for r in refs} | {r.lstrip(".").split(".")[0] for r in refs}
        children = [p.stem for p in sorted(folder.glob("*.py")) if p.name != "__init__.py"]
        children += [p.name for p in sorted(folder.iterdir()) if (p / "__init__.py").is_file()]
        missing = [c for c in children if c not in named]
        if missing:
            out[str(folder.relative_to(package.parent))] = missing
    return out


def test_every_module_is_named_in_its_packages_docstring():
    """One module map: each package's ``__init__`` docstring names every module and subpackage in it (``:mod:``),
    so a newcomer finds where a thing lives from the package down; docs/architecture.md links to these."""
    assert _unnamed_modules(PACKAGE) == {}


def test_the_module_map_check_sees_an_unnamed_module(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""- :mod:`.named`: here.\n- :mod:`~pkg.sub`: there."""\n')
    (pkg / "named.py").write_text("")
    (pkg / "forgotten.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text('"""A package whose docstring names nothing."""\n')
    (pkg / "sub" / "inner.py").write_text("")
    assert _unnamed_modules(pkg) == {"pkg": ["forgotten"], "pkg/sub": ["inner"]}


def _constructions(root: Path, cls: str) -> list[str]:
    """Every call ``cls(...)`` in the Python files under ``root``: "path:line in function"."""
    out = []

    def visit(node: ast.AST, where: str, path: Path) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            where = node.name
        if (isinstance(node, ast.Call) and isinstance(node.func, (ast.Name, ast.Attribute))
                and (node.func.id if isinstance(node.func, ast.Name) else node.func.attr) == cls):
            out.append(f"{path.relative_to(root.parent)}:{node.lineno} in {where}")
        for child in ast.iter_child_nodes(node):
            visit(child, where, path)

    for path in sorted(root.rglob("*.py")):
        visit(parse_python(path), "<module>", path)
    return out


def test_the_light_tracer_has_one_constructor():
    """One front door to the tracer: ``MultibounceTracer(...)`` is called in ``build_tracer`` only, in the package,
    its tests and its benchmarks (every site passes its settings by keyword there)."""
    sites = [c for folder in (PACKAGE, PACKAGE.parent / "tests", PACKAGE.parent / "benchmarks")
             for c in _constructions(folder, "MultibounceTracer")]
    assert len(sites) == 1 and sites[0].endswith("in build_tracer"), sites


def test_the_constructor_scan_sees_a_second_site(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text("def build_tracer():\n    return MultibounceTracer(1)\n")
    (pkg / "b.py").write_text("import m\n\ndef pilot():\n    return m.MultibounceTracer(2)\n")
    assert [s.split(" in ")[1] for s in _constructions(pkg, "MultibounceTracer")] == ["build_tracer", "pilot"]


def test_every_dependency_has_a_lower_bound_that_the_lower_bound_run_installs_or_explains():
    """docs/development.md, "Dependency ranges": scripts/lower_bounds.py pins each range's lowest release series."""
    spec = importlib.util.spec_from_file_location("lower_bounds", PACKAGE.parent / "scripts" / "lower_bounds.py")
    lower = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lower)
    floors = dict(lower.lower_bound(r) for r in lower.dependencies())
    assert [name for name, floor in floors.items() if floor is None] == []
    pinned = {re.sub(r"\[.*", "", pin.split("==")[0]) for pin in lower.pins()}
    bare = {re.sub(r"\[.*", "", name) for name in floors}
    assert bare == pinned | set(lower.EXEMPT) and not pinned & set(lower.EXEMPT)
    assert "numpy==1.26.*" in lower.pins() and "dask[distributed]==2024.8.*" in lower.pins()
    assert lower.lower_bound("open3d>=0.20,<0.21") == ("open3d", "0.20")
