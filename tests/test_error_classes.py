"""Which error class each kind of bad input raises (datagen/errors.py, docs/reliability.md).

SceneError: a scene file or scene object; ConfigError: a simulation, detector, room-distribution or dataset config,
or a command-line option; DatasetError: a stored dataset, result or file read back; ResourceError: a setting needing
more memory than the machine has. Every one is a DatagenError (a ValueError) and the CLI prints it as one
``error: …`` line with exit code 2. The units at the boundary have one parser per kind (datagen/units.py)."""
from __future__ import annotations

import warnings
from pathlib import Path

import click
import pytest
import yaml
from click.testing import CliRunner

from test_hostile import cli, scene_file

from datagen.cli.errors import friendly_errors
from datagen.cli.main import main
from datagen.dataset import load_dataset_config, read_card
from datagen.dataset.rooms import load_room_distribution
from datagen.errors import ConfigError, DatagenError, DatasetError, ResourceError, SceneError
from datagen.scene import load_scene
from datagen.simulation import ToleranceOutOfReach, resolve_config
from datagen.simulation.budget import check_memory
from datagen.simulation.tolerance import check_tolerance
from datagen.spad import DetectorConfig
from datagen.units import parse_duration, parse_fraction, parse_rate

SMOKE = Path("configs/datasets/smoke.yaml")
ROOM = Path("configs/rooms/smoke.yaml")


def bad_dataset_config(tmp_path):
    data = yaml.safe_load(SMOKE.read_text())
    data["room"] = str((SMOKE.parent / data["room"]).resolve())
    data["splits"]["val"]["count"] = "many"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    load_dataset_config(path)


def bad_dataset_tolerance(tmp_path):
    data = yaml.safe_load(SMOKE.read_text())
    data["tolerance"] = "one percent%"
    load_dataset_config(data, base_dir=SMOKE.parent)


def missing_dataset_config(tmp_path):
    load_dataset_config(tmp_path / "nope.yaml")


def bad_room_distribution(tmp_path):
    data = yaml.safe_load(ROOM.read_text())
    data["ceiling"] = {"min": 3.0, "max": 2.0}
    path = tmp_path / "room.yaml"
    path.write_text(yaml.safe_dump(data))
    load_room_distribution(path)


def bad_room_yaml(tmp_path):
    path = tmp_path / "room.yaml"
    path.write_text("ceiling: [")
    load_room_distribution(path)


def bad_simulation_setting(tmp_path):
    scene = load_scene(scene_file(tmp_path))
    with warnings.catch_warnings():       # the scene's lookin keys are dropped for the quadrature, with a note
        warnings.simplefilter("ignore")
        resolve_config(scene, {"estimator": {"kind": "quadrature", "edge": -0.01}})


def bad_tolerance(tmp_path):
    check_tolerance(1.5)


def bad_detector_preset(tmp_path):
    path = tmp_path / "det.yaml"
    path.write_text("pde: 2.0\n")
    DetectorConfig.from_yaml(path)


def damaged_card(tmp_path):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "zarr.json").write_text("{not json")
    read_card(tmp_path / "ds")


def card_without_config(tmp_path):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "zarr.json").write_text('{"attributes": {"format": "datagen-dataset"}}')
    read_card(tmp_path / "ds")


def reserved_object_name(tmp_path):
    load_scene(scene_file(tmp_path, lambda d: d["objects"][1].update(name="room")))


