"""Moving objects: poses against closed forms, the refusals of bad motion input, and sequences of frames against
frames simulated on their own (datagen/scene/motion.py, datagen/simulation/sequence.py; docs/motion.md)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

import datagen
from datagen.errors import SceneError
from datagen.scene.load import scene_from_dict
from datagen.scene.motion import FrameSpec, KeyframeMotion, VelocityMotion, WalkMotion, posed_vertices
from datagen.simulation.sequence import simulate_sequence

ROOM = {"builder": "l_room", "relay_x": 6.0, "height": 2.85}
WALKER = {"builder": "box", "name": "walker", "center": [4.0, 3.5, 0.9], "size": [0.4, 0.3, 1.8],
          "motion": {"kind": "walk", "path": [[4.0, 3.5], [5.0, 2.5], [5.0, 4.5]], "speed": 1.0}}
SCENE = {"name": "moving", "objects": [ROOM, WALKER],
         "laser": {"emitter": [0, 0, 1], "spot": [6.0, 0.0, 2.5]},
         "sensor": {"position": [0, 0, 1], "aperture_radius": "20mm",
                    "fov": {"center": [6.0, 0.0, 1.5], "size": [2.0, 2.0]}},
         "capture": {"frames": {"count": 3, "rate": "2Hz", "exposure": "10ms"}},
         "simulation": {"estimator": {"kind": "area", "samples": 16384}, "orders": 1,
                        "time": {"t_start": "20ns", "bin_width": "200ps", "n_bins": 200}, "irf": {"fwhm": "600ps"},
                        "detector": {"model": "poisson", "pde": 0.3, "dcr": 100, "repetition_rate": 1e7,
                                     "exposure": "10ms"}}}


def scene_with(**changes) -> dict:
    data = copy.deepcopy(SCENE)
    for path, value in changes.items():
        node = data
        keys = path.split(".")
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node[k]
        node[keys[-1]] = value
    return data


def test_keyframes_interpolate_linearly_and_hold_outside():
    m = KeyframeMotion(kind="keyframes", keyframes=[{"t": 0, "position": [0, 0, 0]},
                                                    {"t": "2s", "position": [2, 4, 0], "yaw_deg": 90}])
    pos, yaw = m.pose(np.array([-1.0, 0.5, 2.0, 9.0]), np.zeros(3))
    np.testing.assert_allclose(pos, [[0, 0, 0], [0.5, 1, 0], [2, 4, 0], [2, 4, 0]], atol=1e-15)
    np.testing.assert_allclose(yaw, np.radians([0, 22.5, 90, 90]), atol=1e-15)
    smooth = m.model_copy(update={"interpolation": "smooth"})
    np.testing.assert_allclose(smooth.pose(np.array([0.0, 2.0]), np.zeros(3))[0], [[0, 0, 0], [2, 4, 0]],
                               atol=1e-15)


def test_velocity_with_turning_follows_the_circular_arc():
    v, w = 1.5, 30.0                                      # m/s along x, °/s
    m = VelocityMotion(kind="velocity", velocity=[v, 0, 0], turn_rate_deg=w, start=[1, 1, 0])
    half_turn = math.pi / math.radians(w)                 # a semicircle of radius v/ω
    pos, yaw = m.pose(np.array([half_turn]), np.zeros(3))
    np.testing.assert_allclose(pos[0], [1, 1 + 2 * v / math.radians(w), 0], atol=1e-12)
    assert yaw[0] == pytest.approx(math.pi)
    t = np.linspace(0, 5, 501)                            # speed stays |v| all along
    p = m.pose(t, np.zeros(3))[0]
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)
    np.testing.assert_allclose(speed, v, rtol=1e-4)


def test_walk_reaches_each_waypoint_when_its_length_is_walked_and_faces_the_way():
    m = WalkMotion(kind="walk", path=[[0, 0], [3, 4], [3, 0]], speed=2.0, start_time=1.0)
    pos, yaw = m.pose(np.array([0.0, 1.0 + 5 / 2, 1.0 + 9 / 2, 100.0]), np.array([9, 9, 0.7]))
    np.testing.assert_allclose(pos, [[0, 0, 0.7], [3, 4, 0.7], [3, 0, 0.7], [3, 0, 0.7]], atol=1e-12)
    mid_second_leg = m.pose(np.array([1.0 + 7 / 2]), np.zeros(3))[1][0]
    assert mid_second_leg == pytest.approx(-math.pi / 2 - math.atan2(4, 3))


def test_scene_at_moves_only_the_moving_object_rigidly():
    scene = scene_from_dict(SCENE)
    later = scene.at(1.2)
    for a, b in zip(scene.objects, later.objects):
        if a.name == "walker":
            da = np.linalg.norm(a.vertices[:, None] - a.vertices[None], axis=2)
            db = np.linalg.norm(b.vertices[:, None] - b.vertices[None], axis=2)
            np.testing.assert_allclose(db, da, atol=1e-12)
            assert np.abs(b.vertices - a.vertices).max() > 0.5
        else:
            assert b.vertices is a.vertices
    built = scene.moving["walker"].vertices
    np.testing.assert_allclose(posed_vertices(scene.moving["walker"].motion, built, 0.0), built, atol=1e-12)


def test_each_instant_checks_the_moving_object_against_everything_and_the_still_pairs_once(monkeypatch):
    import datagen.scene.coincident as coincident
    crate = {"builder": "box", "name": "crate", "center": [4.5, 3.0, 0.3], "size": [0.4, 0.4, 0.6]}
    scene = scene_from_dict({**SCENE, "objects": [ROOM, crate, WALKER]})
    tested = []
    find = coincident.find_coincident_faces
    monkeypatch.setattr(coincident, "find_coincident_faces",
                        lambda *a: tested.append(a[3]) or find(*a))
    for t in (0.1, 0.2):                  # the walker on the floor, clear of the crate: as built from scratch
        frame = scene.at(t)
        pairs = tested[-1]                # the walker's pairs only (the still ones were checked when built)
        assert pairs is not None and pairs.tolist() == [o.name == "walker" for o in scene.objects]
        alone = datagen.Scene(frame.objects, frame.laser, frame.sensor, capture=frame.capture)
        assert [o.faces.tolist() for o in frame.objects] == [o.faces.tolist() for o in alone.objects]
        assert frame.notes == alone.notes
    with pytest.raises(SceneError, match="'crate' and 'walker'.*coplanar faces"):
        scene.at(0.707)                   # walked into the crate: their bottoms overlap, seen from below


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("changes, expected", [
    ({"objects.1.motion": {"kind": "keyframes", "keyframes": [{"t": 0, "position": [4, 3, 0.9]},
                                                              {"t": 2, "position": [4, 3.5, 0.9]},
                                                              {"t": 1, "position": [4, 4, 0.9]}]}},
     "objects.1.box.motion.keyframes.keyframes: keyframe times must increase: keyframes.2.t = 1 s is not after"),
    ({"objects.1.motion": {"kind": "velocity", "velocity": [0, 2.0, 0]},
      "capture.frames": {"count": 100, "rate": "10Hz", "exposure": "10ms"}},
     "objects.1.motion: object 'walker' leaves the room at t = 0.71 s (y reaches 5.070 m, the room spans "
     "-1.050..5.050 m)"),
    ({"capture.frames": {"count": 10, "rate": "10Hz", "exposure": "200ms"}},
     "capture.frames: exposure 200 ms is longer than a frame (1/rate = 100 ms at 10 Hz)"),
    ({"objects.1.motion.path": [[4, 3], [4, 3]]}, "path.1 repeats path.0 [4.0, 3.0]"),
    ({"objects.1.motion.speed": 0}, "objects.1.box.motion.walk.speed: Input should be greater than 0"),
])
def test_bad_motion_input_is_refused_in_one_line_naming_the_field(tmp_path, changes, expected):
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene_with(**changes)))
    with pytest.raises(SceneError) as err:
        datagen.load_scene(path)
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(path)) and expected in message, message


def test_frame_spec_scan_order_times():
    frames = FrameSpec(count=2, rate=10, exposure=0.04, scan_order="serpentine")
    t = frames.point_times(4, (2, 2))        # dwell 10 ms: rows visited 0 1 | 3 2
    np.testing.assert_allclose(t[1] - 0.1, [0.005, 0.015, 0.035, 0.025], atol=1e-15)


def _norm(a):
    return float(np.sqrt(np.sum(a * a)))


def test_sequence_frames_match_frames_simulated_alone_within_their_stated_error():
    """A 100-frame sequence by the 'changes' method: frames 0, 50 and 99 against each instant simulated on its own
    at 16× the sampling (another seed: an independent estimate), within the two stated Monte Carlo errors; the step
    from frame 50 to 51 against that of the references, within the stated step error and the references' noise."""
    scene = scene_from_dict(scene_with(**{"capture.frames": {"count": 100, "rate": "25Hz", "exposure": "10ms"}}))
    config = datagen.resolve_config(scene)
    seq = simulate_sequence(scene, config, change_split=8)
    assert seq.envelopes.shape == (100, 200) and seq.counts.shape == (100, 200) and seq.counts.dtype == np.int64
    fine = datagen.resolve_config(scene, {"estimator": {"kind": "area", "samples": 262144}, "seed": 7})
    refs = {}
    for f in (0, 50, 51, 99):
        ref = datagen.simulate(scene.at(seq.frame_times[f] + 0.005), fine)
        refs[f] = ref.envelope
        bound = math.hypot(seq.monte_carlo_error[f], ref.attrs["error"]["monte_carlo"])   # the same orders
        gap = _norm(seq.envelopes[f] - ref.envelope) / _norm(ref.envelope)
        assert gap <= bound, (f, gap, bound)
    assert seq.monte_carlo_error[50] < 1.5 * seq.monte_carlo_error[0]   # the change adds little noise
    step, ref_step = seq.envelopes[51] - seq.envelopes[50], refs[51] - refs[50]
    assert _norm(step) / _norm(seq.envelopes[50]) > 1e-4             # the walker moved 4 cm: the frames differ
    step_gap = _norm(step - ref_step) / _norm(seq.envelopes[50])
    assert step_gap <= seq.difference_error + ref.attrs["error"]["monte_carlo"] / 4, (step_gap, seq.difference_error)
    assert seq.difference_error < seq.monte_carlo_error[0] / 2
    np.testing.assert_allclose(seq.positions[[0, 50], 0, :2], [[4.0035, 3.4965], [5.0, 3.0908]], atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(seq.velocities[:50, 0], axis=1), 1.0, rtol=1e-6)
    assert np.all(seq.boxes[:, 0, 0] < seq.positions[:, 0]) and np.all(seq.positions[:, 0] < seq.boxes[:, 0, 1])


