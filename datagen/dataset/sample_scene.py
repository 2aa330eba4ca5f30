"""The scene of one sample of a built dataset, drawn again from its card (``datagen view``, ``datagen inspect``),
or of a dataset config (:func:`sample_setup`: any sample at any accuracy).

A dataset stores a sample's parameters, not its meshes. The room of sample (split, i) is a function of the
config in the dataset card and the sample's seeds only (:func:`datagen.dataset.config.draw_room`), so it is
drawn again here and, when the dataset stores ``params``, checked against the stored ones.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import DatasetError
from .config import DatasetConfig, config_from_json, draw_room, load_dataset_config, setup_sample
from .sampler import SampledRoom
from .store import read_card


def scene_of_sample(dataset_dir: str | Path, split: str | None = None, index: int = 0
                    ) -> tuple[SampledRoom, str, dict]:
    """Draw again the room of sample (``split``, ``index``) of the dataset built at ``dataset_dir``.

    Args:
        split: split name (default: the first split with samples).
        index: sample index within the split.
    Returns:
        (room, split, card): the :class:`~datagen.dataset.sampler.SampledRoom` (``scene``, ``params``,
        ``objects``), the split used and the dataset card.
    Raises:
        FileNotFoundError: no datagen dataset at ``dataset_dir``.
        ConfigError: unknown split or index out of range. DatasetError: a dataset with no samples, or a room
            that differs from the stored sample's parameters (a dataset built by another version of the room
            sampler).
    """
    card = read_card(dataset_dir)
    if split is None:
        split = next((s for s, info in card.get("splits", {}).items() if info.get("count", 0) > 0), None)
        if split is None:
            raise DatasetError(f"{dataset_dir}: the dataset has no samples")
    room, _ = draw_room(config_from_json(card["config"]), split, index)
    stored = _stored_room_params(Path(dataset_dir), card, split, index)
    if stored is not None:
        mine = json.loads(json.dumps(room.params, default=lambda v: v.tolist()))
        if stored.get("room") != mine.get("room") or stored.get("objects") != mine.get("objects"):
            raise DatasetError(f"{dataset_dir}: sample ({split}, {index}) drawn again from the card differs from "
                             "its stored parameters (built by another version of datagen's room sampler?)")
    return room, split, card


def _stored_room_params(root: Path, card: dict, split: str, index: int) -> dict | None:
    """The stored room parameters of one sample (``params["room"]``: ``room``, ``objects``, …), or None when
    the dataset does not store ``params`` or its build is not complete."""
    info = card.get("splits", {}).get(split, {})
    if "params" not in info.get("fields", {}) or card.get("status") != "complete":
        return None
    from .loader import NLOSDataset

    data = NLOSDataset(root, split=split, fields=["params"]).params(index)
    return data.get("room") if isinstance(data, dict) else None


def sample_setup(config: DatasetConfig | str | Path, split: str, index: int):
    """The scene and simulation config of sample ``index`` of ``split``: regenerate it at any accuracy, e.g.
    ``datagen.converged_reference(*datagen.sample_setup("configs/datasets/default.yaml", "val", 3))``.

    Args:
        config: a resolved :class:`DatasetConfig` or a dataset YAML path.
    Returns:
        (:class:`~datagen.scene.Scene`, :class:`~datagen.simulation.SimulationConfig`): the room the sample was
        drawn from and its resolved simulation settings (the dataset's ``simulation`` block over the room's).
        The sample itself is ``simulate_to_tolerance(scene, sim_config, config.tolerance, max_cost=
        config.cost_cap, sampling_rng=..., noise_rng=...)`` with the sample's streams
        (:func:`datagen.dataset.config.sample_rngs`).
    Raises:
        ConfigError: an unknown split, an index out of range, an invalid config file.
    """
    if not isinstance(config, DatasetConfig):
        config = load_dataset_config(config)
    room, sim_config, _ = setup_sample(config, split, index)   # as make_sample sets it up
    return room.scene, sim_config
