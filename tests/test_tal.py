"""tal interop (datagen/io/tal.py, datagen/cli/tal.py): render-YAML translation, HDF5 layout and round trip, and
datagen's tal-render H on the hidden-square scene against an independent area quadrature, for every capture type.

No tal / mitransient here (they live in benchmarks/tal's own venv); the quadrature below is the independent
reference. Primary (third-bounce) light, point-radiance convention, per unit power at the laser spot:

    L(y, t) = ∫_S dA_x  f_w cosθ_l cosθ_x,in / |x − x_l|² · f_s cosθ_x,out cosθ_y,in / |y − x|² · f_w
              · [OPL |x − x_l| + |y − x| in bin t]

and tal render's H = K_l · L with K_l = π·e·cosθ_e/d_e² (datagen/io/tal.py docstring; confirmed against
mitransient in benchmarks/tal/compare.py).
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from datagen.cli.main import main
from datagen.errors import DatasetError
from datagen.errors import SceneError
from datagen.simulation import resolve_config, simulate
from datagen.io import write_result
from datagen.io import read_tal_hdf5, scene_from_tal_yaml, tal_arrays, write_tal_hdf5
from datagen.io.tal import load_tal_config, tal_transform
from datagen.io.tal_hdf5 import GridFormat, HFormat, VolumeFormat

C = 299_792_458.0
BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "tal" / "hidden_square.yaml"
RHO_WALL, RHO_SQUARE = 0.9, 0.6
SQUARE_CENTER = np.array([0.1, -0.05, 1.0])    # off the wall's centre so every axis-order mistake shows
LASER = np.array([-0.5, 0.0, 0.25])

# Tolerances. Both datagen estimators are Monte Carlo; the quadrature is a 200×200 midpoint rule, exact to
# ~1e-5 in totals and to well below these tolerances per 1 cm bin. Seeded errors measured with the settings
# below (max per-point total error, relative L2 over bins above 1 % of the peak):
#   lookin (cosine rays from the spot, ~5 % hit the square): single 256×256: 0.1 %, 2.0 %; confocal 256×256:
#     0.7 %, 3.4 %; exhaustive 384×384: ~0.5 %, ~3.5 %;
#   area (hidden-surface samples, datagen.transport.area), 16 384 samples per laser point: single 0.04 %, 1.0 %;
#     confocal 0.04 %, 1.0 %; exhaustive 0.05 %, 1.5 %;
#   quadrature (datagen.transport.quadrature, default 2 cm edge): per-point totals 0.011 %, 0.20–0.34 % (the reference
#     integrand's own binning error).
# The tolerances are about twice those, so a wrong factor (K, an albedo, a cosine), a transposed grid or a
# shifted time axis fails them by far.
SETTINGS = {"lookin": {"single": {"lookins": "256x256"}, "confocal": {"lookins": "256x256"},
                       "exhaustive": {"lookins": "384x384"}},
            "area": {scan: {"estimator": "area", "area_samples": 16384} for scan in ("single", "confocal", "exhaustive")},
            "quadrature": {scan: {"estimator": "quadrature"} for scan in ("single", "confocal", "exhaustive")}}
TOL = {"lookin": {"single": (0.01, 0.04), "confocal": (0.02, 0.07), "exhaustive": (0.015, 0.07)},
       "area": {"single": (0.003, 0.025), "confocal": (0.003, 0.025), "exhaustive": (0.003, 0.03)},
       "quadrature": {"single": (0.001, 0.006), "confocal": (0.001, 0.006), "exhaustive": (0.001, 0.006)}}
"""estimator → capture type → (per-point total rtol, relative L2 bound)."""


def hidden_square(tmp_path: Path, scan: str, **changes) -> Path:
    """The benchmark's hidden-square YAML, made small: 1 cm bins, grey albedos, off-centre square."""
    cfg = yaml.safe_load(BENCH.read_text())
    cfg.update(scan_type=scan, num_bins=230, bin_width_opl=0.01, start_opl=1.8, sensor_width=4, sensor_height=3,
               laser_width=3, laser_height=2)
    wall = f'<bsdf type="diffuse"><rgb name="reflectance" value="{RHO_WALL}, {RHO_WALL}, {RHO_WALL}"/></bsdf>'
    square = f'<bsdf type="diffuse"><float name="reflectance" value="{RHO_SQUARE}"/></bsdf>'
    cfg["geometry"][0].update(displacement_x=float(SQUARE_CENTER[0]), displacement_y=float(SQUARE_CENTER[1]),
                              material={"id": "custom", "text": square})
    cfg["geometry"][1]["material"] = {"id": "custom", "text": wall}
    if scan == "confocal":
        cfg.update(laser_width=4, laser_height=3)
    cfg.update(changes)
    path = tmp_path / f"{scan}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def quadrature(spot: np.ndarray, points: np.ndarray, edges: np.ndarray, n: int = 200) -> np.ndarray:
    """Point radiance per unit power at ``spot`` leaving each wall point (P, 3) toward the sensor, binned by
    OPL ``edges`` (legs to emitter and sensor not counted): (P, T). Midpoint rule over n×n square elements."""
    g = ((np.arange(n) + 0.5) / n - 0.5) * 0.4
    gx, gy = np.meshgrid(g, g, indexing="ij")
    x = np.stack([gx.ravel(), gy.ravel(), np.zeros(n * n)], axis=-1) + SQUARE_CENTER
    d_a = (0.4 / n) ** 2
    n_wall, n_sq = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    d_l = x - spot
    r_l = np.linalg.norm(d_l, axis=1)
    cos_l = (d_l @ n_wall) / r_l
    cos_x_in = -(d_l @ n_sq) / r_l
    out = np.zeros((len(points), len(edges) - 1))
    for i, y in enumerate(points):
        d = y - x
        r = np.linalg.norm(d, axis=1)
        cos_x_out = (d @ n_sq) / r
        cos_y_in = -(d @ n_wall) / r
        w = (RHO_WALL / np.pi) * cos_l * cos_x_in / r_l ** 2 * (RHO_SQUARE / np.pi) * cos_x_out * cos_y_in / r ** 2 \
            * (RHO_WALL / np.pi) * d_a
        out[i] = np.histogram(r_l + r, bins=edges, weights=w)[0]
    return out


