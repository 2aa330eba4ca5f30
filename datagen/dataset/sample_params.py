"""Pieces of a sample's ``params`` record (:func:`datagen.dataset.config.make_sample`; docs/datasets.md, "Loading"):
what its adaptive sampling did, the JSON encoding of numpy values, and the record itself."""
from __future__ import annotations

import json

import numpy as np

__all__ = ["accuracy_record", "json_default", "params_array"]


def accuracy_record(attrs: dict) -> dict:
    """What the sample's adaptive sampling did: target, estimate, met, replicas and their setting, nominal s (from a
    simulation result's ``attrs``: its ``tolerance`` and ``error`` blocks)."""
    tol, err = attrs["tolerance"], attrs["error"]
    return {"tolerance": tol["target"], "envelope_error": err["rel_l2"], "met": tol["met"],
            "replicas": err["replicas"], "replica_setting": err["replica_setting"],
            "nominal_seconds": tol.get("nominal_seconds")}


def json_default(value):
    """``json.dumps``'s ``default``: numpy arrays and scalars as lists and numbers. Raises TypeError otherwise."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON-able: {type(value).__name__}")


def params_array(ids: dict, room, attrs: dict, accuracy: dict, drawn: dict | None, orders: dict | None = None
                 ) -> np.ndarray:
    """A sample's ``params``: a 0-d object array holding its JSON (keys sorted). ``ids`` (dataset seed, split, its
    key, index, stream ids), the room's ``params`` and ``objects``, the ``effects`` and the plan's decisions (on,
    forced, reason) of ``attrs`` (a simulation result's), ``accuracy``, ``orders`` and the detector draw when
    given."""
    plan = {effect: {k: d[k] for k in ("on", "forced", "reason")} for effect, d in attrs["plan"].items()}
    params = {**ids, "room": room.params, "objects": room.objects, "effects": attrs.get("effects"),
              "accuracy": accuracy, "plan": plan}
    if orders is not None:
        params["orders"] = orders
    if drawn:
        params["detector_draw"] = drawn
    return np.array(json.dumps(params, sort_keys=True, default=json_default), dtype=object)
