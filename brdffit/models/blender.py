r"""Blender's Principled BSDF as Cycles evaluates an opaque one with the GGX distribution (Blender 4.2+).

Cycles' principled closure (``intern/cycles/kernel/svm/closure.h``) with no transmission, subsurface, sheen, coat
or emission, and ``Specular Tint`` white, is a sum of three layers. With h = normalize(ωi + ωo), α = roughness²,
ωo the direction to the viewer (Cycles' ``sd->wi``) and c = ωi·h:

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
lies over that sum as Cycles layers it (closure.h's second layer):

- the coat, a GGX dielectric closure of weight w with α_c = r_c² that Cycles keeps energy-preserving
  (``bsdf_microfacet_setup_fresnel_dielectric``, ``microfacet_ggx_preserve_energy``):
  f_c = w (1 + F_ms (1 − E)/E) F_d(c; η_c) D_c G2_c/(4 ci co), F_ms = F_ss E_avg/(1 − F_ss (1 − E_avg)), with E and
  E_avg Cycles' tables ``ggx_E`` (32 × 32 over (r_c, co), bilinear) and ``ggx_Eavg`` (32 over r_c), computed again
  here by quadrature (`energy_tables`), and F_ss = (η_c − 1)/(4.08567 + 1.00071 η_c) Cycles' fit of the average
  Fresnel (``fresnel_dielectric_Fss``, bsdf_util.h);
- everything beneath weighted by ``closure_layering_weight``: clamp(1 − w K R, 0, 1), K = (1 + F_ms (1 − E)/E)/(1 +
  (1 − E)/E) the closure's darkening and R = F0(η_c) + (1 − F0(η_c)) s(r_c, co, η_c) its albedo estimate (the table
  above), times the tint mix(1, Coat Tint^(1/cosθt), w), θt the view refracted into the coat (Beer's law along
  the refracted view, Cycles' approximation).

``Coat Tint`` is held white unless a fit frees it (it scales the base as Base Color does, but for its dependence on
the view).
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
from .specs import base_color, metallic, perceptual_roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["BlenderPrincipled", "layering_table", "energy_tables", "TABLE_SIZE", "ENERGY_TABLE_SIZE"]

TABLE_SIZE = 16
ENERGY_TABLE_SIZE = 32  # Cycles' ggx_E and ggx_Eavg
# Gauss-Legendre nodes of the table's quadrature: in u, the GGX distribution's own CDF variable of θh, and in φh.
_U_NODES, _PHI_NODES = 96, 64
_MAX_IOR = 3.0


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


@functools.lru_cache(maxsize=1)
def energy_tables() -> tuple[np.ndarray, np.ndarray]:
    """Cycles' ``ggx_E`` and ``ggx_Eavg`` by quadrature: shapes ``(co, roughness)`` = (32, 32) and ``(roughness,)``.

    E(r, μ) is the directional albedo of GGX with F = 1 and height-correlated masking at α = r², view at cosine μ,
    as ``cycles_precompute.cpp`` estimates it (the mean of G2/G1 over the visible normals, a reflection below the
    surface counting 0): E = ∫ (v·h)⁺ D(h) G2(ℓ, v) 1[ℓ·n > 0]/μ dω_h, in u = tan²θh/(α² + tan²θh), where D cosθh dω_h
    = du dφ/(2π): E = 1/(2π μ) ∫∫ (v·h)⁺ G2 1[ℓ·n > 0]/cosθh du dφ. E_avg(r) = ∫₀¹ 2μ E(r, μ) dμ (Gauss-Legendre in μ).
    Nodes as Cycles': r and μ at i/31 clamped to [1e-4, 1]; values clamped to [0, 1].

    Returns:
        ``(E, E_avg)``, float64.
    """
    nodes = np.clip(np.arange(ENERGY_TABLE_SIZE) / (ENERGY_TABLE_SIZE - 1), 1e-4, 1.0)
    x, wx = np.polynomial.legendre.leggauss(_U_NODES)
    u, wu = 0.5 * (x + 1.0), 0.5 * wx
    y, wy = np.polynomial.legendre.leggauss(_PHI_NODES)
    phi, wphi = np.pi * 0.5 * (y + 1.0), np.pi * 0.5 * wy  # φh in [0, π]: the integrand is even in φh
    g, wg = np.polynomial.legendre.leggauss(_U_NODES)
    mu_avg, w_avg = 0.5 * (g + 1.0), 0.5 * wg

    def albedo(r: float, mu: np.ndarray) -> np.ndarray:
        a2 = r ** 4
        tan2 = a2 * u / (1.0 - u)
        cos_h = (1.0 / np.sqrt(1.0 + tan2))[:, None, None]
        sin_h = np.sqrt(tan2)[:, None, None] * cos_h
        hx, hz = sin_h * np.cos(phi)[None, :, None], cos_h
        vx, vz = np.sqrt(1.0 - mu * mu)[None, None, :], mu[None, None, :]
        vh = vx * hx + vz * hz
        lz = 2.0 * vh * hz - vz

        def lam(c):
            c = np.maximum(c, 1e-300)
            return 0.5 * (np.sqrt(1.0 + a2 * (1.0 - c * c) / (c * c)) - 1.0)

        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            g2 = 1.0 / (1.0 + lam(vz) + lam(lz))
            term = np.where((vh > 0.0) & (lz > 0.0), vh * g2 / hz, 0.0)
        weight = (2.0 * wu[:, None] * wphi[None, :] / (2.0 * np.pi))[..., None]  # both halves of φh
        return np.sum(weight * term, axis=(0, 1)) / mu

    e = np.empty((ENERGY_TABLE_SIZE, ENERGY_TABLE_SIZE))
    e_avg = np.empty(ENERGY_TABLE_SIZE)
    for i, r in enumerate(nodes):
        e[:, i] = np.clip(albedo(r, nodes), 0.0, 1.0)
        e_avg[i] = np.clip(np.sum(w_avg * 2.0 * mu_avg * albedo(r, mu_avg)), 0.0, 1.0)
    return e, e_avg


def average_fresnel(eta):
    """Cycles' fit of the cosine-weighted hemispherical average of the dielectric Fresnel term for η ≥ 1
    (``fresnel_dielectric_Fss``, intern/cycles/kernel/closure/bsdf_util.h)."""
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


@dataclasses.dataclass(frozen=True)
class BlenderPrincipled(Lobe):
    """Blender's Principled BSDF with the GGX distribution as Cycles evaluates it (module doc): Base Color,
    Metallic, Roughness and IOR, the other inputs at their neutral values (Specular IOR Level 0.5, Specular Tint
    white, no subsurface, sheen, coat, transmission or emission).

    Options:
        coat: add the node's coat (Coat Weight, Coat Roughness, Coat IOR; Coat Tint held white unless freed), a
            dielectric layer over the rest, for lacquer and varnish (module doc). With coat_weight 0 it is the
            model without coat.
    """

    name = "blender"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("Blender 4.2+ Principled BSDF as Cycles evaluates it: intern/cycles/kernel/svm/closure.h, "
                 "kernel/closure/bsdf_microfacet.h, app/cycles_precompute.cpp")
    reciprocal = False
    offset = True

    coat: bool = False

    def __post_init__(self):
        if not isinstance(self.coat, bool):
            raise ValueError(f"blender: coat must be True or False, got {self.coat!r}")

    def param_specs(self):
        return (
            base_color("Base Color: the diffuse albedo, and the metal's normal reflectance"),
            metallic("Metallic: blends the dielectric layers into the metal"),
            perceptual_roughness("Roughness: GGX α = roughness²"),
            ParamSpec("ior", 1.5, 1.0, _MAX_IOR, doc="IOR: the dielectric specular layer's index of refraction"),
        ) + (self._coat_specs() if self.coat else ())

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
        return self._coated(params, pair, beneath) if self.coat else beneath

    @staticmethod
    def _coated(params, pair: LocalPair, beneath):
        """The coat over ``beneath`` as Cycles layers it (module doc)."""
        weight, rough, eta = params["coat_weight"], params["coat_roughness"], params["coat_ior"]
        e_table, e_avg_table = energy_tables()
        e = multilinear(e_table, pair.cos_o, rough)
        e_avg = multilinear(e_avg_table, rough)
        fss = average_fresnel(eta)
        missing = (1.0 - e) / e
        scale = 1.0 + fss * e_avg / (1.0 - fss * (1.0 - e_avg)) * missing  # darkening × energy scale
        coat = weight * scale * fr.dielectric(pair.cos_d, 1.0, eta) * ggx_correlated(pair, rough * rough)
        f0 = fr.normal_reflectance(eta)
        s = multilinear(layering_table(), jnp.sqrt((eta - 1.0) / (eta + 1.0)), pair.cos_o, rough)
        layer = jnp.clip(1.0 - weight * scale / (1.0 + missing) * (f0 + (1.0 - f0) * s), 0.0, 1.0)
        refracted = jnp.sqrt(1.0 - (1.0 - pair.cos_o * pair.cos_o) / (eta * eta))
        tint = 1.0 + weight * (params["coat_tint"] ** (1.0 / refracted)[..., None] - 1.0)
        return coat[..., None] + layer[..., None] * tint * beneath
