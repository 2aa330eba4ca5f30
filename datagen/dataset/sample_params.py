"""Pieces of a sample's ``params`` record (:func:`datagen.dataset.config.make_sample`; docs/datasets.md, "Loading"):
what its adaptive sampling did, and the JSON encoding of numpy values."""
from __future__ import annotations

__all__ = ["accuracy_record", "json_default"]


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
