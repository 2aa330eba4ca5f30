"""datagen: NLOS SPAD lidar simulation (Scholes & Leach, Sensors 2024) and dataset generation.

Public entry points::

    scene = datagen.load_scene("scene_library/demo_room.yaml")
    result = datagen.simulate(scene, datagen.resolve_config(scene, {"lookins": "10x10"}))
    result.envelope, result.components["box"], result.counts
"""
from .scene import Scene, SceneError, load_scene
from .simulate import Result, SimulationConfig, resolve_config, simulate

__all__ = ["Scene", "SceneError", "load_scene", "Result", "SimulationConfig", "resolve_config", "simulate"]
