"""Physical constants and unit parsing at the configuration boundary.

Inside datagen every length is in metres and every time in seconds (docs/physics.md §1). Configuration files and
command-line options may write durations as strings with a unit (``"600ps"``, ``"100 ns"``, ``"5min"``), rates
(``"20MHz"``, ``"100cps"``), energies, lengths and fractions (``"1%"``); one parser per kind converts them once, at
the boundary: :func:`parse_duration`, :func:`parse_rate`, :func:`parse_energy`, :func:`parse_length`,
:func:`parse_fraction` (and :func:`parse_grid` for ``"10x10"``).
"""
from __future__ import annotations

import math
import re
from typing import Any

SPEED_OF_LIGHT = 299_792_458.0
"""c in m/s (exact, SI definition)."""

PLANCK = 6.626_070_15e-34
"""h in J·s (exact, SI definition)."""

_TIME_UNITS = {"h": 3600.0, "min": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15}
_ENERGY_UNITS = {"J": 1.0, "mJ": 1e-3, "uJ": 1e-6, "µJ": 1e-6, "nJ": 1e-9, "pJ": 1e-12, "fJ": 1e-15}
_RATE_UNITS = {"hz": 1.0, "khz": 1e3, "mhz": 1e6, "ghz": 1e9, "cps": 1.0, "kcps": 1e3, "mcps": 1e6}
"""Rate units, matched ignoring case (``"20MHz"`` = ``"20mhz"``; there is no millihertz)."""
_LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9, "cm": 1e-2, "km": 1e3}
_NUMBER_WITH_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-zµ]*)\s*$")


def _parse(value: float | int | str, units: dict[str, float], kind: str, *, fold_case: bool = False,
           messages: tuple[str, str, str] | None = None) -> float:
    """``value`` (a number in SI units, or a string: a number then one of ``units``) as a float. ``messages``
    replaces the three error texts (not a number / unreadable / unknown unit), formatted with ``value``,
    ``unit`` and ``known``."""
    bad, unreadable, unknown = messages or (
        "expected a {kind} (number or string with unit), got {value!r}",
        "cannot read {value!r} as a {kind}; write e.g. '600ps' or a number in SI units",
        "unknown {kind} unit {unit!r} in {value!r}; known: {known}")
    if isinstance(value, bool):
        raise ValueError(bad.format(kind=kind, value=value))
    if isinstance(value, (int, float)):
        return float(value)
    match = _NUMBER_WITH_UNIT.match(str(value))
    if match is None:
        raise ValueError(unreadable.format(kind=kind, value=value))
    number, unit = match.groups()
    if unit == "":
        return float(number)
    key = unit.lower() if fold_case else unit
    if key not in units:
        raise ValueError(unknown.format(kind=kind, value=value, unit=key, known=", ".join(units)))
    return float(number) * units[key]


def parse_duration(value: float | int | str) -> float:
    """Return a duration in seconds from a number (seconds) or a string such as ``"600ps"``, ``"10 ms"``,
    ``"5min"`` or ``"2h"`` (units: h, min, s, ms, us, µs, ns, ps, fs).

    Raises:
        ValueError: the string has no number or an unknown unit (the message names the value).
    """
    return _parse(value, _TIME_UNITS, "duration")


def format_duration(seconds: float) -> str:
    """``seconds`` as a duration :func:`parse_duration` reads back, rounded up: whole seconds below 2 min ("8s"),
    whole minutes below 2 h ("17min"), tenths of an hour above ("2.5h")."""
    if seconds < 120:
        return f"{math.ceil(seconds)}s"
    if seconds < 7200:
        return f"{math.ceil(seconds / 60)}min"
    return f"{math.ceil(seconds / 360) / 10:g}h"


def parse_rate(value: float | int | str) -> float:
    """Return a rate in Hz from a number (Hz) or a string such as ``"20MHz"`` or ``"100cps"`` (units: Hz, kHz,
    MHz, GHz, cps, kcps, Mcps, any case).

    Raises:
        ValueError: a bool, a string with no number, or an unknown unit (the message names the value).
    """
    return _parse(value, _RATE_UNITS, "rate", fold_case=True, messages=(
        "expected a rate in Hz, got {value!r}",
        "cannot read {value!r} as a rate; write e.g. '20MHz' or a number in Hz",
        "unknown rate unit {unit!r} in {value!r}; known: Hz, kHz, MHz, GHz, cps, kcps, Mcps"))


def parse_fraction(value: float | int | str) -> float:
    """Return a fraction from a number (``0.01``) or a percentage string (``"1%"`` → 0.01, ``"0.5 %"``); a
    string without ``%`` is read as a plain number. The range is the caller's to check.

    Raises:
        ValueError: a bool, or a string that is not a number or a percentage ("must look like 1% or 0.01, got …").
    """
    if isinstance(value, bool):
        raise ValueError(f"must look like 1% or 0.01, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    text = str(value).strip()
    try:
        return float(text[:-1]) / 100.0 if text.endswith("%") else float(text)
    except ValueError:
        raise ValueError(f"must look like 1% or 0.01, got {value!r}") from None


def parse_energy(value: float | int | str) -> float:
    """Return an energy in joules from a number (J) or a string such as ``"1nJ"``."""
    return _parse(value, _ENERGY_UNITS, "energy")


def parse_length(value: float | int | str) -> float:
    """Return a length in metres from a number (m) or a string such as ``"532nm"``."""
    return _parse(value, _LENGTH_UNITS, "length")


def photons_per_pulse(pulse_energy: float, wavelength: float) -> float:
    """Photons in a pulse of ``pulse_energy`` joules at ``wavelength`` metres: E·λ/(h·c)."""
    if pulse_energy < 0 or wavelength <= 0:
        raise ValueError(f"pulse_energy must be >= 0 and wavelength > 0, got {pulse_energy!r}, {wavelength!r}")
    return pulse_energy * wavelength / (PLANCK * SPEED_OF_LIGHT)


_GRID = re.compile(r"^\s*(\d+)\s*[x×X]\s*(\d+)\s*$")


def parse_grid(value: Any, field_name: str) -> tuple[int, int]:
    """Read a grid size from ``"10x10"``, ``10`` (→ 10×10) or ``[10, 10]``; both counts ≥ 1."""
    if isinstance(value, str):
        m = _GRID.match(value)
        if not m:
            raise ValueError(f"{field_name} must look like '10x10', got {value!r}")
        grid = (int(m.group(1)), int(m.group(2)))
    elif isinstance(value, int) and not isinstance(value, bool):
        grid = (value, value)
    elif isinstance(value, (list, tuple)) and len(value) == 2:
        grid = (int(value[0]), int(value[1]))
    else:
        raise ValueError(f"{field_name} must look like '10x10', got {value!r}")
    if min(grid) < 1:
        raise ValueError(f"{field_name} counts must be >= 1, got {value!r}")
    return grid
