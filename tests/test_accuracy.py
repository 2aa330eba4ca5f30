"""Error measure, estimator convergence toward closed forms, and the ``datagen bench accuracy`` command."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from conftest import patch_scene
from test_area import two_patch_closed_form, two_patch_scene
from test_reference import AXIS, IRF, patch_envelope, rel_l2

from datagen.errors import ConfigError
from datagen.analysis import envelope_error, run_accuracy
from datagen.analysis.accuracy import AccuracyRow, ESTIMATORS, LADDERS, format_table, pareto_front
from datagen.scene import Material
from datagen.cli.main import main
from datagen.timing import EnvelopeAccumulator
from datagen.scene import RayCaster
from datagen.analysis import converged_reference
from datagen.analysis.reference import REFERENCE_POINT_SECONDS, REFERENCE_SAMPLES, check_reference_size, peak_time
from datagen.transport import LookinSampler, LookinSettings

EDGES = np.arange(201) * 10e-12


def bump(center_s, sigma_s=80e-12, height=1.0):
    t = 0.5 * (EDGES[1:] + EDGES[:-1])
    return height * np.exp(-0.5 * ((t - center_s) / sigma_s) ** 2)


def test_error_measure_closed_forms():
    ref = bump(1.0e-9)
    err = envelope_error(1.1 * ref, ref, EDGES)
    assert err["rel_l2"] == pytest.approx(0.1, rel=1e-12)
    assert err["total"] == pytest.approx(0.1, rel=1e-12)
    assert err["peak_time"] == pytest.approx(0.0, abs=1e-18)
    # a shift by three bins: peak-time error 30 ps (both peaks refined the same way), relative L2 from the formula
    shifted = np.roll(ref, 3)
    err = envelope_error(shifted, ref, EDGES)
    assert err["peak_time"] == pytest.approx(30e-12, rel=1e-9)
    mask = ref > 0.01 * ref.max()
    assert err["rel_l2"] == pytest.approx(np.linalg.norm((shifted - ref)[mask]) / np.linalg.norm(ref[mask]))
    assert err["total"] == pytest.approx(0.0, abs=1e-12)
    # bins where the reference is below 1 % of its peak do not enter the relative L2 (they do enter the total)
    extra = np.zeros_like(ref)
    extra[-5:] = 0.5
    err = envelope_error(ref + extra, ref, EDGES)
    assert err["rel_l2"] == 0.0 and err["total"] == pytest.approx(2.5 / ref.sum())


def test_peak_time_is_sub_bin():
    for center in (1.0e-9, 1.0037e-9, 1.0071e-9):
        assert peak_time(bump(center), EDGES) == pytest.approx(center, abs=0.2e-12)   # bin 10 ps, σ 80 ps


def test_error_measure_rejects_bad_input():
    ref = bump(1e-9)
    with pytest.raises(ConfigError, match="shape"):
        envelope_error(ref[:-1], ref, EDGES)
    with pytest.raises(ConfigError, match="zero everywhere"):
        envelope_error(ref, np.zeros_like(ref), EDGES)
    with pytest.raises(ConfigError, match="time_edges"):
        envelope_error(ref, ref)
    with pytest.raises(ConfigError, match="finite"):
        envelope_error(np.full_like(ref, np.nan), ref, EDGES)


def test_pareto_front_keeps_only_undominated_runs():
    rows = [AccuracyRow("a", "1", 1, 1.0, 0.10, 0, 0), AccuracyRow("a", "2", 2, 2.0, 0.05, 0, 0),
            AccuracyRow("b", "1", 1, 1.5, 0.20, 0, 0), AccuracyRow("b", "2", 2, 3.0, 0.01, 0, 0),
            AccuracyRow("c", "1", 1, 0.5, 0.50, 0, 0)]
    front = pareto_front(rows)
    assert [(r.estimator, r.setting) for r in front] == [("c", "1"), ("a", "1"), ("a", "2"), ("b", "2")]
    assert not rows[2].pareto
    assert "| b | 2 | 3.00 | 1.00e-02 |" in format_table(rows)


def test_lookin_primary_error_falls_as_one_over_root_n():
    """The paper's sampler (primary, 32×32 camera pixels) against the closed-form patch envelope: RMS relative
    L2 over 3 seeds at N = 8² … 64² lookins falls with slope −1/2 in N (measured −0.57; tolerance ±0.2)."""
    ref = patch_envelope(AXIS, IRF)
    scene = patch_scene()
    caster = RayCaster(scene)
    ns, errs = [8, 16, 32, 64], []
    for n in ns:
        e = []
        for seed in range(3):
            tr = LookinSampler(scene, LookinSettings(lookins=(n, n), pixels=(32, 32), secondary="none"), caster)
            acc = EnvelopeAccumulator(AXIS, IRF, len(tr.component_names))
            tr.run(acc, np.random.default_rng(seed))
            e.append(rel_l2(acc.binned().sum(0), ref))
        errs.append(np.sqrt(np.mean(np.square(e))))
    slope = np.polyfit(np.log(np.square(ns)), np.log(errs), 1)[0]
    print("lookin rel L2", np.round(errs, 4), "slope", round(slope, 3))
    assert -0.77 < slope < -0.37 and errs[-1] < 0.1


def test_secondary_estimators_against_closed_form():
    """Two facing patches (closed-form secondary): the full and the exact secondary fall toward it as N grows
    (measured slope −0.70 in N, 4.6 % at 64²) and agree with each other; the optimized top-1 secondary stays
    ~89 % low at every N (biased by design)."""
    mats = (Material(albedo=0.8), Material(albedo=0.7))
    sec = two_patch_closed_form(mats)[2]
    scene = two_patch_scene(mats)
    caster = RayCaster(scene)
    modes = ["full", "optimized"] + (["exact"] if "exact" in ESTIMATORS else [])
    ns = [8, 16, 32, 64]
    errs = {m: [] for m in modes}
    for mode in modes:
        for n in ns:
            vals = []
            for seed in range(3):
                tr = LookinSampler(scene, LookinSettings(lookins=(n, n), pixels=(32, 32), secondary=mode), caster)
                acc = EnvelopeAccumulator(AXIS, IRF, len(tr.component_names))
                tr.run(acc, np.random.default_rng(seed))
                vals.append(acc.total_weight()[3] / sec - 1)
            errs[mode].append(vals)
    rms = {m: np.sqrt(np.mean(np.square(v), axis=1)) for m, v in errs.items()}
    print({m: np.round(v, 4) for m, v in rms.items()})
    assert np.polyfit(np.log(np.square(ns)), np.log(rms["full"]), 1)[0] < -0.4
    assert rms["full"][-1] < 0.1
    assert np.all(np.array(errs["optimized"]) < -0.5)
    if "exact" in rms:
        assert np.allclose(errs["exact"], errs["full"], atol=1e-3)


def test_run_accuracy_on_a_small_scene():
    scene = patch_scene(with_occluder=True)
    from test_reference import config

    cfg = config(secondary="full")
    ref = converged_reference(scene, cfg, rel_tol=3e-2, samples=1 << 10)
    rows = run_accuracy(scene, ref, cfg, budget=1.0, estimators=("lookin", "area"))
    assert {r.estimator for r in rows} == {"lookin", "area"}
    assert all(np.isfinite([r.seconds, r.rel_l2, r.total, r.peak_time]).all() for r in rows)
    assert any(r.pareto for r in rows)
    for name in ("lookin", "area"):                 # the ladder runs in order and stops on the budget
        settings = [r.setting for r in rows if r.estimator == name]
        assert settings == [LADDERS[name].describe(s) for s in LADDERS[name].ladder[:len(settings)]]
        assert len(settings) < len(LADDERS[name].ladder)
    with pytest.raises(ConfigError, match="unknown estimator"):
        run_accuracy(scene, ref, cfg, budget=1, estimators=("magic",))


def tiny_scene_yaml(path):
    data = {
        "name": "tiny",
        "objects": [
            {"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [2.0, -2.0, -2.0],
             "edge_u": [0.0, 4.0, 0.0], "edge_v": [0.0, 0.0, 4.0], "material": {"albedo": 0.9}},
            {"builder": "quad", "name": "patch", "corner": [1.0, -0.2, 0.3], "edge_u": [0.0, 0.4, 0.0],
             "edge_v": [0.0, 0.0, 0.4], "material": {"albedo": 0.8}},
            {"builder": "box", "name": "occluder", "center": [1.45, 0.1, 0.1], "size": [0.1, 0.25, 0.25]},
        ],
        "laser": {"emitter": [0.0, 0.0, -0.5], "spot": [2.0, 0.0, 0.0]},
        "sensor": {"position": [0.0, 0.0, -0.5], "aperture_radius": "20mm",
                   "fov": {"center": [2.0, 0.0, -0.6], "size": [0.8, 0.8]}},
        "simulation": {"time": {"t_start": "0ns", "bin_width": "20ps", "n_bins": 1000}, "irf": {"fwhm": "100ps"},
                       "secondary": "full", "detector": {"repetition_rate": 1.0e7, "n_cycles": 100}},
    }
    path.write_text(yaml.safe_dump(data))
    return path


def test_bench_accuracy_cli_writes_csv_png_and_table(tmp_path):
    scene = tiny_scene_yaml(tmp_path / "tiny.yaml")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--budget", "8s", "--out", str(out),
                                    "--rel-tol", "0.05", "--reference-samples", "1024",
                                    "--cache-dir", str(tmp_path / "cache"), "--estimators", "lookin,top1,area"])
    assert res.exit_code == 0, res.output
    with (out / "accuracy.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["estimator"] for r in rows} == {"lookin", "top1", "area"}
    assert all(float(r["seconds"]) > 0 and float(r["rel_l2"]) >= 0 for r in rows)
    assert any(r["pareto"] == "1" for r in rows)
    assert (out / "accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| estimator | setting |" in res.output and "reference:" in res.output
    assert list((tmp_path / "cache").glob("reference_*.npz"))


def test_bench_accuracy_with_every_order_runs_the_tolerance_loop_against_an_all_order_reference(tmp_path):
    """--orders auto: the reference holds every order and the tolerance ladder (the area sampler's tolerance loop)
    runs from 16 % down; each of its results is within twice its tolerance of that reference, and the error falls
    along the ladder. A bad --orders is one line."""
    scene = tiny_scene_yaml(tmp_path / "tiny.yaml")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--budget", "40s", "--out", str(out),
                                    "--rel-tol", "0.02", "--reference-samples", "4096", "--orders", "auto",
                                    "--cache-dir", str(tmp_path / "cache"), "--estimators", "area,tolerance"])
    assert res.exit_code == 0, res.output
    with (out / "accuracy.csv").open() as fh:
        rows = [r for r in csv.DictReader(fh) if r["estimator"] == "tolerance"]
    assert len(rows) >= 3 and rows[0]["setting"] == "tol=0.16"
    for r in rows:
        assert float(r["rel_l2"]) <= 2 * float(r["setting"].split("=")[1]) + 0.02, r     # + the reference's own
    assert float(rows[-1]["rel_l2"]) < float(rows[0]["rel_l2"])
    bad = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--orders", "0"])
    assert bad.exit_code == 2 and "--orders" in bad.output and "Traceback" not in bad.output


def test_bench_accuracy_over_dataset_rooms_reports_median_and_p95(tmp_path):
    """--dataset CONFIG --samples N: the ladders run on rooms 0 … N-1 of the val split, each against its own
    reference; the CSV has a line per (room, step) and a median / p95 summary per setting."""
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", "--dataset", "configs/datasets/smoke.yaml", "--samples", "2",
                                    "--budget", "20s", "--out", str(out), "--rel-tol", "0.05",
                                    "--reference-samples", "1024", "--cache-dir", str(tmp_path / "cache"),
                                    "--estimators", "area"])
    assert res.exit_code == 0, res.output
    with (out / "accuracy.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    rooms = {r["room"] for r in rows if r["kind"] == "room"}
    assert rooms == {"val[0]", "val[1]"}
    summary = [r for r in rows if r["kind"] == "summary"]
    assert summary and all(r["estimator"] == "area" for r in summary)
    first = summary[0]
    per_room = [float(r["rel_l2"]) for r in rows if r["kind"] == "room" and r["setting"] == first["setting"]]
    assert float(first["rel_l2"]) == pytest.approx(float(np.median(per_room)), rel=1e-5)
    assert int(first["rooms"]) == len(per_room) == 2
    assert (out / "accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| estimator | setting | rooms |" in res.output and "references: 2 rooms" in res.output
    res = CliRunner().invoke(main, ["bench", "accuracy", "--dataset", "configs/datasets/smoke.yaml", "--samples",
                                    "99", "--out", str(out)])
    assert res.exit_code == 2 and "--samples must be in [1, 8]" in res.output


def test_bench_accuracy_refuses_a_scan_whose_reference_outlasts_the_budget(tmp_path):
    """A scanned capture's Monte Carlo reference runs the area sampler once per laser point and a replica cannot
    stop half-way (16 × 16 points: ≈ 17 min per replica): the command refuses at once, in one line naming the file,
    the laser points and what to change (--quadrature-reference among it), for a scene and for a dataset config,
    and writes nothing. (Before, both
    ran past a 60 s --budget for tens of minutes without a word; the tests' hang guard would stop that here.)"""
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", "scene_library/confocal_scan.yaml", "--budget", "60s",
                                    "--out", str(out)])
    line = res.output.strip()
    assert res.exit_code == 2 and "\n" not in line, res.output
    assert "confocal_scan.yaml" in line and "256 laser points" in line
    replica = 256 * REFERENCE_POINT_SECONDS                        # 1024 s at the default samples
    assert f"--budget {int(np.ceil(2 * replica / 60))}min or more" in line
    assert f"--reference-samples {int(REFERENCE_SAMPLES * 60 / replica)} or fewer" in line
    assert "--quadrature-reference" in line and not out.exists()
    res = CliRunner().invoke(main, ["bench", "accuracy", "--dataset", "configs/datasets/wall_smoke.yaml",
                                    "--samples", "2", "--out", str(out)])
    assert res.exit_code == 2 and "wall_smoke.yaml (train[0])" in res.output and "256 laser points" in res.output
    assert not out.exists()


