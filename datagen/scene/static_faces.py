"""What the coincident-face check found among the objects of a scene that do not move, kept across the instants of a
capture sequence (:meth:`datagen.scene.Scene.at`, :func:`datagen.scene.coincident.resolve_coincident_faces`)."""
from __future__ import annotations

import operator as op

import numpy as np

from .parts import SceneObject


class StaticFaces:
    """The check's verdict on the objects that do not move, kept across a sequence's frames (:meth:`Scene.at
    <datagen.scene.Scene.at>`): once the objects not named in ``moving`` passed :func:`~datagen.scene.coincident.resolve_coincident_faces` with
    nothing among them to remove or refuse, a check of the same objects (the same instances) at the same tolerance,
    from the same viewpoints, tests only the pairs with a moving object: every moving object against everything.

    Attributes:
        moving: the moving objects' names; objects: the static objects found clean (() before); tol: metres, the
            tolerance then; view: the viewpoints their verdict read ((3,) tuples; None: no two of their faces
            coincide); spot_on: the laser spot lies on one of their faces; reach: name → (object, viewpoints, its
            ``_Reach._closed`` in :mod:`datagen.scene.coincident`).
    """

    def __init__(self, moving):
        self.moving, self.objects, self.tol, self.view, self.spot_on = frozenset(moving), (), None, None, False
        self.reach: dict[str, tuple] = {}

    def holds(self, statics: tuple[SceneObject, ...], tol: float) -> bool:
        """Whether the verdict covers ``statics`` at ``tol`` (the viewpoints are the caller's to compare)."""
        return self.tol == tol and len(statics) == len(self.objects) and all(map(op.is_, statics, self.objects))


def viewpoint_key(points: list) -> tuple:
    """The viewpoints ((3,) m each) as a tuple of float tuples, to compare."""
    return tuple(tuple(float(x) for x in np.asarray(p, dtype=np.float64)) for p in points)
