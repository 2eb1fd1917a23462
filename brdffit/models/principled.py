"""The Disney principled BRDF as Mitsuba 3 evaluates it (its ``principled`` plugin without transmission).

Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes, and Extending the Disney BRDF to a BSDF
with integrated subsurface scattering, SIGGRAPH 2015 course notes; the terms, parameter names, ranges and the
remappings below are those of Mitsuba 3's ``principled`` (src/bsdfs/principled.cpp and principledhelpers.h), so
that a fitted model exports to it exactly. With h = normalize(ωi + ωo), cd = ωi·h, ci, co the cosines and
w(c) = (1 − c)⁵ the Schlick weight:

- diffuse with retro-reflection (Burley 2015, §3.1): (1 − metallic) base_color/π ·
  [(1 − w(ci)/2)(1 − w(co)/2) + R (w(ci) + w(co) + w(ci) w(co)(R − 1))], R = 2 roughness cd², which is Burley
  2012's diffuse expanded (`brdffit.models.diffuse.burley_shape`, evaluated here);
- sheen: sheen (1 − metallic) w(cd) · lerp(1, base_color/lum, sheen_tint);
- main specular: F D G / (4 ci co), D and G the anisotropic GGX with separable Smith masking at
  αx = max(0.001, roughness²/a), αy = max(0.001, roughness² a), a = √(1 − 0.9 anisotropic), and
  F = (1 − metallic)(1 − spec_tint) F_dielectric(cd, η) + metallic S(base_color)
  + (1 − metallic) spec_tint S(base_color/lum · ((η − 1)/(η + 1))²), S(f0) Schlick's with that f0 at cd,
  η = 2/(1 − √(0.08 specular)) − 1;
- clearcoat: clearcoat/4 · S(0.04) · D_GTR1(h) · G1(ωi) G1(ωo), GTR1 (Burley 2012, App. B, γ = 1) of width
  lerp(0.1, 0.001, clearcoat_gloss) and GGX G1 of width 0.25, without the 1/(4 ci co) of the main lobe (as the
  plugin evaluates it).

lum is the luminance of base_color (Rec. 709 weights for three channels, as Mitsuba's RGB modes; the value itself
for one channel; the mean otherwise).
"""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from . import fresnel as fr
from .diffuse import burley_shape
from .lobe import Lobe
from .microfacet import DISTRIBUTIONS, smith
from .peaks import Peak, scalar

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Principled", "specular_to_eta", "luminance"]

# Rec. 709 / sRGB luminance weights of linear RGB (Mitsuba's ``luminance`` in its RGB modes).
_LUMINANCE = (0.212671, 0.715160, 0.072169)
# The smallest microfacet width of the main lobe and the clearcoat's GGX masking width (the plugin's constants).
_MIN_ALPHA = 0.001
_CLEARCOAT_MASKING = 0.25


def _unit(name: str, default: float, doc: str, fixed: bool = False, colour: bool = False) -> ParamSpec:
    return ParamSpec(name, default, 0.0, 1.0, colour=colour, unit="1", doc=doc, fixed=fixed)


def specular_to_eta(specular):
    """Mitsuba's index of refraction of a ``specular`` value: η = 2/(1 − √(0.08 specular)) − 1 (0.5 -> 1.5)."""
    return 2.0 / (1.0 - jnp.sqrt(0.08 * specular)) - 1.0


def luminance(colour):
    """The luminance of a colour ``(C,)``: Rec. 709 weights for C = 3, the value for C = 1, the mean otherwise."""
    channels = colour.shape[-1]
    if channels == 3:
        return sum(w * colour[..., k] for k, w in enumerate(_LUMINANCE))
    return colour[..., 0] if channels == 1 else jnp.mean(colour, axis=-1)


def _gtr1(cos_h, alpha):
    """Burley 2012, App. B, GTR with γ = 1: D = (α² − 1)/(π ln(α²) (1 + (α² − 1) cos²θh))."""
    a2 = alpha * alpha
    return (a2 - 1.0) / (jnp.pi * jnp.log(a2) * (1.0 + (a2 - 1.0) * cos_h * cos_h))