def test_a_changes_sequence_starts_from_its_first_frame_simulated_alone_and_scrambles_each_sobol_set_once(
        monkeypatch):
    """The 'changes' method's reference runs with the config as given: frame 0 is the frame simulated on its own, to
    the bit. Its changes draw the same Sobol sets every frame: the Sobol memo (datagen.sampling.sobol) scrambles each
    set once, gives it again to the bit and spawns the child the scrambling would have spawned, so every later draw
    is the same too."""
    from scipy.stats import qmc

    from datagen.sampling import sobol

    scene = scene_from_dict(scene_with())
    config = datagen.resolve_config(scene)
    seq = simulate_sequence(scene, config, change_split=8)
    alone = datagen.simulate(scene.at(seq.frame_times[0] + 0.005), config)
    np.testing.assert_array_equal(seq.envelopes[0], alone.envelope)
    assert seq.error[0] == alone.attrs["error"]["rel_l2"] and np.all(seq.error[1:] > seq.error[0])

    def draws(points):
        rng = np.random.default_rng(np.random.SeedSequence(11, spawn_key=(3, 0)))
        return [points(4, 128, rng), points(5, 64, rng), rng.random(4), points(4, 128, rng),
                rng.spawn(1)[0].random(3)]
    first = draws(lambda d, n, rng: qmc.Sobol(d=d, scramble=True, seed=rng).random(n))
    scrambled, engine = [], qmc.Sobol
    monkeypatch.setattr(sobol.qmc, "Sobol", lambda *a, **k: scrambled.append(k["d"]) or engine(*a, **k))
    for _ in range(2):                       # the second time from the memo
        for a, b in zip(first, draws(sobol.scrambled_sobol)):
            np.testing.assert_array_equal(a, b)
    assert sorted(scrambled) == [4, 4, 5]    # three sets, each scrambled once


