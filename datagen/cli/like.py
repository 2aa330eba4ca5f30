"""``datagen simulate SCENE.yaml --like STORE [--detector FILE.yaml]``: what the option reads and how it changes
the simulation (docs/capture_io.md, "Simulating a capture"); :mod:`datagen.cli.main` calls it, the library is
:mod:`datagen.io.like_capture`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

DETECTOR_FILE_BLOCKS = ("detector", "irf")
"""Top-level keys of a ``--detector`` file holding simulation blocks; a file with other keys is one flat detector
block (a configs/detectors preset, what ``fit-detector --out`` writes)."""


def read_detector_file(path: Path, scene_detector: dict | None = None) -> tuple[dict, dict | None]:
    """(detector fields, irf block or None) of a ``--detector`` YAML: a mapping with ``detector`` and / or ``irf``
    blocks (the simulation's), or one flat detector mapping; its map paths (``gain_map``, ``background_map``) are
    relative to the file, as :meth:`datagen.spad.DetectorConfig.from_yaml` reads them. The detector is checked
    merged over the scene's (``scene_detector``), the IRF alone.

    Raises:
        ConfigError: not a mapping, a block that is not a mapping, or a field the detector or IRF refuses (one line
            naming the file, the field and the value).
    """
    from pydantic import ValidationError

    from .. import spad
    from ..errors import ConfigError
    from ..scene.load import format_validation_error, read_yaml
    from ..spad.maps import maps_relative_to
    from ..timing.irf import Irf

    data = read_yaml(Path(path), "detector file", ConfigError)
    if not isinstance(data, dict) or not data:
        raise ConfigError(f"{path}: expected a mapping of detector fields or detector / irf blocks, got "
                          f"{type(data).__name__}")
    blocks = set(data) <= set(DETECTOR_FILE_BLOCKS)
    detector = data.get("detector") if blocks else data
    irf = data.get("irf") if blocks else None
    for name, block in (("detector", detector), ("irf", irf)):
        if block is not None and not isinstance(block, dict):
            raise ConfigError(f"{path}: {name}: expected a mapping, got {type(block).__name__}")
    detector = maps_relative_to(detector or {}, Path(path).parent)
    try:
        if irf is not None:
            Irf.model_validate(irf)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, f"{path} (irf)")) from None
    try:
        from ..io.like_capture import merge_detector

        spad.DetectorConfig.model_validate({"bin_width": 1e-12, "t_start": 0.0,
                                            **merge_detector(scene_detector, detector)})
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, f"{path} (detector)")) from None
    return detector, irf


def like_setup(scene, store: Path, detector_path: Path | None, echo) -> tuple[object, dict, object]:
    """(scene with the capture's grid, simulation overrides, the :class:`~datagen.io.like_capture.CaptureTemplate`)
    for ``--like store``; ``echo`` prints what was replaced and where each setting comes from.

    Raises:
        FileNotFoundError: ``store`` is not a result store; DatasetError / SceneError / ConfigError: what
            :mod:`datagen.io.like_capture` and :func:`read_detector_file` refuse.
    """
    from ..io.like_capture import capture_template, like_overrides, scene_like
    from .capture import load_capture

    store = Path(store)
    if not store.is_dir():
        raise FileNotFoundError(f"--like {store}: not a capture store (a directory); import a lab file first with "
                                "`datagen import-capture FILE --out STORE`")
    result, offsets, _ = load_capture(store)
    template = capture_template(result, offsets, str(store))
    scene, notes = scene_like(scene, template)
    scene_detector = scene.defaults.get("detector") if isinstance(scene.defaults.get("detector"), dict) else {}
    detector, irf = read_detector_file(detector_path, scene_detector) if detector_path is not None else ({}, None)
    overrides = like_overrides(template, scene.defaults, detector, irf)
    echo(f"like {store}: {template.describe()}")
    for line in notes:
        echo(f"note: {line}")
    det = overrides.get("detector") or {}
    from ..units import parse_duration
    from ..validate import format_seconds

    exposure = (format_seconds(parse_duration(det["exposure"])) if det.get("exposure") is not None else
                f"{det['n_cycles']} cycles" if det.get("n_cycles") else None)
    origin = ("--detector " + str(detector_path) if detector_path is not None and
              {"exposure", "n_cycles"} & set(detector) else f"the store {store}" if template.detector and
              {"exposure", "n_cycles"} & set(template.detector) else "the scene's detector block")
    echo(f"exposure {exposure} per scan point from {origin}" if exposure else
         "note: no exposure in the scene, the store or --detector: the detector's own default applies")
    return scene, overrides, template


def like_finish(result, template, out: Path, seed: int) -> tuple[Path, object]:
    """Put ``result`` on the capture's bins (:func:`~datagen.io.like_capture.to_capture_axis`; counts redrawn from
    the noise stream of ``seed`` when points are shifted) and write it to ``out``/result.zarr, with the capture's
    per-point ``time_offsets`` when it has them. Returns (the store written, the result on the capture's bins)."""
    from ..io import write_result
    from ..io.like_capture import to_capture_axis, write_time_offsets
    from ..io.store import RESULT_NAME
    from ..simulation.config import STREAM_NOISE, stream_rng

    rng = stream_rng(int(seed) + 1, STREAM_NOISE)       # not the stream the simulation drew its counts from
    shifted = to_capture_axis(result, template, rng)
    store = write_result(shifted, Path(out) / RESULT_NAME)
    if template.offsets is not None:
        write_time_offsets(store, np.asarray(template.offsets))
    return store, shifted
