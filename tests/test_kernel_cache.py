"""numba's kernel cache is keyed by the sources of every module that uses numba (datagen.kernel_cache_dir): numba
itself checks only the file of a kernel, not the inlined device functions it calls from other modules."""
from __future__ import annotations

import numba

from datagen import kernel_cache_dir


def test_cache_key_follows_every_numba_module(tmp_path):
    (tmp_path / "physics.py").write_text("from numba import njit\n\n@njit(inline='always')\ndef f(x):\n    return x\n")
    (tmp_path / "kernel.py").write_text("from numba import njit\nfrom .physics import f\n")
    (tmp_path / "docs.py").write_text("'''no compiled code here'''\n")
    first = kernel_cache_dir(tmp_path)
    assert first.name.startswith("numba-") and len(first.name) == len("numba-") + 16
    (tmp_path / "docs.py").write_text("'''edited, still no compiled code'''\n")
    assert kernel_cache_dir(tmp_path) == first                     # an edit elsewhere keeps the cache
    (tmp_path / "physics.py").write_text("from numba import njit\n\n@njit(inline='always')\ndef f(x):\n    return 2 * x\n")
    assert kernel_cache_dir(tmp_path) != first                     # an inlined formula changed: a new cache


def test_package_uses_its_key():
    import os

    expected = os.environ.get("NUMBA_CACHE_DIR") or str(kernel_cache_dir())
    assert numba.config.CACHE_DIR == expected
    assert kernel_cache_dir().parent.name in ("__pycache__", "datagen")
