"""datagen: NLOS SPAD lidar simulation (Scholes & Leach, Sensors 2024) and dataset generation.

Public entry points::

    scene = datagen.load_scene("scene_library/demo_room.yaml")
    result = datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "10x10"}))
    result.envelope, result.components["box"], result.counts

    # datasets (docs/datasets.md): `datagen build configs/datasets/smoke.yaml --out data/smoke`, then
    ds = datagen.NLOSDataset("data/smoke", split="train", noise="resample")   # a torch Dataset

    # any dataset sample at any accuracy, against the converged reference (docs/accuracy.md)
    scene, config = datagen.sample_setup("configs/datasets/default.yaml", "val", 3)
    reference = datagen.converged_reference(scene, config, rel_tol=3e-3)
    noise = datagen.SPADNoise(ds.detector, exposure=("1ms", "10ms"))          # batched SPAD noise in torch
"""
import hashlib
import os
import shutil
from pathlib import Path


def kernel_cache_dir(package: Path | None = None) -> Path:
    """The folder of numba's compiled-kernel cache for this source tree: ``__pycache__/numba-<key>`` beside the
    package (``~/.cache/datagen/numba-<key>`` when the package folder is read-only), the key a SHA-1 of every module
    of the package that uses numba. numba's own cache checks only the modification time of the file that holds a
    kernel, not of the inlined device functions it calls from other modules (``transport/physics.py``,
    ``scene/brdf_kernel.py``, ``timing/curvature.py``: docs/architecture.md, "Each formula once"), so after an edit
    there a cached kernel would run the old formula; a new key compiles everything afresh (about a minute) instead.
    Set ``NUMBA_CACHE_DIR`` to choose the folder yourself (the key is then not applied)."""
    root = Path(__file__).resolve().parent if package is None else Path(package)
    digest = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text:
            digest.update(str(path.relative_to(root)).encode() + b"\0" + text)
    key = "numba-" + digest.hexdigest()[:16]
    local = root / "__pycache__"
    return local / key if os.access(root, os.W_OK) else Path.home() / ".cache" / "datagen" / key


KEPT_KERNEL_CACHES = 3
"""``numba-<key>`` folders kept in the cache's folder, the current one included: an edit of a numba module (or an
upgrade) starts a new key, and the older keys' kernels (≈ 3 MB each) would otherwise stay for good."""


def prune_kernel_caches(current: Path, keep: int = KEPT_KERNEL_CACHES) -> list[Path]:
    """Delete the ``numba-<key>`` folders beside ``current`` (the kernels of other sources: earlier edits, other
    versions) beyond the ``keep`` − 1 most recently written ones (by their newest file); ``current`` and every other
    name are left alone. Failures (a folder another process deletes or writes meanwhile, permissions) are ignored:
    a deleted cache only means a compile. Returns the folders deleted."""
    def newest(folder: Path) -> float:
        try:
            return max((f.stat().st_mtime for f in folder.rglob("*") if f.is_file()), default=folder.stat().st_mtime)
        except OSError:
            return 0.0

    try:
        others = [p for p in current.parent.glob("numba-*") if p.is_dir() and p != current]
    except OSError:
        return []
    old = sorted(others, key=newest, reverse=True)[max(0, keep - 1):]
    for folder in old:
        shutil.rmtree(folder, ignore_errors=True)
    return old


if not os.environ.get("NUMBA_CACHE_DIR"):
    import numba

    _cache = kernel_cache_dir()
    if not _cache.exists():                              # a new key: the first import after an edit or upgrade
        prune_kernel_caches(_cache)
    numba.config.CACHE_DIR = str(_cache)                 # before any kernel module is imported

from .errors import ConfigError, DatagenError, DatasetError, ResourceError, SceneError  # noqa: E402
from .scene import Scene, load_scene  # noqa: E402
from .simulation import Result, SimulationConfig, resolve_config, simulate, simulate_to_tolerance  # noqa: E402

__all__ = ["Scene", "load_scene", "Result", "SimulationConfig", "resolve_config", "simulate",
           "simulate_to_tolerance", "NLOSDataset", "SPADNoise", "sample_setup", "converged_reference",
           "DatagenError", "SceneError", "ConfigError", "DatasetError", "ResourceError"]


def __getattr__(name: str):
    """``datagen.NLOSDataset`` and ``datagen.SPADNoise`` import torch on first use only (``import datagen`` stays
    light for workers); ``sample_setup`` and ``converged_reference`` load the dataset and analysis layers on
    first use."""
    if name == "NLOSDataset":
        from .dataset import NLOSDataset
        return NLOSDataset
    if name == "SPADNoise":
        from .spad.torch_noise import SPADNoise
        return SPADNoise
    if name == "sample_setup":
        from .dataset import sample_setup
        return sample_setup
    if name == "converged_reference":
        from .analysis import converged_reference
        return converged_reference
    raise AttributeError(f"module 'datagen' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names with the lazy ones (``help(datagen)`` and completion list them)."""
    return sorted(set(globals()) | set(__all__))
