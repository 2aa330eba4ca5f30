"""Each BRDF formula once: scalar numba device functions, called by every compiled kernel and by the numpy paths.

The formulas of :mod:`datagen.scene.materials` (its module doc states them and their sources):

- :func:`lambertian_value`: f = ρ/π;
- :func:`sin_theta_value`: f = ½ρ·|sin φ_in|·|sin φ_out| (:func:`sin_theta_scale` is its c = ½ρ in the separable
  split), with :func:`abs_sin_azimuth` the |sin φ| of one direction;
- :func:`phong_value`: the normalised modified Phong BRDF (Lafortune & Willems 1994)
  f = ρ·[(1 − k_s)/π + k_s·(e + 2)/(2π)·cos^e α], α the angle between ω_out and the mirror direction of ω_in;
  :func:`phong_gloss` is its glossy term k_s·(e + 2)/(2π)·cos^e α, :func:`phong_diffuse_scale` the c =
  (1 − k_s)ρ/π of the separable split;
- :func:`retro_value`: the retroreflective kind, a diffuse part plus the Minimal Retroreflective Microfacet lobe
  (Portsmouth, Raab, Belcour & Liu, JCGT 15(1), 2026: a GGX microfacet BRDF evaluated at the *back vector*
  h_b = unit(ω_in + R ω_out), R the mirror reflection about the normal)
  f = ρ·[(1 − k_s)/π + k_s·D(h_b)·G₂(ω_in, ω_out)/(4 cosθ_in cosθ_out)], with :func:`ggx_ndf` D (Trowbridge &
  Reitz 1975; Walter et al. 2007), :func:`smith_lambda` Λ and the height-correlated Smith G₂ = 1/(1 + Λ_in + Λ_out)
  (Heitz 2014), times the entrance-angle falloff (cosθ_in cosθ_out)^(m/2) of real sheeting (:func:`retro_entrance`);
  :func:`retro_lobe` is its lobe per unit ρ·k_s and :func:`retro_cos_h` the cosine of h_b;
  :func:`retro_pdf` and :func:`retro_sample` sample that lobe through the distribution of visible normals (Heitz,
  "Sampling the GGX distribution of visible normals", JCGT 7(4), 2018), reflected about the normal;
- :func:`sample_direction`: the directions estimators draw at a surface point, cosine-weighted, or for a
  retroreflective material the mixture k_s·lobe + (1 − k_s)·cosine; :func:`sampling_ratio` is its density over the
  cosine density (exactly 1 for a cosine draw), which the balance heuristics of the estimators that draw them use;
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

import numpy as np
from numba import njit
from numba.core.registry import CPUDispatcher

BRDF_KINDS = ("lambertian", "sin_theta", "phong", "retroreflective")
LAMBERTIAN, SIN_THETA, PHONG, RETROREFLECTIVE = range(4)
"""BRDF kind codes (:attr:`datagen.scene.materials.MaterialTable.kind`), indices into ``BRDF_KINDS``."""

TANGENT_EPS = 1e-12
"""Below this squared tangential length a direction is along the normal and its azimuth is undefined;
the sin θ lobe is then 0 there (a set of measure zero)."""

__all__ = ["BRDF_KINDS", "LAMBERTIAN", "PHONG", "RETROREFLECTIVE", "SIN_THETA", "TANGENT_EPS", "abs_sin_azimuth",
           "brdf_value", "ggx_ndf", "lambertian_value", "on_arrays", "phong_cos_alpha", "phong_diffuse_scale",
           "phong_gloss", "phong_power", "phong_value", "retro_cos_h", "retro_directions", "retro_entrance",
           "retro_lobe", "retro_pdf", "retro_sample", "retro_value", "sample_direction", "sample_directions", "samples_lobe",
           "sampling_ratio", "sin_theta_scale", "sin_theta_value", "smith_lambda"]


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
    """c = (1 − k_s)ρ/π of the Phong and retroreflective kinds' separable split (the part of f that does not depend
    on angles)."""
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
def ggx_ndf(alpha, cos_h):
    """GGX (Trowbridge–Reitz) microfacet distribution D = α² / (π (cos²θ_h (α² − 1) + 1)²) in 1/sr, normalised so
    that ∫ D cosθ_h dω_h = 1 over the hemisphere (Walter et al., EGSR 2007, eq. 33); α > 0 its width, cos_h = n·h."""
    a2 = alpha * alpha
    t = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * (t * t))


@njit(cache=True, inline="always")
def smith_lambda(alpha, cos):
    """Λ(ω) of the GGX Smith masking function, (√(1 + x) − 1)/2 with x = α² tan²θ (Heitz, JCGT 3(2), 2014, eq. 72),
    written x / (2(1 + √(1 + x))) so that small x keeps its digits; cos = n·ω > 0."""
    c2 = cos * cos
    x = alpha * alpha * (1.0 - c2) / c2
    return x / (2.0 * (1.0 + (1.0 + x) ** 0.5))


@njit(cache=True, inline="always")
def retro_cos_h(cos_in, cos_out, cos_io):
    """n·h_b of the back vector h_b = unit(ω_in + R ω_out), R ω = 2(n·ω)n − ω the mirror image about the normal:
    (cosθ_in + cosθ_out) / √(2 + 2(2 cosθ_in cosθ_out − ω_in·ω_out)); ``cos_io`` = ω_in·ω_out. It is 1 at
    ω_out = ω_in and symmetric in the two directions."""
    return (cos_in + cos_out) / (2.0 + 2.0 * (2.0 * cos_in * cos_out - cos_io)) ** 0.5


@njit(cache=True, inline="always")
def retro_entrance(falloff, cos_in, cos_out):
    """The retroreflective lobe's entrance-angle factor (cosθ_in cosθ_out)^(m/2), m = ``entrance_falloff`` ≥ 0:
    cos^m of the entrance angle where the lobe is (ω_out ≈ ω_in), symmetric in the two directions and ≤ 1; exactly 1
    for m = 0 (x⁰ = 1 in IEEE pow: no falloff, bit for bit). Real sheeting's coefficient of retroreflection falls
    with the entrance angle (ASTM D4956's minimum R_A at +30° is 0.43–0.60 of that at −4°: m ≈ 3.6–6;
    docs/physics.md, "Retroreflective")."""
    return (cos_in * cos_out) ** (0.5 * falloff)


@njit(cache=True, inline="always")
def retro_lobe(alpha, falloff, cos_in, cos_out, cos_h):
    """The retroreflective lobe per unit ρ·k_s, D(h_b)·G₂ / (4 cosθ_in cosθ_out)·:func:`retro_entrance` (1/sr),
    G₂ = 1/(1 + Λ_in + Λ_out) the height-correlated Smith shadowing-masking (Heitz 2014, eq. 99); α = ``lobe_width``,
    ``falloff`` the entrance-angle exponent m, cos_h from :func:`retro_cos_h`. Without the falloff its albedo
    ∫ lobe cosθ_out dω_out is that of the forward GGX lobe at the same incidence (R keeps solid angle and cosθ_out),
    ≤ 1 since G₂ ≤ G₁(ω_in) (Portsmouth et al. 2026); the falloff, ≤ 1, only lowers it."""
    masking = 1.0 + (smith_lambda(alpha, cos_in) + smith_lambda(alpha, cos_out))
    return ggx_ndf(alpha, cos_h) / (4.0 * cos_in * cos_out * masking) * retro_entrance(falloff, cos_in, cos_out)


@njit(cache=True, inline="always")
def retro_value(rho, ks, alpha, falloff, cos_in, cos_out, cos_h):
    """Retroreflective f = ρ·[(1 − k_s)/π + k_s·:func:`retro_lobe`] (1/sr); ρ albedo, k_s the fraction in the lobe,
    α its width, ``falloff`` its entrance-angle exponent m, both cosines > 0."""
    return rho * ((1.0 - ks) / math.pi + ks * retro_lobe(alpha, falloff, cos_in, cos_out, cos_h))


@njit(cache=True, inline="always")
def retro_pdf(alpha, cos_in, cos_h):
    """Density (1/sr) of the directions :func:`retro_sample` draws, G₁(ω_in)·D(h_b) / (4 cosθ_in), G₁ = 1/(1 + Λ_in):
    the visible-normal density G₁ D max(0, ω_in·h)/cosθ_in (Heitz 2018, eq. 2) over the reflection's Jacobian
    4 ω_in·h; R keeps solid angle. Some of its mass lies below the surface (draws there carry f = 0)."""
    return ggx_ndf(alpha, cos_h) / (4.0 * cos_in * (1.0 + smith_lambda(alpha, cos_in)))


@njit(cache=True, inline="always")
def retro_sample(alpha, v0, v1, v2, u1, u2):
    """A direction of the retroreflective lobe for ω_in = v (local frame, normal +z, v2 > 0) from uniforms u1, u2:
    a visible normal h of the GGX distribution seen from v (Heitz, JCGT 7(4), 2018: stretch, a point of the
    projected hemisphere, unstretch), the mirror direction 2(v·h)h − v, then its image under R (x, y negated), so
    that the back vector of (v, result) is h. Returns (o0, o1, o2); o2 ≤ 0 when the draw falls below the surface."""
    s0, s1, s2 = alpha * v0, alpha * v1, v2
    inv = 1.0 / math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    s0, s1, s2 = s0 * inv, s1 * inv, s2 * inv
    lensq = s0 * s0 + s1 * s1
    if lensq > 0.0:
        il = 1.0 / math.sqrt(lensq)
        t0, t1, t2 = -s1 * il, s0 * il, 0.0
    else:
        t0, t1, t2 = 1.0, 0.0, 0.0
    b0, b1, b2 = s1 * t2 - s2 * t1, s2 * t0 - s0 * t2, s0 * t1 - s1 * t0
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1, p2 = r * math.cos(phi), r * math.sin(phi)
    blend = 0.5 * (1.0 + s2)
    p2 = (1.0 - blend) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + blend * p2
    pz = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    h0 = alpha * (p1 * t0 + p2 * b0 + pz * s0)
    h1 = alpha * (p1 * t1 + p2 * b1 + pz * s1)
    h2 = max(0.0, p1 * t2 + p2 * b2 + pz * s2)
    inv = 1.0 / math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    h0, h1, h2 = h0 * inv, h1 * inv, h2 * inv
    d = 2.0 * (v0 * h0 + v1 * h1 + v2 * h2)
    return -(d * h0 - v0), -(d * h1 - v1), d * h2 - v2


@njit(cache=True)
def retro_directions(alpha, w_in, u1, u2):
    """:func:`retro_sample` over arrays: w_in (m, 3) local unit directions (normal +z), u1, u2 (m,) uniforms →
    (m, 3) float64 (rows with z ≤ 0 fell below the surface)."""
    out = np.empty((w_in.shape[0], 3))
    for i in range(w_in.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = retro_sample(alpha, w_in[i, 0], w_in[i, 1], w_in[i, 2], u1[i], u2[i])
    return out


@njit(cache=True, inline="always")
def samples_lobe(mat, obj, cos_in):
    """Whether the direction sampler of object ``obj``'s material (:func:`sample_direction`) draws from a lobe for
    light arriving from ω_in (``cos_in`` = n·ω_in): a retroreflective material with k_s > 0 lit from above."""
    return mat[0][obj] == RETROREFLECTIVE and mat[2][obj] > 0.0 and cos_in > 0.0


@njit(cache=True, inline="always")
def sample_direction(mat, obj, n0, n1, n2, i0, i1, i2, u, v):
    """A direction leaving a point of object ``obj`` (unit normal n, light from unit ω_in = i) from uniforms u, v:
    cosine-weighted about n (Shirley & Chiu's concentric disk lifted by Malley's method, in the tangent frame of
    Duff et al., JCGT 6(1), 2017), or where :func:`samples_lobe` holds, the retroreflective lobe
    (:func:`retro_sample`) when u < k_s and a cosine direction from (u − k_s)/(1 − k_s) otherwise: one uniform picks
    the part and places the direction. Density: :func:`sampling_ratio` × cosθ_out/π. Returns (o0, o1, o2, cosθ_out);
    a lobe draw below the surface has cosθ_out ≤ 0 (it carries f = 0)."""
    sign = 1.0 if n2 >= 0.0 else -1.0
    aa = -1.0 / (sign + n2)
    bb = n0 * n1 * aa
    t0, t1, t2 = 1.0 + sign * n0 * n0 * aa, sign * bb, -sign * n0
    b0, b1, b2 = bb, sign + n1 * n1 * aa, -n1
    lobe = samples_lobe(mat, obj, i0 * n0 + i1 * n1 + i2 * n2)
    ks = mat[2][obj]
    if lobe and u < ks:
        lx, ly, z = retro_sample(mat[6][obj], i0 * t0 + i1 * t1 + i2 * t2, i0 * b0 + i1 * b1 + i2 * b2,
                                 i0 * n0 + i1 * n1 + i2 * n2, u / ks, v)
    else:
        if lobe:
            u = (u - ks) / (1.0 - ks)
        a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
        if abs(a) > abs(b):
            rr, phi = a, (math.pi / 4) * (b / a)
        elif b != 0.0:
            rr, phi = b, math.pi / 2 - (math.pi / 4) * (a / b)
        else:
            rr, phi = b, 0.0
        z = math.sqrt(max(0.0, 1.0 - rr * rr))
        lx, ly = rr * math.cos(phi), rr * math.sin(phi)
    return lx * t0 + ly * b0 + z * n0, lx * t1 + ly * b1 + z * n1, lx * t2 + ly * b2 + z * n2, z


@njit(cache=True)
def sample_directions(normals, obj, w_in, u, v, mat):
    """:func:`sample_direction` over arrays: normals, w_in (m, 3) unit, obj (m,) int, u, v (m,) uniforms, mat the
    material arrays (:func:`datagen.transport.leg_kernels.material_arrays`) → (m, 3) float64 directions."""
    out = np.empty((normals.shape[0], 3))
    for i in range(normals.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], _ = sample_direction(mat, obj[i], normals[i, 0], normals[i, 1], normals[i, 2],
                                                              w_in[i, 0], w_in[i, 1], w_in[i, 2], u[i], v[i])
    return out


@njit(cache=True, inline="always")
def sampling_ratio(mat, obj, cos_in, cos_out, cos_io):
    """p(ω_out) / (cosθ_out/π): the density of :func:`sample_direction` for object ``obj``'s material over the cosine
    density (ω_out above the surface, cos_in = n·ω_in, cos_io = ω_in·ω_out). Exactly 1.0 where it draws cosine
    directions only (:func:`samples_lobe` false), else (1 − k_s) + k_s·:func:`retro_pdf`·π/cosθ_out."""
    if not (samples_lobe(mat, obj, cos_in) and cos_out > 0.0):
        return 1.0
    ks, alpha = mat[2][obj], mat[6][obj]
    return (1.0 - ks) + ks * (retro_pdf(alpha, cos_in, retro_cos_h(cos_in, cos_out, cos_io)) * math.pi / cos_out)


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
    exponent (Phong's e; the retroreflective kind's entrance-angle exponent m), axis (n, 3), constant f, lobe width)
    per object id
    (:func:`datagen.transport.leg_kernels.material_arrays`).

    The constant f of ``mat`` when it is not NaN (Lambertian without angle work,
    :meth:`datagen.transport.physics.LegPhysics.brdf`), else :meth:`MaterialTable.evaluate`: 0 unless both
    cosines are > 0, then the kind's formula (module doc).
    """
    kind, albedo, specular, exponent, axis, const_f, width = mat
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
    if k == RETROREFLECTIVE:
        cos_h = retro_cos_h(cos_in, cos_out, i0 * o0 + i1 * o1 + i2 * o2)
        return retro_value(rho, specular[obj], width[obj], exponent[obj], cos_in, cos_out, cos_h)
    if k == LAMBERTIAN:
        return lambertian_value(rho)
    return 0.0
