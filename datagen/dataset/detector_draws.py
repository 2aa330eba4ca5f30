"""A detector drawn per sample at build time: the ``detector_draws`` block of a dataset config (docs/datasets.md,
"The LCT release's kind of set-up").

Real confocal captures differ from one another in their detector and set-up as much as in their scenes: the SPAD's
slow-tail IRF, the floor of dark and ambient counts, the per-point gain (laser power, focus, the wall's albedo) and
the background that drifts in bands over a scan, how much of the direct light gets through (docs/detector.md). A
dataset whose ``detector_draws`` names ranges for them gives every sample its own detector, drawn from its own
stream and recorded in its params as ``detector_draw``; the envelope then holds the sample's IRF and direct-light
attenuation, the counts its gain, background map, dark count rate and exposure. Fields (each optional; absent
ones keep the config's fixed value):

============================  =================================================================================
``irf``                       ``{sigma, tail, tail_weight, tail2, tail2_weight, tail_delay}``: ranges of a
                              two-tail IRF (:class:`datagen.timing.irf.Irf`, kind ``two_tail``; s, or "60ps")
``dcr``                       Hz: the background rate (the floor per bin is dcr × bin width × cycles)
``exposure``                  s per scan point, drawn log-uniformly (a capture at a tenth or a hundredth of the
                              light: the detections thinned, signal and background alike)
``gain_scale``                the gain map's mean: the light each point receives, relative to the transport's
``hidden_counts``             instead of ``gain_scale``: the light level as the median over the scan points of
                              their expected hidden counts (the light less the direct component) at the config's
                              own exposure, drawn log-uniformly; the gain map is scaled to it once the sample is
                              simulated and the counts drawn with it (:func:`scale_to_hidden_counts`), the drawn
                              ``exposure`` thinning them after. A lab sets its exposure for its object: the LCT
                              release's diffuse "S" needed about 40 times the charts' light for its 356 hidden
                              counts per point, where one light level for every material leaves Lambertian
                              cut-outs 30-100 times dimmer than it (docs/datasets.md)
``gain_range``                the gain map's max/min, drawn log-uniformly (a smooth field:
                              :func:`datagen.spad.map_draws.draw_gain_fields`)
``background_bands``          ``{ratio, bands}``: the background map's band levels up to ``ratio`` apart in
                              ``bands`` bands of columns (:func:`datagen.spad.map_draws.draw_background_bands`)
``direct``                    ``{attenuation[, until]}``: :class:`datagen.spad.maps.DirectLight`, the
                              attenuation drawn log-uniformly (without ``until``: the direct component at every
                              time; it needs ``effects.first_bounce``)
============================  =================================================================================

Every draw is uniform in its range (``exposure``, ``gain_range``, ``hidden_counts`` and ``direct.attenuation``
log-uniform: they span decades). The stream is ``SeedSequence(seed, spawn_key=(split_key, index,
DETECTOR_STREAM))``: :data:`N_UNIFORMS` uniforms in a fixed order whatever fields are set, then one integer seeding
the torch generator of the maps, so a sample's draw depends only on (config, split, index) and adding a field moves
no other draw.
"""
from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, ValidationError, field_validator, model_validator

from ..errors import ConfigError
from ..units import parse_duration
from .ranges import CountRange, Model, NonNegative, Positive, Range, Unit

__all__ = ["DETECTOR_STREAM", "MAX_DETECTION_PROBABILITY", "N_UNIFORMS", "DetectorDraws", "check_detector_draws",
           "draw_detector", "draw_sample_detector", "scale_to_hidden_counts"]

MAX_DETECTION_PROBABILITY = 0.3
""":func:`scale_to_hidden_counts` raises a sample's light no further than its brightest bin's expected detections
per laser cycle reaching 0.3, the LCT release's brightest direct light (docs/datasets.md): past it a SPAD piles up,
and a lab attenuates the direct light instead (the release's diffuse "S" let 0.27 % of it through). It also bounds a
scene that returns almost no hidden light, whose direct light would otherwise be raised past any count."""

