"""Preloaded by the build's fork server only: importing it ties the fork server's life to the build process
(:func:`datagen.dataset.workers.guard_forkserver`; a no-op in any other process)."""
from __future__ import annotations

from .workers import guard_forkserver

guard_forkserver()
