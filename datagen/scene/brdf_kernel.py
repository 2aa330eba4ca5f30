"""Each BRDF formula once: scalar numba device functions, called by every compiled kernel and by the numpy paths.

The formulas of :mod:`datagen.scene.materials` (its module doc states them and their sources):

- :func:`lambertian_value`: f = ρ/π;
- :func:`sin_theta_value`: f = ½ρ·|sin φ_in|·|sin φ_out| (:func:`sin_theta_scale` is its c = ½ρ in the separable
  split), with :func:`abs_sin_azimuth` the |sin φ| of one direction;
- :func:`phong_value`: the normalised modified Phong BRDF (Lafortune & Willems 1994)
  f = ρ·[(1 − k_s)/π + k_s·(e + 2)/(2π)·cos^e α], α the angle between ω_out and the mirror direction of ω_in;
  :func:`phong_gloss` is its glossy term k_s·(e + 2)/(2π)·cos^e α, :func:`phong_diffuse_scale` the c =
  (1 − k_s)ρ/π of the separable split;
- :func:`brdf_value`: f(ω_in, ω_out) of one point of any kind from the material arrays (the compiled form of
  :meth:`~datagen.scene.materials.MaterialTable.evaluate`).

The formula functions take scalars already reduced to the quantities the formula needs (ρ, k_s, e, cos^e α,
|sin φ|): the geometry that produces them (dot products, the mirror direction) is the caller's, since numpy's
``einsum`` sums three products in another order than a scalar loop. Numpy code calls the same functions on
arrays through :func:`on_arrays` (their Python bodies are plain arithmetic, the same float operations in the same
order), so a compiled kernel and a numpy path evaluate each formula from one definition.
``tests/test_formulas_once.py`` checks that no other function writes these expressions.
"""
from __future__ import annotations

import math
import types

from numba import njit
from numba.core.registry import CPUDispatcher

BRDF_KINDS = ("lambertian", "sin_theta", "phong")
LAMBERTIAN, SIN_THETA, PHONG = range(3)
"""BRDF kind codes (:attr:`datagen.scene.materials.MaterialTable.kind`), indices into ``BRDF_KINDS``."""

TANGENT_EPS = 1e-12
"""Below this squared tangential length a direction is along the normal and its azimuth is undefined;
the sin θ lobe is then 0 there (a set of measure zero)."""

__all__ = ["BRDF_KINDS", "LAMBERTIAN", "PHONG", "SIN_THETA", "TANGENT_EPS", "abs_sin_azimuth", "brdf_value",
           "lambertian_value", "on_arrays", "phong_cos_alpha", "phong_diffuse_scale", "phong_gloss", "phong_power",
           "phong_value", "sin_theta_scale", "sin_theta_value"]


_ON_ARRAYS: dict = {}


def on_arrays(formula):
    """The Python body of a compiled formula function, for numpy arrays: elementwise, the same float operations in
    the same order as the compiled function applies to scalars (the formula functions called inside it run as
    Python too, so no numba array code is compiled)."""
    if formula not in _ON_ARRAYS:
        fn = formula.py_func
        env = dict(fn.__globals__)
        for name in fn.__code__.co_names:
            if isinstance(env.get(name), CPUDispatcher):
                env[name] = on_arrays(env[name])
        _ON_ARRAYS[formula] = types.FunctionType(fn.__code__, env, fn.__name__, fn.__defaults__, fn.__closure__)
    return _ON_ARRAYS[formula]


@njit(cache=True, inline="always")
def lambertian_value(rho):
    """Lambertian f = ρ/π (1/sr), ρ the albedo."""
    return rho / math.pi


@njit(cache=True, inline="always")
def sin_theta_scale(rho):
    """c = ½ρ of the sin θ kind's separable form f = c·|sin φ_in|·|sin φ_out| (1/sr)."""
    return 0.5 * rho


@njit(cache=True, inline="always")
def sin_theta_value(rho, s_in, s_out):
    """sin θ f = ½ρ·|sin φ_in|·|sin φ_out| (1/sr), ``s_in``, ``s_out`` from :func:`abs_sin_azimuth`."""
    return sin_theta_scale(rho) * s_in * s_out


@njit(cache=True, inline="always")
def phong_gloss(ks, expo, power):
    """The glossy term k_s·(e + 2)/(2π)·cos^e α of the Phong kind (1/sr per unit ρ); ``power`` = cos^e α."""
    return ks * ((expo + 2.0) / (2.0 * math.pi) * power)


@njit(cache=True, inline="always")
def phong_value(rho, ks, expo, power):
    """Phong f = ρ·[(1 − k_s)/π + :func:`phong_gloss`] (1/sr); ρ albedo, k_s specular fraction, e exponent (> 0),
    ``power`` = cos^e α (:func:`phong_power`)."""
    return rho * ((1.0 - ks) / math.pi + phong_gloss(ks, expo, power))


