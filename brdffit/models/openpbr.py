r"""OpenPBR Surface as MaterialX 1.39 evaluates an opaque one (``open_pbr_surface``, its GLSL implementation).

MaterialX's graph of the node (``libraries/bxdf/open_pbr_surface.mtlx``, ``NG_open_pbr_surface_surfaceshader``)
with no coat, fuzz, thin film, transmission, subsurface or emission, isotropic, and ``base_weight`` 1 reduces to
a mix by ``base_metalness`` of two BSDFs, evaluated by the shader code of ``libraries/pbrlib/genglsl``. With ωo
the direction to the viewer (MaterialX's V), ωi the light's (L), h their half vector, c = ωi·h, μo = n·ωo,
μi = n·ωi, α = specular_roughness² (``open_pbr_anisotropy`` at anisotropy 0) and DG = D(h) G2(ωi, ωo)/(4 μi μo)
(GGX with height-correlated Smith masking, Heitz 2014 Eq. 99; ``mx_ggx_NDF``, ``mx_ggx_smith_G2``):

- the dielectric base, a ``layer`` of a ``dielectric_bsdf`` (tint specular_color, index η') over an
  energy-compensated Oren-Nayar diffuse of base_color (``mx_layer_bsdf``: top + top's throughput × base):
  f_d = specular_color F(c; η') DG K(F) + (1 − E(μo; F0') K(F)) f_on, where
  - η' is the index the graph modulates by specular_weight w: ε = sign(η − 1) √(clamp(w F0(η), 0, 0.99999)),
    η' = (1 + ε)/(1 − ε), F0' = F0(η') (``modulated_eta_s``), F the exact dielectric Fresnel term;
  - E(μ; F0) = F0 A(μ, α) + B(μ, α) is the GGX directional albedo of MaterialX's rational fit
    (``mx_ggx_dir_albedo_analytic``), and K(F) = 1 + F (1 − E₁)/E₁ with E₁ = A + B its energy compensation
    (``mx_ggx_energy_compensation``; Turquin 2019, Eqs. 14 and 16);
  - f_on is OpenPBR's energy-preserving Oren-Nayar diffuse of roughness r = base_diffuse_roughness
    (``mx_oren_nayar_compensated_diffuse``; Fujii's improved Oren-Nayar plus a multiple-scattering lobe):
    f_on = (ρ a (1 + r t) + ρ_ms (1 − E_f(μo)) (1 − E_f(μi)) / (1 − Ē)) / π, with a = 1/(1 + c₁ r),
    s = ωi·ωo − μi μo, t = s / max(μi, μo) where s > 0 and t = s elsewhere, E_f(μ) = a + r a G(μ)/π Fujii's
    directional albedo, Ē = a (1 + c₂ r), ρ_ms = ρ² Ē / (1 − ρ (1 − Ē)), c₁ = 1/2 − 2/(3π), c₂ = 2/3 − 28/(15π);
- the metal, a ``generalized_schlick_bsdf`` of weight w, color0 base_color and color82 specular_color:
  f_m = w F_82(c) DG K(F_82), with F_82 the F82-tinted Schlick term of Hoffman 2023
  (``mx_fresnel_hoffman_schlick``, `brdffit.models.fresnel.f82_tint`): F_82 = F0 + (1 − F0)(1 − c)⁵ − a c (1 − c)⁶,
  a = (F0 + (1 − F0)(6/7)⁵)(1 − F82) / ((1/7)(6/7)⁶).

f = (1 − base_metalness) f_d + base_metalness f_m. MaterialX clamps the cosines to at least 1e-8 and ωi·ωo to
[1e-8, 1] inside the diffuse term (``mx_oren_nayar_diffuse_bsdf``); this lobe does the same, so at r = 0 the
multiple-scattering lobe is ρ² 1e-8, as there. The layer's weight depends on the viewing direction (and on c
through K), so the model is not reciprocal, as MaterialX's is not; nothing in it is linear in a parameter.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._lazy import module
from ..geometry import LocalPair, safe_sqrt
from ..params import ParamSpec
from . import fresnel as fr
from .lobe import Lobe
from .microfacet import ggx_correlated
from .peaks import Peak, scalar
from .specs import MIN_ROUGHNESS

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["OpenPBR", "ggx_albedo_fit", "EPS"]

EPS = 1e-8  # MaterialX's M_FLOAT_EPS (libraries/stdlib/genglsl/lib/mx_math.glsl)
# MaterialX's rational fit of the GGX directional albedo (mx_ggx_dir_albedo_analytic): r = Σ_k c_k m_k(μ, α) over
# the monomials 1, μ, α, μα, μ², α², μ²α, μα², μ²α² (rows), for the four terms (columns) of A = r0/r2, B = r1/r3.
_ALBEDO_FIT = np.array([
    [0.1003, 0.9345, 1.0, 1.0],
    [-0.6303, -2.323, -1.765, 0.2281],
    [9.748, 2.229, 8.263, 15.94],
    [-2.038, -3.748, 11.53, -55.83],
    [29.34, 1.424, 28.96, 13.08],
    [-8.245, -0.7684, -7.507, 41.26],
    [-26.44, 1.436, -36.11, 54.9],
    [19.99, 0.2913, 15.86, 300.2],
    [-5.448, 0.6286, 33.37, -285.1],
])
_FUJII_1 = 0.5 - 2.0 / (3.0 * math.pi)
_FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)
_F0_CAP = 0.99999  # the graph's clamp of the weighted F0 (scaled_specular_F0_clamped)


def ggx_albedo_fit(mu, alpha, xp=None):
    """MaterialX's fit of the GGX directional albedo as its two terms ``(A, B)``: E = F0 A + F90 B
    (``mx_ggx_dir_albedo_analytic``, each clamped to [0, 1]).

    Arguments:
        mu: cosine of the viewing direction; alpha: the GGX width (broadcastable).
        xp: the array module (default ``jax.numpy``).
    """
    xp = jnp if xp is None else xp
    x, y = mu, alpha
    monomials = (1.0, x, y, x * y, x * x, y * y, x * x * y, x * y * y, x * x * y * y)
    r = [sum(c * m for c, m in zip(_ALBEDO_FIT[:, k], monomials)) for k in range(4)]
    return xp.clip(r[0] / r[2], 0.0, 1.0), xp.clip(r[1] / r[3], 0.0, 1.0)


def _fujii_albedo(mu, rough, a):
    """Fujii's directional albedo of his improved Oren-Nayar lobe (``mx_oren_nayar_fujii_diffuse_dir_albedo``)."""
    si = safe_sqrt(1.0 - mu * mu, tiny=0.0)
    g = si * (jnp.arccos(jnp.clip(mu, -1.0, 1.0)) - si * mu) + 2.0 * ((si / mu) * (1.0 - si ** 3) - si) / 3.0
    return a + rough * a * g / jnp.pi


