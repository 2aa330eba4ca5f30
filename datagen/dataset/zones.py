"""Multi-zone samples: a room distribution whose ``capture.scan`` has a ``flood`` (:class:`~datagen.dataset.scan.
FloodScan`) stores what a consumer multi-zone sensor outputs (docs/multizone.md, "The multi-zone dataset").

The sample is simulated as every scan is, the exhaustive capture of the flood's nodes × the zones; then
:func:`zone_capture` composes the zones' envelope (Z_y, Z_x, T) with the flood's weights
(:func:`datagen.simulation.multizone.zone_result`) and draws their counts with the dataset's detector from the
sample's noise stream, as :func:`datagen.simulation.multizone.simulate_multizone` draws them. ``envelope``,
``counts``, ``components`` and ``reference`` are then the zones' (axes ``zone_y``, ``zone_x``, ``time``); the
per-node envelope is stored as ``node_envelope`` (L_y, L_x, Z_y, Z_x, T) only with ``store.node_envelope``.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError


def zone_capture(config, split: str, room, sim_config, result, noise_rng: np.random.Generator, where: str):
    """(result, per-node envelope) of a sample: unchanged and None without a flood; with one,
    :func:`~datagen.simulation.multizone.zone_result` of ``result`` (counts drawn with ``noise_rng``) and the
    (L_y, L_x, Z_y, Z_x, T) float64 node envelope.

    Args:
        config: the :class:`~datagen.dataset.config.DatasetConfig`; split: the sample's split; room: its
            :class:`~datagen.dataset.sampler.SampledRoom`; sim_config: its resolved simulation config; result: its
            :class:`~datagen.simulation.detection.Result`; noise_rng: the zones' counts' generator (make_sample: a fresh
            noise stream of the sample, :func:`datagen.dataset.config.sample_rngs`); where: names the sample.
    Raises:
        ConfigError: ``store.node_envelope`` without a flood (naming the field), or the zones' detector draw fails.
    """
    from ..simulation.multizone import zone_result

    scan = config.room_distribution(split).capture.scan
    flood = scan.flood if scan is not None else None
    if flood is None:
        if config.store.node_envelope:
            raise ConfigError("store.node_envelope: true needs a multi-zone capture (room capture.scan.flood); "
                              "remove it")
        return result, None
    zones = zone_result(result, np.asarray(room.scene.laser.emitter, dtype=np.float64), flood.profile, sim_config,
                        noise_rng, f"{where}: ")
    return zones, result.envelope
