"""Each leg weight and each BRDF formula is written once, and no compiled kernel takes more than 16 arguments.

The rule (docs/architecture.md, "Each formula once"): every leg weight of docs/physics.md §2 and every BRDF is a
numba device function in the module that models it (:data:`FORMULAS`: ``datagen/scene/brdf_kernel.py`` for the
BRDFs, ``datagen/transport/physics.py`` for the legs); compiled kernels call it, numpy code calls it through
``datagen.scene.brdf_kernel.on_arrays``. The test parses every module of ``datagen/`` except
``datagen/analysis/oracle.py`` (the brute-force oracle of the tests, which writes the formulas again on purpose) and
looks for the expression *shapes* that characterise each formula (:data:`SHAPES`):

- ``lambertian``: an albedo divided by π (``rho / math.pi``, ``albedo[o] / np.pi``);
- ``sin_theta``: one half times an albedo (``0.5 * rho``);
- ``phong``: the lobe's normalisation (e + 2)/(2π);
- ``ggx``: the GGX distribution's α² / (π (t·t)) (the retroreflective lobe);
- ``attenuation``: exp of minus μ times a length (``np.exp(-mu * path)``);
- ``collection``: a product holding the detection efficiency ``pde`` and a cosine;
- ``irradiance``: a product holding ``photons`` and a cosine;
- ``inverse_square``: a cosine-weighted expression divided by r² (``… cos … / r ** 2``) or multiplied by
  ``inv * inv`` (the geometric factor, the laser irradiance, the FoV connection, the sensor collection);

A shape found in a function that is not one of its home functions (:data:`HOMES`) is a copy of a formula, and
the test fails naming it, unless :data:`ALLOWED` lists that function with its reason (an expression of the same
shape that is not that formula, or a copy kept on purpose). Pasting ``photons * f * cos / r ** 2`` into a kernel,
or ``rho / np.pi`` into a numpy path, therefore fails the test. The geometry that feeds the formulas (dot
products, the mirror direction, the azimuth of the sin θ kind) is not a formula here: numpy's ``einsum`` sums
three products in another order than a scalar loop, so the numpy and compiled paths each compute their own.
"""
from __future__ import annotations

import ast
from pathlib import Path

import datagen
from conftest import parse_python

ROOT = Path(datagen.__file__).parent
ORACLE = "analysis/oracle.py"
MAX_KERNEL_ARGS = 16

FORMULAS = {
    "scene/brdf_kernel.py": ("lambertian_value", "sin_theta_scale", "sin_theta_value", "phong_gloss", "phong_value",
                             "phong_diffuse_scale", "phong_power", "phong_cos_alpha", "abs_sin_azimuth",
                             "ggx_ndf", "smith_lambda", "retro_cos_h", "retro_lobe", "retro_value", "retro_pdf",
                             "retro_sample", "sampling_ratio", "brdf_value"),
    "transport/physics.py": ("emission_term", "irradiance_term", "geometry_term", "fov_term", "collection_term",
                             "direct_term", "launched_flux", "attenuation_term"),
}
"""The formula functions: numba device functions (``inline="always"``), one per formula."""

HOMES = {
    "lambertian": {("scene/brdf_kernel.py", "lambertian_value"), ("scene/brdf_kernel.py", "phong_diffuse_scale")},
    "sin_theta": {("scene/brdf_kernel.py", "sin_theta_scale")},
    "phong": {("scene/brdf_kernel.py", "phong_gloss")},
    "ggx": {("scene/brdf_kernel.py", "ggx_ndf")},
    "attenuation": {("transport/physics.py", "attenuation_term")},
    "collection": {("transport/physics.py", "collection_term"), ("transport/physics.py", "direct_term")},
    "irradiance": {("transport/physics.py", "irradiance_term"), ("transport/physics.py", "direct_term")},
    "inverse_square": {("transport/physics.py", name) for name in
                       ("irradiance_term", "geometry_term", "fov_term", "collection_term", "direct_term")},
}
"""Where each shape is written: the formula functions that define it."""

ALLOWED = {
    ("planner/decisions.py", "_decide_brdf_angles"): "the planner's message text quotes f = ρ/π of a material",
    ("io/tal.py", "scene_from_tal_config"): "tal's laser normalisation π·E·cosθ_e/d², a file-format convention, not a leg",
    ("plot/energy.py", "lookin_energy"): "the figure's f·cos/r² of the paper's illustration (docs/physics.md §2)",
}
"""Functions that write a shape of another formula, with the reason (see the module doc)."""


def _ident(node: ast.AST) -> str:
    """The identifier of a name, attribute or subscript (``albedo[o]`` → ``albedo``, ``self.pde`` → ``pde``)."""
    while isinstance(node, ast.Subscript):
        node = node.value
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return ""


def _names(node: ast.AST) -> set[str]:
    return {_ident(n) for n in ast.walk(node) if isinstance(n, (ast.Name, ast.Attribute))} - {""}


def _is_pi(node: ast.AST) -> bool:
    return _ident(node) == "pi"


def _albedo(node: ast.AST) -> bool:
    return any(k in n.lower() for n in _names(node) for k in ("albedo", "rho")) and not isinstance(node, ast.Call)


def _has_cos(node: ast.AST) -> bool:
    return any("cos" in n for n in _names(node))


def _product(node: ast.AST) -> list[ast.AST]:
    """The factors of a chain of * and / (the divisors too)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Mult, ast.Div)):
        return _product(node.left) + _product(node.right)
    return [node]


def _square(node: ast.AST) -> bool:
    """``x ** 2`` or ``inv * inv``."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
        return isinstance(node.right, ast.Constant) and node.right.value == 2
    return (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult)
            and ast.dump(node.left) == ast.dump(node.right) and isinstance(node.left, (ast.Name, ast.Subscript)))