def _oren_nayar(pair: LocalPair, mu_i, mu_o, colour, rough):
    """OpenPBR's energy-compensated Oren-Nayar diffuse times π (``mx_oren_nayar_compensated_diffuse``)."""
    cos_io = jnp.clip(2.0 * pair.cos_d * pair.cos_d - 1.0, EPS, 1.0)  # ωi·ωo, clamped as MaterialX clamps it
    s = cos_io - mu_i * mu_o
    t = jnp.where(s > 0.0, s / jnp.maximum(mu_i, mu_o), s)
    a = 1.0 / (1.0 + _FUJII_1 * rough)
    single = colour * (a * (1.0 + rough * t))[..., None]
    mean = a * (1.0 + _FUJII_2 * rough)
    multi_colour = colour * colour * mean[..., None] / (1.0 - colour * jnp.maximum(0.0, 1.0 - mean)[..., None])
    weight = (jnp.maximum(EPS, 1.0 - _fujii_albedo(mu_o, rough, a))
              * jnp.maximum(EPS, 1.0 - _fujii_albedo(mu_i, rough, a)) / jnp.maximum(EPS, 1.0 - mean))
    return single + multi_colour * weight[..., None]


@dataclasses.dataclass(frozen=True)
class OpenPBR(Lobe):
    """OpenPBR Surface, opaque and uncoated, as MaterialX 1.39 evaluates it (module doc): base_color,
    base_metalness, base_diffuse_roughness, specular_weight, specular_color, specular_roughness and specular_ior,
    under OpenPBR's names and in its ranges; the other inputs at their defaults or off (base_weight 1, no coat,
    fuzz, thin film, transmission, subsurface or emission, anisotropy 0).

    specular_weight and specular_color are held at 1 (white) unless a fit frees them: the graph modulates the
    dielectric's index by the product specular_weight · F0(specular_ior) alone, so with no metal the two are one
    degree of freedom, and the tint scales the dielectric's specular as the index partly does."""

    name = "openpbr"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("OpenPBR Surface 1.1 as MaterialX 1.39 evaluates it: libraries/bxdf/open_pbr_surface.mtlx and the "
                 "genglsl shader code of its BSDF nodes (dielectric_bsdf, generalized_schlick_bsdf, "
                 "oren_nayar_diffuse_bsdf, layer, mix)")
    reciprocal = False
    offset = True

    def param_specs(self):
        return (
            ParamSpec("base_color", 0.8, 0.0, 1.0, colour=True,
                      doc="Base Color: the diffuse albedo, and the metal's normal reflectance"),
            ParamSpec("base_metalness", 0.0, 0.0, 1.0, doc="Base Metalness: mixes the dielectric base into the metal"),
            ParamSpec("base_diffuse_roughness", 0.0, 0.0, 1.0,
                      doc="Base Diffuse Roughness: the energy-preserving Oren-Nayar roughness of the diffuse"),
            ParamSpec("specular_weight", 1.0, 0.0, 1.0, fixed=True,
                      doc="Specular Weight: scales the dielectric's F0 (through its index) and the metal's specular"),
            ParamSpec("specular_color", 1.0, 0.0, 1.0, colour=True, fixed=True,
                      doc="Specular Color: the dielectric's tint and the metal's F82 tint"),
            ParamSpec("specular_roughness", 0.3, math.sqrt(MIN_ROUGHNESS), 1.0, scale=True,
                      doc="Specular Roughness: GGX α = specular_roughness²"),
            ParamSpec("specular_ior", 1.5, 1.0, 3.0, doc="Specular IOR: the dielectric's index of refraction"),
        )

    def peaks(self, params):
        return (Peak("half", scalar(params, "specular_roughness") ** 2),)

    def __call__(self, params, pair: LocalPair):
        base, tint = params["base_color"], params["specular_color"]
        metalness, weight = params["base_metalness"], params["specular_weight"]
        eta, rough = params["specular_ior"], params["base_diffuse_roughness"]
        alpha = jnp.clip(params["specular_roughness"] ** 2, EPS, 1.0)
        mu_i, mu_o = jnp.clip(pair.cos_i, EPS, 1.0), jnp.clip(pair.cos_o, EPS, 1.0)
        c = jnp.clip(pair.cos_d, EPS, 1.0)
        microfacet = ggx_correlated(pair, alpha)
        a_fit, b_fit = ggx_albedo_fit(mu_o, alpha)
        e_white = a_fit + b_fit

        def compensation(f):  # K(F), Turquin 2019, Eqs. 14 and 16
            return 1.0 + f * ((1.0 - e_white) / e_white)[..., None]

        weighted_f0 = jnp.clip(weight * fr.normal_reflectance(eta), 0.0, _F0_CAP)
        epsilon = jnp.sign(eta - 1.0) * safe_sqrt(weighted_f0, tiny=0.0)
        modulated = (1.0 + epsilon) / (1.0 - epsilon)
        f_dielectric = fr.dielectric(c, 1.0, modulated)[..., None]
        k_dielectric = compensation(f_dielectric)
        albedo = (fr.normal_reflectance(modulated) * a_fit + b_fit)[..., None] * k_dielectric
        diffuse = _oren_nayar(pair, mu_i, mu_o, base, rough) / jnp.pi
        dielectric = tint * f_dielectric * microfacet[..., None] * k_dielectric + (1.0 - albedo) * diffuse
        f_metal = fr.f82_tint(c[..., None], base, tint)
        metal = weight * f_metal * microfacet[..., None] * compensation(f_metal)
        return (1.0 - metalness) * dielectric + metalness * metal
