"""Package attributes imported on first use, so that importing a package loads none of its heavy modules.

``import datagen`` (and ``datagen.dataset``, ``datagen.scene``, ``datagen.simulation``) binds every public name lazily:
a script that only reads a dataset (``datagen.NLOSDataset``) never imports numba, Embree or the simulator
(``tests/test_architecture.py`` checks it in a fresh interpreter).
"""
from __future__ import annotations

import importlib
import sys
from collections.abc import Callable


def lazy_attributes(package: str, table: dict[str, str]) -> Callable[[str], object]:
    """A module ``__getattr__`` for ``package``: name → the attribute of that name in the submodule ``table[name]``
    (relative to ``package``), imported on first use and then bound in the package (later uses are plain lookups).

    Raises (from the returned function):
        AttributeError: a name not in ``table``.
    """
    def __getattr__(name: str):
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)
        return value
    return __getattr__
