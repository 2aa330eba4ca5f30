"""The estimator registry is the only place that knows estimators by name (docs/architecture.md, "Adding an
estimator"): budget, run, accuracy, view and the command line ask the registry entry, never compare a name.

The AST test walks every module of the package outside ``datagen/transport`` (where the estimators register
themselves) and fails on any comparison (``==``, ``!=``, ``in``, ``not in``, ``is``) one of whose operands is a
registered estimator's name as a string literal, or a tuple / list / set holding one: ``config.estimator ==
"area"``, ``kind in ("lookin", "area")``. Choosing an estimator by looking its name up in the registry
(``estimator("lookin")``) is not a comparison and stays allowed.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import datagen
from conftest import patch_scene
from datagen.simulation import SimulationConfig, simulation_memory
from datagen.transport import estimator, estimator_names
from conftest import parse_python

PACKAGE = Path(datagen.__file__).parent


def _name_literal(node: ast.AST, names: set[str]) -> bool:
    if isinstance(node, ast.Constant):
        return node.value in names
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return any(_name_literal(e, names) for e in node.elts)
    return False


def name_branches(root: Path, names: set[str]) -> list[str]:
    """``path:line: source`` of every comparison with an estimator name literal under ``root``, outside
    ``transport/``."""
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] == "transport":
            continue
        for node in ast.walk(parse_python(path)):
            if isinstance(node, ast.Compare) and any(_name_literal(n, names)
                                                     for n in (node.left, *node.comparators)):
                found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
            if isinstance(node, ast.match_case) and _name_literal(getattr(node.pattern, "value", None), names):
                found.append(f"{rel}:{node.pattern.lineno}: case {ast.unparse(node.pattern)}")
    return found


def test_no_estimator_name_branch_outside_the_registry():
    names = set(estimator_names())
    assert names == {"lookin", "area", "quadrature"}
    assert name_branches(PACKAGE, names) == []


def test_the_scan_finds_a_name_branch(tmp_path):
    """The scan is not vacuous: the forms it must catch are caught, a registry look-up is not."""
    (tmp_path / "simulation").mkdir()
    (tmp_path / "simulation" / "x.py").write_text(
        "def f(config, kind):\n"
        "    if config.estimator == 'lookin':\n        pass\n"
        "    if kind in ('area', 'other'):\n        pass\n"
        "    match kind:\n        case 'quadrature':\n            pass\n"
        "    return estimator('lookin')\n")
    (tmp_path / "transport").mkdir()
    (tmp_path / "transport" / "y.py").write_text("ok = 'area' == 'area'\n")
    found = name_branches(tmp_path, {"lookin", "area", "quadrature"})
    assert [f.split(":")[:2] for f in found] == [["simulation/x.py", "2"], ["simulation/x.py", "4"],
                                                  ["simulation/x.py", "7"]]


@pytest.mark.parametrize("name", ["lookin", "area", "quadrature"])
def test_memory_terms_come_from_the_entry(name):
    """simulation_memory = the shared terms + exactly the terms the estimator's entry gives (nothing by name)."""
    options = {"lookin": {"lookins": (8, 8), "pixels": (12, 12)}, "area": {"samples": 4096},
               "quadrature": {"edge": 0.1, "secondary_samples": 4096}}[name]
    config = SimulationConfig(estimator={"kind": name, **options}, secondary="full", workers=2)
    scene, entry = patch_scene(), estimator(name)
    own = entry.memory(scene, config, 1, 1)
    terms = simulation_memory(scene, config)
    assert all(t in terms for t in own) and len(terms) == 3 + len(own)
    fields = {t[0] for t in own}
    assert fields == {"lookin": {"estimator.lookins", "estimator.pixels"}, "area": {"estimator.samples"},
                      "quadrature": {"estimator.secondary_samples", "estimator.edge"}}[name]
    assert entry.casts_lookins == (name == "lookin")
