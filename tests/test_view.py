"""3D pictures (``datagen view``, datagen/plot/view_*.py): offscreen rendering with open3d, the scene of a
dataset sample drawn again, the lookin overlay, the hooks in ``inspect`` and ``simulate --figures``, errors.

Rendering tests need open3d and a Vulkan driver (scripts/test.sh installs the Debian packages as root); they
skip where these are missing, except under CI (CI set), where a missing renderer is a failure.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from datagen import plot
from datagen.cli import main
from datagen.plot import view_geometry, view_render
from datagen.plot.view_geometry import CLASS_COLORS, build_drawables, lookin_points
from datagen.plot.view_overlay import LEGEND_WIDTH
from datagen.plot.view_render import SceneImage
from datagen.plot.view_worker import require_open3d
from datagen.scene import FieldOfView, Laser, Material, Scene, Sensor, box, load_scene, quad

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "scene_library" / "demo_room.yaml"
TAL = ROOT / "benchmarks" / "tal" / "hidden_square.yaml"
SMOKE = ROOT / "configs" / "datasets" / "smoke.yaml"

COLOR_TOL = 3
"""Largest per-channel difference (0-255) between a flat-shaded pixel and its class colour (8-bit rounding)."""

BOX_CENTER = (1.1, 1.1, 1.1)


@pytest.fixture(scope="module")
def o3d():
    try:
        return require_open3d()
    except plot.ViewUnavailable as exc:
        if os.environ.get("CI"):
            raise
        pytest.skip(str(exc))


def small_scene() -> Scene:
    """Relay wall x = 2 facing −x; a teal mesh patch and an orange 0.4 m box in front of it, clear of the
    laser beam and the sensor's lines of sight; emitter and sensor at (0, 0, −0.5)."""
    objects = [
        quad("relay_wall", (2.0, -2.0, -2.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0), Material(albedo=0.9),
             label="relay_wall"),
        quad("patch", (1.0, -1.6, 0.9), (0.0, 0.5, 0.0), (0.0, 0.0, 0.5), Material(albedo=0.8)),
        box("cube", BOX_CENTER, (0.4, 0.4, 0.4), material=Material(albedo=0.5)),
    ]
    return Scene(objects, Laser(emitter=(0.0, 0.0, -0.5), spot=(2.0, 0.0, 0.0)),
                 Sensor(position=(0.0, 0.0, -0.5), aperture_radius=0.02,
                        fov=FieldOfView(center=(2.0, 0.0, -0.6), size=(0.8, 0.8))))


def pixel(shot: SceneImage, point) -> np.ndarray:
    """RGB (0-255 int) of ``shot`` at the projection of ``point`` through the renderer's own camera."""
    col, row = shot.project(np.asarray(point, dtype=np.float64))
    h, w = shot.image.shape[:2]
    assert 0 <= col < w and 0 <= row < h, (col, row)
    return shot.image[int(row), int(col)].astype(int)


def rgb255(label: str) -> np.ndarray:
    return np.round(np.array(CLASS_COLORS[label]) * 255)


def test_flat_render_is_not_blank_and_objects_sit_at_their_projections(o3d):
    shot = plot.render_scene_image(small_scene(), 320, 240, shading="flat", supersample=1, edges=False)
    img = shot.image
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    background = np.all(img == 255, axis=-1)
    assert 0.1 < 1 - background.mean() < 0.95                      # something drawn, not everything
    assert len(np.unique(img.reshape(-1, 3), axis=0)) >= 4
    # the colour at the projection of the box's centre (the box's near faces cover it) is the box colour
    np.testing.assert_allclose(pixel(shot, BOX_CENTER), rgb255("box"), atol=COLOR_TOL)
    np.testing.assert_allclose(pixel(shot, (1.0, -1.35, 1.15)), rgb255("mesh"), atol=COLOR_TOL)
    # a point in empty space 0.6 m above the box in the picture plane is not box-coloured
    off = np.asarray(BOX_CENTER) + 0.6 * shot.camera.up
    assert np.abs(pixel(shot, off) - rgb255("box")).max() > 40
    # the renderer's camera is the one we asked for: our own orthographic frame projects the box's centre
    # to the same pixel as open3d's view and projection matrices
    np.testing.assert_allclose(shot.project(np.array(BOX_CENTER)),
                               shot.camera.pixel_of(np.array(BOX_CENTER), 320, 240), atol=0.5)


