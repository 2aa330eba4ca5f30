"""numba's kernel cache is keyed by the sources of every module that uses numba (datagen.kernel_cache_dir): numba
itself checks only the file of a kernel, not the inlined device functions it calls from other modules."""
from __future__ import annotations

import numba

from datagen import KEPT_KERNEL_CACHES, kernel_cache_dir, prune_kernel_caches


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


def test_old_kernel_caches_are_pruned_to_the_most_recent(tmp_path):
    """A new key deletes the other numba-<key> folders beyond the KEPT_KERNEL_CACHES − 1 most recently written
    (by their newest file, not the folder's own time); the current key and other folders are never touched."""
    import os

    assert KEPT_KERNEL_CACHES == 3
    for age, name in enumerate(["numba-a", "numba-b", "numba-c", "numba-d"]):      # numba-a the newest
        sub = tmp_path / name / "transport_x"
        sub.mkdir(parents=True)
        (sub / "kernel.nbi").write_text("index")
        os.utime(sub / "kernel.nbi", (1e9 - 1e5 * age, 1e9 - 1e5 * age))
        os.utime(tmp_path / name, (1e9 + 1e5 * age, 1e9 + 1e5 * age))            # folder times say the opposite
    (tmp_path / "other").mkdir()
    current = tmp_path / "numba-new"
    removed = prune_kernel_caches(current)
    assert sorted(p.name for p in removed) == ["numba-c", "numba-d"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["numba-a", "numba-b", "other"]
    current.mkdir()
    assert prune_kernel_caches(current) == []                                      # current and two others: three
    (tmp_path / "numba-z").mkdir()
    (tmp_path / "numba-z" / "kernel.nbi").write_text("index")                      # written now: the newest
    assert prune_kernel_caches(current) == [tmp_path / "numba-b"]
    assert prune_kernel_caches(tmp_path / "missing" / "numba-x") == []
