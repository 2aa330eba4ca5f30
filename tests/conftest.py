"""Shared fixtures: small analytic scenes, and rooms drawn from configs/rooms/wall.yaml."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from datagen.scene import Material
from datagen.scene import FieldOfView, Laser, Scene, Sensor, box, quad

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("DATAGEN_REAL_CAPTURES", ROOT.parent / "shared" / "real"))
"""The Stanford LCT release's captures (never shipped): $DATAGEN_REAL_CAPTURES or ../shared/real; tests that read
them skip, saying why, when they are absent."""
NEEDS_REAL = pytest.mark.skipif(not (REAL / "data_dot_chart_40cm.mat").is_file(),
                                reason=f"the Stanford LCT release's captures are not at {REAL} (set "
                                       "DATAGEN_REAL_CAPTURES to the folder holding its data_*.mat files)")


def pytest_sessionstart(session):
    """Compile the numba kernels a dataset sample runs (the quadrature's pair kernel, the shadow map, the fold and
    binning, the detector) before the first test, in each test process: on an empty numba cache (a fresh clone)
    the pair kernel alone compiles for about 70 s, which would otherwise land in whichever test runs it first and
    count against that test's hang guard (pytest-timeout). With a filled cache this takes about a second."""
    from datagen.dataset import load_dataset_config, make_sample

    for name in ("confocal_smoke", "wall_smoke"):
        make_sample(load_dataset_config(ROOT / "configs" / "datasets" / f"{name}.yaml"), "train", 0)


def patch_scene(patch_size: float = 0.4, albedo: float = 0.8, with_occluder: bool = False) -> Scene:
    """Relay wall x = 2 facing −x, laser spot (2, 0, 0); a square Lambertian patch of side ``patch_size``
    centred at (1, 0, 0.5) facing +x (toward the wall); sensor/emitter at (0, 0, −0.5);
    FoV 0.8 m square centred at (2, 0, −0.6). Optionally a box between the patch and the FoV's lower part.
    """
    s = patch_size
    objects = [
        quad("relay_wall", (2.0, -2.0, -2.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0), Material(albedo=0.9),
             label="relay_wall"),
        quad("patch", (1.0, -s / 2, 0.5 - s / 2), (0.0, s, 0.0), (0.0, 0.0, s), Material(albedo=albedo)),
    ]
    if with_occluder:
        objects.append(box("occluder", (1.45, 0.1, 0.1), (0.1, 0.25, 0.25), material=Material(albedo=0.5)))
    return Scene(objects, Laser(emitter=(0.0, 0.0, -0.5), spot=(2.0, 0.0, 0.0)),
                 Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02,
                        fov=FieldOfView(center=(2.0, 0.0, -0.6), size=(0.8, 0.8))))


def wall_room(seed: int, index: int, overrides: dict):
    """A room of configs/rooms/wall.yaml's distribution with ``overrides``
    (:meth:`datagen.dataset.RoomDistribution.with_overrides`), drawn as sample ``index`` of the streams of ``seed``
    (the :func:`datagen.dataset.sample_room` result)."""
    from datagen.dataset import load_room_distribution, sample_room
    from datagen.dataset.sampler import STREAMS

    dist = load_room_distribution(ROOT / "configs" / "rooms" / "wall.yaml").with_overrides(overrides)
    rngs = {name: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, index, k)))
            for k, name in enumerate(STREAMS)}
    return sample_room(dist, rngs)


def box_before_wall(points: int):
    """:func:`wall_room` with ``points`` × ``points`` confocal scan points and the shipped box primitive (0.4–0.6 m,
    upright, facing the wall) as its hidden mesh, drawn with seed 13."""
    box_mesh = str(ROOT / "assets" / "meshes" / "primitives" / "box.ply")
    return wall_room(13, 0, {"capture": {"scan": {"points": [points, points]}},
                             "objects": {"mesh": {"assets": [box_mesh], "yaw_deg": 0.0, "tilt_deg": 0.0,
                                                  "size": {"min": 0.4, "max": 0.6}}}})


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def parse_python(path) -> "ast.Module":
    """``ast.parse`` of a source file, retried on CPython 3.11's spurious "AST constructor recursion depth
    mismatch" SystemError (python/cpython#106905: the AST state is shared, so another thread building an AST at
    the same moment, e.g. a Dask client's thread left by an earlier test in the worker, can trip it)."""
    import ast
    from pathlib import Path

    source = Path(path).read_text(encoding="utf-8")
    for _ in range(4):
        try:
            return ast.parse(source, str(path))
        except SystemError:
            pass
    return ast.parse(source, str(path))                 # the fifth try raises what it raises