def test_shaded_render_keeps_each_class_hue(o3d):
    shot = plot.render_scene_image(small_scene(), 320, 240, supersample=2)
    ratio = (pixel(shot, BOX_CENTER) / 255.0) / np.array(CLASS_COLORS["box"])
    # a shaded face is AMBIENT … 1 times its colour, the same factor on every channel (±8-bit rounding)
    assert view_geometry.AMBIENT - 0.02 <= ratio.min() and ratio.max() <= 1.02
    assert ratio.max() - ratio.min() < 0.03


def test_walls_and_ceiling_in_front_are_cut_away(o3d):
    d = build_drawables(o3d, load_scene(DEMO))
    assert "ceiling" in d.cut and "walls" in d.cut                  # the camera looks in from above, outside
    drawn = {name for name, _, _ in d.meshes}
    assert {"relay_wall", "floor", "box", "pillar"} <= drawn and "ceiling" not in drawn
    walls = next(v for name, v, _ in d.meshes if name == "walls")
    assert 0 < len(walls) < 2 * 3 * 8                                # some walls kept (2 windings, 3 vertices)


def test_render_scene_writes_a_png_with_legend(o3d, tmp_path):
    from PIL import Image

    image = plot.render_scene(small_scene(), tmp_path / "pic.png", width=640, height=360)
    assert image.shape == (360, 640, 3)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "pic.png").convert("RGB")), image)
    legend = image[:, int(640 * (1 - LEGEND_WIDTH)) + 10:]
    assert (legend < 128).any()                                     # legend text is drawn


def test_a_stalled_render_is_killed_and_retried(o3d, monkeypatch):
    """The watchdog: a child that does not answer within RENDER_TIMEOUT_S is killed, the render retried in a
    fresh child, and after RENDER_ATTEMPTS a one-line RuntimeError (a 1 ms budget: every attempt 'stalls')."""
    monkeypatch.setattr(view_render, "RENDER_TIMEOUT_S", 0.001)
    monkeypatch.setattr(view_render, "RENDER_ATTEMPTS", 2)
    with pytest.raises(RuntimeError, match="stalled 2 times"):
        plot.render_scene_image(small_scene(), 64, 48, supersample=1)
    assert view_render.WORKER.proc is None                          # no child left behind


def test_lookin_points_are_the_runs_lookins(monkeypatch):
    from datagen.simulation import resolve_config, simulate
    from datagen.transport import LookinSampler

    scene = load_scene(DEMO)
    config = resolve_config(scene, {"lookins": "6x6", "pixels": "8x8", "secondary": "none", "seed": 5})
    cast = []
    original = LookinSampler.lookins

    def recording(self, rng, laser=0):
        look = original(self, rng, laser)
        cast.append(look.points[look.hit])
        return look

    monkeypatch.setattr(LookinSampler, "lookins", recording)
    simulate(scene, config)
    monkeypatch.setattr(LookinSampler, "lookins", original)
    points = lookin_points(scene, config)
    assert len(cast) == config.error.replicas and len(points) >= 16      # 8 replicas of a 2x2 grid, most hit
    np.testing.assert_array_equal(points, np.concatenate(cast))


@pytest.fixture(scope="module")
def smoke_dataset(tmp_path_factory):
    from datagen.dataset import build_dataset, load_dataset_config
    from datagen.dataset.config import SplitSpec

    config = load_dataset_config(SMOKE)
    config = config.model_copy(update={"splits": {"train": SplitSpec(count=3), "val": SplitSpec(count=1)},
                                       "shard_size": 2})
    out = tmp_path_factory.mktemp("view") / "ds"
    build_dataset(config, out, workers=0, progress=False)
    return out, config


def test_scene_of_sample_draws_the_stored_sample_again(smoke_dataset):
    from datagen.dataset import NLOSDataset, scene_of_sample
    from datagen.dataset.config import draw_room

    path, config = smoke_dataset
    room, split, card = scene_of_sample(path, "train", 2)
    assert split == "train" and card["name"] == config.name
    stored = NLOSDataset(path, split="train", fields=["params"]).params(2)["room"]
    assert json.loads(json.dumps(room.params, default=lambda v: v.tolist())) == stored
    again, _ = draw_room(config, "train", 2)
    np.testing.assert_array_equal(again.scene.vertices, room.scene.vertices)
    assert [o.name for o in room.scene.objects][:4] == ["relay_wall", "walls", "floor", "ceiling"]
    other, _, _ = scene_of_sample(path, "train", 1)
    assert other.params != room.params