def test_bench_accuracy_of_a_scan_dataset_against_the_quadrature_reference(tmp_path):
    """--quadrature-reference: each room's quadrature ladder (4× the config's edge down to it, factors of √2, the
    grading ratio scaled with the edge) against the quadrature at a quarter of the config's edge. confocal_smoke's
    8 × 8 rooms: the error falls as h² (the 1 m → 0.5 m steps differ by 2–8×, 3.5× measured), the finest step is
    the config's edge, and each reference states its own error far below that step's."""
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", "--dataset", "configs/datasets/confocal_smoke.yaml",
                                    "--samples", "2", "--quadrature-reference", "--budget", "120s",
                                    "--out", str(out)])
    assert res.exit_code == 0, res.output
    with (out / "accuracy.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    summary = {r["setting"]: r for r in rows if r["kind"] == "summary"}
    assert list(summary) == ["h=2 m", "h=1.41 m", "h=1 m", "h=0.707 m", "h=0.5 m"]      # edge 0.5 m × 4 … × 1
    assert all(r["estimator"] == "quadrature" and r["rooms"] == "2" for r in summary.values())
    err = {k: float(v["rel_l2"]) for k, v in summary.items()}
    assert 2.0 < err["h=1 m"] / err["h=0.5 m"] < 8.0
    for r in rows:
        if r["kind"] == "room" and r["setting"] == "h=0.5 m":
            assert float(r["reference_error"]) < float(r["rel_l2"]) / 4
    assert "reference quadrature h = 0.125 m" in res.output


def test_scan_ladder_ends_at_the_samples_own_transport():
    """The scan ladder's finest step is the config's edge itself (even steps exact powers of 2) with its grading
    ratio and FoV cells, so measured against the envelope ``datagen.simulate`` gives the dataset sample its error is
    round-off (3e-15 measured; 0 on a wall.yaml room); the reference is a quarter of that edge with a quarter of the
    grading ratio."""
    import datagen
    from datagen.analysis.scan_accuracy import SCAN_LADDER, scan_ladder
    from datagen.dataset import load_dataset_config, sample_setup

    scene, sim = sample_setup(load_dataset_config("configs/datasets/confocal_smoke.yaml"), "train", 1)
    ladder, ref_step = scan_ladder(scene, sim)
    assert [s["edge"] for s in ladder.ladder[::2]] == [2.0, 1.0, 0.5]               # edge 0.5 m: 4×, 2×, 1×
    assert ladder.ladder[-1]["grading"] == sim.estimator.grading == 0.5
    assert ref_step["edge"] == 0.125 and ref_step["grading"] == 0.125
    sample = datagen.simulate(scene, sim)
    rows = run_accuracy(scene, sample, sim, budget=60.0, estimators=(SCAN_LADDER,), ladder_table={SCAN_LADDER: ladder})
    assert [r.setting for r in rows] == [ladder.describe(s) for s in ladder.ladder]
    assert rows[-1].rel_l2 < 1e-12 and rows[-1].total < 1e-12
    assert rows[0].rel_l2 > 0.01                                                     # 2 m: a few per cent


def test_bench_accuracy_quadrature_reference_on_a_scene_and_its_bad_input(tmp_path):
    """The scene form of --quadrature-reference writes the ladder's CSV; other estimators, --reference-edge without
    it, and a reference edge too coarse for any step are one-line errors."""
    scene = tiny_scene_yaml(tmp_path / "tiny.yaml")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--quadrature-reference",
                                    "--reference-edge", "0.01", "--budget", "60s", "--out", str(out)])
    assert res.exit_code == 0, res.output
    with (out / "accuracy.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and {r["estimator"] for r in rows} == {"quadrature"}
    assert float(rows[-1]["rel_l2"]) < float(rows[0]["rel_l2"])
    for args, words in ((["--quadrature-reference", "--estimators", "area"], "quadrature's ladder only"),
                        (["--reference-edge", "0.01"], "goes with --quadrature-reference"),
                        (["--quadrature-reference", "--reference-edge", "9"], "would be coarser")):
        res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), *args, "--out", str(out)])
        assert res.exit_code == 2 and words in res.output and res.output.count("\n") == 1, res.output


