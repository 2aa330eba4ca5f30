"""Error reporting shared by every ``datagen`` command: invalid input becomes one ``error: …`` line, exit code 2.

The command modules (:mod:`datagen.cli.main`, :mod:`datagen.cli.tal`, :mod:`datagen.cli.bench`,
:mod:`datagen.cli.dataset`) decorate their commands with :func:`friendly_errors`; this module imports no other
command module, so the command modules never import each other.

What becomes one line (never a traceback): invalid scenes, configs and data (:class:`~datagen.errors.DatagenError`, any
``ValueError`` or ``TypeError`` the library raises for bad input), resource refusals, missing or clobbered
files, and every operating-system error of reading or writing (``OSError``: disk full, permission denied, a
path under a file, …), plus ``MemoryError`` as a last resort. The line is cut to :data:`MAX_LINE` characters;
``DATAGEN_DEBUG=1`` shows the traceback instead.
"""
from __future__ import annotations

import os
import sys
import warnings
from functools import wraps
from pathlib import Path

import click

from ..errors import DatagenError, DatagenWarning
from ..simulation.config import LegacyKeysWarning

MAX_LINE = 2000
"""Characters of an error line printed (a hostile input cannot flood the terminal)."""

DEBUG_ENV = "DATAGEN_DEBUG"
"""Set (to anything) to get the traceback instead of the one-line error (for developers)."""

INPUT_ERRORS = (DatagenError, ValueError, TypeError, OSError)
"""Exceptions a command reports as ``error: …`` with exit code 2 (OSError covers FileNotFoundError,
FileExistsError, PermissionError, NotADirectoryError and a full disk)."""


def error_line(exc: BaseException) -> str:
    """``exc`` as one line of at most :data:`MAX_LINE` characters (a MemoryError gets a sentence)."""
    if isinstance(exc, MemoryError):
        text = f"out of memory ({exc or 'the allocation failed'}): lower the sampling, the time bins or the grids"
    else:
        text = str(exc) or type(exc).__name__
    text = " ".join(text.split())
    return text if len(text) <= MAX_LINE else text[:MAX_LINE - 1] + "…"


def fail(exc: BaseException, code: int = 2):
    """Print ``error: <one line>`` on stderr and exit with ``code``."""
    click.echo(f"error: {error_line(exc)}", err=True)
    sys.exit(code)


def friendly_errors(func):
    """Turn invalid-input, resource and file-system exceptions into a one-line ``error: …`` on stderr and exit
    code 2."""

    @wraps(func)
    def wrapper(*args, **kwargs):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("default", LegacyKeysWarning)      # each distinct note once
                warnings.simplefilter("default", DatagenWarning)
                shown = warnings.showwarning
                warnings.showwarning = _note_printer(shown)
                return func(*args, **kwargs)
        except (*INPUT_ERRORS, MemoryError) as exc:
            if os.environ.get(DEBUG_ENV):
                raise
            fail(exc)

    return wrapper


def _note_printer(shown):
    """A ``warnings.showwarning`` printing a :class:`~datagen.simulation.LegacyKeysWarning` (old configuration
    keys translated) as one ``note: …`` line and a :class:`~datagen.errors.DatagenWarning` (orders left out, a
    zone grid the flood barely lights) as one ``warning: …`` line on stderr, and anything else as ``shown`` does."""
    seen: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, (LegacyKeysWarning, DatagenWarning)):
            if str(message) not in seen:            # once per command, wherever it was raised
                seen.add(str(message))
                kind = "note" if issubclass(category, LegacyKeysWarning) else "warning"
                click.echo(f"{kind}: {error_line(message)}", err=True)
        else:
            shown(message, category, filename, lineno, file, line)
    return show


def check_output_file(path: Path, option: str) -> None:
    """Refuse an output file whose directory does not exist (or is a file) or that is a directory."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{option} {path} is a directory, not a file")
    if path.parent.exists() and not path.parent.is_dir():
        raise FileExistsError(f"{option} {path}: {path.parent} is a file, not a directory")
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{option} {path}: directory {path.parent} does not exist")


def announce_work(scene, config) -> None:
    """Before a simulation's work: check its memory and every knob's bound (:func:`datagen.simulation.budget.
    check_simulation_memory`: one ``error:`` line when one fails), then print the projection of long work as one
    ``note:`` line on stderr, --quiet or not (:func:`datagen.simulation.bounds.long_work_line`)."""
    from ..simulation.bounds import long_work_line
    from ..simulation.budget import check_simulation_memory

    check_simulation_memory(scene, config)
    line = long_work_line(scene, config)
    if line is not None:
        click.echo(f"note: {line}", err=True)
