"""The glTF 2.0 metallic-roughness material, as the glTF specification's Appendix B defines its BRDF, with the
ratified extensions KHR_materials_ior, KHR_materials_specular, KHR_materials_sheen and KHR_materials_clearcoat.

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
- with a sheen (KHR_materials_sheen, "Implementation Notes"): sheen_color · D_s V_s + material · s, with D_s the
  Charlie distribution (2 + 1/α_s) sin^(1/α_s)θh/(2π) and V_s = 1/((1 + Λ(ωi) + Λ(ωo)) 4 ci co) the Charlie
  visibility, Λ Estevez & Kulla's fit (`brdffit.models.sheen`), α_s = sheen_roughness²; and the albedo scaling
  s = min(1 − max_c(sheen_color) E(ci), 1 − max_c(sheen_color) E(co)) ("Albedo-scaling technique"), E the sheen's
  directional albedo (`sheen_albedo_table`);
- with a clearcoat (KHR_materials_clearcoat, "Implementation"): mix(material, clearcoat_brdf, clearcoat · Fc),
  Fc = 0.04 + 0.96 (1 − |ωo·n|)⁵ and clearcoat_brdf Appendix B's specular_brdf at α = clearcoat_roughness² (the
  clearcoat normal is the surface's). Fc takes the viewing direction, not h, so a clearcoat makes the material
  non-reciprocal, as the extension says.

The sheen's directional albedo E(μ; sheen_roughness) = ∫ D_s V_s cosθi dωi (the sheen BRDF of a white sheen colour
at a direction of cosine μ) is a table, as the extension has it ("The values E(x) can be looked up in a table", with
x = n·v and y = sheenRoughness). The extension prints no table (it points to the Enterprise PBR Shading Model's
16 × 16 Monte Carlo table, §6.2.3, and a viewer ships its own texture, the Sample Viewer an 8-bit PNG), so brdffit
computes it from the definition by quadrature (`sheen_albedo_table`): 32 × 32 nodes, μ = i/31 (the first at
μ = 1e-4: the fitted Λ stays finite at μ = 0, so V_s's 1/(4 μ) makes E diverge there) and sheen_roughness uniform on
[0.1, 1] (the declared range), read by bilinear interpolation. The interpolation departs from E by up to 0.10 in
the first μ cell (θ > 88.2°), 0.09 in the second at the smallest roughness and 0.011 elsewhere. The Enterprise
PBR table (``res/pbrlut.hpp`` of its repository, the revision with Estevez & Kulla's Λ: nodes at (i + ½)/16 in μ
and in sheenRoughness, α = sheenRoughness²) agrees with the quadrature within 0.011 (its Monte Carlo noise) for
sheen roughness ≥ 0.28; below that it holds its own roughness clamp. Where the fitted Λ lets the sheen's albedo
exceed 1 (sheen roughness below 0.26, at grazing angles) E is clamped to 1, as a viewer's 8-bit lookup texture
holds it, so that the base layer's weight stays in [0, 1].

Every parameter is declared in the range a glTF file accepts (base colour, metallic, roughness, specular and the
sheen's colour and roughness in [0, 1], ior ≥ 1), so that a fit is a material any glTF viewer takes as written. The
sheen is held at sheen_color = 0 and the clearcoat at 0 unless freed (``free=["sheen_color", "sheen_roughness"]``,
``free=["clearcoat", "clearcoat_roughness"]``); a zero sheen colour leaves the material exactly as without the
extension. The value is affine in the base colour channel by channel (f = f₀ + base_color · B, with f₀ the
Fresnel-weighted specular, the metal's grazing tint and the sheen; the albedo scaling does not depend on the base
colour), so the base colour is a linear amplitude that a fit solves exactly.

Reciprocity: the Appendix B material and the sheen are reciprocal (the sheen's D_s V_s is symmetric in ωi and ωo,
and its albedo scaling takes the smaller weight of the two directions, as the extension's punctual-light form and
the Sample Viewer do, rather than the view-only approximation the extension offers for speed); the clearcoat's
Fresnel weight takes the viewing direction alone, so a clearcoat makes the material non-reciprocal.
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
from .sheen import charlie_distribution, charlie_visibility
from .specs import base_color, metallic, perceptual_roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["GltfMaterial", "sheen_albedo_table", "sheen_albedo", "SHEEN_TABLE_SIZE",
           "MIN_SHEEN_ROUGHNESS"]

# KHR_materials_ior: ior ≥ 1 (or 0, which brdffit does not write); 3 is f0 = 0.25, beyond every common dielectric.
_MAX_IOR = 3.0
# KHR_materials_sheen: sheenRoughnessFactor in [0, 1]; brdffit's fits stay at α_s = sheen_roughness² ≥ 0.01 (the
# charlie-sheen lobe's smallest α), where the Charlie distribution is resolved by the albedo table's quadrature.
MIN_SHEEN_ROUGHNESS = 0.1
# The sheen albedo table: nodes per axis (μ and sheen_roughness), the smallest μ it is computed at, and its
# quadrature (Gauss-Legendre nodes in each half of cosθi and in φ; `sheen_albedo_table`).
SHEEN_TABLE_SIZE = 32
_MIN_MU = 1e-4
_COS_NODES, _PHI_NODES = 64, 64


def sheen_table_nodes():
    """The nodes of the sheen albedo table.

    Returns:
        ``(mu, sheen_roughness)``: the cosines i/31 with the first at 1e-4, and sheen_roughness uniform on
        [MIN_SHEEN_ROUGHNESS, 1], each ``(SHEEN_TABLE_SIZE,)`` float64.
    """
    steps = np.arange(SHEEN_TABLE_SIZE) / (SHEEN_TABLE_SIZE - 1)
    return np.maximum(steps, _MIN_MU), MIN_SHEEN_ROUGHNESS + (1.0 - MIN_SHEEN_ROUGHNESS) * steps


def sheen_quadrature(mu, cos_nodes: int = _COS_NODES, phi_nodes: int = _PHI_NODES):
    """Nodes and weights of ∫ g(ωi) dωi over the upper hemisphere for a view at cosine ``mu`` (azimuth 0), as
    the sheen albedo table integrates: cosθi on [0, ½] and [½, 1] (Λ's two branches meet at ½), each by
    Gauss-Legendre in u with cosθi = ½u³ and 1 − ½u³ (Λ's L(x) has x^c, c < 1, at both ends); φi on [0, π] (the
    integrand is even in φi; doubled) by Gauss-Legendre in v with φi = π v³ (the sheen of a grazing view peaks at
    φi = 0, where h is most nearly horizontal).

    Arguments:
        mu: the view's cosine.
        cos_nodes, phi_nodes: Gauss-Legendre nodes per half of cosθi and in φ.

    Returns:
        ``(cos_i (2 cos_nodes, 1), cos_h (2 cos_nodes, phi_nodes), weights (2 cos_nodes, phi_nodes))``: n·ωi, n·h
        and the weights (dωi included).
    """
    u, wu = _unit_legendre(cos_nodes)
    half = 0.5 * u ** 3
    half_w = 1.5 * u ** 2 * wu
    cos_i = np.concatenate([half, 1.0 - half])[:, None]
    w_cos = np.concatenate([half_w, half_w])[:, None]
    v, wv = _unit_legendre(phi_nodes)
    phi, w_phi = np.pi * v ** 3, 2.0 * 3.0 * np.pi * v ** 2 * wv  # 2: both halves of φi
    sin_i = np.sqrt(1.0 - cos_i * cos_i)
    hx = sin_i * np.cos(phi)[None, :] + np.sqrt(1.0 - mu * mu)
    hy = sin_i * np.sin(phi)[None, :]
    hz = cos_i + mu
    cos_h = hz / np.sqrt(hx * hx + hy * hy + hz * hz)
    return cos_i, cos_h, w_cos * w_phi[None, :]


@functools.lru_cache(maxsize=4)
def _unit_legendre(n: int):
    """Gauss-Legendre nodes and weights of ∫₀¹."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@functools.lru_cache(maxsize=1)
def sheen_albedo_table() -> np.ndarray:
    """The directional albedo of KHR_materials_sheen's BRDF, by quadrature: shape ``(sheen_roughness, μ)`` =
    (32, 32) on `sheen_table_nodes`.

    E(μ; r) = ∫ D_s(h) V_s(ωi, ωo) cosθi dωi over the upper hemisphere, ωo at cosine μ, D_s and V_s the Charlie
    distribution and visibility at α_s = r² (`brdffit.models.sheen`), integrated by `sheen_quadrature` (within
    about 1e-7 of an adaptive quadrature at every node), then clamped to [0, 1] (module doc).

    Returns:
        The table, float64.
    """
    mus, rough = sheen_table_nodes()
    alpha = (rough * rough)[:, None, None]
    table = np.empty((SHEEN_TABLE_SIZE, SHEEN_TABLE_SIZE))
    for j, mu in enumerate(mus):  # in NumPy: the table is data, computed on the host even inside a traced function
        cos_i, cos_h, weights = sheen_quadrature(mu)
        brdf = charlie_distribution(cos_h, alpha, np) * charlie_visibility(cos_i, mu, alpha, np)
        table[:, j] = np.sum(brdf * cos_i * weights, axis=(1, 2))
    return np.clip(table, 0.0, 1.0)


def sheen_albedo(mu, sheen_roughness):
    """E(μ; sheen_roughness) read from `sheen_albedo_table` by bilinear interpolation (arguments clamped to the
    table's nodes).

    Arguments:
        mu: cosines, any shape; sheen_roughness: a scalar or broadcastable.

    Returns:
        E, the broadcast shape.
    """
    # The first μ node holds E(1e-4) and is read as μ = 0 (Cycles' tables clamp their first node the same way).
    return multilinear(sheen_albedo_table(),
                       (sheen_roughness - MIN_SHEEN_ROUGHNESS) / (1.0 - MIN_SHEEN_ROUGHNESS), mu)


@dataclasses.dataclass(frozen=True)
class GltfMaterial(Lobe):
    """The glTF 2.0 metallic-roughness material with KHR_materials_ior, _specular, _sheen and _clearcoat (module
    doc): the BRDF a glTF file describes. ``specular_color`` is held at white unless freed (it trades off against
    ``ior`` and ``specular``), the sheen and the clearcoat at 0."""

    name = "gltf"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("The Khronos Group, glTF 2.0 Specification, Appendix B (BRDF Implementation); KHR_materials_ior; "
                 "KHR_materials_specular; KHR_materials_sheen; KHR_materials_clearcoat")
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
            ParamSpec("sheen_color", 0.0, 0.0, 1.0, colour=True, fixed=True,
                      doc="KHR_materials_sheen sheenColorFactor: the sheen's colour and strength (0: no sheen)"),
            ParamSpec("sheen_roughness", 0.5, MIN_SHEEN_ROUGHNESS, 1.0, scale=True, fixed=True,
                      doc="KHR_materials_sheen sheenRoughnessFactor: the Charlie distribution's α = "
                          "sheen_roughness²"),
            ParamSpec("clearcoat", 0.0, 0.0, 1.0, fixed=True,
                      doc="KHR_materials_clearcoat clearcoatFactor: weight of the clear coat"),
            dataclasses.replace(perceptual_roughness("KHR_materials_clearcoat clearcoatRoughnessFactor: the coat's "
                                                     "GGX α = clearcoat_roughness²"),
                                name="clearcoat_roughness", default=0.1, fixed=True),
        )

    def peaks(self, params):
        """The specular GGX lobe and, with a clearcoat, KHR_materials_clearcoat's GGX lobe (α = roughness²)."""
        found = [Peak("half", scalar(params, "roughness") ** 2)]
        if scalar(params, "clearcoat") > 0:
            found.append(Peak("half", scalar(params, "clearcoat_roughness") ** 2))
        return tuple(found)

    def __call__(self, params, pair: LocalPair):
        base = params["base_color"]
        metallic = params["metallic"]
        alpha = params["roughness"] ** 2
        specular_brdf = ggx_correlated(pair, alpha)[..., None]  # V D, Appendix B's specular_brdf
        weight = fr.schlick_weight(pair.cos_d)[..., None]
        f0 = jnp.minimum(fr.normal_reflectance(params["ior"]) * params["specular_color"], 1.0)  # (C,)
        fresnel = f0 + (1.0 - f0) * weight  # (..., C)
        strength = params["specular"]
        dielectric = ((1.0 - strength * jnp.max(fresnel, axis=-1, keepdims=True)) * base / jnp.pi
                      + strength * fresnel * specular_brdf)
        metal = (base + (1.0 - base) * weight) * specular_brdf
        material = (1.0 - metallic) * dielectric + metallic * metal
        # KHR_materials_sheen, "Sheen layering": sheen_color D_s V_s + material min(1 − m E(ci), 1 − m E(co)).
        sheen_color, sheen_roughness = params["sheen_color"], params["sheen_roughness"]
        alpha_s = sheen_roughness ** 2
        sheen_brdf = (charlie_distribution(pair.cos_h, alpha_s)
                      * charlie_visibility(pair.cos_i, pair.cos_o, alpha_s))[..., None]
        sheen_max = jnp.max(sheen_color, axis=-1, keepdims=True)
        scaling = jnp.minimum(1.0 - sheen_max * sheen_albedo(pair.cos_i, sheen_roughness)[..., None],
                              1.0 - sheen_max * sheen_albedo(pair.cos_o, sheen_roughness)[..., None])
        material = sheen_color * sheen_brdf + material * scaling
        # KHR_materials_clearcoat: mix(material, clearcoat_brdf, clearcoat Fc), Fc at the viewing direction.
        alpha_c = params["clearcoat_roughness"] ** 2
        coat_brdf = ggx_correlated(pair, alpha_c)[..., None]
        coat = params["clearcoat"] * (0.04 + 0.96 * fr.schlick_weight(pair.cos_o))[..., None]
        return (1.0 - coat) * material + coat * coat_brdf
