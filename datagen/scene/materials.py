"""Bidirectional reflectance distribution functions (BRDFs) and materials.

Every BRDF here is reciprocal, f(ω_i, ω_o) = f(ω_o, ω_i), and energy-conserving: its hemispherical albedo
a(ω_i) = ∫ f(ω_i, ω_o) cos θ_o dω_o ≤ albedo ≤ 1 for every incidence (docs/physics.md §2). Directions are
unit vectors pointing *away* from the surface, in world coordinates; ``normals`` are unit surface normals on
the side the light arrives from. f is in 1/sr.

Kinds:

- ``lambertian``: f = ρ/π (the paper's walls, box and relay wall; Scholes & Leach 2024 §3.1, B = cos φ with
  the cosine written separately here).
- ``sin_theta``: the paper's illustrative anisotropic lobe on the pillar (§3.2, B_j = sin θ̂_j^r, θ the
  azimuth in the local tangent plane, measured from the material's ``axis`` projected onto that plane).
  The paper's form depends on the outgoing azimuth only, which is neither reciprocal nor normalised; we use
  the reciprocal, normalised separable form f = (ρ/2)·|sin θ_i|·|sin θ_o|, whose albedo is ρ·|sin θ_i| ≤ ρ
  (∫|sin θ| dθ · ∫cos φ sin φ dφ = 4 · ½ = 2, hence the ½). With ``axis`` = +z on a vertical face it sends
  light into the horizontal plane, as in the paper's Figure 5b.
- ``phong``: normalised modified Phong (Lafortune & Willems 1994): f = ρ·[(1−k_s)/π + k_s·(n+2)/(2π)·
  max(0, r_i·ω_o)^n], r_i the mirror direction of ω_i. Reciprocal since r_i·ω_o = r_o·ω_i; the lobe's
  albedo is ≤ 1 for every incidence, so a(ω_i) ≤ ρ. Large n approaches a mirror.
- ``retroreflective``: light sent back toward where it came from (road signs, safety apparel, bicycle reflectors:
  glass beads or corner cubes), the Minimal Retroreflective Microfacet model (Portsmouth, Raab, Belcour & Liu,
  "The Minimal Retroreflective Microfacet Model", JCGT 15(1), 2026; the back-vector formulation adopted by OpenPBR
  and MaterialX): f = ρ·[(1−k_s)/π + k_s·D(h_b)·G₂(ω_i, ω_o)/(4 cosθ_i cosθ_o)], a GGX lobe of width α =
  ``lobe_width`` evaluated at the back vector h_b = unit(ω_i + R ω_o), R the mirror reflection about the normal, so
  that it peaks at ω_o = ω_i. Reciprocal (h_b(ω_o, ω_i) = R h_b(ω_i, ω_o) and D, G₂ are symmetric about the
  normal); R keeps solid angle and cosθ_o, so its lobe's albedo is that of the forward GGX lobe, ≤ 1 (G₂ ≤ G₁),
  and a(ω_i) ≤ ρ. For small α the returned light falls to half its peak ≈ 1.29·α rad from ω_i (at normal
  incidence); real sheeting returns most of its light within 1–2°, α ≈ 0.01–0.03. ``entrance_falloff`` m ≥ 0
  multiplies the lobe by (cosθ_i cosθ_o)^(m/2), cos^m of the entrance angle at retroreflection, as real sheeting's
  return falls with it (glass beads, micro-prisms); symmetric and ≤ 1, so reciprocity and a(ω_i) ≤ ρ hold. Formulas
  and sources: :mod:`datagen.scene.brdf_kernel`.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer

from .brdf_kernel import (BRDF_KINDS, LAMBERTIAN, PHONG, RETROREFLECTIVE, SIN_THETA, TANGENT_EPS, lambertian_value,
                          on_arrays, phong_diffuse_scale, phong_gloss, phong_value, retro_cos_h, retro_lobe,
                          retro_value, sin_theta_scale, sin_theta_value)
from ..vectors import norm

__all__ = ["BRDF_KINDS", "ENTRANCE_FALLOFF_MAX", "LAMBERTIAN", "LOBE_WIDTH_MAX", "PHONG", "RETROREFLECTIVE", "SIN_THETA",
           "TANGENT_EPS", "Material", "MaterialTable", "tangent_frame"]

LOBE_WIDTH_MAX = 1.0
"""Widest retroreflective lobe accepted (GGX α): at α = 1 the lobe already spreads over the whole hemisphere, and a
wider one is no retroreflector."""
ENTRANCE_FALLOFF_MAX = 50.0
"""Largest retroreflective entrance-angle exponent m accepted: cos^50 is 0.5 at 9.5°, steeper than any sheeting."""


class Material(BaseModel):
    """Surface material: albedo (reflectivity Γ of the paper) and BRDF kind with its lobe parameters.

    ``lobe_width`` is written out (:meth:`model_dump`) only for the retroreflective kind, and ``entrance_falloff``
    only for a retroreflective material that has one, so that other records are what they were before these existed.

    Raises:
        pydantic.ValidationError: albedo outside [0, 1], unknown kind, specular outside [0, 1],
            exponent ≤ 0, lobe_width outside (0, :data:`LOBE_WIDTH_MAX`], entrance_falloff outside
            [0, :data:`ENTRANCE_FALLOFF_MAX`], or a zero-length anisotropy axis (the
            message names the field and value).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["lambertian", "sin_theta", "phong", "retroreflective"] = "lambertian"
    albedo: float = Field(1.0, ge=0.0, le=1.0, description="hemispherical reflectance scale ρ (Γ), 0..1")
    specular: float = Field(0.5, ge=0.0, le=1.0,
                            description="phong, retroreflective: fraction k_s of ρ in the glossy or "
                                        "retroreflective lobe")
    exponent: float = Field(50.0, gt=0.0, allow_inf_nan=False, description="phong: lobe exponent n (larger is sharper)")
    axis: tuple[float, float, float] = Field((0.0, 0.0, 1.0), description="sin_theta: azimuth reference axis")
    lobe_width: float = Field(0.05, gt=0.0, le=LOBE_WIDTH_MAX, allow_inf_nan=False,
                              description="retroreflective: GGX width α of the lobe about the incident direction "
                                          "(half maximum ≈ 1.29·α rad from it)")
    entrance_falloff: float = Field(0.0, ge=0.0, le=ENTRANCE_FALLOFF_MAX, allow_inf_nan=False,
                                    description="retroreflective: exponent m of the lobe's falloff with the entrance "
                                                "angle θ, cos^m θ (0: none; real sheeting ≈ 3.6–6)")

    @model_serializer(mode="wrap")
    def _dump(self, handler):
        data = handler(self)
        if self.kind != "retroreflective":
            data.pop("lobe_width", None)
        if self.kind != "retroreflective" or self.entrance_falloff == 0.0:
            data.pop("entrance_falloff", None)
        return data

    @field_validator("axis")
    @classmethod
    def _axis_nonzero(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if not np.all(np.isfinite(value)) or norm(value) == 0:
            raise ValueError(f"axis must be a finite non-zero vector, got {value!r}")
        return value

    @property
    def is_lambertian(self) -> bool:
        """True when f does not depend on directions (enables the factorised secondary, docs/physics.md §3)."""
        return self.kind == "lambertian" or (self.kind in ("phong", "retroreflective") and self.specular == 0.0)


class MaterialTable:
    """Materials of a scene as parallel arrays, indexed by object id, for vectorised BRDF evaluation.

    Attributes:
        kind: (n_objects,) int8 BRDF kind code (LAMBERTIAN, SIN_THETA, PHONG, RETROREFLECTIVE).
        albedo, specular, exponent, width: (n_objects,) float64 (width: the retroreflective lobe_width α; exponent:
        Phong's n, or for the retroreflective kind its entrance_falloff m, the slot the kernels read it from).
        axis: (n_objects, 3) float64 unit anisotropy axes.
    """

    def __init__(self, materials: list[Material]):
        self.materials = list(materials)
        self.kind = np.array([BRDF_KINDS.index(m.kind) for m in materials], dtype=np.int8)
        self.albedo = np.array([m.albedo for m in materials], dtype=np.float64)
        self.specular = np.array([m.specular for m in materials], dtype=np.float64)
        self.exponent = np.array([m.entrance_falloff if m.kind == "retroreflective" else m.exponent
                                  for m in materials], dtype=np.float64)
        self.width = np.array([m.lobe_width for m in materials], dtype=np.float64)
        axis = np.array([m.axis for m in materials], dtype=np.float64).reshape(-1, 3)
        self.axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
        self.lambertian = np.array([m.is_lambertian for m in materials], dtype=bool)

    def evaluate(self, object_ids: np.ndarray, normals: np.ndarray, w_in: np.ndarray,
                 w_out: np.ndarray) -> np.ndarray:
        """BRDF values f(ω_in, ω_out) in 1/sr for each point (broadcasting over leading axes).

        Args:
            object_ids: (...,) int, object of each point (indexes this table).
            normals: (..., 3) float64 unit normals on the lit side.
            w_in, w_out: (..., 3) float64 unit directions away from the surface.
        Returns:
            (...,) float64; 0 where either direction is below the surface.
        """
        object_ids, normals, w_in, w_out = _broadcast(object_ids, normals, w_in, w_out)
        cos_in = np.einsum("...k,...k->...", normals, w_in)
        cos_out = np.einsum("...k,...k->...", normals, w_out)
        f = np.zeros(object_ids.shape, dtype=np.float64)
        kind = self.kind[object_ids]
        rho = self.albedo[object_ids]
        f = np.where(kind == LAMBERTIAN, on_arrays(lambertian_value)(rho), f)
        sel = kind == SIN_THETA
        if np.any(sel):
            axis = self.axis[object_ids[sel]]
            n = normals[sel]
            s_in = _abs_sin_azimuth(n, axis, w_in[sel])
            s_out = _abs_sin_azimuth(n, axis, w_out[sel])
            f[sel] = on_arrays(sin_theta_value)(rho[sel], s_in, s_out)
        sel = kind == PHONG
        if np.any(sel):
            ids = object_ids[sel]
            ks, expo = self.specular[ids], self.exponent[ids]
            n, wi, wo = normals[sel], w_in[sel], w_out[sel]
            mirror = 2.0 * cos_in[sel][:, None] * n - wi
            cos_alpha = np.clip(np.einsum("ij,ij->i", mirror, wo), 0.0, 1.0)
            f[sel] = on_arrays(phong_value)(rho[sel], ks, expo, cos_alpha ** expo)
        sel = (kind == RETROREFLECTIVE) & (cos_in > 0) & (cos_out > 0)
        if np.any(sel):
            ids = object_ids[sel]
            cos_h = _retro_cos_h(cos_in[sel], cos_out[sel], w_in[sel], w_out[sel])
            f[sel] = on_arrays(retro_value)(rho[sel], self.specular[ids], self.width[ids], self.exponent[ids],
                                            cos_in[sel], cos_out[sel], cos_h)
        return np.where((cos_in > 0) & (cos_out > 0), f, 0.0)


    # -- separable split (used by the exact factorised secondary, docs/physics.md §3) ---------------------

    def separable_scale(self, object_ids: np.ndarray) -> np.ndarray:
        """c in the split f(ω_i, ω_o) = c·g(ω_i)·g(ω_o) + lobe(ω_i, ω_o), per object id (1/sr).

        Lambertian: c = ρ/π, g = 1, no lobe. sin θ: c = ρ/2, g = |sin azimuth|, no lobe (the lobe is a
        product of an incoming and an outgoing factor). Phong: c = (1 − k_s)ρ/π, g = 1, lobe = ρ·k_s·(n+2)/(2π)
        ·cos^n α (not separable: summed pairwise). Retroreflective: c = (1 − k_s)ρ/π, g = 1, lobe = ρ·k_s·
        D G₂/(4 cosθ_i cosθ_o) (summed pairwise).
        """
        ids = np.asarray(object_ids)
        kind, rho = self.kind[ids], self.albedo[ids]
        return np.where(kind == SIN_THETA, on_arrays(sin_theta_scale)(rho),
                        np.where((kind == PHONG) | (kind == RETROREFLECTIVE),
                                 on_arrays(phong_diffuse_scale)(rho, self.specular[ids]),
                                 on_arrays(lambertian_value)(rho)))

    def separable_factor(self, object_ids: np.ndarray, normals: np.ndarray, w: np.ndarray) -> np.ndarray:
        """g(ω) of :meth:`separable_scale`'s split, (...,) for (..., 3) directions away from the surface."""
        object_ids, normals, w, _ = _broadcast(object_ids, normals, w, w)
        g = (np.einsum("...k,...k->...", normals, w) > 0).astype(np.float64)
        sel = self.kind[object_ids] == SIN_THETA
        if np.any(sel):
            g[sel] *= _abs_sin_azimuth(normals[sel], self.axis[object_ids[sel]], w[sel])
        return g

    def separable_factor_above(self, object_ids: np.ndarray, normals: np.ndarray, w: np.ndarray) -> np.ndarray:
        """:meth:`separable_factor` for directions known to lie above the surface (skips the cos test)."""
        object_ids = np.asarray(object_ids)
        g = np.ones(object_ids.shape, dtype=np.float64)
        sel = self.kind[object_ids] == SIN_THETA
        if np.any(sel):
            g[sel] = _abs_sin_azimuth(normals[sel], self.axis[object_ids[sel]], w[sel])
        return g

    def has_lobe(self, object_ids: np.ndarray) -> np.ndarray:
        """True where the material has a non-separable lobe (Phong or retroreflective with k_s > 0)."""
        ids = np.asarray(object_ids)
        return ((self.kind[ids] == PHONG) | (self.kind[ids] == RETROREFLECTIVE)) & (self.specular[ids] > 0)

    def lobe(self, object_ids: np.ndarray, normals: np.ndarray, w_in: np.ndarray,
             w_out: np.ndarray) -> np.ndarray:
        """The non-separable part of f (Phong's glossy lobe, the retroreflective lobe; 0 for other kinds), broadcasting
        like evaluate."""
        object_ids, normals, w_in, w_out = _broadcast(object_ids, normals, w_in, w_out)
        cos_in = np.einsum("...k,...k->...", normals, w_in)
        cos_out = np.einsum("...k,...k->...", normals, w_out)
        out = np.zeros(object_ids.shape, dtype=np.float64)
        sel = self.has_lobe(object_ids) & (cos_in > 0) & (cos_out > 0)
        if np.any(sel):
            ids = object_ids[sel]
            retro = self.kind[ids] == RETROREFLECTIVE
            mirror = 2.0 * cos_in[sel][..., None] * normals[sel] - w_in[sel]
            cos_alpha = np.clip(np.einsum("...k,...k->...", mirror, w_out[sel]), 0.0, 1.0)
            expo = self.exponent[ids]
            lobe = np.where(retro, 0.0, on_arrays(phong_gloss)(self.specular[ids], expo, cos_alpha ** expo))
            if np.any(retro):
                ci, co = cos_in[sel][retro], cos_out[sel][retro]
                cos_h = _retro_cos_h(ci, co, w_in[sel][retro], w_out[sel][retro])
                lobe[retro] = self.specular[ids][retro] * on_arrays(retro_lobe)(self.width[ids][retro],
                                                                                expo[retro], ci, co, cos_h)
            out[sel] = self.albedo[ids] * lobe
        return out


def _broadcast(ids, normals, w_in, w_out):
    ids = np.asarray(ids)
    shape = np.broadcast_shapes(ids.shape, normals.shape[:-1], w_in.shape[:-1], w_out.shape[:-1])
    return (np.broadcast_to(ids, shape), np.broadcast_to(normals, shape + (3,)),
            np.broadcast_to(w_in, shape + (3,)), np.broadcast_to(w_out, shape + (3,)))


def _retro_cos_h(cos_in: np.ndarray, cos_out: np.ndarray, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """n·h_b of the retroreflective back vector (:func:`~datagen.scene.brdf_kernel.retro_cos_h`) for (m,) cosines
    and (m, 3) directions."""
    return on_arrays(retro_cos_h)(cos_in, cos_out, np.einsum("ij,ij->i", w_in, w_out))


def _abs_sin_azimuth(normals: np.ndarray, axis: np.ndarray, w: np.ndarray) -> np.ndarray:
    """|sin θ| of direction w's azimuth θ about the normal, measured from ``axis`` projected on the plane.

    (n, 3) inputs, (n,) output. Where the axis is parallel to the normal the reference falls back to an
    arbitrary fixed tangent (:func:`tangent_frame`).
    """
    t = axis - np.einsum("ij,ij->i", axis, normals)[:, None] * normals
    t_len2 = np.einsum("ij,ij->i", t, t)
    fallback, _ = tangent_frame(normals)
    t = np.where((t_len2 > TANGENT_EPS)[:, None], t / np.sqrt(np.maximum(t_len2, TANGENT_EPS))[:, None], fallback)
    b = np.cross(normals, t)
    w_t = w - np.einsum("ij,ij->i", w, normals)[:, None] * normals
    tan_len2 = np.einsum("ij,ij->i", w_t, w_t)
    sin_az = np.abs(np.einsum("ij,ij->i", w_t, b)) / np.sqrt(np.maximum(tan_len2, TANGENT_EPS))
    return np.where(tan_len2 > TANGENT_EPS, np.minimum(sin_az, 1.0), 0.0)


def tangent_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents (t, b) with t × b = n for unit normals, (n, 3) → two (n, 3) arrays.

    Duff et al., "Building an orthonormal basis, revisited", JCGT 6(1), 2017 (branch-free, stable for all n).
    """
    n = np.asarray(normals, dtype=np.float64)
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)
    bt = np.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], axis=-1)
    return t, bt
