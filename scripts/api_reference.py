"""Write the API reference pages docs/reference/<package>.md: one mkdocstrings entry per name of the public surface
(``__all__`` of ``datagen`` and of each subpackage, as tests/test_architecture.py defines it), pointing at the module
that defines the name so lazily exported names (``datagen.NLOSDataset``) resolve too.

    python scripts/api_reference.py           # rewrite the pages
    python scripts/api_reference.py --check   # exit 1 when a page is out of date (tests/test_docs.py runs this)
"""
from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUBPACKAGES = ("scene", "sampling", "timing", "transport", "spad", "planner", "simulation", "io", "dataset",
               "analysis", "plot", "cli")


def page_name(package: str) -> str:
    """File name of a package's page under docs/reference/ (``top.md`` for ``datagen`` itself)."""
    return "top.md" if package == "datagen" else package.split(".")[-1] + ".md"


def defining_path(package: str, name: str) -> str:
    """Dotted path mkdocstrings can collect for ``package.name``: the class's or function's own module, else the
    package path (constants)."""
    obj = getattr(importlib.import_module(package), name)
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if isinstance(module, str) and module.startswith("datagen") and qualname == name:
        return f"{module}.{name}"
    return f"{package}.{name}"


ROLE = re.compile(r":(?:mod|class|func|meth|attr|data|exc):`~?([^`]+)`")


def package_doc(module) -> str:
    """The package docstring as Markdown: what the stage does and its module map (each module named once, as
    tests/test_architecture.py checks); Sphinx roles (``:mod:`.physics```) become code spans."""
    paragraphs = [p.replace("\n", " ") if not p.lstrip().startswith("- ") else p
                  for p in (module.__doc__ or "").strip().split("\n\n")]
    return ROLE.sub(r"`\1`", "\n\n".join(paragraphs))


def page(package: str) -> str:
    """The Markdown of one package's reference page: its docstring (the module map), then its public names."""
    module = importlib.import_module(package)
    lines = [f"# `{package}`", "", package_doc(module), "",
             f"Every name of `{package}.__all__` with its docstring (generated from the source by mkdocstrings; "
             "`python scripts/api_reference.py` rewrites this page).", ""]
    for name in module.__all__:
        lines += [f"::: {defining_path(package, name)}", "    options:", f"      heading: \"{name}\"", ""]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    stale = []
    for package in ("datagen", *(f"datagen.{p}" for p in SUBPACKAGES)):
        path = ROOT / "docs" / "reference" / page_name(package)
        text = page(package)
        if "--check" in argv:
            if not path.exists() or path.read_text() != text:
                stale.append(str(path.relative_to(ROOT)))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    if stale:
        print("out of date (run python scripts/api_reference.py):", ", ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