def test_check_reference_size_projects_laser_points_times_samples():
    """The projection is laser points × REFERENCE_POINT_SECONDS × samples / REFERENCE_SAMPLES against the budget:
    the same 256-point scan passes at 1/128 of the samples (8 s of a 60 s budget) and a single laser point passes
    at the default samples (4 s) but not under a 3 s budget, whose message then has no scan advice."""
    from datagen.scene import load_scene

    scan = load_scene("scene_library/confocal_scan.yaml")
    check_reference_size(scan, "scan", REFERENCE_SAMPLES // 128, 60.0)
    with pytest.raises(ConfigError, match="256 laser points"):
        check_reference_size(scan, "scan", REFERENCE_SAMPLES // 8, 60.0)        # 128 s
    room = load_scene("scene_library/demo_room.yaml")
    check_reference_size(room, "room", REFERENCE_SAMPLES, 60.0)
    with pytest.raises(ConfigError) as info:
        check_reference_size(room, "room", REFERENCE_SAMPLES, 3.0)
    assert "its laser point takes ≈ 4s" in str(info.value) and "--quadrature-reference" not in str(info.value)


def test_bench_accuracy_cli_bad_input_is_one_line(tmp_path):
    scene = tiny_scene_yaml(tmp_path / "tiny.yaml")
    res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--budget", "-1s", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "error:" in res.output and "--budget" in res.output
    res = CliRunner().invoke(main, ["bench", "accuracy", str(scene), "--estimators", "magic", "--out",
                                    str(tmp_path), "--rel-tol", "0.5", "--reference-samples", "256",
                                    "--cache-dir", str(tmp_path / "c")])
    assert res.exit_code == 2 and "unknown estimator" in res.output


def test_scan_ladder_keeps_the_configs_fixed_fov_cells():
    """A config that fixes its FoV cells (wall_smoke: one per 12.5 cm pixel, where its 12 cm edge alone would take
    2 × 2; a scan that leaves them unset gets one per pixel at every edge too) has them at every step of the ladder
    and in the reference, so the finest step is the sample's own transport again (error round-off against
    ``datagen.simulate``'s envelope)."""
    import datagen
    from datagen.analysis.scan_accuracy import SCAN_LADDER, scan_ladder
    from datagen.dataset import load_dataset_config, sample_setup
    from datagen.transport import estimator as transport_estimator

    scene, sim = sample_setup(load_dataset_config("configs/datasets/wall_smoke.yaml"), "train", 0)
    assert sim.estimator.fov_cells == 1
    capture = datagen.scene.resolve_capture(scene, datagen.scene.RayCaster(scene))
    cells = transport_estimator(SCAN_LADDER).cls.aperture_cells
    # unset on a scan: one per pixel at every edge; "edge" (the old default): ceil(12.5 cm / edge)
    assert [cells(capture, e) for e in (sim.estimator.edge, 0.05, 0.01)] == [1, 1, 1]
    assert [cells(capture, e, "edge") for e in (sim.estimator.edge, 0.05, 0.01)] == [2, 3, 13]
    single = datagen.load_scene("scene_library/demo_room.yaml")           # one laser spot: the cells follow the edge
    spot = datagen.scene.resolve_capture(single, datagen.scene.RayCaster(single))
    side = max(np.asarray(spot.fov_size) / np.asarray(spot.fov_pixels))
    assert cells(spot, side / 2.5) == 3 and cells(spot, side / 2.5, 2) == 2
    ladder, ref_step = scan_ladder(scene, sim)
    assert {s["fov_cells"] for s in ladder.ladder} == {1} and ref_step["fov_cells"] == 1
    rows = run_accuracy(scene, datagen.simulate(scene, sim), sim, budget=60.0, estimators=(SCAN_LADDER,),
                        ladder_table={SCAN_LADDER: ladder})
    assert rows[-1].rel_l2 < 1e-12 and rows[0].rel_l2 > 1e-3
