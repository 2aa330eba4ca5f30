"""Mesh assets as hidden objects: the shipped library, placement in rooms, recorded transforms, read errors,
occupancy of meshes; scanned captures in room distributions; orthographic wall-view labels."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from datagen.errors import ConfigError
from datagen.dataset import LabelSpec, load_room_distribution, sample_room, scene_labels
from datagen.dataset.labels import occupancy_grid
from datagen.dataset.sampler import SampledRoom
from datagen.dataset.assets import asset_files, load_asset, place_asset
from datagen.dataset.obb import box_hits_pyramid, yaw_matrix
from datagen.dataset.sampler import STREAMS
from datagen.scene import (CaptureSpec, Laser, Material, RayCaster, Scene, Sensor, quad,
                           resolve_capture)

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets" / "meshes"
WALL = ROOT / "configs" / "rooms" / "wall.yaml"


def rngs_for(seed: int, i: int) -> dict[str, np.random.Generator]:
    return {name: np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, i, k)))
            for k, name in enumerate(STREAMS)}


@pytest.fixture(scope="module")
def wall_dist():
    return load_room_distribution(WALL)


@pytest.fixture(scope="module")
def wall_rooms(wall_dist):
    return [sample_room(wall_dist, rngs_for(5, i)) for i in range(60)]


# --- the shipped library --------------------------------------------------------------------------------------


def test_shipped_library_matches_its_manifest():
    manifest = json.loads((ASSETS / "manifest.json").read_text())
    assert len(manifest["alphanumeric"]) == 36 and len(manifest["primitives"]) >= 5
    total = 0
    for folder, entries in manifest.items():
        for e in entries:
            path = ASSETS / folder / e["file"]
            assert hashlib.sha256(path.read_bytes()).hexdigest() == e["sha256"], path
            asset = load_asset(str(path))
            assert len(asset.faces) == e["triangles"] and asset.watertight == e["watertight"] is True
            extent = asset.vertices.max(0) - asset.vertices.min(0)
            np.testing.assert_allclose(extent.max(), 1.0, rtol=1e-12)          # normalised: longest side 1
            np.testing.assert_allclose(asset.vertices.max(0) + asset.vertices.min(0), 0.0, atol=1e-12)
            total += path.stat().st_size
    assert total < 200 * 1024                                                   # small in git


def test_glyphs_are_upright_and_face_x():
    a = trimesh.load(ASSETS / "alphanumeric" / "T.ply", process=False)
    extent = a.extents
    assert extent[0] < 0.25 and extent[2] == pytest.approx(1.0)        # thin along x, as tall as it is long
    assert a.is_watertight and a.volume > 0                              # outward normals kept
    top = a.vertices[:, 2] > 0.4                                         # the T's bar is at the top and wide
    assert np.ptp(a.vertices[top, 1]) > 0.8


# --- mesh objects in rooms ----------------------------------------------------------------------------------


def test_mesh_objects_are_placed_inside_their_region_and_box(wall_rooms, wall_dist):
    reg = wall_dist.objects.mesh.placement.corridor_end
    gap = wall_dist.objects.min_gap
    seen = set()
    for room in wall_rooms:
        (obj,) = room.objects
        mesh = next(o for o in room.scene.objects if o.name == obj["name"])
        seen.add(Path(obj["asset"]).name)
        x1 = room.params["room"]["relay_x"]
        v = mesh.vertices
        assert v[:, 0].max() <= x1 - reg.min_depth - gap + 1e-9 and v[:, 0].min() >= x1 - reg.depth + gap - 1e-9
        # the oriented bounding box in params is tight around the mesh (vertices in the yaw frame)
        local = (v - obj["center"]) @ yaw_matrix(obj["yaw_deg"])
        np.testing.assert_allclose(local.max(0) - local.min(0), obj["size"], atol=1e-9)
        np.testing.assert_allclose(0.5 * (local.max(0) + local.min(0)), 0.0, atol=1e-9)
        assert 0.5 - 1e-9 <= max(np.ptp(local, axis=0)) / 1.0 <= 0.9 * np.sqrt(3) + 1e-9
        # the recorded file → world transform reproduces the scene's vertices from the file
        file = asset_files(tuple(wall_dist.objects.mesh.assets))[obj["asset_index"]]
        raw = trimesh.load(file, force="mesh", process=False)
        m = np.array(obj["transform"])
        np.testing.assert_allclose(raw.vertices @ m[:3, :3].T + m[:3, 3], v, atol=1e-9)
        # the recorded name is location-free: the file's path from the folder holding the asset entry
        assert not Path(obj["asset"]).is_absolute() and file.endswith("/" + obj["asset"])
        assert obj["asset"] == f"{Path(file).parent.name}/{Path(file).name}"     # e.g. alphanumeric/J.ply
    assert len(seen) >= 20                                              # draws spread over the library


def test_scan_beams_and_view_are_unobstructed(wall_rooms):
    """Every laser point of the 64 × 64 scan is visible from the emitter (resolve_capture checks each beam) and
    the inflated box of the mesh misses the beam pyramid."""
    for room in wall_rooms[:10]:
        capture = resolve_capture(room.scene, RayCaster(room.scene))
        assert capture.kind == "confocal" and capture.spots.shape == (64 * 64, 3)
        scan = room.params["sensor"]["scan"]
        x, cy, cz = scan["laser_grid"]["center"]
        w, h = scan["laser_grid"]["size"]
        base = np.array([[x, cy + a * w / 2, cz + b * h / 2] for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        assert not box_hits_pyramid(room.objects[0], np.array(room.scene.laser.emitter), base)
        # grid order: point (iy, ix) at centre + ((ix+½)/nx − ½)·w·u + ((iy+½)/ny − ½)·h·v, u = +y, v = +z
        grid = capture.spots.reshape(64, 64, 3)
        np.testing.assert_allclose(grid[0, 1] - grid[0, 0], [0.0, w / 64, 0.0], atol=1e-12)
        np.testing.assert_allclose(grid[1, 0] - grid[0, 0], [0.0, 0.0, h / 64], atol=1e-12)


def test_mesh_read_error_names_the_file(tmp_path, wall_dist):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    with pytest.raises(ConfigError, match="broken.obj"):
        load_asset(str(bad))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ConfigError, match=r"objects\.mesh\.assets.*no mesh file"):
        wall_dist.with_overrides({"objects": {"mesh": {"assets": [str(empty)]}}})
    with pytest.raises(ConfigError, match=r"objects\.mesh\.assets: asset folder or file not found: 'nowhere'"):
        wall_dist.with_overrides({"objects": {"mesh": {"assets": ["nowhere"]}}})


def test_wall_family_refuses_room_placement(wall_dist):
    with pytest.raises(ConfigError, match=r"objects\.mesh\.placement\.room\.weight.*no L-bend room"):
        wall_dist.with_overrides({"objects": {"mesh": {"placement": {"room": {"weight": 1.0}}}}})


def test_occupancy_of_a_sphere_asset_matches_its_volume():
    """Voxel centres inside a closed mesh estimate its volume (V/pitch³ within the grid's discretisation)."""
    asset = load_asset(str(ASSETS / "primitives" / "sphere.ply"))
    r_mesh = np.abs(asset.vertices).max()                                # 0.5: unit-diameter icosphere
    verts, _ = place_asset(asset, 0.8, 0.0, 0.0, (0.0, 0.0, 0.0), 0.0)
    obj = {"class": "mesh", "name": "m", "center": [0.0, 0.0, 0.0], "size": [0.8, 0.8, 0.8], "yaw_deg": 0.0}
    pitch = 0.8 / 40
    grid = occupancy_grid([obj], np.array([-0.5, -0.5, -0.5]), pitch, 50, {"m": (verts, asset.faces)})
    volume = trimesh.Trimesh(verts, asset.faces).volume
    assert r_mesh == pytest.approx(0.5)
    assert grid.sum() * pitch ** 3 == pytest.approx(volume, rel=0.03)
    # an open mesh (one face removed) gives the voxels its surface passes through, not its inside
    open_faces = asset.faces[1:]
    shell = occupancy_grid([obj], np.array([-0.5, -0.5, -0.5]), pitch, 50, {"m": (verts, open_faces)})
    assert 0 < shell.sum() < 0.5 * grid.sum() and shell[25, 25, 25] == 0


# --- orthographic wall-view labels --------------------------------------------------------------------------


def scanned_plane_room(distance: float, half: float, points=(20, 16)) -> SampledRoom:
    """Relay wall x = 6 facing −x, a hidden square of half-size ``half`` parallel to it at 6 − distance, centred
    0.3 m off the scan centre along +y, and a confocal scan of 1.6 m × 1.2 m centred at (6, 0, 1.5)."""
    grid = {"center": [6.0, 0.0, 1.5], "size": [1.6, 1.2], "points": list(points)}
    objects = [quad("relay_wall", (6.0, -3.0, -1.0), (0.0, 6.0, 0.0), (0.0, 0.0, 5.0), label="relay_wall"),
               quad("plane", (6.0 - distance, 0.3 - half, 1.5 - half), (0.0, 2 * half, 0.0), (0.0, 0.0, 2 * half),
                    Material(albedo=0.7), label="mesh")]
    scene = Scene(objects, Laser(emitter=(5.8, -1.0, 1.0), spot=(6.0, 0.0, 1.5)), Sensor(position=(5.8, -1.0, 1.0)),
                  capture=CaptureSpec(type="confocal", laser_grid=grid))
    params = {"label_region": {"origin": [0.0, -3.0, 0.0], "size": [6.0, 6.0, 3.0]},
              "sensor": {"scan": {"type": "confocal", "convention": "aperture", "laser_grid": grid,
                                  "sensor_grid": None}}}
    obj = {"class": "mesh", "name": "plane", "center": [6.0 - distance, 0.3, 1.5], "size": [1e-3, 2 * half, 2 * half],
           "yaw_deg": 0.0, "material": {"kind": "lambertian", "albedo": 0.7}}
    return SampledRoom(scene, params, [obj])


def test_wall_view_of_a_parallel_plane_is_its_distance_on_its_footprint():
    d, half = 0.8, 0.35
    labels = scene_labels(scanned_plane_room(d, half), LabelSpec(max_objects=2, depth_map=(8, 8), voxels=4))
    depth, mask = labels["wall_depth"], labels["wall_mask"]
    assert depth.shape == (16, 20) and mask.shape == (2, 16, 20)        # (H, W) = scan grid (ny, nx)
    # pixel (i, j) centre: y = ((j+½)/20 − ½)·1.6, z = 1.5 + ((i+½)/16 − ½)·1.2
    y = ((np.arange(20) + 0.5) / 20 - 0.5) * 1.6
    z = 1.5 + ((np.arange(16) + 0.5) / 16 - 0.5) * 1.2
    inside = (np.abs(y[None, :] - 0.3) < half) & (np.abs(z[:, None] - 1.5) < half)
    assert 0 < inside.sum() < inside.size
    np.testing.assert_allclose(depth[inside], d, rtol=1e-6)
    assert np.all(depth[~inside] == 0.0)
    np.testing.assert_array_equal(mask[0], inside.astype(np.uint8))
    assert not mask[1].any()
    np.testing.assert_allclose(labels["wall_albedo"][inside], 0.7, rtol=1e-6)
    np.testing.assert_array_equal(labels["wall_normal"][inside], np.broadcast_to([1.0, 0.0, 0.0], (inside.sum(), 3)))
    # an explicit resolution resamples the same rectangle
    fine = scene_labels(scanned_plane_room(d, half), LabelSpec(max_objects=2, depth_map=(8, 8), voxels=4,
                                                               wall_view=(32, 40)))
    assert fine["wall_depth"].shape == (32, 40)
    none = scene_labels(scanned_plane_room(d, half), LabelSpec(max_objects=2, depth_map=(8, 8), voxels=4,
                                                               wall_view="none"))
    assert "wall_depth" not in none


def test_wall_view_ignores_room_surfaces():
    """A ray whose first hit is a room wall (not a hidden object) is background."""
    room = scanned_plane_room(0.8, 0.35)
    objects = room.scene.objects + [quad("far", (4.0, -3.0, -1.0), (0.0, 6.0, 0.0), (0.0, 0.0, 5.0), label="wall")]
    scene = Scene(objects, room.scene.laser, room.scene.sensor, capture=room.scene.capture)
    labels = scene_labels(SampledRoom(scene, room.params, room.objects), LabelSpec(max_objects=1, voxels=4))
    assert labels["wall_mask"].sum() == (labels["wall_depth"] > 0).sum() > 0
    assert labels["wall_depth"].max() == pytest.approx(0.8, rel=1e-6)


def test_config_fingerprint_does_not_depend_on_where_the_checkout_lives(tmp_path):
    """The loaded config holds the mesh asset folder as an absolute path (workers need it); the fingerprint that
    resume and verify compare is the same for a copy of the configs and assets elsewhere."""
    import shutil
    from datagen.dataset import load_dataset_config
    for part in ("configs", "assets"):
        shutil.copytree(ROOT / part, tmp_path / "elsewhere" / part)
    here = load_dataset_config(ROOT / "configs/datasets/wall.yaml")
    there = load_dataset_config(tmp_path / "elsewhere/configs/datasets/wall.yaml")
    assert here.room["objects"]["mesh"]["assets"] != there.room["objects"]["mesh"]["assets"]   # absolute, differ
    assert here.fingerprint() == there.fingerprint()
    moved = there.model_copy(update={"seed": there.seed + 1})
    assert moved.fingerprint() != here.fingerprint()                                         # still a fingerprint


def test_room_overrides_assets_resolve_against_the_config_folder(tmp_path, monkeypatch):
    """Mesh assets given in a dataset's ``room_overrides`` (configs/datasets/lct_release_charts.yaml: the charts alone)
    are found against the config file's folder from any working directory, replace the room's list, and hash
    location-free like the room's; one that exists nowhere is a ConfigError naming the field and the entry."""
    import shutil
    from datagen.dataset import load_dataset_config
    for part in ("configs", "assets"):
        shutil.copytree(ROOT / part, tmp_path / "elsewhere" / part)
    monkeypatch.chdir(tmp_path)                                       # neither checkout's root
    here = load_dataset_config(ROOT / "configs/datasets/lct_release_charts.yaml")
    there = load_dataset_config(tmp_path / "elsewhere/configs/datasets/lct_release_charts.yaml")
    files = here.room_distribution("val").objects.mesh.assets
    assert len(files) == 15 and all(Path(f).is_file() and Path(f).parent == ROOT / "assets/meshes/cutouts"
                                    for f in files)
    assert {Path(f).stem.split("_")[0] for f in files} == {"dots", "bars"}     # the charts alone
    assert here.fingerprint() == there.fingerprint()
    data = yaml.safe_load((ROOT / "configs/datasets/lct_release_charts.yaml").read_text())
    data["room_overrides"]["objects"]["mesh"]["assets"][0] = "../../assets/meshes/cutouts/no_such_chart.ply"
    with pytest.raises(ConfigError, match=r"room_overrides: objects.mesh.assets: .*'../../assets/meshes/cutouts/"
                                          r"no_such_chart.ply'"):
        load_dataset_config(data, base_dir=ROOT / "configs/datasets")
    data["room_overrides"]["objects"]["mesh"]["assets"][0] = "../../assets/meshes/cutouts/dots_2x2_30.ply"
    data["splits"]["val"]["room_overrides"] = {"objects": {"mesh": {"assets": ["../../assets/meshes/cutouts"]}}}
    split = load_dataset_config(data, base_dir=ROOT / "configs/datasets")     # a split's list, against the same folder
    assert split.room_distribution("val").objects.mesh.assets == [str(ROOT / "assets/meshes/cutouts")]
