"""What a build's probe sample says before the build spends (:func:`probe_notice`), and what its samples' accuracy
says once it has built them (:func:`missed_notice`).

The probe (sample 0 of the first non-empty split, :func:`datagen.dataset.build.build_dataset`) runs before anything is
written; when it misses the config's tolerance, one line says why: the cap it stopped at (``cost_cap``, nominal
seconds) and what meeting the tolerance projects per sample, or the parts of the error that no sampling brings down
(orders left out, smoothing bias) when those alone exceed it (:func:`datagen.simulation.simulate_to_tolerance`).
"""
from __future__ import annotations

from .config import DatasetConfig, Sample


def probe_notice(config: DatasetConfig, split: str, probe: Sample) -> str | None:
    """One line when the probe sample missed the tolerance (None when it met it): the cap that stopped it and what
    meeting the tolerance projects per sample in nominal seconds, or the parts of the error no sampling brings down
    when those alone exceed it. The build goes on: each sample stops at ``cost_cap``; the card lists the misses."""
    acc = probe.accuracy
    if not acc or acc.get("met", True):
        return None
    tol = f"the tolerance {config.tolerance:.2%}" + ("" if "tolerance" in config.model_fields_set
                                                     else " (the default: the config sets none)")
    head = (f"build {config.name}: the probe sample ({split}, 0) reached an estimated error of "
            f"{acc['envelope_error']:.2%}")
    if acc.get("unreachable"):
        return (f"{head} and cannot meet {tol}: the orders left out carry {acc.get('omitted_orders') or 0:.2%} and "
                f"the smoothing bias {acc.get('smoothing') or 0:.2%} of the envelope, which no sampling brings down "
                f"(orders: auto simulates them); samples spend up to cost_cap {config.cost_cap:g} s (nominal) each and "
                "the card lists those that miss")
    stop = {"cost": f"within cost_cap {config.cost_cap:g} s (nominal, {acc.get('nominal_seconds') or 0:.3g} s spent)",
            "replicas": "at its replica cap", "time": "at its time cap"}.get(acc.get("capped"),
                                                                          "when its rounds ran out")
    projected = acc.get("projected_nominal_seconds")
    need = f"; meeting it projects about {projected:.3g} nominal s per sample" if projected is not None else ""
    return (f"{head} {stop}, above {tol}{need}: samples that miss it are built and listed in the card (raise "
            "cost_cap or the tolerance to meet it)")


def missed_notice(card: dict) -> str | None:
    """One line when built samples missed the tolerance (None when none did): how many of how many, their
    estimated errors, where the card lists them and what to change. Read from the card's ``accuracy``
    (:func:`datagen.dataset.store.finish_card`), so a resumed build counts every shard done."""
    acc = card.get("accuracy") or {}
    missed, errors = int(acc.get("n_missed") or 0), acc.get("envelope_error") or {}
    if not missed:
        return None
    def pct(key: str) -> str:
        return f"{100 * float(errors.get(key) or 0):.3g}%"
    return (f"{missed} of {errors.get('n', missed)} samples missed the tolerance {100 * acc['tolerance']:.3g}% "
            f"(estimated envelope errors {pct('min')} .. {pct('max')}, median {pct('median')}); they are stored with "
            f"their error and listed in the card (accuracy.missed): raise cost_cap ({acc.get('time_cap_s', 0):g} s) "
            "or loosen the tolerance")