def test_motion_during_a_confocal_scan_is_each_point_at_its_own_instant():
    """A box crossing a 3 × 3 confocal scan during one frame: the 'frames' method with one slot per point equals,
    to the bit, a scan simulated at each point's instant with that point kept; the late points see the box moved
    (its return earlier or later than in a scan frozen at the frame's start)."""
    data = {"name": "scan_motion",
            "objects": [{"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [2.0, -1.05, -0.05],
                         "edge_u": [0.0, 0.0, 2.1], "edge_v": [0.0, 2.1, 0.0]},
                        {"builder": "box", "name": "box", "center": [1.1, -0.6, 1.0], "size": [0.3, 0.3, 0.3],
                         "motion": {"kind": "velocity", "velocity": [-1.0, 12.0, 0.0]}}],
            "laser": {"emitter": [1.5, -3.0, 1.0], "spot": [2.0, 0.0, 1.0], "pulse_energy": "10pJ"},
            "sensor": {"position": [1.5, -3.0, 1.0], "aperture_radius": "20mm"},
            "capture": {"type": "confocal", "laser_grid": {"center": [2.0, 0.0, 1.0], "size": [1.0, 1.0],
                                                            "points": [3, 3]},
                        "frames": {"count": 1, "rate": "10Hz", "exposure": "90ms"}},
            "simulation": {"estimator": {"kind": "quadrature", "edge": 0.1}, "orders": 1,
                           "effects": {"first_bounce": False}, "count_laser_leg": False, "count_sensor_leg": False,
                           "time": {"t_start": "0ns", "bin_width": "32ps", "n_bins": 256}, "irf": {"fwhm": "70ps"},
                           "detector": {"model": "poisson", "pde": 0.3, "dcr": 100, "repetition_rate": 1e7,
                                        "exposure": "10ms"}}}
    scene = scene_from_dict(data)
    config = datagen.resolve_config(scene)
    seq = simulate_sequence(scene, config, method="frames")
    times = scene.capture.frames.point_times(9, (3, 3))[0]
    by_hand = np.empty((9, 256))
    for k, t in enumerate(times):
        by_hand[k] = datagen.simulate(scene.at(t), config).envelope.reshape(9, 256)[k]
    np.testing.assert_array_equal(seq.envelopes[0].reshape(9, 256), by_hand)
    frozen = datagen.simulate(scene.at(times[0]), config).envelope.reshape(9, 256)
    centre = lambda e: (e * np.arange(256)).sum(axis=-1) / e.sum(axis=-1)   # noqa: E731
    np.testing.assert_array_equal(by_hand[0], frozen[0])
    assert np.abs(centre(by_hand[-3:]) - centre(frozen[-3:])).max() > 2      # bins: the last row sees it moved
    with pytest.raises(SceneError, match="needs a Monte Carlo estimator"):
        simulate_sequence(scene, config, method="changes")


