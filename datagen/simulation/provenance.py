"""Provenance of results: the versions of Python and of the libraries a result depends on, recorded in every
result's and every dataset card's attributes (``attrs["versions"]``)."""
from __future__ import annotations

import functools
import platform
from importlib import metadata


def library_versions() -> dict[str, str]:
    """Versions of Python and the libraries a result depends on (recorded in every result's attributes); read
    once per process (``importlib.metadata`` scans the installed distributions: ≈ 8 ms a call)."""
    return dict(_library_versions())


@functools.lru_cache(maxsize=1)
def _library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("datagen", "numpy", "scipy", "trimesh", "embreex", "zarr", "pydantic", "torch"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out
