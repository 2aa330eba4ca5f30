"""Scalar (numba) form of the glossy BRDF for the compiled transport passes.

:func:`phong_value` is :meth:`datagen.scene.materials.MaterialTable.evaluate`'s ``phong`` kind for one point and
one pair of directions, written once for every compiled estimator (:mod:`datagen.transport.area_kernels`,
:mod:`datagen.transport.quad_kernel`): the normalised modified Phong BRDF (Lafortune & Willems 1994; the
materials module doc) f = ρ·[(1 − k_s)/π + k_s·(e + 2)/(2π)·cos^e α], α the angle between ω_out and the mirror
direction of ω_in. ``tests/test_area_kernels.py`` and ``tests/test_quad_kernel.py`` compare the kernels that call
it with :meth:`~datagen.scene.materials.MaterialTable.evaluate` (relative 1e-12).
"""
from __future__ import annotations

import math

from numba import njit

__all__ = ["phong_value"]


@njit(cache=True, inline="always")
def phong_value(rho, ks, expo, cos_in, n0, n1, n2, i0, i1, i2, o0, o1, o2):
    """f in 1/sr of the Phong kind (module doc) at a point with unit normal n on the lit side, for unit
    directions ω_in = i, ω_out = o away from the surface, cos_in = n·ω_in (> 0; the caller tests both cosines).
    ρ albedo, k_s specular fraction, e exponent (> 0), all float64 scalars."""
    m0, m1, m2 = 2.0 * cos_in * n0 - i0, 2.0 * cos_in * n1 - i1, 2.0 * cos_in * n2 - i2
    cos_alpha = min(max(m0 * o0 + m1 * o1 + m2 * o2, 0.0), 1.0)
    power = cos_alpha ** expo if cos_alpha > 0.0 or expo <= 0.0 else 0.0      # 0^e = 0 without pow
    return rho * ((1.0 - ks) / math.pi + ks * ((expo + 2.0) / (2.0 * math.pi) * power))