def test_sequence_command_writes_a_store_that_reads_back_and_its_figure(tmp_path):
    from click.testing import CliRunner

    from datagen.cli.main import main
    from datagen.io.store import read_sequence

    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene_with(**{"simulation.estimator.samples": 4096,
                                                 "capture.frames.count": 4})))
    out = tmp_path / "out"
    run = CliRunner().invoke(main, ["sequence", str(path), "--out", str(out), "--change-split", "4"])
    assert run.exit_code == 0, run.output
    assert "4 frames at 2 Hz, 10 ms each (changes)" in run.output and "walker: from [4.004, 3.496, 0.9]" in run.output
    seq = read_sequence(out)
    assert seq.envelopes.shape == (4, 200) and seq.counts.shape == (4, 200) and seq.moving == ["walker"]
    assert seq.positions.shape == (4, 1, 3) and seq.boxes.shape == (4, 1, 2, 3) and seq.attrs["change_split"] == 4
    assert (out / "sequence.png").stat().st_size > 10_000
    again = CliRunner().invoke(main, ["sequence", str(path), "--out", str(tmp_path / "again"), "--change-split", "4"])
    np.testing.assert_array_equal(read_sequence(tmp_path / "again").counts, seq.counts)   # a seed's bits
    path.write_text(yaml.safe_dump(scene_with(**{"capture": {"type": "single"}})))
    refused = CliRunner().invoke(main, ["sequence", str(path), "--out", str(out)])
    assert refused.exit_code != 0 and "capture.frames is missing" in refused.output
    assert len(refused.output.strip().splitlines()) == 1


