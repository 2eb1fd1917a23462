r"""OpenPBR Surface as MaterialX 1.39 evaluates an opaque one (``open_pbr_surface``, its GLSL implementation).

MaterialX's graph of the node (``libraries/bxdf/open_pbr_surface.mtlx``, ``NG_open_pbr_surface_surfaceshader``)
with no thin film, transmission, subsurface or emission, isotropic, ``base_weight`` 1, and without the coat and
fuzz of the options below, reduces to a mix by ``base_metalness`` of two BSDFs, evaluated by the shader code of
``libraries/pbrlib/genglsl`` (MaterialX 1.39.5, the ``materialx`` package of the test extra). With ωo the direction
to the viewer (MaterialX's V), ωi the light's (L), h their half vector, c = ωi·h, μo = n·ωo,
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

With ``coat=True`` the graph's coat lies over that base (``coat_layer``): a ``layer`` of a GGX ``dielectric_bsdf``
of weight w_c = coat_weight, index η_c = coat_ior and width α_c = coat_roughness², untinted, over the base
darkened and attenuated, f_coat = w_c F(c; η_c) DG_c K_c(F) + (1 − w_c E_c(μo; F0(η_c)) K_c(F)) T_c f_base, where
- the base sees the coat: its specular roughness r_s becomes the mix by w_c of r_s and (min(1, 2 r_c⁴ + r_s⁴))^¼
  (``effective_specular_roughness``), and its index the mix by w_c of η and η/η_c or η_c/η, whichever is ≥ 1
  (``eta_s``, the graph's fix of total internal reflection), before specular_weight modulates it;
- T_c = (1 + w_c (coat_color − 1)) (1 + w_c coat_darkening (Δ − 1)) with Δ = (1 − K)/(1 − E_b K), K = 1 − (1 −
  F0(η_c))/η_c² (the coat's internal diffuse reflection) and E_b = base_color (1 − base_metalness +
  base_metalness specular_weight) (``coat_attenuation``, ``base_darkening``);
- coat_color is held at white (a clear coat: it tints the diffuse as base_color does) and coat_darkening at 1
  (the physical value) unless a fit frees them. Where specular_ior is below coat_ior the base's index has a kink at
  their equality (the graph's fix), where the base's specular vanishes: a fit can stop there (``stalled``), and a
  multistart fit (``multistart=``) looks past it.

With ``fuzz=True`` the graph's fuzz layer lies over that base (``fuzz_layer``, a ``layer`` of a ``sheen_bsdf`` in
its ``zeltner`` mode): Zeltner et al.'s (2022) microfibre sheen, a linearly transformed cosine fitted to the
multiple-scattering microflake volume, as MaterialX's GLSL evaluates it (``mx_zeltner_sheen_brdf``,
``mx_zeltner_sheen_dir_albedo``, its rational and Gaussian fits to the LTC's coefficients and albedo). With
r = clamp(fuzz_roughness, 0.01, 1), E_z(μo, r) the fitted albedo and D_LTC(ωi) the LTC of the view (its frame: X
along ωo's projection on the surface, Y = n × X; ω = (ωi·X, ωi·Y, μi) mapped to ω' = (a ω_x + b μi, a ω_y, μi)
with a, b the inverse matrix's fitted entries; D_LTC = (ω'_z/π) (a/|ω'|²)²):
  f = fuzz_weight fuzz_color E_z(μo, r) D_LTC(ωi)/μi + (1 − fuzz_weight E_z(μo, r)) f_base,
the layer's throughput being 1 − fuzz_weight E_z, the sheen's response E_z D_LTC its f cosθi
(``mx_sheen_bsdf``). D_LTC integrates to 1 over the hemisphere (the transform keeps ω_z), so the fuzz's own view
albedo is fuzz_weight fuzz_color E_z(μo, r).
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
from .sheen import zeltner_sheen
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


def _mix(bg, fg, amount):
    """MaterialX's ``mix`` node: fg where amount is 1, bg where it is 0."""
    return bg * (1.0 - amount) + fg * amount


def _compensation(e_white):
    """K(F) = 1 + F (1 − E₁)/E₁ as a function of F ``(..., C)`` (``mx_ggx_energy_compensation``; Turquin 2019,
    Eqs. 14 and 16), E₁ ``(...)`` the white GGX albedo at the view."""
    gain = ((1.0 - e_white) / e_white)[..., None]
    return lambda f: 1.0 + f * gain