def test_cli_renders_a_dataset_sample_with_its_lookins(o3d, smoke_dataset, tmp_path):
    from PIL import Image

    path, _ = smoke_dataset
    out = tmp_path / "sample.png"
    res = CliRunner().invoke(main, ["view", str(path), "--split", "train", "--index", "1", "--lookins", "4x4",
                                    "--out", str(out), "--size", "700x430"])
    assert res.exit_code == 0, res.output
    n_lookins = int(res.output.split(" lookins")[0].split(", ")[-1])   # "…, N lookins": the lookins that hit
    assert "wrote" in res.output and 8 < n_lookins <= 16   # the 4×4 grid given, less the rays that leave the room
    assert Image.open(out).size == (700, 430)
    bad = CliRunner().invoke(main, ["view", str(path), "--split", "train", "--index", "9", "--out", str(out)])
    assert bad.exit_code == 2 and bad.output.startswith("error: ") and "index 9" in bad.output


def test_inspect_puts_a_picture_beside_each_sample(o3d, smoke_dataset, tmp_path):
    from PIL import Image

    path, _ = smoke_dataset
    res = CliRunner().invoke(main, ["inspect", str(path), "--samples", "1", "--png", str(tmp_path / "i.png")])
    assert res.exit_code == 0, res.output
    assert "no 3D sample pictures" not in res.output
    width, _ = Image.open(tmp_path / "i.png").size
    assert width == round((13.5 + 6.4) * 90)                         # envelope and labels + the picture


def test_cli_renders_a_tal_config(o3d, tmp_path):
    res = CliRunner().invoke(main, ["view", str(TAL), "--out", str(tmp_path / "tal.png"), "--size", "600x400"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "tal.png").stat().st_size > 10_000


def test_cli_without_open3d_gives_one_line(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "open3d", None)              # `import open3d` now raises ImportError
    res = CliRunner().invoke(main, ["view", str(DEMO), "--out", str(tmp_path / "x.png")])
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "open3d" in lines[0], res.output
    assert "libusb-1.0-0 mesa-vulkan-drivers" in lines[0]             # the Debian packages are named
    assert "Traceback" not in res.output and not (tmp_path / "x.png").exists()


def test_cli_usage_errors(monkeypatch, tmp_path):
    res = CliRunner().invoke(main, ["view", str(DEMO)])
    assert res.exit_code == 2 and "--out" in res.output
    res = CliRunner().invoke(main, ["view", str(DEMO), "--split", "train", "--out", str(tmp_path / "x.png")])
    assert res.exit_code == 2 and "dataset directory" in res.output
    res = CliRunner().invoke(main, ["view", str(DEMO), "--size", "12x", "--out", str(tmp_path / "x.png")])
    assert res.exit_code == 2 and "--size" in res.output
    res = CliRunner().invoke(main, ["view", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "x.png")])
    assert res.exit_code == 2 and res.output.startswith("error: ") and "missing.yaml" in res.output
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    res = CliRunner().invoke(main, ["view", str(DEMO), "--show"])
    assert res.exit_code == 2 and "display" in res.output and len(res.output.strip().splitlines()) == 1


def test_datagen_works_without_open3d(smoke_dataset, tmp_path):
    """In a process where open3d cannot be imported: ``import datagen`` and the plot package work,
    ``simulate --figures`` writes its other figures with a one-line note, ``inspect`` draws its figure."""
    path, _ = smoke_dataset
    code = ("import sys; sys.modules['open3d'] = None\n"
            "import datagen, datagen.cli, datagen.plot\n"
            "from click.testing import CliRunner\n"
            f"res = CliRunner().invoke(datagen.cli.main, ['simulate', {str(DEMO)!r}, '--out', {str(tmp_path)!r}, "
            "'--lookins', '4x4', '--pixels', '8x8', '--secondary', 'none', '--figures', '--quiet'])\n"
            "print(res.exit_code); print(res.output)\n"
            f"res = CliRunner().invoke(datagen.cli.main, ['inspect', {str(path)!r}, '--samples', '1', "
            f"'--png', {str(tmp_path / 'i.png')!r}])\n"
            "print(res.exit_code); print(res.output)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("0\n"), out.stdout
    notes = [line for line in out.stdout.splitlines() if line.startswith("note: no 3D")]
    assert len(notes) == 2 and all("open3d" in line for line in notes), out.stdout
    assert (tmp_path / "fig3_laser_energy.png").exists() and not (tmp_path / "scene_view.png").exists()
    assert (tmp_path / "i.png").exists()
