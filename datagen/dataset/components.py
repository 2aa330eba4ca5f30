"""The ``components`` field of a dataset sample: its slots (room, each hidden object, the other components) and
the (C, *S, T) array of one simulation result in that order (:func:`datagen.dataset.config.make_sample`)."""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError

COMPONENT_ROOM = "room"
OTHER_COMPONENTS = ("secondary", "first_bounce")
"""Envelope components that are not the room or a hidden object; each has a fixed slot in ``components``."""

MULTIBOUNCE = "multibounce"
"""Light with three or more hidden vertices (docs/physics.md §2, "Orders"): the last slot, in datasets whose
``orders`` is "auto" or ≥ 3 only (datasets of orders 1–2 keep their layout)."""


def component_slots(max_objects: int, multibounce: bool = False) -> list[str]:
    """Names of the ``components`` slots: room, object_0 … object_{max_objects-1}, then :data:`OTHER_COMPONENTS`
    and, when ``multibounce``, :data:`MULTIBOUNCE`."""
    return ([COMPONENT_ROOM] + [f"object_{k}" for k in range(max_objects)] + list(OTHER_COMPONENTS)
            + ([MULTIBOUNCE] if multibounce else []))


def component_arrays(result, room, max_objects: int, dtype: str, where: str,
                     multibounce: bool = False) -> tuple[list[str], np.ndarray]:
    """(C, *S, T) envelopes and their names: room, hidden object k (in ``room.objects`` order; zero when
    absent), then :data:`OTHER_COMPONENTS` and (``multibounce``) :data:`MULTIBOUNCE` (zero when the simulation did
    not produce it, e.g. an effect or the orders ≥ 3 the planner switched off for this sample).

    Object k is matched to its scene component by ``room.objects[k]["name"]`` when present, else by the
    order of the hidden objects in the scene (the generator builds them in ``objects`` order)."""
    names = list(result.components)
    scene_hidden = [o.name for o in room.scene.objects if o.name in names and o.name != COMPONENT_ROOM]
    order = [obj.get("name", scene_hidden[k] if k < len(scene_hidden) else None) for k, obj in enumerate(room.objects)]
    if sorted(map(str, order)) != sorted(scene_hidden):
        raise ConfigError(f"{where}: cannot match hidden objects {order} to envelope components {scene_hidden}")
    others = list(OTHER_COMPONENTS) + ([MULTIBOUNCE] if multibounce else [])
    unknown = [n for n in names if n != COMPONENT_ROOM and n not in scene_hidden and n not in others]
    if unknown:
        raise ConfigError(f"{where}: components {unknown} have no slot in the dataset (known: room, the hidden "
                         f"objects, {others})")
    slots = component_slots(max_objects, multibounce)
    env = result.envelope
    out = np.zeros((len(slots),) + env.shape, dtype=dtype)
    out[0] = result.components[COMPONENT_ROOM]
    for k, name in enumerate(order):
        out[1 + k] = result.components[name]
    for j, name in enumerate(others):
        if name in result.components:
            out[1 + max_objects + j] = result.components[name]
    return slots, out


def orders_summary(result) -> dict:
    """The light of every order in one sample (docs/physics.md §2, "Orders"): the ``orders`` setting, the orders
    simulated ("1..all", "1..2", …), the share of the in-window envelope left out (the planner's pilot; counted in
    ``envelope_error``) and the share the ``multibounce`` component (orders ≥ 3) carries."""
    o = result.attrs["orders"]
    env = float(np.sum(result.envelope))
    mb = result.components.get("multibounce")
    return {"setting": o["setting"], "simulated": o["simulated"], "residual_share": float(o["residual_share"]),
            "multibounce_share": float(np.sum(mb)) / env if mb is not None and env > 0 else 0.0}
