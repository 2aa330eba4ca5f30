"""Command-line stage: the ``datagen`` command (entry point ``datagen.cli:main``). It only parses and calls the
library.

In: command-line arguments and the files they name (scene YAML, detector YAML, dataset configs, tal render
YAML, result stores). Out: what the library writes (result stores, figures, datasets, tal HDF5 captures,
benchmark tables) and a short report on stdout; invalid input gives one ``error: …`` line on stderr and exit
code 2 (:func:`~datagen.cli.errors.friendly_errors`).

Modules (they import each other directly, never through this package):

- :mod:`~datagen.cli.main`: the ``main`` group, ``simulate`` and ``detect``; registers the other commands;
- :mod:`~datagen.cli.like`: ``simulate --like STORE`` and ``--detector FILE`` (what they read and change);
- :mod:`~datagen.cli.errors`: :func:`~datagen.cli.errors.friendly_errors`, shared by the command modules;
- :mod:`~datagen.cli.tal`: ``tal-render``, ``export-tal``;
- :mod:`~datagen.cli.dataset`: ``build``, ``inspect``, ``verify``;
- :mod:`~datagen.cli.bench`: ``bench accuracy``;
- :mod:`~datagen.cli.view`: ``view`` (3D pictures with open3d).
- :mod:`~datagen.cli.capture`: ``import-capture``, ``export``, ``fit-detector``, ``compare-capture``;
- :mod:`~datagen.cli.estimate`: ``estimate-capture`` (the IRF, gain and background maps of a capture);
- :mod:`~datagen.cli.reconstruct`: ``reconstruct`` (LCT, phasor or FBP on any confocal store);
- :mod:`~datagen.cli.multizone`: ``multizone`` and the multi-zone path of ``simulate``;
- :mod:`~datagen.cli.suite`: ``suite build``, ``suite verify``, ``suite score``;
- :mod:`~datagen.cli.sequence`: ``sequence`` (the frames of a scene whose objects move);
- :mod:`~datagen.cli.__main__`: ``python -m datagen.cli``.
"""
from .main import main

__all__ = ["main"]
