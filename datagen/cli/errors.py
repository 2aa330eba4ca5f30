"""Error reporting shared by every ``datagen`` command: invalid input becomes one ``error: …`` line, exit code 2.

The command modules (:mod:`datagen.cli.main`, :mod:`datagen.cli.tal`, :mod:`datagen.cli.bench`) decorate their
commands with :func:`friendly_errors`; this module imports no other command module, so the command modules
never import each other.
"""
from __future__ import annotations

import sys
from functools import wraps

import click

from ..scene import SceneError


def friendly_errors(func):
    """Turn invalid-input exceptions into a one-line ``error: …`` on stderr and exit code 2."""

    @wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (SceneError, ValueError, FileNotFoundError, FileExistsError) as exc:
            message = " ".join(str(exc).split())
            click.echo(f"error: {message}", err=True)
            sys.exit(2)

    return wrapper
