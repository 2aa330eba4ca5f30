"""Batched SPAD noise on the training device: :class:`SPADNoise`, a ``torch.nn.Module`` that draws
finite-exposure histograms from a batch of envelopes with a ``torch.Generator``.

The physics is the detector model of docs/physics.md §6, as :func:`datagen.spad.rates_from_envelope` and
:func:`datagen.spad.sample_histogram` implement it for one capture at a time in numpy:

    r_i = g_i · ( G·(q / q_env)·L_i + B·(q·ambient_rate + DCR)·Δ_i )      expected avalanches per cycle, bin i

with L the envelope (detected photons per pulse and bin, simulated with the PDE q_env, docs/physics.md §2), q
the PDE of the drawn detector, Δ_i the bin widths (``DetectorConfig.widths``, DNL included) and g_i the gate
fraction of each bin (:func:`datagen.spad.gate_fraction`), G and B each scan point's gain and background factors:
the detector's ``gain_map`` / ``background_map``, or maps drawn per sample (``gain_range``, ``background_bands``:
:mod:`datagen.spad.map_draws`), else 1. Over n = round(exposure × repetition_rate) cycles:

* ``pile_up`` (synchronous first photon, Coates 1968): the counts are Multinomial(n; p_0 … p_{T−1}, p_none)
  with p_i = e^{−C_i}(1 − e^{−r_i}) = e^{−C_i} − e^{−C_{i+1}}, C_i = Σ_{j<i} r_j, p_none = e^{−Λ};
* ``poisson``: independent Poisson(n·r_i).

Per sample (the first axis), the exposure, the ambient rate, the dark count rate and the PDE may each be
fixed or drawn uniformly from a ``(low, high)`` range with the caller's generator: detector randomisation
as reconstruction networks' loaders vary exposure and background, with the SPAD's own physics.

Sampler (exact). numpy draws the pile-up multinomial as sequential conditional binomials on a binary tree
of bins (:func:`datagen.spad.first_photon_tree`); torch's binomial sampler costs 70–180 ns per element, so
that route would cost more per sample than numpy's. Here the n cycles are Poissonised: with
m = n − POISSONIZATION_MARGIN·√n, X_i ~ Poisson(m·p_i) for every bin and X_none ~ Poisson(m·p_none), all
independent (``torch.poisson``). Given their total s, (X, X_none) is Multinomial(s; p). A row with s > n is
redrawn (that conditions on s ≤ n, a function of s only, so the law given s is unchanged; probability
≈ Φ(−margin) ≈ 2 %); the n − s missing cycles are then a further Multinomial(n − s; p): their detections
A ~ Binomial(n − s, 1 − p_none), each placed in bin i with probability p_i / (1 − p_none) by inverse CDF.
The sum is exactly Multinomial(n; p). The pmf is computed as the difference of the float64 survival
e^{−C_{i+1}} (absolute error ~1e-16 per cycle, as the numpy pmf). Draws differ from numpy's for the same
seed; the law is the same (tests/test_torch_noise.py: χ² per bin and moments against
:func:`datagen.spad.sample_histogram`, including strong pile-up).

Cost (benchmarks/bench_loader_noise.py; one CPU thread, 1 536 bins, the default config's flux). ``torch.poisson``
is ≈ 65 % of the time and sets the floor (≈ 24 µs per sample): ≈ 7 ns per bin below 0.1 expected counts,
50–95 ns between 3 and 10 (it multiplies one uniform per count), 35–50 ns above 10. Drawing a Poisson total and
placing its events by inverse CDF is the same law but costs 40–140 ns per event in torch (``searchsorted``),
so it lost to per-bin draws wherever it was tried: whole rows with fewer expected counts than bins, the bins
below a threshold of 0.03–1 expected count, or every bin's share min(λ, τ) for τ from 0.01 to 10.
"""
from __future__ import annotations

import math
import numbers
from typing import Any, Mapping

import torch

from .config import DetectorConfig
from .map_draws import draw_background_bands, draw_gain_fields
from .maps import check_map_shape
from .models import detector_model, model_names
from .ranges import RANDOMISED_FIELDS, detector_ranges, draw_detector_params, fixed_cycles
from .rates import NEGATIVE_ENVELOPE_RTOL, gate_fraction
from .synchronous import MAX_EXPECTED_COUNTS

