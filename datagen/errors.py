"""The errors datagen raises for invalid input or data, one hierarchy (docs/reliability.md).

Every one is a ``ValueError`` (code that caught ``ValueError`` keeps working) whose message is one line naming
the file, the field (or option) and the value; the command line prints it as ``error: …`` with exit code 2
(:mod:`datagen.cli.errors`)::

    DatagenError
    ├── SceneError      a scene file or scene object (geometry, materials, laser, sensor, capture)
    ├── ConfigError     a simulation, detector or dataset config, a command-line option
    ├── DatasetError    a stored dataset, result or file read back (incomplete, damaged, another format)
    └── ResourceError   a setting that needs more memory or time than the machine has, refused up front

Warnings that the command line prints as one ``warning: …`` line derive from :class:`DatagenWarning`.
"""
from __future__ import annotations

__all__ = ["DatagenError", "SceneError", "ConfigError", "DatasetError", "ResourceError", "DatagenWarning"]


class DatagenError(ValueError):
    """Base of every error datagen raises for invalid input or data; the message names file, field and value."""


class SceneError(DatagenError):
    """A scene is invalid; the message names the file (when there is one), the field and the value."""


class ConfigError(DatagenError):
    """A simulation, detector or dataset config (or a command-line option) is invalid."""


class DatasetError(DatagenError):
    """A stored dataset, result or file read back is incomplete, damaged or not what the reader expects."""


class ResourceError(DatagenError):
    """A simulation or build needs more memory (or time) than the machine has; the message names the field, its
    value, the estimate and what is available."""


class DatagenWarning(UserWarning):
    """A result that is valid but probably not what the user meant, or costlier than it needs to be (e.g. orders
    left out, a zone grid the flood barely lights); the command line prints it once as one ``warning: …`` line."""