def _shapes(node: ast.AST) -> set[str]:
    """The formula shapes ``node`` (one expression node, not its children) writes."""
    out = set()
    if isinstance(node, ast.BinOp):
        op, left, right = node.op, node.left, node.right
        if isinstance(op, ast.Div) and _is_pi(right) and _albedo(left):
            out.add("lambertian")
        if isinstance(op, ast.Mult) and isinstance(left, ast.Constant) and left.value == 0.5 and _albedo(right):
            out.add("sin_theta")
        if (isinstance(op, ast.Div) and isinstance(left, ast.BinOp) and isinstance(left.op, ast.Add)
                and isinstance(left.right, ast.Constant) and left.right.value == 2.0
                and isinstance(right, ast.BinOp) and isinstance(right.op, ast.Mult)
                and isinstance(right.left, ast.Constant) and right.left.value == 2.0 and _is_pi(right.right)):
            out.add("phong")
        if (isinstance(op, ast.Div) and isinstance(right, ast.BinOp) and isinstance(right.op, ast.Mult)
                and _is_pi(right.left) and _square(right.right)):
            out.add("ggx")
        if isinstance(op, ast.Div) and _square(right) and _has_cos(left):
            out.add("inverse_square")
        if isinstance(op, ast.Mult) and _square(right) and _has_cos(left):
            out.add("inverse_square")
        if isinstance(op, (ast.Mult, ast.Div)):
            idents = {_ident(f) for f in _product(node)}
            cos = any(_has_cos(f) for f in _product(node))
            if "pde" in idents and cos:
                out.add("collection")
            if "photons" in idents and cos:
                out.add("irradiance")
    if isinstance(node, ast.Call) and _ident(node.func) == "exp" and node.args:
        arg = node.args[0]
        first = _product(arg)[0] if isinstance(arg, ast.BinOp) else arg
        if isinstance(first, ast.UnaryOp) and isinstance(first.op, ast.USub) and "mu" in _ident(first.operand):
            out.add("attenuation")
    return out


def _functions(tree: ast.Module):
    """(qualified name, node) of every function, outermost first; nested functions are scanned as their own."""
    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                yield name, child
                yield from visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                yield from visit(child, prefix + child.name + ".")
            else:
                yield from visit(child, prefix)
    yield from visit(tree, "")


def _modules():
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel != ORACLE:
            yield rel, parse_python(path)


def formula_sites() -> dict[str, set[tuple[str, str]]]:
    """Shape → {(module, function)} of every function of datagen/ (but the oracle) that writes it."""
    sites: dict[str, set[tuple[str, str]]] = {}
    for rel, tree in _modules():
        for name, fn in _functions(tree):
            own = [n for n in ast.walk(fn) if n is not fn]
            nested = {id(n) for f in own if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                      for n in ast.walk(f)}
            for node in own:
                if id(node) in nested:
                    continue
                for shape in _shapes(node):
                    sites.setdefault(shape, set()).add((rel, name.split(".")[-1] if "." in name else name))
    return sites


def test_each_formula_shape_is_written_in_its_formula_function_only():
    sites = formula_sites()
    copies = {shape: sorted(found - HOMES[shape] - set(ALLOWED)) for shape, found in sites.items()}
    assert not any(copies.values()), f"formulas written outside their formula function: {copies}"
    for shape, homes in HOMES.items():
        assert homes <= sites.get(shape, set()), f"{shape}: the detector no longer finds {homes - sites[shape]}"


def test_the_detectors_catch_a_pasted_copy(tmp_path):
    pasted = ast.parse("def kernel(photons, f, cos_l, cos_in, r, rho, mu, path, pde, area, cos_ap, d, expo):\n"
                       "    e = photons * (f * cos_l) * cos_in / r ** 2\n"
                       "    lamb = rho / math.pi\n"
                       "    half = 0.5 * rho\n"
                       "    norm = (expo + 2.0) / (2.0 * math.pi)\n"
                       "    ndf = a2 / (math.pi * (t * t))\n"
                       "    att = math.exp(-mu * path)\n"
                       "    out = pde * f * cos_ap * area / d ** 2\n")
    found = set()
    for node in ast.walk(pasted):
        found |= _shapes(node)
    assert found == set(HOMES)


def test_formula_functions_are_inline_device_functions():
    trees = dict(_modules())
    for rel, names in FORMULAS.items():
        defs = {fn.name: fn for fn in ast.walk(trees[rel]) if isinstance(fn, ast.FunctionDef)}
        for name in names:
            decorators = [ast.unparse(d) for d in defs[name].decorator_list]
            assert any("njit" in d and 'inline="always"' in d.replace("'", '"') for d in decorators), (rel, name)


def _decorator_name(d: ast.expr) -> str:
    """The called name of a decorator: ``njit`` of ``@numba.njit(cache=True)``, ``option`` of ``@click.option(…)``."""
    d = d.func if isinstance(d, ast.Call) else d
    return d.attr if isinstance(d, ast.Attribute) else d.id if isinstance(d, ast.Name) else ""


def test_no_compiled_kernel_takes_more_than_16_arguments():
    too_many = []
    for rel, tree in _modules():
        for name, fn in _functions(tree):
            if not any(_decorator_name(d) in ("njit", "jit", "vectorize") for d in fn.decorator_list):
                continue                    # by the decorator's name: a click option's help saying "jitter" is none
            a = fn.args
            n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
            if n > MAX_KERNEL_ARGS:
                too_many.append((rel, name, n))
    assert not too_many, f"compiled functions with more than {MAX_KERNEL_ARGS} arguments: {too_many}"
