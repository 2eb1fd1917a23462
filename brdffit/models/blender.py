r"""Blender's Principled BSDF as Cycles evaluates an opaque one with the GGX distribution (Blender 4.2+).

Cycles' principled closure (``intern/cycles/kernel/svm/closure.h``) with no transmission, subsurface, sheen, coat
(but see the options below) or emission, and ``Specular Tint`` white, is a sum of three layers. With
h = normalize(ωi + ωo), α = roughness², ωo the direction to the viewer (Cycles' ``sd->wi``) and c = ωi·h:

- metal: metallic · F_S(c; base_color) · D G2 / (4 ci co), F_S Schlick's term with f0 = base_color (Cycles' F82-tint
  Fresnel with a white tint is Schlick's);
- dielectric specular: (1 − metallic) · F_d(c; η) · D G2 / (4 ci co), F_d the exact dielectric Fresnel term
  (Cycles' generalized Schlick with a negative exponent and a white tint) at η = ``ior`` (``Specular IOR Level``
  0.5 leaves it as it is);
- diffuse: (1 − metallic) (1 − E(co)) base_color/π, Lambert's, attenuated by the specular layer's albedo as Cycles
  estimates it (``bsdf_microfacet_estimate_albedo``, ``closure_layering_weight``): E = f0 + (1 − f0) s, f0 = F0(η),
  with s read by trilinear interpolation from a 16 × 16 × 16 table over (roughness, co, z = √((η − 1)/(η + 1))).

D is GGX and G2 the height-correlated Smith term 1/(1 + Λ(ωi) + Λ(ωo)) (Cycles' ``bsdf_G``). The table is Cycles'
``ggx_gen_schlick_ior_s`` computed again here by quadrature (`layering_table`): s is the mean of the Fresnel blend
factor (F_d(h·ωo; η) − F0)/(1 − F0) over the GGX visible normals of ωo whose mirror direction stays above the
surface (``cycles_precompute.cpp``'s estimator: Monte Carlo with 2²⁰ samples there, Gauss-Legendre here), on Cycles'
nodes (roughness and co at i/15 clamped to [1e-4, 1], z at i/15 clamped to [1e-4, 0.99], η = (1 + z²)/(1 − z²)).

The diffuse weight depends on the viewing direction alone, so the model is not reciprocal (as Cycles' is not). The
value is affine in base_color channel by channel, a linear amplitude that a fit solves exactly.

With ``coat=True`` the node's coat (``Coat Weight`` w, ``Coat Roughness`` r_c, ``Coat IOR`` η_c, ``Coat Tint``)
lies over that sum as Cycles 4.2 layers it (closure.h's second layer, the kernel source that the ``bpy`` 4.2 package
ships): a GGX closure of weight w with α_c = r_c² and the exact dielectric Fresnel term of η_c (no energy
compensation: ``bsdf_microfacet_setup_fresnel_dielectric`` sets none in 4.2), f_c = w F_d(c; η_c) D_c G2_c/(4 ci co);
everything beneath weighted by ``closure_layering_weight``, clamp(1 − w F_d(co; η_c), 0, 1) (the closure's albedo
estimate for a dielectric Fresnel term is the smooth surface's, ``bsdf_microfacet_estimate_albedo``), and by the
tint along the refracted view, mix(1, Coat Tint^(1/cosθt), w) with cosθt = √(1 − (1 − co²)/η_c²) (Beer's law,
Cycles' approximation). ``Coat Tint`` is held white unless a fit frees it (it scales the base as Base Color does,
but for its dependence on the view).

With ``sheen=True`` the node's sheen (``Sheen Weight`` w_s, ``Sheen Tint`` t_s, ``Sheen Roughness`` r_s) lies over
everything else, coat included (closure.h's first layer): Zeltner et al.'s (2022) microfibre sheen, a linearly
transformed cosine (``kernel/closure/bsdf_sheen.h``), f_s = w_s t_s E(μo, r_s) D_LTC(ωi)/μi, and the layers beneath
weighted by ``closure_layering_weight``, clamp(1 − max(w_s t_s) E(μo, r_s), 0, 1), E the sheen's albedo at the view.
Cycles reads E and the LTC's two coefficients from a 32 × 32 table over (μo, r_s) that the ``bpy`` package does not
ship; this model evaluates MaterialX's fits to the same quantities (`brdffit.models.sheen.zeltner_sheen`), so the
sheen is an approximation of Cycles' by the fits' error (measured in Cycles' renders: docs/export.md).
``Sheen Tint`` is held white unless a fit frees it (w_s and t_s enter as their product).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from . import fresnel as fr
from .lobe import Lobe
from .lookup import multilinear
from .microfacet import ggx_correlated
from .peaks import Peak, scalar
from .sheen import zeltner_sheen
from .specs import base_color, metallic, perceptual_roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["BlenderPrincipled", "layering_table", "TABLE_SIZE"]

TABLE_SIZE = 16
# Gauss-Legendre nodes of the table's quadrature: in u, the GGX distribution's own CDF variable of θh, and in φh.
_U_NODES, _PHI_NODES = 96, 64
_MAX_IOR = 3.0
# The sheen roughness where MaterialX's fits of Zeltner's LTC start (MaterialX clamps to it); Cycles takes [0, 1].
_MIN_SHEEN_ROUGHNESS = 0.01


@functools.lru_cache(maxsize=1)
def layering_table() -> np.ndarray:
    """Cycles' ``ggx_gen_schlick_ior_s`` by quadrature, shape ``(z, co, roughness)`` = (16, 16, 16) (module doc).

    s(r, μ, η) = ∫ D_v(h) b(h·v) 1[ℓ·n > 0] dh, with v at cosine μ, ℓ = 2(v·h)h − v its mirror direction,
    b = (F_d(h·v; η) − F0)/(1 − F0) and D_v(h) = G1(v) (v·h)⁺ D(h)/μ the visible normals of GGX at α = r²
    (Heitz 2014, Eq. 38). In u = tan²θh/(α² + tan²θh), D cosθh dω_h = du dφ/(2π), so
    s = G1(v)/(2π μ) ∫∫ (v·h)⁺ b 1[ℓ·n > 0] / cosθh du dφ.

    Returns:
        The table, float64.
    """
    nodes = np.arange(TABLE_SIZE) / (TABLE_SIZE - 1)
    rough = np.clip(nodes, 1e-4, 1.0)
    mu = np.clip(nodes, 1e-4, 1.0)
    z = np.clip(nodes, 1e-4, 0.99)
    eta = (1.0 + z * z) / (1.0 - z * z)
    x, wx = np.polynomial.legendre.leggauss(_U_NODES)
    u, wu = 0.5 * (x + 1.0), 0.5 * wx
    y, wy = np.polynomial.legendre.leggauss(_PHI_NODES)
    phi, wphi = np.pi * 0.5 * (y + 1.0), np.pi * 0.5 * wy  # φh in [0, π]: the integrand is even in φh
    table = np.empty((TABLE_SIZE, TABLE_SIZE, TABLE_SIZE))
    for i, r in enumerate(rough):
        a2 = r ** 4
        tan2 = a2 * u / (1.0 - u)
        cos_h = 1.0 / np.sqrt(1.0 + tan2)[:, None]
        sin_h = np.sqrt(tan2)[:, None] * cos_h
        # v lies in the xz plane, so only h's x and z components enter.
        hx, hz = sin_h * np.cos(phi)[None, :], cos_h * np.ones_like(phi)[None, :]
        weight = 2.0 * wu[:, None] * wphi[None, :] / (2.0 * np.pi)  # both halves of φh
        for j, m in enumerate(mu):
            vx, vz = np.sqrt(1.0 - m * m), m
            vh = vx * hx + vz * hz
            lz = 2.0 * vh * hz - vz
            g1 = 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - m * m) / (m * m)))
            visible = (vh > 0.0) & (lz > 0.0)
            base = np.where(visible, weight * vh / hz, 0.0) * g1 / m
            for k, e in enumerate(eta):
                f0 = ((e - 1.0) / (e + 1.0)) ** 2
                blend = np.clip((fr.dielectric(vh, 1.0, e, np) - f0) / (1.0 - f0), 0.0, 1.0)
                table[k, j, i] = np.clip(np.sum(base * blend), 0.0, 1.0)
    return table


@dataclasses.dataclass(frozen=True)
class BlenderPrincipled(Lobe):
    """Blender's Principled BSDF with the GGX distribution as Cycles evaluates it (module doc): Base Color,
    Metallic, Roughness and IOR (and the coat's and the sheen's inputs where the options add them), the other
    inputs at their neutral values (Specular IOR Level 0.5, Specular Tint white, no subsurface, transmission or
    emission).

    Options:
        coat: add the node's coat (Coat Weight, Coat Roughness, Coat IOR; Coat Tint held white unless freed), a
            dielectric layer over the rest, for lacquer and varnish (module doc). With coat_weight 0 it is the
            model without coat.
        sheen: add the node's sheen (Sheen Weight, Sheen Roughness; Sheen Tint held white unless freed), Zeltner's
            microfibre sheen over the rest, for cloth and felt (module doc; an approximation of Cycles' table).
            With sheen_weight 0 it is the model without sheen.
    """

    name = "blender"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("Blender 4.2+ Principled BSDF as Cycles evaluates it: intern/cycles/kernel/svm/closure.h, "
                 "kernel/closure/bsdf_microfacet.h, app/cycles_precompute.cpp")
    reciprocal = False
    offset = True
    layers = {"coat": "coat_weight", "sheen": "sheen_weight"}

    coat: bool = False
    sheen: bool = False

    def __post_init__(self):
        for option in ("coat", "sheen"):
            if not isinstance(getattr(self, option), bool):
                raise ValueError(f"blender: {option} must be True or False, got {getattr(self, option)!r}")

    def param_specs(self):
        return (
            base_color("Base Color: the diffuse albedo, and the metal's normal reflectance"),
            metallic("Metallic: blends the dielectric layers into the metal"),
            perceptual_roughness("Roughness: GGX α = roughness²"),
            ParamSpec("ior", 1.5, 1.0, _MAX_IOR, doc="IOR: the dielectric specular layer's index of refraction"),
        ) + (self._coat_specs() if self.coat else ()) + (self._sheen_specs() if self.sheen else ())

    @staticmethod
    def _coat_specs():
        return (
            ParamSpec("coat_weight", 0.5, 0.0, 1.0, doc="Coat Weight: the coat's presence"),
            dataclasses.replace(perceptual_roughness("Coat Roughness: GGX α = coat_roughness² of the coat"),
                                name="coat_roughness", default=0.1),
            ParamSpec("coat_ior", 1.5, 1.0, _MAX_IOR, doc="Coat IOR: the coat's index of refraction"),
            ParamSpec("coat_tint", 1.0, 0.0, 1.0, colour=True, fixed=True,
                      doc="Coat Tint: the coat's colour at normal incidence (Beer's law along the refracted view)"),
        )

    @staticmethod
    def _sheen_specs():
        return (
            ParamSpec("sheen_weight", 0.5, 0.0, 1.0, doc="Sheen Weight: the sheen's presence"),
            ParamSpec("sheen_tint", 1.0, 0.0, 1.0, colour=True, fixed=True, doc="Sheen Tint: the sheen's colour"),
            ParamSpec("sheen_roughness", 0.5, _MIN_SHEEN_ROUGHNESS, 1.0,
                      doc="Sheen Roughness: the roughness of Zeltner's sheen (the fits' range starts at 0.01)"),
        )

    def peaks(self, params):
        peaks = (Peak("half", scalar(params, "roughness") ** 2),)
        return peaks + ((Peak("half", scalar(params, "coat_roughness") ** 2),) if self.coat else ())

    def __call__(self, params, pair: LocalPair):
        base = params["base_color"]
        metallic, roughness, eta = params["metallic"], params["roughness"], params["ior"]
        alpha = roughness * roughness
        lobe = ggx_correlated(pair, alpha)
        metal = fr.schlick(pair.cos_d[..., None], base) * lobe[..., None]
        specular = fr.dielectric(pair.cos_d, 1.0, eta) * lobe
        f0 = fr.normal_reflectance(eta)
        z = jnp.sqrt((eta - 1.0) / (eta + 1.0))
        s = multilinear(layering_table(), z, pair.cos_o, roughness)  # Cycles: x roughness (fastest), y μ, z
        albedo = f0 + (1.0 - f0) * s
        diffuse = jnp.clip(1.0 - albedo, 0.0, 1.0)[..., None] * base / jnp.pi
        beneath = metallic * metal + (1.0 - metallic) * (specular[..., None] + diffuse)
        beneath = self._coated(params, pair, beneath) if self.coat else beneath
        return self._sheened(params, pair, beneath) if self.sheen else beneath

    @staticmethod
    def _coated(params, pair: LocalPair, beneath):
        """The coat over ``beneath`` as Cycles 4.2 layers it (module doc)."""
        weight, rough, eta = params["coat_weight"], params["coat_roughness"], params["coat_ior"]
        coat = weight * fr.dielectric(pair.cos_d, 1.0, eta) * ggx_correlated(pair, rough * rough)
        layer = jnp.clip(1.0 - weight * fr.dielectric(pair.cos_o, 1.0, eta), 0.0, 1.0)
        refracted = jnp.sqrt(1.0 - (1.0 - pair.cos_o * pair.cos_o) / (eta * eta))
        tint = 1.0 + weight * (params["coat_tint"] ** (1.0 / refracted)[..., None] - 1.0)
        return coat[..., None] + layer[..., None] * tint * beneath

    @staticmethod
    def _sheened(params, pair: LocalPair, beneath):
        """The sheen over ``beneath`` as Cycles layers it (module doc)."""
        colour = params["sheen_weight"] * params["sheen_tint"]
        albedo, sheen = zeltner_sheen(pair, pair.cos_o, params["sheen_roughness"])
        layer = jnp.clip(1.0 - jnp.max(colour, axis=-1) * albedo, 0.0, 1.0)
        return colour * sheen[..., None] + layer[..., None] * beneath
