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

Package map, in data-flow order (docs/architecture.md; each package's ``__init__`` names its modules):
:mod:`.scene` (geometry, materials, laser, sensor, capture), :mod:`.sampling` (lookins, hemisphere cameras,
surface points), :mod:`.planner` (the effects and orders a scene calls for), :mod:`.transport` (estimators of the
path integral), :mod:`.timing` (time axis, IRF, binning), :mod:`.spad` (the detector), :mod:`.simulation` (the
main job, scene to result), :mod:`.io` (result stores, lab and tal files), :mod:`.dataset` (builds, stores, the
torch loader), :mod:`.analysis` (accuracy, references, reconstructions), :mod:`.plot` (figures), :mod:`.cli` (the
``datagen`` command). Shared modules: :mod:`.errors` (the error classes and warnings), :mod:`.validate` (checks of
arrays read from outside), :mod:`.units` (constants, unit parsing), :mod:`.vectors` (vector helpers),
:mod:`.threads` (numba's threads), :mod:`.processes` (child processes that die with their parent), :mod:`.lazy`
(package names imported on first use).
"""
import hashlib
import os
import shutil
import sys
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


def _use_kernel_cache() -> None:
    """Point numba's cache at :func:`kernel_cache_dir` unless ``NUMBA_CACHE_DIR`` is set: through the environment
    (numba reads it when first imported, here or in a worker process), or on numba's config when numba is already
    imported. numba itself is not imported here: ``import datagen`` stays light."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    cache = kernel_cache_dir()
    if not cache.exists():                               # a new key: the first import after an edit or upgrade
        prune_kernel_caches(cache)
    numba = sys.modules.get("numba")
    if numba is not None:
        numba.config.CACHE_DIR = str(cache)              # before any kernel module is imported
    else:
        os.environ["NUMBA_CACHE_DIR"] = str(cache)


_use_kernel_cache()

from . import threads  # noqa: E402,F401  (numba's threading layer, set through its environment: numba not imported)

from .errors import ConfigError, DatagenError, DatasetError, ResourceError, SceneError  # noqa: E402
from .lazy import lazy_attributes  # noqa: E402

__all__ = ["Scene", "load_scene", "Result", "SimulationConfig", "resolve_config", "simulate",
           "simulate_to_tolerance", "NLOSDataset", "SPADNoise", "sample_setup", "converged_reference",
           "DatagenError", "SceneError", "ConfigError", "DatasetError", "ResourceError"]

_LAZY = {"Scene": "scene", "load_scene": "scene", "Result": "simulation", "SimulationConfig": "simulation",
         "resolve_config": "simulation", "simulate": "simulation", "simulate_to_tolerance": "simulation",
         "NLOSDataset": "dataset.loader", "SPADNoise": "spad.torch_noise", "sample_setup": "dataset.sample_scene",
         "converged_reference": "analysis.reference"}
"""Public names loaded on first use (module under ``datagen``): ``import datagen`` imports neither numba nor the
simulator, so a training script that only reads a dataset (``datagen.NLOSDataset``) pays for neither."""


__getattr__ = lazy_attributes(__name__, _LAZY)


def __dir__() -> list[str]:
    """The module's names with the lazy ones (``help(datagen)`` and completion list them)."""
    return sorted(set(globals()) | set(__all__))