def laser_scale(spot: np.ndarray) -> float:
    """mitransient's K = π·cosθ_e/d_e² for a unit mono emission (datagen/io/tal.py)."""
    d = LASER - spot
    return math.pi * (d[2] / np.linalg.norm(d)) / float(d @ d)


def run(path: Path, lookins: str = "64x64", seed: int = 1, estimator: str = "lookin", **settings):
    """Simulate a tal YAML with the lookin estimator (``lookins``) or the area estimator (``area_samples``)."""
    scene, tal = scene_from_tal_yaml(path)
    overrides = {"estimator": estimator, "seed": seed, **settings}
    if estimator == "lookin":
        overrides["lookins"] = lookins
    result = simulate(scene, resolve_config(scene, overrides))
    return scene, tal, result


def rel_l2(h: np.ndarray, ref: np.ndarray) -> float:
    mask = ref > 0.01 * ref.max()
    return float(np.linalg.norm((h - ref)[mask]) / np.linalg.norm(ref[mask]))


def opl_edges(result) -> np.ndarray:
    return result.time_edges * C


# ---------------------------------------------------------------------------------------------------------
# render YAML → datagen scene


def test_hidden_square_yaml_translates_to_the_scene_tal_renders():
    scene, tal = scene_from_tal_yaml(BENCH)
    square, wall = scene.objects
    assert (square.name, wall.name, wall.label) == ("square", "relay_wall", "relay_wall")
    # 0.4 m square 1 m from the wall (rot_degrees_x 180 flips y), 2 m × 2 m wall in z = 0
    np.testing.assert_allclose(np.sort(square.vertices, axis=0),
                               [[-0.2, -0.2, 1.0], [-0.2, -0.2, 1.0], [0.2, 0.2, 1.0], [0.2, 0.2, 1.0]], atol=1e-12)
    np.testing.assert_allclose(np.ptp(wall.vertices, axis=0), [2.0, 2.0, 0.0])
    assert square.material.albedo == 1.0 and wall.material.kind == "lambertian"
    cap = scene.capture
    assert (cap.type, cap.convention, cap.sensor_grid.points, cap.sensor_grid.size) == (
        "single", "point_radiance", (16, 16), (2.0, 2.0))
    assert scene.laser.spot == (0.0, 0.0, 0.0) and scene.laser.emitter == (-0.5, 0.0, 0.25)
    t = scene.defaults["time"]
    assert t["n_bins"] == 768 and math.isclose(t["bin_width"] * C, 0.003) and math.isclose(t["t_start"] * C, 1.8)
    assert scene.defaults["count_laser_leg"] is False and scene.defaults["count_sensor_leg"] is False
    assert scene.defaults["irf"] == {"sigma": 0.0} and scene.defaults["secondary"] == "none"
    # tal's sensor grid (tal.render.util.get_grid_xyz): x grows with the first index
    assert tal.sensor_grid_xyz.shape == (16, 16, 3)
    np.testing.assert_allclose(tal.sensor_grid_xyz[0, 0], [-0.9375, -0.9375, 0.0])
    np.testing.assert_allclose(tal.sensor_grid_xyz[1, 0], [-0.8125, -0.9375, 0.0])
    # K = π cosθ_e / d_e² = π (0.25/√0.3125) / 0.3125 for the mono emission 1.0
    assert math.isclose(float(tal.laser_scale[0, 0]), math.pi * 0.25 / 0.3125 ** 1.5, rel_tol=1e-12)