def _dielectric_layer(f, f0, microfacet, a_fit, b_fit, weight=1.0):
    """MaterialX's ``dielectric_bsdf`` in reflection (``mx_dielectric_bsdf``), untinted: ``(response, throughput)``,
    w F DG K(F) and 1 − w E(μo; F0) K(F), the f of the layer and the weight of what lies beneath it.

    Arguments:
        f: the dielectric Fresnel term at the pair ``(..., 1)``; f0: its value at normal incidence.
        microfacet: DG ``(...)``; a_fit, b_fit: MaterialX's albedo fit at the view (`ggx_albedo_fit`).
        weight: the node's weight.
    """
    k = _compensation(a_fit + b_fit)(f)
    return weight * f * microfacet[..., None] * k, 1.0 - weight * (f0 * a_fit + b_fit)[..., None] * k


@dataclasses.dataclass(frozen=True)
class OpenPBR(Lobe):
    """OpenPBR Surface, opaque, as MaterialX 1.39 evaluates it (module doc): base_color, base_metalness,
    base_diffuse_roughness, specular_weight, specular_color, specular_roughness and specular_ior, and the coat's and
    the fuzz's inputs where the options add them, under OpenPBR's names and in its ranges; the other inputs at their
    defaults or off (base_weight 1, no thin film, transmission, subsurface or emission, anisotropy 0).

    specular_weight and specular_color are held at 1 (white) unless a fit frees them: the graph modulates the
    dielectric's index by the product specular_weight · F0(specular_ior) alone, so with no metal the two are one
    degree of freedom, and the tint scales the dielectric's specular as the index partly does.

    Options:
        coat: add OpenPBR's coat (coat_weight, coat_roughness, coat_ior; coat_color held at white and
            coat_darkening at 1 unless freed), a dielectric layer over the base, for lacquer, varnish and car paint
            (module doc). With coat_weight 0 it is the model without coat. A coat's colour tints the base as the
            base colour does, so a fit holds it unless told otherwise.
        fuzz: add OpenPBR's fuzz layer (fuzz_weight, fuzz_color, fuzz_roughness; Zeltner et al.'s sheen), for
            cloth, felt and dusty surfaces (module doc). With fuzz_weight 0 it is the model without fuzz.
    """

    name = "openpbr"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("OpenPBR Surface 1.1 as MaterialX 1.39 evaluates it: libraries/bxdf/open_pbr_surface.mtlx and the "
                 "genglsl shader code of its BSDF nodes (dielectric_bsdf, generalized_schlick_bsdf, "
                 "oren_nayar_diffuse_bsdf, layer, mix)")
    reciprocal = False
    offset = True
    layers = {"coat": "coat_weight", "fuzz": "fuzz_weight"}

    coat: bool = False
    fuzz: bool = False

    def __post_init__(self):
        for option in ("coat", "fuzz"):
            if not isinstance(getattr(self, option), bool):
                raise ValueError(f"openpbr: {option} must be True or False, got {getattr(self, option)!r}")

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
        ) + (self._coat_specs() if self.coat else ()) + (self._fuzz_specs() if self.fuzz else ())

    @staticmethod
    def _coat_specs():
        return (
            ParamSpec("coat_weight", 0.5, 0.0, 1.0, doc="Coat Weight: the coat's presence"),
            ParamSpec("coat_color", 1.0, 0.0, 1.0, colour=True, fixed=True,
                      doc="Coat Color: the coat's transmittance, which tints what lies beneath it"),
            ParamSpec("coat_roughness", 0.1, math.sqrt(MIN_ROUGHNESS), 1.0, scale=True,
                      doc="Coat Roughness: GGX α = coat_roughness² of the coat's reflection"),
            ParamSpec("coat_ior", 1.6, 1.0, 3.0, doc="Coat IOR: the coat's index of refraction"),
            ParamSpec("coat_darkening", 1.0, 0.0, 1.0, fixed=True,
                      doc="Coat Darkening: scales the darkening of the base by the coat's internal reflection"),
        )

    @staticmethod
    def _fuzz_specs():
        return (
            ParamSpec("fuzz_weight", 0.5, 0.0, 1.0,
                      doc="Fuzz Weight: the fuzz layer's presence (its sheen's weight, and its darkening of the base)"),
            ParamSpec("fuzz_color", 1.0, 0.0, 1.0, colour=True, doc="Fuzz Color: the sheen's colour"),
            ParamSpec("fuzz_roughness", 0.5, 0.01, 1.0,
                      doc="Fuzz Roughness: Zeltner's sheen roughness (MaterialX clamps it to [0.01, 1])"),
        )

    def peaks(self, params):
        peaks = (Peak("half", scalar(params, "specular_roughness") ** 2),)
        return peaks + ((Peak("half", scalar(params, "coat_roughness") ** 2),) if self.coat else ())

    def __call__(self, params, pair: LocalPair):
        base, tint = params["base_color"], params["specular_color"]
        metalness, weight = params["base_metalness"], params["specular_weight"]
        eta, rough = params["specular_ior"], params["base_diffuse_roughness"]
        specular_roughness = params["specular_roughness"]
        if self.coat:  # the base under a coat: roughened, and its index relative to the coat's
            coat_weight, coat_ior = params["coat_weight"], params["coat_ior"]
            roughened = jnp.minimum(1.0, 2.0 * params["coat_roughness"] ** 4 + specular_roughness ** 4) ** 0.25
            specular_roughness = _mix(specular_roughness, roughened, coat_weight)
            ratio = eta / coat_ior
            eta = _mix(eta, jnp.where(ratio > 1.0, ratio, coat_ior / eta), coat_weight)
        alpha = jnp.clip(specular_roughness ** 2, EPS, 1.0)
        mu_i, mu_o = jnp.clip(pair.cos_i, EPS, 1.0), jnp.clip(pair.cos_o, EPS, 1.0)
        c = jnp.clip(pair.cos_d, EPS, 1.0)
        microfacet = ggx_correlated(pair, alpha)
        a_fit, b_fit = ggx_albedo_fit(mu_o, alpha)

        weighted_f0 = jnp.clip(weight * fr.normal_reflectance(eta), 0.0, _F0_CAP)
        epsilon = jnp.sign(eta - 1.0) * safe_sqrt(weighted_f0, tiny=0.0)
        modulated = (1.0 + epsilon) / (1.0 - epsilon)
        specular, throughput = _dielectric_layer(fr.dielectric(c, 1.0, modulated)[..., None],
                                                 fr.normal_reflectance(modulated), microfacet, a_fit, b_fit)
        diffuse = _oren_nayar(pair, mu_i, mu_o, base, rough) / jnp.pi
        dielectric = tint * specular + throughput * diffuse
        f_metal = fr.f82_tint(c[..., None], base, tint)
        metal = weight * f_metal * microfacet[..., None] * _compensation(a_fit + b_fit)(f_metal)
        base_f = (1.0 - metalness) * dielectric + metalness * metal
        if self.coat:
            base_f = self._coated(params, pair, mu_o, c, base_f)
        if not self.fuzz:
            return base_f
        fuzz_weight = params["fuzz_weight"]
        # MaterialX clamps the roughness to [0.01, 1] and leaves the fitted albedo unclamped in this mode.
        sheen_albedo, sheen = zeltner_sheen(pair, mu_o, jnp.clip(params["fuzz_roughness"], 0.01, 1.0))
        return (fuzz_weight * params["fuzz_color"] * sheen[..., None]
                + (1.0 - fuzz_weight * sheen_albedo)[..., None] * base_f)

    @staticmethod
    def _coated(params, pair: LocalPair, mu_o, c, base_f):
        """The graph's ``coat_layer`` over ``base_f`` (module doc)."""
        weight, ior, base = params["coat_weight"], params["coat_ior"], params["base_color"]
        f0 = fr.normal_reflectance(ior)
        internal = 1.0 - (1.0 - f0) / (ior * ior)  # Kcoat
        albedo_estimate = _mix(base, base * params["specular_weight"], params["base_metalness"])  # Ebase
        darkening = (1.0 - internal) / (1.0 - albedo_estimate * internal)
        beneath = (_mix(1.0, darkening, weight * params["coat_darkening"])
                   * _mix(1.0, params["coat_color"], weight)) * base_f
        alpha = jnp.clip(params["coat_roughness"] ** 2, EPS, 1.0)
        response, throughput = _dielectric_layer(fr.dielectric(c, 1.0, ior)[..., None], f0,
                                                 ggx_correlated(pair, alpha), *ggx_albedo_fit(mu_o, alpha), weight)
        return response + throughput * beneath
