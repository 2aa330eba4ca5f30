"""The ``components`` field of a dataset sample: its slots (room, each hidden object, the other components) and
the (C, *S, T) array of one simulation result in that order (:func:`datagen.dataset.config.make_sample`)."""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError

COMPONENT_ROOM = "room"
OTHER_COMPONENTS = ("secondary", "first_bounce")
"""Envelope components that are not the room or a hidden object; each has a fixed slot in ``components``."""


def component_slots(max_objects: int) -> list[str]:
    """Names of the ``components`` slots: room, object_0 … object_{max_objects-1}, then :data:`OTHER_COMPONENTS`."""
    return [COMPONENT_ROOM] + [f"object_{k}" for k in range(max_objects)] + list(OTHER_COMPONENTS)


def component_arrays(result, room, max_objects: int, dtype: str, where: str) -> tuple[list[str], np.ndarray]:
    """(C, *S, T) envelopes and their names: room, hidden object k (in ``room.objects`` order; zero when
    absent), then :data:`OTHER_COMPONENTS` (zero when the simulation did not produce it, e.g. an effect the
    planner switched off for this sample).

    Object k is matched to its scene component by ``room.objects[k]["name"]`` when present, else by the
    order of the hidden objects in the scene (the generator builds them in ``objects`` order)."""
    names = list(result.components)
    scene_hidden = [o.name for o in room.scene.objects if o.name in names and o.name != COMPONENT_ROOM]
    order = [obj.get("name", scene_hidden[k] if k < len(scene_hidden) else None) for k, obj in enumerate(room.objects)]
    if sorted(map(str, order)) != sorted(scene_hidden):
        raise ConfigError(f"{where}: cannot match hidden objects {order} to envelope components {scene_hidden}")
    unknown = [n for n in names if n != COMPONENT_ROOM and n not in scene_hidden and n not in OTHER_COMPONENTS]
    if unknown:
        raise ConfigError(f"{where}: components {unknown} have no slot in the dataset (known: room, the hidden "
                         f"objects, {list(OTHER_COMPONENTS)})")
    slots = component_slots(max_objects)
    env = result.envelope
    out = np.zeros((len(slots),) + env.shape, dtype=dtype)
    out[0] = result.components[COMPONENT_ROOM]
    for k, name in enumerate(order):
        out[1 + k] = result.components[name]
    for j, name in enumerate(OTHER_COMPONENTS):
        if name in result.components:
            out[1 + max_objects + j] = result.components[name]
    return slots, out