@njit(cache=True, inline="always")
def phong_diffuse_scale(rho, ks):
    """c = (1 − k_s)ρ/π of the Phong kind's separable split (the part of f that does not depend on angles)."""
    return (1.0 - ks) * rho / math.pi


@njit(cache=True, inline="always")
def phong_power(cos_alpha, expo):
    """cos^e α, 0 for cos α = 0 without calling pow (e > 0)."""
    return cos_alpha ** expo if cos_alpha > 0.0 or expo <= 0.0 else 0.0


@njit(cache=True, inline="always")
def phong_cos_alpha(cos_in, n0, n1, n2, i0, i1, i2, o0, o1, o2):
    """cos α, clipped to [0, 1], between ω_out = o and the mirror direction 2(n·ω_in)n − ω_in of ω_in = i about the
    unit normal n (cos_in = n·ω_in)."""
    m0, m1, m2 = 2.0 * cos_in * n0 - i0, 2.0 * cos_in * n1 - i1, 2.0 * cos_in * n2 - i2
    return min(max(m0 * o0 + m1 * o1 + m2 * o2, 0.0), 1.0)


@njit(cache=True, inline="always")
def abs_sin_azimuth(n0, n1, n2, a0, a1, a2, w0, w1, w2):
    """|sin| of w's azimuth about n from the axis a (materials' ``_abs_sin_azimuth``, Duff et al. fallback): the
    angular factor of the sin θ BRDF (:func:`sin_theta_value`)."""
    an = a0 * n0 + a1 * n1 + a2 * n2
    t0, t1, t2 = a0 - an * n0, a1 - an * n1, a2 - an * n2
    t_len2 = t0 * t0 + t1 * t1 + t2 * t2
    if t_len2 > TANGENT_EPS:
        s = math.sqrt(max(t_len2, TANGENT_EPS))
        t0, t1, t2 = t0 / s, t1 / s, t2 / s
    else:                                            # tangent_frame: Duff et al., JCGT 6(1), 2017
        sign = 1.0 if n2 >= 0.0 else -1.0
        a = -1.0 / (sign + n2)
        b = n0 * n1 * a
        t0, t1, t2 = 1.0 + sign * n0 ** 2 * a, sign * b, -sign * n0
    b0, b1, b2 = n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0
    wn = w0 * n0 + w1 * n1 + w2 * n2
    u0, u1, u2 = w0 - wn * n0, w1 - wn * n1, w2 - wn * n2
    tan_len2 = u0 * u0 + u1 * u1 + u2 * u2
    if not tan_len2 > TANGENT_EPS:
        return 0.0
    sin_az = abs(u0 * b0 + u1 * b1 + u2 * b2) / math.sqrt(max(tan_len2, TANGENT_EPS))
    return min(sin_az, 1.0)


@njit(cache=True, inline="always")
def brdf_value(mat, obj, n0, n1, n2, i0, i1, i2, o0, o1, o2):
    """f(ω_in, ω_out) in 1/sr at a point of object ``obj`` with unit normal n (lit side) for unit directions
    ω_in = (i0, i1, i2), ω_out = (o0, o1, o2) away from the surface; ``mat`` = (kind int8, albedo, specular,
    exponent, axis (n, 3), constant f) per object id (:func:`datagen.transport.leg_kernels.material_arrays`).

    The constant f of ``mat`` when it is not NaN (Lambertian without angle work,
    :meth:`datagen.transport.physics.LegPhysics.brdf`), else :meth:`MaterialTable.evaluate`: 0 unless both
    cosines are > 0, then the kind's formula (module doc).
    """
    kind, albedo, specular, exponent, axis, const_f = mat
    f = const_f[obj]
    if not math.isnan(f):
        return f
    cos_in = n0 * i0 + n1 * i1 + n2 * i2
    cos_out = n0 * o0 + n1 * o1 + n2 * o2
    if not (cos_in > 0.0 and cos_out > 0.0):
        return 0.0
    k, rho = kind[obj], albedo[obj]
    if k == SIN_THETA:
        a0, a1, a2 = axis[obj, 0], axis[obj, 1], axis[obj, 2]
        return sin_theta_value(rho, abs_sin_azimuth(n0, n1, n2, a0, a1, a2, i0, i1, i2),
                               abs_sin_azimuth(n0, n1, n2, a0, a1, a2, o0, o1, o2))
    if k == PHONG:
        expo = exponent[obj]
        return phong_value(rho, specular[obj], expo,
                           phong_power(phong_cos_alpha(cos_in, n0, n1, n2, i0, i1, i2, o0, o1, o2), expo))
    if k == LAMBERTIAN:
        return lambertian_value(rho)
    return 0.0
