"""Hostile input, part 3: builds, resumes and their inputs (issue 28).

The card pins the mesh assets (name, sha256, triangles of each file): ``build --resume`` and ``verify`` refuse
assets that changed since the build (added, removed or changed files), naming the asset folder and the file; a
card written before assets were pinned is accepted with a note. A mesh with millions of triangles is refused up
front from its header, before any sample is computed. ``--resume`` compares the stored config before the probe
sample. ``--splits`` with every count 0 is one line; a split at 0 beside others is kept, empty.

Each refusal that must come before the probe sample replaces the probe with a function that fails the test.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_hostile import cli   # the in-process runner: exit code, needles, no traceback, one error line

import datagen.dataset.build as build_module
from datagen.errors import ConfigError
from datagen.dataset import NLOSDataset, build_dataset, load_dataset_config, read_card, verify_dataset
from datagen.dataset.assets import MAX_ASSET_TRIANGLES, load_asset, mesh_triangles

ROOT = Path(__file__).resolve().parents[1]
WALL_SMOKE = ROOT / "configs" / "datasets" / "wall_smoke.yaml"
GLYPHS = ROOT / "assets" / "meshes" / "alphanumeric"


def asset_folder(tmp_path: Path, names=("A", "B")) -> Path:
    """``tmp_path/assets/meshes`` holding copies of the shipped glyph meshes ``names``."""
    folder = tmp_path / "assets" / "meshes"
    folder.mkdir(parents=True)
    for name in names:
        shutil.copy(GLYPHS / f"{name}.ply", folder / f"{name}.ply")
    return folder


def asset_config(tmp_path: Path, folder: Path, splits=None, edit=None) -> Path:
    """wall_smoke.yaml drawing its meshes from ``folder``, cut to a 4 × 4 scan and one-sample shards (a few
    tenths of a second per sample once numba has compiled)."""
    data = load_dataset_config(WALL_SMOKE).to_json()
    data["room"]["objects"]["mesh"]["assets"] = [str(folder)]
    data["room_overrides"] = {"capture": {"scan": {"points": [4, 4]}}}
    data["splits"] = splits or {"train": {"count": 2}}
    data["shard_size"] = 1
    if edit is not None:
        edit(data)
    path = tmp_path / "config.json"            # JSON is YAML
    path.write_text(json.dumps(data))
    return path


def build_args(config: Path, out: Path, *extra) -> list:
    return ["build", config, "--out", out, "--workers", "0", "--quiet", *extra]


@pytest.fixture
def no_probe(monkeypatch):
    """The probe sample (minutes on a real config) must not run: the refusal comes first."""
    def probe(config):
        raise AssertionError("the probe sample was computed before the refusal")
    monkeypatch.setattr(build_module, "_probe", probe)


@pytest.fixture
def built(tmp_path):
    """A complete 2-shard dataset drawn from a folder of two meshes, then its second shard un-done (as an
    interrupted build leaves it): (config, out, folder)."""
    folder = asset_folder(tmp_path)
    config, out = asset_config(tmp_path, folder), tmp_path / "ds"
    cli(build_args(config, out), 0, "2 shards built")
    cli(["verify", out], 0, "ok, 2 shards")
    (out / "_done" / "train" / "000001.json").unlink()
    return config, out, folder


def snapshot(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------------ assets changed

CHANGES = {   # how the asset folder changes after the build: (edit of the folder, what the message says)
    "a mesh added": (lambda f: shutil.copy(GLYPHS / "C.ply", f / "C.ply"), "meshes/C.ply was added"),
    "a mesh removed": (lambda f: (f / "B.ply").unlink(), "meshes/B.ply was removed"),
    "a mesh changed": (lambda f: shutil.copy(GLYPHS / "Z.ply", f / "A.ply"), "meshes/A.ply changed (sha256"),
}


def test_the_card_pins_every_asset_file(built):
    import hashlib
    _, out, folder = built
    assert read_card(out)["assets"] == [
        {"file": f"meshes/{name}.ply", "sha256": hashlib.sha256((folder / f"{name}.ply").read_bytes()).hexdigest(),
         "triangles": mesh_triangles(folder / f"{name}.ply")} for name in ("A", "B")]
    assert mesh_triangles(folder / "A.ply") == 44     # trimesh reads 44 faces from it


@pytest.mark.timeout(300)
@pytest.mark.parametrize("case", sorted(CHANGES))
def test_resume_and_verify_refuse_assets_changed_since_the_build(built, monkeypatch, case):
    config, out, folder = built
    change, says = CHANGES[case]
    change(folder)
    before = snapshot(out)
    with monkeypatch.context() as m:
        m.setattr(build_module, "_probe", lambda c: pytest.fail("probe computed before the asset check"))
        cli(build_args(config, out, "--resume"), 2, f"{out}: the mesh assets differ from those the dataset was "
            f"built from: {folder}: {says}", "restore the assets the card lists", "build into a new --out")
    assert snapshot(out) == before                       # nothing written, no shard drawn from the new list
    problems = verify_dataset(out)                       # verify names the change too (and the missing shard)
    assert any(p.startswith(f"mesh assets: {folder}: {says}") and "since the build" in p for p in problems), problems


@pytest.mark.timeout(300)
def test_a_mesh_added_to_a_finished_dataset_fails_verify_and_restoring_it_lets_resume_finish(built):
    config, out, folder = built
    shutil.copy(GLYPHS / "C.ply", folder / "C.ply")
    text = cli(["verify", out], 1, f"BAD mesh assets: {folder}: meshes/C.ply was added since the build")
    assert "ok" not in text.split("BAD")[0]
    (folder / "C.ply").unlink()                         # the assets restored: the resume completes the dataset
    cli(build_args(config, out, "--resume"), 0, "1 shards built", "1 already done", "status complete")
    cli(["verify", out], 0, "ok, 2 shards")


@pytest.mark.timeout(300)
def test_a_card_without_pinned_assets_is_accepted_with_a_note_and_pinned_on_resume(built):
    """Datasets built before the card pinned its assets: verify checks the rest and says the assets were not
    checked; a resume is accepted (nothing to compare), says so, and pins the current files from then on."""
    config, out, folder = built
    meta = out / "zarr.json"
    data = json.loads(meta.read_text())
    del data["attributes"]["assets"]
    meta.write_text(json.dumps(data))
    cli(build_args(config, out, "--resume"), 0, "repaired: card: pinned the 2 mesh asset files found now",
        "were not checked against it", "1 shards built")
    assert [a["file"] for a in read_card(out)["assets"]] == ["meshes/A.ply", "meshes/B.ply"]
    data = json.loads(meta.read_text())                  # again without the list (and complete now)
    del data["attributes"]["assets"]
    meta.write_text(json.dumps(data))
    notes: list[str] = []
    assert verify_dataset(out, notes) == []
    assert notes == ["the card pins no mesh assets (built before datagen recorded them): the asset files were "
                     "not checked"]
    text = cli(["verify", out], 0, "note: the card pins no mesh assets", "ok, 2 shards")
    assert "BAD" not in text


# ------------------------------------------------------------------------------------------ a huge mesh

def write_binary_stl(path: Path, triangles: int) -> None:
    """A binary STL of ``triangles`` random triangles: 80-byte header, uint32 count, 50 bytes per triangle."""
    record = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    data = np.zeros(triangles, dtype=record)
    data["v"] = np.random.default_rng(0).random((triangles, 3, 3), dtype=np.float32)
    with open(path, "wb") as fh:
        fh.write(b"\0" * 80 + np.uint32(triangles).tobytes())
        fh.write(data.tobytes())


@pytest.mark.timeout(60)
def test_a_two_million_triangle_mesh_is_refused_up_front(tmp_path, no_probe):
    folder = asset_folder(tmp_path)
    big = folder / "big.stl"
    write_binary_stl(big, 2_000_000)
    out = tmp_path / "ds"
    cli(build_args(asset_config(tmp_path, folder), out), 2,
        f"mesh asset {big}: 2000000 triangles, more than the {MAX_ASSET_TRIANGLES} a hidden mesh may have",
        "MAX_ASSET_TRIANGLES", "decimate it")
    assert not out.exists()
    with pytest.raises(ConfigError, match="2000000 triangles"):   # and anything else that loads it
        load_asset(str(big))


def test_triangle_counts_are_read_from_the_headers(tmp_path):
    """The count each format's header (or face records) gives is trimesh's count of the loaded mesh."""
    import trimesh
    mesh = trimesh.creation.icosphere(subdivisions=2)
    files = {"binary.stl": None, "mesh.obj": None, "mesh.off": None, "mesh.glb": None, "binary.ply": None}
    for name in files:
        mesh.export(tmp_path / name)
    (tmp_path / "ascii.stl").write_text(trimesh.exchange.stl.export_stl_ascii(mesh))
    (tmp_path / "ascii.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="ascii"))
    for path in sorted(tmp_path.iterdir()):
        assert mesh_triangles(path) == len(trimesh.load(path, force="mesh").faces) == 320, path
    write_binary_stl(tmp_path / "big.stl", 200_001)
    assert mesh_triangles(tmp_path / "big.stl") == 200_001
    (tmp_path / "garbage.ply").write_bytes(b"\x00\x01 not a mesh")
    assert mesh_triangles(tmp_path / "garbage.ply") is None      # not countable: trimesh names the error later


# ------------------------------------------------------------------------------------------ another config

@pytest.mark.timeout(300)
def test_resume_with_another_estimator_is_refused_before_the_probe(built, monkeypatch):
    config, out, folder = built
    (config.parent / "other").mkdir()
    other = asset_config(config.parent / "other", folder,
                         edit=lambda d: d["simulation"].update(estimator={"kind": "area"}))
    monkeypatch.setattr(build_module, "_probe", lambda c: pytest.fail("probe computed before the config check"))
    before = snapshot(out)
    cli(build_args(other, out, "--resume"), 2, f"{out} was built from a different config (differs in: "
        "simulation.estimator.edge, simulation.estimator.fov_cells, simulation.estimator.kind): "
        "simulation.estimator.edge is 0.12 in the dataset's card, (absent) in this config; resume with the same "
        "config or build into another --out")
    assert snapshot(out) == before


def test_resume_names_the_first_of_several_differences(built, no_probe):
    config, out, folder = built
    (config.parent / "other").mkdir()
    other = asset_config(config.parent / "other", folder,
                         edit=lambda d: (d.update(seed=7), d["simulation"]["estimator"].pop("fov_cells")))
    cli(build_args(other, out, "--resume"), 2, "differs in: seed, simulation.estimator.fov_cells)",
        "seed is 20250302 in the dataset's card, 7 in this config")


# ------------------------------------------------------------------------------------------ --splits

@pytest.mark.parametrize("value", ["train=0", "train=0,test=0"])
def test_splits_with_every_count_zero_is_one_line(tmp_path, value, no_probe):
    config = asset_config(tmp_path, asset_folder(tmp_path), splits={"train": {"count": 2}, "test": {"count": 1}})
    out = tmp_path / "ds"
    cli(build_args(config, out, "--splits", value), 2,
        f"--splits '{value}': every split it builds has count 0 (the splits it leaves out are not built): "
        "nothing to build")
    assert not out.exists()


def test_splits_given_twice_is_one_line(tmp_path, no_probe):
    config = asset_config(tmp_path, asset_folder(tmp_path), splits={"train": {"count": 2}, "test": {"count": 1}})
    cli(build_args(config, tmp_path / "ds", "--splits", "train=1,train=2"), 2,
        "--splits 'train=1,train=2': split 'train' is given twice")


@pytest.mark.timeout(300)
def test_a_split_at_zero_beside_others_is_kept_empty(tmp_path):
    config = asset_config(tmp_path, asset_folder(tmp_path), splits={"train": {"count": 2}, "test": {"count": 1}})
    out = tmp_path / "ds"
    cli(build_args(config, out, "--splits", "train=0,test=1"), 0, "1 shards built", "status complete")
    card = read_card(out)
    assert {s: i["count"] for s, i in card["splits"].items()} == {"train": 0, "test": 1}
    assert len(NLOSDataset(out, split="train")) == 0 and len(NLOSDataset(out, split="test")) == 1
    cli(["verify", out], 0, "ok, 1 shards")


def test_the_api_refuses_a_config_whose_splits_are_all_zero(tmp_path, no_probe):
    config = load_dataset_config(asset_config(tmp_path, asset_folder(tmp_path)))
    empty = config.model_copy(update={"splits": {"train": config.splits["train"].model_copy(update={"count": 0})}})
    with pytest.raises(ValueError, match=r"every split has count 0 \(train\): nothing to build"):
        build_dataset(empty, tmp_path / "ds", workers=0, progress=False)
    assert not (tmp_path / "ds").exists()


@pytest.mark.timeout(300)
def test_a_store_opens_and_reads_the_same_once_its_asset_folder_is_gone(tmp_path):
    """The card names the mesh asset folder by its absolute path on the build's machine. Reading needs no mesh file
    (the room's simulation block, capture and motion): once the folder is removed, as on another machine or after
    the build's checkout is deleted, the store still opens and its counts and labels read bit for bit as before, and
    ``datagen verify`` checks every shard, says in a note that the asset files were not checked, and passes."""
    folder = asset_folder(tmp_path)
    config, out = asset_config(tmp_path, folder), tmp_path / "ds"
    cli(build_args(config, out), 0, "2 shards built")
    fields = ("counts", "envelope", "wall_depth")
    before = [NLOSDataset(out, split="train", fields=fields).read(i) for i in range(2)]
    shutil.rmtree(tmp_path / "assets")
    read = (f"import numpy as np, datagen; ds = datagen.NLOSDataset({str(out)!r}, split='train', fields={fields!r}); "
            f"np.savez({str(tmp_path / 'after.npz')!r}, **{{f'{{n}}{{i}}': np.asarray(ds.read(i)[n]) "
            f"for i in range(2) for n in {fields!r}}})")
    done = subprocess.run([sys.executable, "-c", read], capture_output=True, text=True, timeout=240)  # a new process
    assert done.returncode == 0, done.stderr[-2000:]
    after = np.load(tmp_path / "after.npz")
    for i, item in enumerate(before):
        for name in fields:
            np.testing.assert_array_equal(np.asarray(item[name]), after[f"{name}{i}"])
    assert after["counts0"].sum() > 0
    verify = subprocess.run([sys.executable, "-c", "from datagen.cli.main import main; main()", "verify", str(out),
                             "--quiet"], capture_output=True, text=True, timeout=240)
    assert verify.returncode == 0, verify.stderr[-2000:]
    assert "ok, 2 shards" in verify.stdout and "Traceback" not in verify.stderr
    note = [line for line in verify.stderr.splitlines() if line.startswith("note:")]
    assert len(note) == 1 and "mesh asset files were not checked" in note[0] and "asset folder or file not found" \
        in note[0], verify.stderr


def test_only_a_missing_asset_folder_is_a_note_in_the_asset_check(tmp_path, monkeypatch):
    """asset_problems: an asset folder that exists nowhere (a store copied from the machine that built it; the
    error resolve_assets raises for it) adds one note naming the folder and reports no problem; any other config
    error (here an invalid room, raised where the entries are resolved) is raised as it is, not turned into a note.
    The end-to-end case, verify on a store whose folders are gone, is the test above."""
    from datagen.dataset import integrity
    from datagen.dataset.assets import resolve_assets
    from datagen.errors import ConfigError

    config = load_dataset_config(asset_config(tmp_path, asset_folder(tmp_path)))
    gone = tmp_path / "elsewhere" / "meshes"

    def missing(config):
        return resolve_assets([str(gone)], tmp_path, "rooms.yaml: objects.mesh.assets")

    monkeypatch.setattr(integrity, "config_asset_entries", missing)
    notes: list[str] = []
    assert integrity.asset_problems({"assets": []}, config, notes) == []
    assert len(notes) == 1 and "asset folder or file not found" in notes[0] and str(gone) in notes[0], notes

    def invalid(config):
        raise ConfigError("room: walls.albedo: 1.5 is above 1")

    monkeypatch.setattr(integrity, "config_asset_entries", invalid)
    with pytest.raises(ConfigError, match="walls.albedo: 1.5"):
        integrity.asset_problems({"assets": []}, config, [])
