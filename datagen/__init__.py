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
from .errors import ConfigError, DatagenError, DatasetError, ResourceError, SceneError
from .scene import Scene, load_scene
from .simulation import Result, SimulationConfig, resolve_config, simulate, simulate_to_tolerance

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