def test_rooms_draw_walkers_that_stay_in_the_room_and_pass_the_objects():
    from datagen.dataset.rooms import load_room_distribution
    from datagen.dataset.obb import box_hits_segment
    from datagen.dataset.sampler import sample_room
    from datagen.errors import ConfigError

    frames = {"count": 50, "rate": "10Hz", "exposure": "50ms"}
    dist = load_room_distribution("configs/rooms/default.yaml").with_overrides(
        {"motion": {"walkers": 1, "speed": {"min": 0.5, "max": 2.0}, "frames": frames}})
    for seed in range(6):
        streams = ("geometry", "materials", "sensor", "motion")
        rngs = {k: np.random.default_rng([seed, i]) for i, k in enumerate(streams)}
        room = sample_room(dist, rngs)
        walker = room.params["motion"]["walkers"][0]
        assert 0.5 <= walker["speed"] <= 2.0 and 1.6 <= walker["size"][2] <= 1.9
        scene = room.scene
        assert list(scene.moving) == ["walker_0"] and scene.capture.frames.count == 50
        ends = np.array(walker["path"])
        for o in room.objects:     # the straight walk, widened by the walker, misses every object below its top
            if o["center"][2] - o["size"][2] / 2 < walker["size"][2]:
                z = o["center"][2]
                assert not box_hits_segment(o, np.array([*ends[0], z]), np.array([*ends[1], z]),
                                            math.hypot(*walker["size"][:2]))
        again = sample_room(dist, {k: np.random.default_rng([seed, i]) for i, k in enumerate(streams)})
        assert again.params["motion"] == room.params["motion"]
    with pytest.raises(ConfigError, match="motion: walkers need frames"):
        load_room_distribution("configs/rooms/default.yaml").with_overrides({"motion": {"walkers": 1}})
    with pytest.raises(ConfigError, match="needs a 'motion' stream"):
        sample_room(dist, {k: np.random.default_rng(0) for k in ("geometry", "materials", "sensor")})


def test_aligned_tracer_draws_share_the_paths_that_miss_a_moved_object():
    """The order ≥ 3 tracer with aligned draws (common random numbers): a walker moved by 5 cm changes the tracer's
    envelope by far less than the seed's own noise, since every path that misses it is traced identically; with the
    live-only draws, the paths after the first that meets it shift their numbers and the change is the noise."""
    scene = scene_from_dict(scene_with(**{"simulation.orders": 3, "simulation.estimator.samples": 2048}))
    moved = scene.at(0.05)
    gaps = {}
    for aligned in (False, True):
        config = datagen.resolve_config(scene)
        config = config.model_copy(update={"error": config.error.model_copy(update={"common_random_numbers": aligned}),
                                           "multibounce": config.multibounce.model_copy(update={"paths": 20000})})
        a = datagen.simulate(scene, config).components["multibounce"]
        b = datagen.simulate(moved, config).components["multibounce"]
        other = datagen.simulate(scene, config.model_copy(update={"seed": 1})).components["multibounce"]
        gaps[aligned] = _norm(b - a) / _norm(other - a)
    assert gaps[True] < 0.2 < gaps[False], gaps


def test_a_person_walks_in_a_scene_file_and_in_the_rooms():
    """The person builder: 72 triangles, feet on the floor, head at its height, 0.17 H deep and 0.43 H wide facing +x;
    a scene file's walking person keeps its shape; a room's walker can be a person."""
    from datagen.dataset.rooms import load_room_distribution
    from datagen.dataset.sampler import sample_room
    from datagen.scene.builders import person

    p = person("p", (1.0, 2.0), 1.8)
    assert len(p.faces) == 72
    np.testing.assert_allclose(p.vertices.min(axis=0), [1.0 - 0.085 * 1.8, 2.0 - 0.215 * 1.8, 0.0], atol=1e-12)
    np.testing.assert_allclose(p.vertices.max(axis=0), [1.0 + 0.085 * 1.8, 2.0 + 0.215 * 1.8, 1.8], atol=1e-12)
    walker = {"builder": "person", "name": "walker", "center": [4.0, 3.5], "height": 1.7,
              "motion": {"kind": "walk", "path": [[4.0, 3.5], [5.0, 3.5]], "speed": 1.0}}
    scene = scene_from_dict(scene_with(**{"objects": [ROOM, walker]}))
    later = scene.at(0.5).objects[-1].vertices
    np.testing.assert_allclose(later - scene.objects[-1].vertices, np.tile([0.5, 0.0, 0.0], (len(later), 1)),
                               atol=1e-12)
    dist = load_room_distribution("configs/rooms/default.yaml").with_overrides(
        {"motion": {"walkers": 1, "shape": "person", "frames": {"count": 4, "rate": "10Hz", "exposure": "50ms"}}})
    room = sample_room(dist, {k: np.random.default_rng([3, i])
                              for i, k in enumerate(("geometry", "materials", "sensor", "motion"))})
    body = room.scene.objects[-1]
    height = room.params["motion"]["walkers"][0]["size"][2]
    assert len(body.faces) == 72 and body.vertices[:, 2].max() == pytest.approx(height)