def scene_yaml_syntax(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text("objects: [")
    load_scene(path)


def too_much_memory(tmp_path):
    check_memory(1e30, "time.n_bins", "1e12", "scene.yaml (simulation): ")


CASES = [
    # (bad input, the function feeding it, the class raised, the message)
    ("dataset config field", bad_dataset_config, ConfigError, r"bad\.yaml: splits\.val\.count: "),
    ("dataset config tolerance", bad_dataset_tolerance, ConfigError, r"tolerance: .*must look like 1% or 0\.01"),
    ("missing dataset config", missing_dataset_config, ConfigError, r"dataset config not found: .*nope\.yaml"),
    ("room distribution field", bad_room_distribution, ConfigError,
     r"room\.yaml: ceiling: .*min \(3\.0\) must be <= max \(2\.0\)"),
    ("room distribution YAML", bad_room_yaml, ConfigError, r"room\.yaml: not valid YAML"),
    ("simulation setting", bad_simulation_setting, ConfigError, r"estimator\.edge"),
    ("simulation tolerance", bad_tolerance, ConfigError, r"^tolerance must be in \(0, 1\), got 1\.5$"),
    ("detector preset", bad_detector_preset, ConfigError, r"det\.yaml: invalid detector config: field 'pde'"),
    ("damaged dataset card", damaged_card, DatasetError, r"zarr\.json: the dataset card is not a JSON object"),
    ("dataset card without config", card_without_config, DatasetError, r"the dataset card has no 'config' mapping"),
    ("scene object name", reserved_object_name, SceneError, r"scene\.yaml: objects\.1: object name 'room' is reserved"),
    ("scene YAML", scene_yaml_syntax, SceneError, r"scene\.yaml: not valid YAML"),
    ("memory", too_much_memory, ResourceError, r"time\.n_bins 1e12 needs about .* GiB of memory"),
]


@pytest.mark.parametrize("name, make, cls, message", CASES, ids=[c[0] for c in CASES])
def test_each_bad_input_raises_its_class(tmp_path, monkeypatch, name, make, cls, message):
    monkeypatch.setattr("datagen.simulation.budget.available_memory", lambda: 8 << 30)
    with pytest.raises(DatagenError, match=message) as info:
        make(tmp_path)
    assert type(info.value) is cls, (name, type(info.value).__name__, str(info.value))
    assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_tolerance_out_of_reach_is_a_config_error():
    assert issubclass(ToleranceOutOfReach, ConfigError) and not issubclass(ToleranceOutOfReach, SceneError)


@pytest.mark.parametrize("cls", [DatagenError, SceneError, ConfigError, DatasetError, ResourceError])
def test_the_cli_prints_every_class_as_one_error_line(cls):
    @click.command()
    @friendly_errors
    def command():
        raise cls(f"somewhere.yaml: field: bad value for {cls.__name__}")

    res = CliRunner().invoke(command, [])
    assert res.exit_code == 2
    assert res.output == f"error: somewhere.yaml: field: bad value for {cls.__name__}\n"


def test_the_cli_reports_a_damaged_dataset_and_a_bad_option(tmp_path):
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "zarr.json").write_text("{not json")
    line = cli(["verify", tmp_path / "ds"], 2)
    assert f"error: {tmp_path / 'ds' / 'zarr.json'}: the dataset card is not a JSON object" in line
    out = cli(["view", scene_file(tmp_path), "--split", "train", "--out", tmp_path / "v.png"], 2)
    assert out.startswith("error: --split and --index pick a sample of a dataset directory")


# ---------------------------------------------------------------------------------------- one parser per kind

def test_durations_rates_and_fractions_have_one_parser_each():
    assert parse_duration("5min") == 300.0 and parse_duration("2h") == 7200.0 and parse_duration("600ps") == 6e-10
    assert parse_duration("1.5 ms") == pytest.approx(1.5e-3)
    assert parse_rate("20MHz") == 2e7 and parse_rate("20mhz") == 2e7 and parse_rate("100 kcps") == 1e5
    assert parse_rate(5) == 5.0
    assert parse_fraction("1%") == 0.01 and parse_fraction(" 0.5 % ") == 0.005 and parse_fraction("0.02") == 0.02
    with pytest.raises(ValueError, match=r"^unknown rate unit 'mhzz' in '20 mHzz'; known: Hz, kHz, MHz, GHz, cps"):
        parse_rate("20 mHzz")
    with pytest.raises(ValueError, match=r"^cannot read 'MHz' as a rate; write e\.g\. '20MHz'"):
        parse_rate("MHz")
    with pytest.raises(ValueError, match=r"^expected a rate in Hz, got True$"):
        parse_rate(True)
    with pytest.raises(ValueError, match=r"^must look like 1% or 0\.01, got 'one percent%'$"):
        parse_fraction("one percent%")
    with pytest.raises(ValueError, match=r"^unknown duration unit 'fortnights' in '3 fortnights'; known: h, min, s"):
        parse_duration("3 fortnights")


def test_the_detector_reads_rates_with_the_shared_parser():
    config = DetectorConfig(exposure="1ms", dcr="2kcps", ambient_rate="1MHz", repetition_rate="20MHz", bin_width="50ps",
                            t_start=0.0)
    assert (config.dcr, config.ambient_rate, config.repetition_rate) == (2e3, 1e6, 2e7)
    with pytest.raises(ValueError, match=r"(?s)dcr\n.*unknown rate unit 'furlongs' in '3 furlongs'"):
        DetectorConfig(exposure="1ms", dcr="3 furlongs", repetition_rate="20MHz", bin_width="50ps", t_start=0.0)


def test_bench_budgets_are_read_by_the_shared_duration_parser(tmp_path):
    scene = scene_file(tmp_path)
    line = cli(["bench", "accuracy", scene, "--budget", "xmin"], 2)
    assert "error: --budget: cannot read 'xmin' as a duration; write e.g. '600ps'" in line
    line = cli(["bench", "accuracy", scene, "--budget", "0s"], 2)
    assert "error: --budget must be a positive duration such as 60s or 5min, got '0s'" in line