DETECTOR_STREAM = 5
"""Last entry of the spawn_key of a sample's detector draw (the build's streams are 0–4: :data:`~.config.STREAMS`)."""

N_UNIFORMS = 16
"""Uniforms drawn per sample, in the order of :data:`_ORDER` (the rest reserved)."""

_ORDER = ("irf.sigma", "irf.tail", "irf.tail_weight", "irf.tail2", "irf.tail2_weight", "irf.tail_delay", "dcr",
          "exposure", "gain_scale", "gain_range", "background_bands.ratio", "background_bands.bands",
          "direct.attenuation", "direct.until", "hidden_counts")


def _durations(value: Any) -> Any:
    """A range of durations: "60ps", ["50ps", "80ps"] or {min: "50ps", max: "80ps"} → seconds."""
    def one(v):
        return parse_duration(v) if isinstance(v, str) else v
    if isinstance(value, dict):
        return {k: one(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [one(v) for v in value]
    return one(value)


Seconds = Annotated[Positive, BeforeValidator(_durations)]
"""A :data:`~.ranges.Positive` range of durations: s, or strings such as "60ps"."""
SecondsFromZero = Annotated[NonNegative, BeforeValidator(_durations)]
"""A :data:`~.ranges.NonNegative` range of durations."""


class IrfDraws(Model):
    """Ranges of a two-tail IRF's parameters (:class:`datagen.timing.irf.Irf`): s, or strings such as "60ps"."""

    sigma: Seconds
    tail: Seconds
    tail_weight: Unit
    tail2: Seconds
    tail2_weight: Unit
    tail_delay: SecondsFromZero = Range(min=0.0, max=0.0)

    @model_validator(mode="after")
    def _weights(self) -> "IrfDraws":
        if self.tail_weight.max + self.tail2_weight.max > 1:
            raise ValueError(f"tail_weight.max + tail2_weight.max must be <= 1, got {self.tail_weight.max} + "
                             f"{self.tail2_weight.max}")
        return self


class BandDraws(Model):
    """The background map's bands: level ``ratio`` (max/min ≥ 1) and the number of ``bands`` (≥ 1)."""

    ratio: Range
    bands: CountRange

    @model_validator(mode="after")
    def _bounds(self) -> "BandDraws":
        if self.ratio.min < 1 or self.bands.min < 1:
            raise ValueError(f"ratio must be >= 1 and bands >= 1, got ratio.min {self.ratio.min}, "
                             f"bands.min {self.bands.min}")
        return self


class DirectDraws(Model):
    """The direct light's ``attenuation`` (in (0, 1], log-uniform) and optionally a gate's ``until`` (s, or "1.5ns");
    without ``until`` the direct component is attenuated at every time (:class:`datagen.spad.maps.DirectLight`)."""

    attenuation: Range
    until: Seconds | None = None

    @model_validator(mode="after")
    def _bounds(self) -> "DirectDraws":
        if not (0 < self.attenuation.min and self.attenuation.max <= 1):
            raise ValueError(f"attenuation must lie in (0, 1], got [{self.attenuation.min}, {self.attenuation.max}]")
        return self


class DetectorDraws(Model):
    """The ``detector_draws`` block (module doc)."""

    irf: IrfDraws | None = None
    dcr: NonNegative | None = None
    exposure: Seconds | None = None
    gain_scale: Positive | None = None
    hidden_counts: Positive | None = None
    gain_range: Range | None = None
    background_bands: BandDraws | None = None
    direct: DirectDraws | None = None

    @model_validator(mode="after")
    def _one_light_level(self):
        if self.gain_scale is not None and self.hidden_counts is not None:
            raise ValueError("give gain_scale or hidden_counts, not both: each sets the light level")
        return self

    @field_validator("gain_range")
    @classmethod
    def _at_least_one(cls, value: Range | None) -> Range | None:
        if value is not None and value.min < 1:
            raise ValueError(f"min must be >= 1 (a dynamic range max/min), got {value.min}")
        return value


def check_detector_draws(value: dict | None, where: str) -> DetectorDraws | None:
    """The validated block, or None. Raises ConfigError: one line per problem, ``where: detector_draws.field:
    message (got value)``."""
    if value is None:
        return None
    try:
        return DetectorDraws.model_validate(value)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = ".".join(["detector_draws"] + [str(p) for p in err["loc"]])
            got = err.get("input")
            shown = "" if isinstance(got, dict) else f" (got {got!r})"
            lines.append(f"{where}{loc}: {str(err['msg']).removeprefix('Value error, ')}{shown}")
        raise ConfigError("; ".join(lines)) from None


def draw_detector(value: dict | None, rng: np.random.Generator, scan: tuple[int, int] | None, sim_config):
    """Sample's simulation config with its drawn detector, and the draw's record.

    Args:
        value: the dataset config's ``detector_draws`` (None: nothing drawn); rng: the sample's detector stream
            (module doc); scan: (ny, nx) scan points (the gain and background maps need one); sim_config: the
            sample's resolved :class:`~datagen.simulation.SimulationConfig`.
    Returns:
        (SimulationConfig, dict): the config with ``irf`` and ``detector`` updated, and the JSON-able draw
        (``{}`` when nothing is drawn).
    Raises:
        ConfigError: maps drawn for a capture that is not a scan, or an invalid block.
    """
    draws = check_detector_draws(value, "")
    if draws is None:
        return sim_config, {}
    u = dict(zip(_ORDER, rng.random(N_UNIFORMS)))
    record: dict[str, Any] = {}
    detector = dict(sim_config.detector)
    update: dict[str, Any] = {}
    if draws.irf is not None:
        from ..timing.irf import Irf
        irf = {k: getattr(draws.irf, k).draw(u[f"irf.{k}"]) for k in IrfDraws.model_fields}
        update["irf"] = Irf(kind="two_tail", **irf)
        record["irf"] = irf
    if draws.dcr is not None:
        record["dcr"] = detector["dcr"] = draws.dcr.draw(u["dcr"])
    if draws.exposure is not None:
        record["exposure"] = detector["exposure"] = draws.exposure.draw_log(u["exposure"])
    if draws.direct is not None:
        direct = {"attenuation": draws.direct.attenuation.draw_log(u["direct.attenuation"])}
        if draws.direct.until is not None:
            direct["until"] = draws.direct.until.draw(u["direct.until"])
        record["direct"] = detector["direct"] = direct
    if draws.hidden_counts is not None:
        record["hidden_counts"] = draws.hidden_counts.draw_log(u["hidden_counts"])
        record["full_cycles"] = float(sim_config.detector_config().cycles)
    maps = (draws.gain_scale, draws.gain_range, draws.background_bands, draws.hidden_counts)
    if any(m is not None for m in maps):
        if scan is None:
            raise ConfigError("detector_draws: gain_scale, hidden_counts, gain_range and background_bands need a "
                              "scanned capture (capture.scan in the room distribution)")
        import torch

        from ..spad.map_draws import draw_background_bands, draw_gain_fields
        gen = torch.Generator().manual_seed(int(rng.integers(2**62)))
        scale = draws.gain_scale.draw(u["gain_scale"]) if draws.gain_scale is not None else 1.0
        span = draws.gain_range.draw_log(u["gain_range"]) if draws.gain_range is not None else 1.0
        gain = scale * draw_gain_fields(tuple(scan), span, 1, gen)[0].numpy()
        detector["gain_map"] = gain.tolist()
        record.update(gain_scale=scale, gain_range=span)
        if draws.background_bands is not None:
            b = draws.background_bands
            ratio = b.ratio.draw(u["background_bands.ratio"])
            bands = b.bands.min + min(int(u["background_bands.bands"] * (b.bands.max - b.bands.min + 1)),
                                      b.bands.max - b.bands.min)
            detector["background_map"] = draw_background_bands(tuple(scan), ratio, bands, 1, gen)[0].numpy().tolist()
            record["background_bands"] = {"ratio": ratio, "bands": bands}
    update["detector"] = detector
    return sim_config.model_copy(update=update), record


def draw_sample_detector(draws: dict | None, stream: np.random.SeedSequence, room, sim_config):
    """:func:`draw_detector` for one sample: a :class:`~datagen.dataset.config.DatasetConfig`'s ``detector_draws``,
    the sample's detector stream (``sample_seed_sequence(seed, split, index, DETECTOR_STREAM)``) and the scan of its
    sampled ``room``. Returns (SimulationConfig, record); unchanged and ``{}`` when the config draws nothing."""
    if draws is None:
        return sim_config, {}
    capture = room.scene.capture
    grid = capture.laser_grid if capture is not None and capture.type == "confocal" else None
    scan = None if grid is None else (int(grid.points[1]), int(grid.points[0]))     # points are (nx, ny)
    return draw_detector(draws, np.random.default_rng(stream), scan, sim_config)


def scale_to_hidden_counts(result, sim_config, drawn: dict, noise_rng: np.random.Generator, where: str = ""):
    """A simulated sample brought to its drawn light level (``detector_draws.hidden_counts``, module doc): the gain map
    G times s, s = target / median over the scan points p of C·Σ_t h_p(t)·G_p, held so that no bin expects more than
    :data:`MAX_DETECTION_PROBABILITY` detections per cycle (G·envelope), for h the envelope less its
    ``first_bounce`` component (the hidden light, as the detector receives it) and C the laser cycles of the config's
    own exposure (``drawn["full_cycles"]``), then the counts drawn again from the envelope with it
    (:func:`datagen.simulation.detection.detector_counts`). The envelope is unchanged (the gain acts at the detector).

    Args:
        result: the sample's :class:`~datagen.simulation.Result`; sim_config: the config it was simulated with (its
            drawn detector); drawn: :func:`draw_detector`'s record; noise_rng: the generator of the new draw.
    Returns:
        (result, sim_config, drawn) with the new counts, detector and ``gain_scale`` = s (and ``held``: true when
        the detection limit held the light short of the target); unchanged without a ``hidden_counts`` draw, or
        (with a ``note``) when the scene returns no hidden light.
    """
    target = drawn.get("hidden_counts")
    if target is None:
        return result, sim_config, drawn
    import dataclasses

    from ..simulation.detection import detector_counts

    envelope = np.asarray(result.envelope, dtype=np.float64)
    hidden = envelope - np.asarray(result.components["first_bounce"]) if "first_bounce" in result.components \
        else envelope
    gain = sim_config.detector_config().scan_map("gain_map")
    gain = np.ones(envelope.shape[:-1]) if gain is None else gain
    level = float(np.median(drawn["full_cycles"] * hidden.sum(axis=-1) * gain))
    if not level > 0:
        return result, sim_config, {**drawn, "note": "no hidden light: the light level was not set"}
    limit = MAX_DETECTION_PROBABILITY / float((envelope * gain[..., None]).max())
    scale = min(target / level, limit)
    detector = {**sim_config.detector, "gain_map": (gain * scale).tolist()}
    config = sim_config.model_copy(update={"detector": detector})
    counts, det, plan = detector_counts(envelope, config, result.attrs["plan"], noise_rng, where)
    attrs = {**result.attrs, "detector": det.model_dump(mode="json"), "config": config.model_dump(mode="json"),
             "plan": plan}
    return (dataclasses.replace(result, counts=counts, attrs=attrs), config,
            {**drawn, "gain_scale": scale, "held": bool(limit < target / level)})
