"""Dataset configs with the older key names: renamed keys (:data:`RENAMED_KEYS`), the one-line note that lists the
old keys of a loaded config (:func:`note_old_keys`) and the canonical form that compares a card's config with a
config in the new form (:func:`canonical_json`, used when a build resumes)."""
from __future__ import annotations

import copy
import warnings
from typing import Any

from ..errors import ConfigError

RENAMED_KEYS = {"time_cap": "cost_cap"}
"""Dataset config keys renamed (old → new): ``time_cap`` was nominal seconds here and wall seconds on the command
line (``simulate --time-cap``); the nominal cap is ``cost_cap``."""


def canonical_json(data: dict) -> dict:
    """A card's ``config`` or :meth:`DatasetConfig.to_json`, location-free
    (:func:`datagen.dataset.config.location_free_json`), in one form, to compare configs written with the older and
    the current key names: renamed keys new, the ``simulation`` block as it applies over the room's
    (:func:`datagen.simulation.config.merge_overrides`) and the rooms' blocks translated."""
    from ..simulation.config import merge_overrides
    data = copy.deepcopy(data)
    for old, new in RENAMED_KEYS.items():
        if old in data:
            data.setdefault(new, data.pop(old))
    room = data.get("room") if isinstance(data.get("room"), dict) else {}
    room_sim = room.get("simulation") if isinstance(room.get("simulation"), dict) else {}
    if isinstance(data.get("simulation"), dict):
        data["simulation"] = merge_overrides(room_sim, data["simulation"])[0]
    for block in room_blocks(data):
        if isinstance(block.get("simulation"), dict):
            block["simulation"] = merge_overrides(block["simulation"], {})[0]
    return data


def room_blocks(data: dict) -> list[dict]:
    """The room mappings of a dataset config's JSON (a card's ``config`` or :meth:`DatasetConfig.to_json`): its
    ``room`` and every ``room_overrides`` (the dataset's, then each split's), those that are mappings, in place (not
    copies)."""
    splits = [s for s in (data.get("splits") or {}).values() if isinstance(s, dict)]
    blocks = [data.get("room"), data.get("room_overrides")] + [s.get("room_overrides") for s in splits]
    return [block for block in blocks if isinstance(block, dict)]


def note_old_keys(data: Any, where: str) -> None:
    """One :class:`~datagen.simulation.LegacyKeysWarning` listing the old keys of a dataset config (its
    ``simulation`` block's and :data:`RENAMED_KEYS`), if any.

    Raises:
        ConfigError: an old key and its new home both given, at different values (naming ``where``)."""
    from ..simulation import LegacyKeysWarning
    from ..simulation.config import legacy_note, translate_legacy
    if not isinstance(data, dict):
        return
    moves = [f"{old} -> {new}" for old, new in RENAMED_KEYS.items() if old in data]
    sim = data.get("simulation")
    if isinstance(sim, dict):
        kind = sim.get("estimator") if isinstance(sim.get("estimator"), str) else None
        try:
            moves += [m for m in translate_legacy(sim, kind or "lookin")[1] if kind or "dropped" not in m]
        except ValueError as exc:               # an old key beside its new home, at another value
            raise ConfigError(f"{where}: simulation: {exc}") from None
    if moves:
        warnings.warn(legacy_note(moves, where), LegacyKeysWarning, stacklevel=3)