@dataclasses.dataclass(frozen=True)
class Principled(Lobe):
    """The Disney principled BRDF, parameters and evaluation of Mitsuba 3's ``principled`` (module doc): the
    reflection of an opaque material (no ``spec_trans``, ``flatness`` or ``eta``). ``anisotropic`` and the two tints
    are held at 0 unless freed (a fit of an isotropic file keeps αx = αy)."""

    name = "principled"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes; Burley, Extending the "
                 "Disney BRDF to a BSDF with integrated subsurface scattering, SIGGRAPH 2015; Mitsuba 3's principled "
                 "plugin")

    def param_specs(self):
        return (
            _unit("base_color", 0.5, "base colour (diffuse albedo, and the metal's normal reflectance)", colour=True),
            _unit("metallic", 0.0, "metalness: blends the dielectric response into a Schlick metal of base_color"),
            _unit("roughness", 0.5, "roughness (GGX α = roughness², at least 0.001)"),
            _unit("specular", 0.5, "dielectric reflectance: η = 2/(1 − √(0.08 specular)) − 1 (0.5: η = 1.5)"),
            _unit("spec_tint", 0.0, "fraction of the dielectric reflection tinted by base_color", fixed=True),
            _unit("anisotropic", 0.0, "anisotropy: αx = α/√(1 − 0.9 a), αy = α √(1 − 0.9 a)", fixed=True),
            _unit("sheen", 0.0, "sheen amplitude (grazing retro-reflection of cloth)"),
            _unit("sheen_tint", 0.0, "fraction of the sheen tinted by base_color", fixed=True),
            _unit("clearcoat", 0.0, "clearcoat amplitude (a second, GTR1 specular lobe with f0 = 0.04)"),
            _unit("clearcoat_gloss", 0.0, "clearcoat glossiness: GTR1 width lerp(0.1, 0.001, gloss)"),
        )

    def peaks(self, params):
        """The specular lobe (α = roughness², at least 0.001) and, with a clearcoat, its GTR1 lobe
        (α = lerp(0.1, 0.001, clearcoat_gloss))."""
        found = [Peak("half", max(0.001, scalar(params, "roughness") ** 2))]
        if scalar(params, "clearcoat") > 0:
            found.append(Peak("half", 0.1 + scalar(params, "clearcoat_gloss") * (0.001 - 0.1)))
        return tuple(found)

    def __call__(self, params, pair: LocalPair):
        base = params["base_color"]
        metallic, roughness = params["metallic"], params["roughness"]
        dielectric = 1.0 - metallic
        lum = luminance(base)
        tint = jnp.where(lum > 0.0, base / jnp.where(lum > 0.0, lum, 1.0), 1.0)  # (C,)
        # Diffuse and retro-reflection.
        value = dielectric * base / jnp.pi * burley_shape(pair, roughness)[..., None]

        # Sheen.
        sheen_colour = 1.0 + params["sheen_tint"] * (tint - 1.0)
        value = value + params["sheen"] * dielectric * fr.schlick_weight(pair.cos_d)[..., None] * sheen_colour

        # Main specular: anisotropic GGX, separable Smith, the principled Fresnel mix.
        r2 = roughness * roughness
        aspect = jnp.sqrt(1.0 - 0.9 * params["anisotropic"])
        widths = (jnp.maximum(_MIN_ALPHA, r2 / aspect), jnp.maximum(_MIN_ALPHA, r2 * aspect))
        ggx = DISTRIBUTIONS["ggx"]
        d = ggx.D_aniso(pair.h, widths)
        g = smith(pair, ggx, widths)
        eta = specular_to_eta(params["specular"])
        c = pair.cos_d[..., None]
        f_dielectric = fr.dielectric(c, 1.0, eta)
        r0 = fr.normal_reflectance(eta)
        spec_tint = params["spec_tint"]
        fresnel = (dielectric * (1.0 - spec_tint) * f_dielectric + metallic * fr.schlick(c, base)
                   + dielectric * spec_tint * fr.schlick(c, tint * r0))
        value = value + fresnel * (d * g / (4.0 * pair.cos_i * pair.cos_o))[..., None]

        # Clearcoat.
        alpha_cc = 0.1 + params["clearcoat_gloss"] * (0.001 - 0.1)
        g_cc = ggx.G(pair.cos_i, pair.cos_o, _CLEARCOAT_MASKING)
        clearcoat = 0.25 * params["clearcoat"] * fr.schlick(pair.cos_d, 0.04) * _gtr1(pair.cos_h, alpha_cc) * g_cc
        return value + clearcoat[..., None]