__all__ = ["POISSONIZATION_MARGIN", "RANDOMISED_FIELDS", "SPADNoise", "as_generator", "check_counts_dtype",
           "exact_count_limit", "first_photon", "row_search"]

POISSONIZATION_MARGIN = 2.0
"""The pile-up sampler's Poisson stage uses m = n − margin·√n cycles: a row's Poisson total exceeds n (and the
row is redrawn) with probability ≈ Φ(−margin) ≈ 2.3 %, and ≈ (margin + 0.8)·√n·(1 − p_none) detections are
placed by inverse CDF afterwards (margins 1, 2, 3 and 4 cost within 5 % of each other per sample)."""

COUNT_DTYPES = (torch.int32, torch.float32, torch.int64, torch.float64)
"""Count dtypes suggested, smallest first, when a requested one cannot hold the counts."""

_UNSUPPORTED = {
    "jitter_sigma": "Gaussian jitter after pile-up", "jitter_fwhm": "Gaussian jitter after pile-up",
    "diffusion_tail": "the diffusion tail", "crosstalk_probability": "crosstalk",
    "afterpulse_probability": "afterpulsing",
}


class SPADNoise(torch.nn.Module):
    """Finite-exposure SPAD histograms from a batch of envelopes, on the envelopes' device.

    Args:
        detector: the detector the envelopes were simulated for: a :class:`datagen.spad.DetectorConfig` or a
            mapping of its fields (e.g. ``NLOSDataset.detector``). Model ``pile_up`` or ``poisson``; its
            ``bin_width``/``bin_widths``, ``t_start`` and ``gate`` fix the time axis and the gate; Gaussian
            jitter, the diffusion tail, crosstalk and afterpulsing are not modelled here (NotImplementedError).
        exposure: seconds per sample, a number or a (low, high) range drawn uniformly per sample; strings
            such as ``"1ms"`` are accepted. Default: the detector's exposure (or ``n_cycles``).
        ambient_rate: ambient photons per second at the detector before the PDE (Hz), number or range.
        dcr: dark count rate (Hz), number or range.
        pde: photon detection efficiency, number or range in [0, 1]. The envelope is rescaled by
            pde / envelope_pde (it already contains the PDE it was simulated with, docs/physics.md §2).
        envelope_pde: the PDE inside the envelopes, a finite number in [0, 1]; default ``detector.pde``.
        gain_range: draw a smooth gain map per sample of this dynamic range (max/min ≥ 1, mean 1) over the scan
            points (the envelope's axes between the sample and the bins: (B, ny, nx, T));
            :func:`datagen.spad.map_draws.draw_gain_fields`. Default: the detector's ``gain_map``, else none.
        background_bands: (ratio, bands): draw a background map per sample in ``bands`` bands of columns, levels
            up to ``ratio`` apart (mean 1; :func:`datagen.spad.map_draws.draw_background_bands`). Default: the
            detector's ``background_map``, else none.
        dtype: dtype of the returned counts (float32 default). It must hold every count a bin can reach exactly
            (:func:`check_counts_dtype`): an integer or floating torch dtype whose exact range (``iinfo.max``;
            2**24 for float32, 2**11 float16, 2**8 bfloat16, 2**53 float64) reaches the most laser cycles of an
            exposure (a bin counts at most once per cycle in the pile-up model). bool, complex and narrower
            dtypes are refused here; with the ``poisson`` model, whose bins can count more than the cycles,
            :meth:`sample` also refuses a batch whose counts exceed the dtype's exact range.
    Raises:
        ValueError: invalid field or range (the message names it and the value; exposure, ambient_rate, dcr and
            pde must be finite, ≥ 0, pde ≤ 1); ``envelope_pde`` negative, above 1, NaN or infinite; a ``dtype``
            that cannot hold the counts (e.g. float32 with more than 2**24 cycles, uint8 with more than 255);
            a randomised PDE with ``envelope_pde`` 0. TypeError: ``dtype`` not a torch.dtype.
            NotImplementedError: an effect listed above.

    Example::

        noise = datagen.SPADNoise(ds.detector, exposure=("1ms", "10ms"), ambient_rate=(0, 1e5), pde=(0.2, 0.4))
        counts = noise(batch["envelope"].to(device), generator=gen)      # (B, ..., T) float32 counts
    """

    def __init__(self, detector: DetectorConfig | Mapping[str, Any], *, exposure: Any = None,
                 ambient_rate: Any = None, dcr: Any = None, pde: Any = None, envelope_pde: float | None = None,
                 gain_range: float | None = None, background_bands: tuple[float, int] | None = None,
                 dtype: torch.dtype = torch.float32):
        super().__init__()
        det = detector if isinstance(detector, DetectorConfig) else DetectorConfig.model_validate(dict(detector))
        self.model = detector_model(det.model)                 # its registry entry (datagen.spad.models)
        if not self.model.torch_noise:
            raise NotImplementedError(f"SPADNoise: detector model {det.model!r} is not modelled in torch (only "
                                      f"{', '.join(repr(m) for m in model_names(torch_noise=True))}); use "
                                      "datagen.spad.sample_histogram")
        for field, what in _UNSUPPORTED.items():
            if getattr(det, field):
                raise NotImplementedError(f"SPADNoise: {field}={getattr(det, field)!r}: {what} is not modelled "
                                          "in torch; use datagen.spad.sample_histogram")
        self.detector = det
        given = {"exposure": exposure, "ambient_rate": ambient_rate, "dcr": dcr, "pde": pde}
        self.ranges = detector_ranges(det, {k: v for k, v in given.items() if v is not None})
        self.envelope_pde = float(det.pde if envelope_pde is None else _probability(envelope_pde, "envelope_pde"))
        if self.envelope_pde == 0 and self.ranges["pde"] != (0.0, 0.0):
            raise ValueError("SPADNoise: envelope_pde is 0, so the envelope cannot be rescaled to another pde")
        self.fixed_cycles = fixed_cycles(det, exposure)
        max_cycles = self.fixed_cycles or round(self.ranges["exposure"][1] * det.repetition_rate)
        if round(self.ranges["exposure"][0] * det.repetition_rate) < 1 and self.fixed_cycles is None:
            raise ValueError(f"SPADNoise: exposure {self.ranges['exposure'][0]!r} s is less than one laser cycle at "
                             f"{det.repetition_rate!r} Hz")
        self.gain_range = None if gain_range is None else float(gain_range)
        self.background_bands = None if background_bands is None else (float(background_bands[0]),
                                                                       int(background_bands[1]))
        draw_gain_fields((1, 1), self.gain_range, 0) if self.gain_range is not None else None     # checks the values
        if self.background_bands is not None:
            draw_background_bands((1, 1), *self.background_bands, 0)
        self.dtype = check_counts_dtype(dtype, max_cycles)
        self.count_limit = exact_count_limit(dtype)
        self._axis: dict[tuple[int, str], tuple[torch.Tensor, torch.Tensor]] = {}

    def extra_repr(self) -> str:
        ranges = ", ".join(f"{k}={lo:g}" if lo == hi else f"{k}=({lo:g}, {hi:g})" for k, (lo, hi) in self.ranges.items())
        return f"model={self.detector.model}, {ranges}, envelope_pde={self.envelope_pde:g}"

    # ---- parameters ---------------------------------------------------------------------------------------
    def draw_params(self, batch: int, generator: torch.Generator | int | None = None,
                    device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
        """Per-sample detector parameters: ``exposure`` (s), ``ambient_rate`` (Hz), ``dcr`` (Hz), ``pde`` and
        ``cycles`` (laser cycles, round(exposure × repetition_rate)), each float64 (batch,) on ``device``.

        Always draws (batch, 4) uniforms from ``generator`` (fixed fields included), so the stream layout does
        not depend on which fields are randomised (:func:`datagen.spad.ranges.draw_detector_params`); an int
        seeds a new generator (:func:`as_generator`)."""
        return draw_detector_params(self.ranges, self.detector.repetition_rate, self.fixed_cycles, batch,
                                    as_generator(generator, device), device)

    def draw_maps(self, scan: tuple[int, ...], batch: int, generator: torch.Generator | None | bool,
                  device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
        """Per-sample ``gain`` and ``background`` maps, float64 (batch, *scan), for the scan shape ``scan`` (the
        envelope's axes between the sample and the bins): drawn (``gain_range``, ``background_bands``; after the
        detector parameters, from the same generator) or the detector's fixed maps; absent keys are 1.
        ``generator=False``: the detector's fixed maps only (no draw).

        Raises:
            ValueError: a fixed map of another shape than ``scan``, or a draw for a scan that is not (ny, nx).
        """
        out = {}
        for key, field, draw in (("gain", "gain_map", self.gain_range is not None and generator is not False),
                                 ("background", "background_map",
                                  self.background_bands is not None and generator is not False)):
            if draw:
                out[key] = (draw_gain_fields(scan, self.gain_range, batch, generator, device) if key == "gain" else
                            draw_background_bands(scan, *self.background_bands, batch, generator, device))
            elif getattr(self.detector, field) is not None:
                fixed = check_map_shape(self.detector.scan_map(field), field, tuple(scan), "SPADNoise: detector.")
                out[key] = torch.as_tensor(fixed, device=device).expand((batch,) + tuple(scan))
        return out

    def _time_axis(self, n_bins: int, device: torch.device) -> tuple[torch.Tensor | None, torch.Tensor]:
        """(gate fraction g_i or None when every bin is fully inside the gate, g_i × width_i in s), float64
        (n_bins,) on ``device`` (cached per bin count and device)."""
        key = (n_bins, str(device))
        if key not in self._axis:
            det = self.detector
            gate = gate_fraction(det.bin_edges(n_bins), det.gate)
            weight = torch.as_tensor(gate * det.widths(n_bins), device=device)
            self._axis[key] = (None if bool((gate == 1.0).all()) else torch.as_tensor(gate, device=device), weight)
        return self._axis[key]

    def rates(self, envelope: torch.Tensor, params: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Expected avalanches per cycle and bin (docs/physics.md §6; the module doc's formula).

        Args:
            envelope: (B, ..., T) detected photons per pulse per bin (any float dtype, ≥ 0).
            params: :meth:`draw_params` output for B samples.
        Returns:
            float64 (B, ..., T) rates ≥ 0.
        """
        gate, weight = self._time_axis(envelope.shape[-1], envelope.device)
        lead = (-1,) + (1,) * (envelope.dim() - 1)
        pde = params["pde"]
        scale = pde / self.envelope_pde if self.envelope_pde > 0 else torch.zeros_like(pde)
        rates = torch.mul(envelope, scale.view(lead))                # float64 (type promotion)
        if "gain" in params:
            rates.mul_(params["gain"][..., None])
        if gate is not None:
            rates.mul_(gate)
        background = (pde * params["ambient_rate"] + params["dcr"]).view(lead)
        if "background" in params:
            background = background * params["background"][..., None]
        return rates.addcmul_(background, weight)

    def expected(self, envelope: torch.Tensor, params: Mapping[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Expected counts over the exposure: n·p_i (pile-up) or n·r_i (poisson), float64 (B, ..., T).

        Args:
            envelope: (B, ..., T) detected photons per pulse per bin (≥ 0).
            params: per-sample parameters as :meth:`draw_params` returns them; default the detector's own
                (e.g. the expected empty-room counts from a stored ``reference`` envelope, for subtraction).
        Raises:
            ValueError: an envelope of fewer than 2 dimensions or with 0 bins (the message gives its shape).
        """
        check_envelope_shape(envelope)
        if params is None:
            det, batch = self.detector, envelope.shape[0]
            params = {name: torch.full((batch,), float(value), dtype=torch.float64, device=envelope.device)
                      for name, value in (("exposure", det.cycles / det.repetition_rate), ("cycles", det.cycles),
                                          ("ambient_rate", det.ambient_rate), ("dcr", det.dcr), ("pde", det.pde))}
            params.update(self.draw_maps(tuple(envelope.shape[1:-1]), batch, False, envelope.device))
        rates = self.rates(envelope, params).reshape(-1, envelope.shape[-1])
        cycles = params["cycles"].repeat_interleave(rates.shape[0] // max(envelope.shape[0], 1))[:, None]
        if self.model.dead_time == "none":            # Poisson counts: no dead time
            return (rates * cycles).reshape(envelope.shape)
        survive = torch.cumsum(rates, dim=-1).neg_().exp_()
        pmf = torch.cat([1.0 - survive[:, :1], survive[:, :-1] - survive[:, 1:]], dim=-1)
        return (pmf * cycles).reshape(envelope.shape)

    # ---- sampling -----------------------------------------------------------------------------------------
    def forward(self, envelope: torch.Tensor, generator: torch.Generator | int | None = None) -> torch.Tensor:
        """Counts of one exposure per sample: (B, ..., T) ``dtype`` on the envelope's device (see :meth:`sample`)."""
        return self.sample(envelope, generator)[0]

    def sample(self, envelope: torch.Tensor, generator: torch.Generator | int | None = None
               ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Draw the detector parameters and the counts of a batch.

        Args:
            envelope: (B, ..., T) expected detected photons per pulse per bin (float, ≥ 0, finite), T ≥ 1; the
                leading axis is the sample, the others (pixels) share their sample's detector parameters. An
                envelope with no element (B = 0 or an empty pixel axis) gives empty counts.
            generator: a ``torch.Generator`` on the envelope's device, or an int seed of a new one (the same int
                gives the same draw: pass a Generator to draw fresh noise per batch); None: torch's default.
        Returns:
            (counts (B, ..., T) ``dtype``, params): params as :meth:`draw_params` (float64 (B,)).
        Raises:
            ValueError: an envelope of fewer than 2 dimensions or with 0 bins, a negative or non-finite value,
                (poisson model) a bin expecting more than MAX_EXPECTED_COUNTS counts or counting more than
                ``dtype`` holds exactly. TypeError: an envelope that is not a tensor, a generator that is neither
                a torch.Generator nor an int (e.g. a numpy Generator).
        """
        check_envelope_shape(envelope)
        generator = as_generator(generator, envelope.device)
        if envelope.numel() == 0:
            params = self.draw_params(envelope.shape[0], generator, envelope.device)
            return torch.zeros(envelope.shape, dtype=self.dtype, device=envelope.device), params
        rows = envelope.reshape(-1, envelope.shape[-1])
        low, high = torch.aminmax(rows, dim=-1)                     # NaN propagates into both; ±inf into one
        fine, negative = torch.stack([((low >= -NEGATIVE_ENVELOPE_RTOL * high) & torch.isfinite(high)).all(),
                                      (low < 0).any()]).tolist()
        if not fine:
            raise ValueError("SPADNoise: the envelope has a non-finite value or a value more negative than FFT "
                             f"round-off (below -{NEGATIVE_ENVELOPE_RTOL:g} × its row's maximum)")
        if negative:
            envelope = envelope.clamp_min(0.0)                       # round-off, as rates_from_envelope does
        batch = envelope.shape[0]
        params = self.draw_params(batch, generator, envelope.device)
        params.update(self.draw_maps(tuple(envelope.shape[1:-1]), batch, generator, envelope.device))
        rates = self.rates(envelope, params).reshape(-1, envelope.shape[-1])
        cycles = params["cycles"].repeat_interleave(rates.shape[0] // max(batch, 1))
        if self.model.dead_time == "none":            # Poisson counts: no dead time
            lam = rates * cycles[:, None]
            if bool((lam > MAX_EXPECTED_COUNTS).any()):
                raise ValueError(f"SPADNoise: a bin expects {float(lam.max()):.3g} counts, more than "
                                 f"{MAX_EXPECTED_COUNTS:.3g}: the flux is too high")
            counts = torch.poisson(lam, generator=generator)
            if self.count_limit < 2**53 and float(counts.max()) > self.count_limit:
                raise ValueError(f"SPADNoise: dtype={self.dtype} holds counts up to {self.count_limit} exactly, but "
                                 f"a bin counted {float(counts.max()):.0f}; pass a wider dtype")
        else:
            counts = first_photon(rates, cycles, generator)
        return counts.reshape(envelope.shape).to(self.dtype), params


# ---------------------------------------------------------------------------------------------------------
# Argument checks (shared with datagen.dataset.NLOSDataset's counts_dtype)


def exact_count_limit(dtype: torch.dtype) -> int:
    """The largest n such that every count 0 … n is exact in ``dtype``: ``iinfo(dtype).max`` for integers,
    2 / eps for floats (2**11 float16, 2**8 bfloat16, 2**24 float32, 2**53 float64).

    Raises:
        TypeError: ``dtype`` is not a torch.dtype. ValueError: bool or complex (not a count).
    """
    if not isinstance(dtype, torch.dtype):
        raise TypeError(f"must be a torch.dtype such as torch.int32, got {dtype!r} ({type(dtype).__name__})")
    if dtype == torch.bool or dtype.is_complex:
        raise ValueError(f"{dtype} cannot hold counts; use an integer or floating dtype such as torch.int32")
    return int(2 / torch.finfo(dtype).eps) if dtype.is_floating_point else int(torch.iinfo(dtype).max)


def check_counts_dtype(dtype: Any, max_count: int, name: str = "dtype", owner: str = "SPADNoise") -> torch.dtype:
    """``dtype`` if it holds every count from 0 to ``max_count`` exactly (:func:`exact_count_limit`).

    Args:
        dtype: the requested torch dtype of counts.
        max_count: the most counts a bin can reach (the laser cycles of the longest exposure).
        name, owner: the parameter and who asks, named in the messages.
    Raises:
        TypeError: not a torch.dtype. ValueError: bool, complex, or an exact range below ``max_count``; the
            message names the parameter, the dtype, both numbers and a dtype that fits.
    """
    try:
        limit = exact_count_limit(dtype)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"{owner}: {name}={dtype!r}: {exc}") from None
    if limit < max_count:
        fits = next((d for d in COUNT_DTYPES if exact_count_limit(d) >= max_count), torch.float64)
        raise ValueError(f"{owner}: {name}={dtype} holds counts up to {limit} exactly, but a bin can count up to "
                         f"{max_count} (the laser cycles of an exposure); pass {name}={fits}")
    return dtype


def as_generator(generator: Any, device: torch.device | str = "cpu") -> torch.Generator | None:
    """``generator`` as a ``torch.Generator``: a Generator or None unchanged, an int (Python or numpy) in
    [0, 2**64) as a new Generator on ``device`` seeded with it.

    Raises:
        TypeError: anything else (a numpy Generator, a float, a bool), naming its type. ValueError: an int seed
            outside [0, 2**64).
    """
    if generator is None or isinstance(generator, torch.Generator):
        return generator
    if isinstance(generator, bool) or not isinstance(generator, numbers.Integral):
        kind = f"{type(generator).__module__.split('.')[0]}.{type(generator).__name__}"
        raise TypeError(f"SPADNoise: generator must be a torch.Generator or an int seed, got {kind} (numpy "
                        "generators cannot drive torch's samplers)")
    if not 0 <= int(generator) < 2**64:
        raise ValueError(f"SPADNoise: generator seed must be in [0, 2**64), got {int(generator)}")
    return torch.Generator(device=device).manual_seed(int(generator))


def check_envelope_shape(envelope: Any) -> None:
    """Refuse an envelope that is not a (batch, ..., bins) tensor with at least one bin.

    Raises:
        TypeError: not a torch.Tensor. ValueError: fewer than 2 dimensions or 0 bins (naming the shape).
    """
    if not isinstance(envelope, torch.Tensor):
        raise TypeError(f"SPADNoise: envelope must be a torch.Tensor, got {type(envelope).__name__}")
    if envelope.dim() < 2 or envelope.shape[-1] == 0:
        raise ValueError(f"SPADNoise: envelope must be (batch, ..., bins) with at least one bin, got shape "
                         f"{tuple(envelope.shape)}")


def _probability(value: Any, name: str) -> float:
    """``value`` as a float in [0, 1]; ValueError naming ``name`` and the value otherwise (NaN, ±inf included)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not 0.0 <= number <= 1.0:
        raise ValueError(f"SPADNoise: {name} must be a finite number in [0, 1], got {value!r}")
    return number


# ---------------------------------------------------------------------------------------------------------
# Exact samplers on (rows, T) float64 tensors


def row_search(cum: torch.Tensor, rows: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """For each k the index b with cum[rows[k], b−1] ≤ target[k] < cum[rows[k], b] (cum[·, −1] := −∞, and b = m − 1
    when target ≥ every entry), by a branchless binary search over nondecreasing rows: the torch twin of
    :func:`datagen.spad.arrays.row_search`.

    Args:
        cum: float (n, m), each row nondecreasing.
        rows: int64 (k,) row of each query.
        target: float (k,) values to locate.
    Returns:
        int64 (k,) in [0, m − 1].
    """
    m = cum.shape[1]
    base = rows * m - 1                          # flat index of cum[row, b − 1] is base + b
    if m == 1:
        return torch.zeros_like(rows)
    flat = cum.reshape(-1)
    # pos = base + found, invariant cum[row, found − 1] ≤ target. The first probe splits [0, m) into [0, m − big)
    # and [m − big, m), so every later probe (steps big/2 … 1) stays inside the row: no clamps, no bound tests.
    big = 1 << ((m - 1).bit_length() - 1)
    pos = base.add(torch.le(flat[base + (m - big)], target), alpha=m - big)
    step = big >> 1
    while step:                                  # move right by step if cum[row, found + step − 1] ≤ target
        pos.add_(torch.le(flat[pos + step], target), alpha=step)
        step >>= 1
    return pos - base


def first_photon(rates: torch.Tensor, cycles: torch.Tensor, generator: torch.Generator | None = None
                 ) -> torch.Tensor:
    """Exact synchronous first-photon (pile-up) counts of ``cycles`` laser cycles per row (docs/physics.md §6).

    Args:
        rates: float64 (rows, T) expected avalanches per cycle per bin, ≥ 0 (finite).
        cycles: float64 (rows,) laser cycles (integers ≥ 0).
        generator: torch Generator on the rates' device.
    Returns:
        float64 (rows, T) counts: Multinomial(cycles; e^{−C_i}(1 − e^{−r_i}) per bin, e^{−Λ} no detection) per
        row, drawn as the module doc describes; each row sums to at most ``cycles``.
    """
    n_rows, bins = rates.shape
    survive = torch.cumsum(rates, dim=-1).neg_().exp_()            # e^{−C_{i+1}}: no detection up to bin i
    trials = (cycles - POISSONIZATION_MARGIN * cycles.sqrt()).clamp_min_(0.0)
    lam = torch.empty_like(survive)                                 # m·p_i, p_i = e^{−C_i} − e^{−C_{i+1}}
    lam[:, 0] = 1.0 - survive[:, 0]
    torch.sub(survive[:, :-1], survive[:, 1:], out=lam[:, 1:])
    lam.mul_(trials[:, None])
    none = survive[:, -1]
    counts = torch.poisson(lam, generator=generator)
    spare = cycles - counts.sum(dim=-1) - torch.poisson(trials * none, generator=generator)
    redo = torch.nonzero(spare < 0).squeeze(1)
    while redo.numel():                 # Poisson total above the cycles: redraw those rows
        again = torch.poisson(lam[redo], generator=generator)
        counts[redo] = again
        spare[redo] = cycles[redo] - again.sum(dim=-1) - torch.poisson(trials[redo] * none[redo], generator=generator)
        redo = redo[spare[redo] < 0]
    detect = (1.0 - none).clamp_(0.0, 1.0)
    extra = torch.binomial(spare, detect, generator=generator).long()
    row = torch.repeat_interleave(torch.arange(n_rows, device=rates.device), extra)
    if row.numel():                     # the spare cycles' detections, by inverse CDF on 1 − e^{−C_{i+1}}
        u = torch.rand(row.shape, generator=generator, dtype=torch.float64, device=rates.device)
        at = row_search(survive.neg_(), row, u.mul_(detect[row]).sub_(1.0))
        counts.view(-1).index_add_(0, row * bins + at, torch.ones_like(u))
    return counts