def test_tal_transform_is_mitsubas_scale_rotate_translate_order():
    m = tal_transform({"scale_x": 2.0, "rot_degrees_z": 90.0, "displacement_x": 1.0})
    # scale first (x → 2x), then +90° about z (x → y), then translate
    np.testing.assert_allclose(m[:3, :3] @ [1.0, 0.0, 0.0] + m[:3, 3], [1.0, 2.0, 0.0], atol=1e-12)
    m = tal_transform({"rot_degrees_x": 90.0, "rot_degrees_y": 90.0})
    # R_y·R_x: y → z (about x), then z → x (about y)
    np.testing.assert_allclose(m[:3, :3] @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
    assert np.allclose(tal_transform({}), np.eye(4))


def test_rgb_variant_sums_channels_and_custom_albedo_is_read(tmp_path):
    path = hidden_square(tmp_path, "single", mitsuba_variant="llvm_ad_rgb", laser_emission_mode="rgb",
                         laser_emission="1.0, 0.5, 0.25")
    scene, tal = scene_from_tal_yaml(path)
    assert [o.material.albedo for o in scene.objects] == [RHO_SQUARE, RHO_WALL]
    spot = np.array([0.0, 0.0, 0.0])
    assert math.isclose(float(tal.laser_scale[0, 0]), 1.75 * laser_scale(spot), rel_tol=1e-12)
    path = hidden_square(tmp_path, "single", mitsuba_variant="llvm_mono", laser_emission_mode="rgb",
                         laser_emission="1.0, 1.0, 1.0")
    # mono variants use the luminance of an RGB value: 1 for white
    assert math.isclose(float(scene_from_tal_yaml(path)[1].laser_scale[0, 0]), laser_scale(spot), rel_tol=1e-5)


def test_obj_and_ply_meshes_load_with_tal_transforms(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.export(tmp_path / "box.obj")
    box.export(tmp_path / "box.ply")
    cfg = yaml.safe_load(BENCH.read_text())
    entry = {"name": "b", "mesh": {"type": "obj", "filename": "box.obj"}, "scale_x": 0.1, "scale_y": 0.1,
             "scale_z": 0.1, "rot_degrees_z": 90.0, "displacement_z": 1.0, "material": {"id": "white"}}
    cfg["geometry"] = [entry, dict(entry, name="p", mesh={"type": "ply", "filename": "box.ply"},
                                   displacement_x=0.5), cfg["geometry"][1]]
    (tmp_path / "meshes.yaml").write_text(yaml.safe_dump(cfg))
    scene, _ = scene_from_tal_yaml(tmp_path / "meshes.yaml")
    assert [o.name for o in scene.objects] == ["b", "p", "relay_wall"]
    b, p = scene.objects[:2]
    # extents (0.1, 0.2, 0.3) rotated 90° about z → (0.2, 0.1, 0.3), centred at (0, 0, 1) and (0.5, 0, 1)
    np.testing.assert_allclose(np.ptp(b.vertices, axis=0), [0.2, 0.1, 0.3], atol=1e-12)
    np.testing.assert_allclose(b.vertices.mean(axis=0), [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(p.vertices.mean(axis=0), [0.5, 0.0, 1.0], atol=1e-12)
    assert len(b.faces) == 12 and len(p.faces) == 12


@pytest.mark.parametrize("change, message", [
    ({"geometry0_mesh": {"type": "sphere"}}, "geometry.0.mesh.type: Input should be 'rectangle', 'obj' or 'ply' (got "
                                             "'sphere')"),
    ({"geometry0_mesh": {"type": "obj"}}, "geometry.0.mesh: an obj mesh needs a filename"),
    ({"geometry0_material": {"id": "copper", "alpha": "0.1"}},
     "geometry.0.material.id: Input should be 'white' or 'custom' (got 'copper')"),
    ({"geometry0_material": {"id": "custom", "text": '<bsdf type="roughconductor"/>'}},
     "geometry.0.material.text: BSDF type 'roughconductor' is not supported (diffuse) (got '<bsdf"),
    ({"geometry0_material": {"id": "custom", "text": '<bsdf type="diffuse"><rgb name="reflectance" '
                                                     'value="0.2, 0.5, 0.5"/></bsdf>'}},
     "geometry.0.material.text: reflectance [0.2, 0.5, 0.5] is not grey"),
    ({"geometry0_material": {"id": "custom"}}, "geometry.0.material.text: a custom material needs Mitsuba XML text "
                                               "(got None)"),
    ({"geometry0_mesh": {"type": "obj", "filename": "nowhere.obj"}},
     ("geometry.0.mesh.filename: not found (looked in ", "(got 'nowhere.obj')")),
    ({"geometry0_spin": 3}, "geometry.0.spin: Extra inputs are not permitted (got 3)"),
    ({"geometry0_scale_x": "big"}, "geometry.0.scale_x: Input should be a valid number (got 'big')"),
    ({"geometry1_name": "square"}, "geometry.1.name: repeats geometry.0.name; names must be unique (got 'square')"),
    ({"geometry1_rot_degrees_x": 10.0}, "geometry.1.rot_degrees_x: relay wall rotation is not supported (tal: NYI) "
                                        "(got 10.0)"),
    ({"geometry1_mesh": {"type": "ply", "filename": "wall.ply"}},
     "geometry.1.mesh.type: the relay wall must be a rectangle (tal's sensor grid follows the rectangle's UV) (got "
     "'ply')"),
    ({"geometry1_scale_z": 2}, "geometry.1.scale_z: the relay wall's scale_z must be 1 or -1 (its normal) (got 2.0)"),
    ({"scan_type": "raster"}, "scan_type: Input should be 'single', 'confocal' or 'exhaustive' (got 'raster')"),
    ({"scan_type": "confocal", "laser_width": 8},
     "laser_width: scan_type confocal needs [laser_width, laser_height] == [sensor_width, sensor_height] = [16, 16] "
     "(got [8, 32])"),
    ({"scan_type": "confocal", "laser_aperture_start_x": 0.7, "laser_aperture_end_x": 0.2},
     "laser_aperture_end_x: must be > laser_aperture_start_x 0.7 (got 0.2)"),
    ({"laser_aperture_end_y": 1.5}, "laser_aperture_end_y: Input should be less than or equal to 1 (got 1.5)"),
    ({"histogram_mode": "frequency"}, "histogram_mode: Input should be 'time' (got 'frequency')"),
    ({"auto_detect_bins": True}, "auto_detect_bins: true is not supported (give num_bins and start_opl) (got True)"),
    ({"integrator_filter_bounces": 3}, "integrator_filter_bounces: not supported (-1; use integrator_max_depth: 3 for "
                                       "third-bounce light only) (got 3)"),
    ({"integrator_max_depth": 2}, "integrator_max_depth: renders no light from the hidden scene (datagen needs -1 or "
                                  ">= 3) (got 2)"),
    ({"mitsuba_variant": "llvm_ad_spectral"}, "mitsuba_variant: not supported (llvm_/cuda_ … rgb or mono variants "
                                              "only) (got 'llvm_ad_spectral')"),
    ({"laser_emission_mode": "spectrum"}, "laser_emission_mode: Input should be 'rgb' or 'mono' (got 'spectrum')"),
    ({"laser_emission": "1, 1, 1"}, "laser_emission: mono mode needs one value (got [1.0, 1.0, 1.0])"),
    ({"laser_emission": "1, -1, 1", "laser_emission_mode": "rgb"},
     "laser_emission: expected non-negative numbers (got '1, -1, 1')"),
    ({"num_bins": 0}, "num_bins: Input should be greater than or equal to 1 (got 0)"),
    ({"bin_width_opl": "3mm"}, "bin_width_opl: Input should be a valid number (got '3mm')"),
    ({"laser_z": -0.25}, "is behind the relay wall"),
    ({"relay_wall": "floor"}, "relay_wall: not one of the geometry names ['square', 'relay_wall'] (got 'floor')"),
    ({"sensor_z_offset": 1}, "sensor_z_offset: Extra inputs are not permitted (got 1)"),
    ({"datagen": [1]}, "datagen: Input should be a valid dictionary (got [1])"),
    # what YAML lets slip: a float for an integer, NaN/inf, quoted numbers and booleans, a boolean for a number
    ({"sensor_width": 16.5}, "sensor_width: Input should be a valid integer, got a number with a fractional part "
                             "(got 16.5)"),
    ({"start_opl": float("nan")}, "start_opl: Input should be a finite number (got nan)"),
    ({"laser_x": float("-inf")}, "laser_x: Input should be a finite number (got -inf)"),
    ({"num_bins": "768"}, "num_bins: Input should be a valid number (got '768')"),
    ({"sensor_height": True}, "sensor_height: Input should be a valid number (got True)"),
    ({"account_first_and_last_bounces": "true"}, "account_first_and_last_bounces: Input should be a valid boolean "
                                                 "(got 'true')"),
    ({"integrator_nlos_laser_sampling": 1}, "integrator_nlos_laser_sampling: Input should be a valid boolean (got 1)"),
])
def test_unsupported_or_invalid_tal_options_name_the_option(tmp_path, change, message):
    """One line: the file, the field path (geometry.<i>.… for geometry entries), the reason and the value."""
    cfg = yaml.safe_load(BENCH.read_text())
    for key, value in change.items():
        if key.startswith(("geometry0_", "geometry1_")):
            cfg["geometry"][int(key[8])][key[10:]] = value
        else:
            cfg[key] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with pytest.raises(SceneError) as err:
        scene_from_tal_yaml(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "\n" not in text, text
    for fragment in (message,) if isinstance(message, str) else message:
        assert fragment in text, text


def test_tal_value_or_default_quirks_are_kept(tmp_path):
    """tal reads the laser aperture and the single-scan look-at as `value or default`: an aperture end of 0 or
    null is 1, a start of null is 0, a look-at of 0 or null is the wall's centre (sensor_width / 2)."""
    full_wall = scene_from_tal_yaml(hidden_square(tmp_path, "exhaustive"))[1].laser_grid_xyz
    _, tal = scene_from_tal_yaml(hidden_square(tmp_path, "exhaustive", laser_aperture_start_x=None,
                                               laser_aperture_end_x=0, laser_aperture_end_y=None))
    np.testing.assert_array_equal(tal.laser_grid_xyz, full_wall)
    scene, tal = scene_from_tal_yaml(hidden_square(tmp_path, "single", laser_lookat_x=0, laser_lookat_y=None))
    np.testing.assert_array_equal(tal.laser_grid_xyz[0, 0], [0.0, 0.0, 0.0])
    scene, tal = scene_from_tal_yaml(hidden_square(tmp_path, "single", laser_lookat_x=1, laser_lookat_y=1.5))
    np.testing.assert_allclose(tal.laser_grid_xyz[0, 0], [2 * 1 / 4 - 1, 2 * 1.5 / 3 - 1, 0.0], atol=1e-15)
    assert tal.config["laser_lookat_x"] == 1          # the config is recorded as written


def test_load_tal_config_merges_tal_defaults_and_reads_scene_folders(tmp_path):
    folder = tmp_path / "scene"
    folder.mkdir()
    (folder / "scene.yaml").write_text(BENCH.read_text())
    cfg = load_tal_config(folder)
    assert cfg["histogram_mode"] == "time" and cfg["laser_aperture_end_x"] == 1 and cfg["sensor_width"] == 16
    with pytest.raises(SceneError, match="tal config not found"):
        load_tal_config(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("geometry: [")
    with pytest.raises(SceneError, match="not valid YAML"):
        load_tal_config(tmp_path / "bad.yaml")


# ---------------------------------------------------------------------------------------------------------
# H against the independent quadrature, every capture type


@pytest.mark.parametrize("estimator", ["lookin", "area", "quadrature"])
def test_single_capture_matches_quadrature_in_tal_layout(tmp_path, estimator):
    scene, tal, result = run(hidden_square(tmp_path, "single"), **SETTINGS[estimator]["single"])
    tot, l2 = TOL[estimator]["single"]
    spot = np.zeros(3)
    ref = quadrature(spot, result.sensor_points.reshape(-1, 3), opl_edges(result))
    env = result.envelope.reshape(-1, result.envelope.shape[-1])
    np.testing.assert_allclose(env.sum(1), ref.sum(1), rtol=tot)
    assert rel_l2(env, ref) < l2
    # tal layout: H[t, ix, iy] at tal's grid point, times K; x grows with ix
    H = tal_arrays(result, tal)["H"]
    assert H.shape == (230, 4, 3)
    ref_tal = quadrature(spot, tal.sensor_grid_xyz.reshape(-1, 3), opl_edges(result)) * laser_scale(spot)
    ref_tal = ref_tal.reshape(4, 3, -1).transpose(2, 0, 1)
    np.testing.assert_allclose(H.sum(0), ref_tal.sum(0), rtol=tot)
    assert rel_l2(H, ref_tal) < l2
    assert np.all(np.diff(tal.sensor_grid_xyz[:, 0, 0]) > 0) and np.all(np.diff(tal.sensor_grid_xyz[0, :, 1]) > 0)


@pytest.mark.parametrize("estimator", ["lookin", "area", "quadrature"])
def test_confocal_capture_matches_quadrature_with_the_laser_on_each_point(tmp_path, estimator):
    scene, tal, result = run(hidden_square(tmp_path, "confocal"), **SETTINGS[estimator]["confocal"])
    tot, l2 = TOL[estimator]["confocal"]
    # confocal: laser grid == sensor grid, and each channel is lit at its own point
    np.testing.assert_array_equal(result.laser_points, result.sensor_points)
    edges = opl_edges(result)
    env = result.envelope.reshape(-1, result.envelope.shape[-1])
    ref = np.concatenate([quadrature(p, p[None], edges) for p in result.sensor_points.reshape(-1, 3)])
    np.testing.assert_allclose(env.sum(1), ref.sum(1), rtol=tot)
    assert rel_l2(env, ref) < l2
    data = tal_arrays(result, tal)
    H, grid = data["H"], data["sensor_grid_xyz"]
    assert data["H_format"] == HFormat.T_Sx_Sy and H.shape == (230, 4, 3)
    np.testing.assert_array_equal(data["laser_grid_xyz"], grid)          # tal's is_confocal() holds
    ref_tal = np.array([[quadrature(grid[i, j], grid[i, j][None], edges)[0] * laser_scale(grid[i, j])
                         for j in range(3)] for i in range(4)]).transpose(2, 0, 1)   # (T, Sx, Sy)
    np.testing.assert_allclose(H.sum(0), ref_tal.sum(0), rtol=tot)
    assert rel_l2(H, ref_tal) < l2


@pytest.mark.parametrize("estimator", ["lookin", "area", "quadrature"])
def test_exhaustive_capture_matches_quadrature_for_every_laser_point(tmp_path, estimator):
    scene, tal, result = run(hidden_square(tmp_path, "exhaustive"), **SETTINGS[estimator]["exhaustive"])
    tot, l2 = TOL[estimator]["exhaustive"]
    edges = opl_edges(result)
    ly, lx, sy, sx, nt = result.envelope.shape
    assert (ly, lx, sy, sx) == (2, 3, 3, 4)
    ref = np.stack([quadrature(l, result.sensor_points.reshape(-1, 3), edges)
                    for l in result.laser_points.reshape(-1, 3)])          # (L, S, T)
    env = result.envelope.reshape(ly * lx, sy * sx, nt)
    np.testing.assert_allclose(env.sum(-1), ref.sum(-1), rtol=tot)
    assert rel_l2(env, ref) < l2
    data = tal_arrays(result, tal)
    H = data["H"]
    assert data["H_format"] == HFormat.T_Lx_Ly_Sx_Sy and H.shape == (nt, 3, 2, 4, 3)
    lg, sg = tal.laser_grid_xyz, tal.sensor_grid_xyz
    ref_tal = np.stack([quadrature(l, sg.reshape(-1, 3), edges) * laser_scale(l) for l in lg.reshape(-1, 3)])
    ref_tal = ref_tal.reshape(3, 2, 4, 3, nt).transpose(4, 0, 1, 2, 3)
    np.testing.assert_allclose(H.sum(0), ref_tal.sum(0), rtol=tot)
    assert rel_l2(H, ref_tal) < l2


# ---------------------------------------------------------------------------------------------------------
# HDF5


@pytest.fixture(scope="module")
def confocal_result(tmp_path_factory):
    path = hidden_square(tmp_path_factory.mktemp("conf"), "confocal")
    return run(path, lookins="24x24")


def test_hdf5_round_trip_gives_identical_arrays_and_metadata(tmp_path, confocal_result):
    _, tal, result = confocal_result
    written = tal_arrays(result, tal)
    path = write_tal_hdf5(result, tmp_path / "c.hdf5", tal, compression_level=4)
    back = read_tal_hdf5(path)
    assert set(back) == set(written)
    for key, value in written.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(back[key], value, err_msg=key)
            assert back[key].dtype == value.dtype, key
        else:
            assert back[key] == value, key
    assert back["H_format"] is HFormat.T_Sx_Sy and back["sensor_grid_format"] is GridFormat.X_Y_3
    assert back["volume_format"] is VolumeFormat.UNKNOWN and back["t_accounts_first_and_last_bounces"] is False
    assert math.isclose(back["delta_t"], 0.01) and math.isclose(back["t_start"], 1.8)
    assert back["scene_info"]["config"]["scan_type"] == "confocal"
    assert back["scene_info"]["datagen"]["convention"] == "point_radiance"
    # float32 like tal render; skip_H like tal.io.read_capture
    path32 = write_tal_hdf5(result, tmp_path / "c32.hdf5", tal, dtype="float32")
    np.testing.assert_array_equal(read_tal_hdf5(path32)["H"], written["H"].astype(np.float32))
    assert read_tal_hdf5(path32, skip_H=True)["H"] is None


def test_hdf5_layout_is_tals(tmp_path, confocal_result):
    """What tal.io.capture_data.read_hdf5 relies on: enum datasets of shape (1,) with tal's names and values,
    empty datasets for None, a YAML string for scene_info, and no other keys."""
    _, tal, result = confocal_result
    path = write_tal_hdf5(result, tmp_path / "c.hdf5", tal)
    with h5py.File(path) as f:
        assert set(f) == {"H", "H_format", "sensor_xyz", "sensor_grid_xyz", "sensor_grid_normals",
                          "sensor_grid_format", "laser_xyz", "laser_grid_xyz", "laser_grid_normals",
                          "laser_grid_format", "volume_format", "delta_t", "t_start",
                          "t_accounts_first_and_last_bounces", "scene_info"}
        assert h5py.check_enum_dtype(f["H_format"].dtype) == {"UNKNOWN": 0, "T_Sx_Sy": 1, "T_Lx_Ly_Sx_Sy": 2,
                                                               "T_Si": 3, "T_Li_Si": 4}
        assert h5py.check_enum_dtype(f["sensor_grid_format"].dtype) == {"UNKNOWN": 0, "N_3": 1, "X_Y_3": 2}
        assert f["H_format"].shape == (1,) and f["H_format"][0] == 1 and f["laser_grid_format"][0] == 2
        assert f["volume_format"].shape is None
        assert f["H"].shape == (230, 4, 3) and f["sensor_grid_normals"].shape == (4, 3, 3)
        np.testing.assert_array_equal(f["sensor_grid_normals"][()][..., 2], 1.0)
        assert yaml.safe_load(f["scene_info"][()])["generator"] == "datagen"
        np.testing.assert_array_equal(f["laser_xyz"][()], LASER)


def test_export_of_a_default_result_moves_t_start_by_the_laser_leg(tmp_path):
    """A datagen default (emitter→spot leg not counted, FoV→sensor leg counted) with one laser spot becomes
    tal's 'both legs counted' exactly by starting the axis one emitter→spot leg later."""
    path = hidden_square(tmp_path, "single")
    scene, tal = scene_from_tal_yaml(path)
    scene.defaults["count_sensor_leg"] = True
    result = simulate(scene, resolve_config(scene, {"lookins": "8x8"}))
    data = tal_arrays(result)
    assert data["t_accounts_first_and_last_bounces"] is True
    assert math.isclose(data["t_start"], 1.8 + math.sqrt(0.3125), rel_tol=1e-12)
    np.testing.assert_array_equal(data["H"], result.envelope.transpose(2, 1, 0))   # as is: (T, Sx, Sy), no K
    scene, tal = scene_from_tal_yaml(hidden_square(tmp_path, "confocal"))
    scene.defaults["count_sensor_leg"] = True
    result = simulate(scene, resolve_config(scene, {"lookins": "4x4"}))
    with pytest.raises(DatasetError, match="count_laser_leg == count_sensor_leg"):
        tal_arrays(result)


# ---------------------------------------------------------------------------------------------------------
# CLI


def test_cli_tal_render_and_export_tal(tmp_path):
    path = hidden_square(tmp_path, "single")
    out = tmp_path / "h.hdf5"
    res = CliRunner().invoke(main, ["tal-render", str(path), "--out", str(out), "--lookins", "16x16",
                                    "--seed", "2", "--quiet", "--float32"])
    assert res.exit_code == 0, res.output
    data = read_tal_hdf5(out)
    assert data["H"].shape == (230, 4, 3) and data["H"].dtype == np.float32
    assert data["scene_info"]["args"]["lookins"] == "16x16" and "T_Sx_Sy" in res.output
    # export-tal of a stored datagen result
    scene, _ = scene_from_tal_yaml(path)
    result = simulate(scene, resolve_config(scene, {"lookins": "8x8"}))
    write_result(result, tmp_path / "r" / "result.zarr")
    res = CliRunner().invoke(main, ["export-tal", str(tmp_path / "r"), "--out", str(tmp_path / "e.hdf5")])
    assert res.exit_code == 0, res.output
    np.testing.assert_array_equal(read_tal_hdf5(tmp_path / "e.hdf5")["H"], result.envelope.transpose(2, 1, 0))


def test_cli_tal_render_bad_option_is_one_line(tmp_path):
    path = hidden_square(tmp_path, "single", histogram_mode="frequency")
    res = CliRunner().invoke(main, ["tal-render", str(path), "--out", str(tmp_path / "x.hdf5")])
    assert res.exit_code == 2
    assert "error:" in res.output and "histogram_mode: Input should be 'time' (got 'frequency')" in res.output
    assert len(res.output.strip().splitlines()) == 1, res.output
