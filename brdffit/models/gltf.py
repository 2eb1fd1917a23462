"""The glTF 2.0 metallic-roughness material, as the glTF specification's Appendix B defines its BRDF, with the
ratified extensions KHR_materials_ior, KHR_materials_specular and KHR_materials_clearcoat.

The Khronos Group, glTF 2.0 Specification, Appendix B "BRDF Implementation"; KHR_materials_ior;
KHR_materials_specular (its "Implementation" section). With h = normalize(ωi + ωo), cd = |ωo·h|,
w = (1 − cd)⁵ the Schlick weight and α = roughness²:

- specular_brdf = D V: D the GGX distribution α²/(π ((n·h)²(α² − 1) + 1)²) and V = G/(4 ci co) with G the
  height-correlated Smith masking-shadowing of GGX (Appendix B's "Specular BRDF": Heitz 2014, Eq. 99);
- metal_brdf = specular_brdf · (base_color + (1 − base_color) w);
- dielectric_brdf = fresnel_mix(specular_color, ior, specular, base = base_color/π, layer = specular_brdf)
  = (1 − specular · max_c F) base_color/π + specular · F · specular_brdf, with
  F = f0 + (1 − f0) w and f0 = min(((ior − 1)/(ior + 1))² specular_color, 1) (KHR_materials_specular);
- material = (1 − metallic) dielectric_brdf + metallic metal_brdf;
- with a clearcoat (KHR_materials_clearcoat, "Implementation"): mix(material, clearcoat_brdf, clearcoat · Fc),
  Fc = 0.04 + 0.96 (1 − |ωo·n|)⁵ and clearcoat_brdf Appendix B's specular_brdf at α = clearcoat_roughness² (the
  clearcoat normal is the surface's). Fc takes the viewing direction, not h, so a clearcoat makes the material
  non-reciprocal, as the extension says.

Every parameter is declared in the range a glTF file accepts (base colour, metallic, roughness and specular in
[0, 1], ior ≥ 1), so that a fit is a material any glTF viewer takes as written. The clearcoat is held at 0 unless
freed (``free=["clearcoat", "clearcoat_roughness"]``). The value is affine in the base
colour channel by channel (f = f₀ + base_color · B, with f₀ the Fresnel-weighted specular and the metal's
grazing tint), so the base colour is a linear amplitude that a fit solves exactly.
"""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from . import fresnel as fr
from .lobe import Lobe
from .microfacet import DISTRIBUTIONS, smith_correlated
from .specs import base_color, metallic, perceptual_roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["GltfMaterial", "ior_to_f0"]

# KHR_materials_ior: ior ≥ 1 (or 0, which brdffit does not write); 3 is f0 = 0.25, beyond every common dielectric.
_MAX_IOR = 3.0


def ior_to_f0(ior):
    """The normal-incidence reflectance of an index of refraction against air: ((ior − 1)/(ior + 1))²."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


@dataclasses.dataclass(frozen=True)
class GltfMaterial(Lobe):
    """The glTF 2.0 metallic-roughness material with KHR_materials_ior and KHR_materials_specular (module doc):
    the BRDF a glTF file describes. ``specular_color`` is held at white unless freed (it trades off against
    ``ior`` and ``specular``)."""

    name = "gltf"
    reference = ("The Khronos Group, glTF 2.0 Specification, Appendix B (BRDF Implementation); KHR_materials_ior; "
                 "KHR_materials_specular; KHR_materials_clearcoat")
    reciprocal = False  # the clearcoat's Fresnel weight takes the viewing direction
    offset = True

    def param_specs(self):
        return (
            base_color("baseColorFactor: diffuse albedo of the dielectric, normal reflectance of the metal"),
            metallic("metallicFactor: blends the dielectric into the metal"),
            perceptual_roughness("roughnessFactor: GGX α = roughness² (Appendix B's BRDF is singular at α = 0)"),
            ParamSpec("specular", 1.0, 0.0, 1.0,
                      doc="KHR_materials_specular specularFactor: weight of the dielectric's specular layer"),
            ParamSpec("ior", 1.5, 1.0, _MAX_IOR,
                      doc="KHR_materials_ior ior: the dielectric's f0 = ((ior − 1)/(ior + 1))²"),
            ParamSpec("specular_color", 1.0, 0.0, 1.0, colour=True, fixed=True,
                      doc="KHR_materials_specular specularColorFactor: tint of the dielectric's f0"),
            ParamSpec("clearcoat", 0.0, 0.0, 1.0, fixed=True,
                      doc="KHR_materials_clearcoat clearcoatFactor: weight of the clear coat"),
            dataclasses.replace(perceptual_roughness("KHR_materials_clearcoat clearcoatRoughnessFactor: the coat's "
                                                     "GGX α = clearcoat_roughness²"),
                                name="clearcoat_roughness", default=0.1, fixed=True),
        )

    def amplitude_partners(self, amplitude):
        return ()  # base_color is no lobe's only amplitude: the specular layers do not vanish with it

    def __call__(self, params, pair: LocalPair):
        base = params["base_color"]
        metallic = params["metallic"]
        alpha = params["roughness"] ** 2
        ggx = DISTRIBUTIONS["ggx"]
        # V D with V = G2 / (4 ci co): Appendix B's specular_brdf.
        specular_brdf = (ggx.D(pair.cos_h, alpha) * smith_correlated(pair, ggx, alpha)
                         / (4.0 * pair.cos_i * pair.cos_o))[..., None]
        weight = fr.schlick_weight(pair.cos_d)[..., None]
        f0 = jnp.minimum(ior_to_f0(params["ior"]) * params["specular_color"], 1.0)  # (C,)
        fresnel = f0 + (1.0 - f0) * weight  # (..., C)
        strength = params["specular"]
        dielectric = ((1.0 - strength * jnp.max(fresnel, axis=-1, keepdims=True)) * base / jnp.pi
                      + strength * fresnel * specular_brdf)
        metal = (base + (1.0 - base) * weight) * specular_brdf
        material = (1.0 - metallic) * dielectric + metallic * metal
        # KHR_materials_clearcoat: mix(material, clearcoat_brdf, clearcoat Fc), Fc at the viewing direction.
        alpha_c = params["clearcoat_roughness"] ** 2
        coat_brdf = (ggx.D(pair.cos_h, alpha_c) * smith_correlated(pair, ggx, alpha_c)
                     / (4.0 * pair.cos_i * pair.cos_o))[..., None]
        coat = params["clearcoat"] * (0.04 + 0.96 * fr.schlick_weight(pair.cos_o))[..., None]
        return (1.0 - coat) * material + coat * coat_brdf
