r"""Mitsuba 3's ``roughplastic``: a rough dielectric interface over a diffuse base, as Mitsuba 3 evaluates it.

Mitsuba 3, ``src/bsdfs/roughplastic.cpp`` (``RoughPlastic::eval`` and ``parameters_changed``) and
``include/mitsuba/render/microfacet.h`` (``eval_reflectance``, ``eval_transmittance``); the model is Weidlich &
Wilkie, Arbitrarily layered micro-facet surfaces, GRAPHITE 2007, with the rough interface's transmittance of
Walter et al., Microfacet models for refraction through rough surfaces, EGSR 2007. With ``nonlinear`` false,
η = ``int_ior`` (``ext_ior`` 1), the GGX distribution of width α and separable Smith masking:

    f = ks F(ωi·h; η) D(h) G1(ωi) G1(ωo) / (4 ci co)
        + ρ / (1 − R_int) · T(ci) T(co) / (π η²),

ks = ``specular_reflectance``, ρ = ``diffuse_reflectance``, and two quantities of the interface alone (α, η) that
the plugin computes when it loads:

- T(μ), the external transmittance at 64 cosines μ_j = max(1e-6, j/63): the expectation over the visible normals
  m of a direction of cosine μ (Heitz & d'Eon 2014's sampling, ``sample_visible_11``) of (1 − F(ωi·m; η))
  G1(ωt, m), ωt the refracted direction, by Gauss-Legendre quadrature on 32 × 32 nodes of the sampling's unit
  square (128 × 128 where η < 1); read between the nodes by linear interpolation (``lerp_gather``);
- R_int, the interface's reflectance from inside averaged over the cosine-weighted hemisphere:
  2 mean_j(R(μ_j; 1/η) μ_j), R(μ; η) the same expectation of F(ωi·m; η) G1(ωr, m), ωr the reflected direction,
  on 128 × 128 nodes (η < 1 inside).

`transmittance` (NumPy or JAX) and `internal_reflectance` (NumPy) compute both as the plugin does. The lobe
evaluates T exactly so, in JAX. R_int is a mean over evenly spaced cosines of an integrand with a kink at the critical
angle: it jumps by up to 6e-3 between nearby α and η, and costs 26 ms per evaluation in JAX, so the lobe reads
instead a smooth counterpart R_smooth (`smooth_internal_reflectance`: the same rule applied to the integrand
without its kink) from a table (`internal_reflectance_table`), and the export writes ρ (1 − R_int)/(1 − R_table)
as ``diffuse_reflectance``, with the plugin's own R_int (`internal_reflectance`): the diffuse term Mitsuba
evaluates is then exactly the fitted one.

Reciprocal (T(ci) T(co) and the specular term are symmetric in ωi and ωo), affine in ks and linear in ρ channel by
channel: both are linear amplitudes.
"""

from __future__ import annotations

import dataclasses
import functools
import math

from .._lazy import module
from ..geometry import LocalPair, safe_sqrt
from ..params import ParamSpec
from . import cubic
from .cook_torrance import CookTorrance
from .fresnel import dielectric
from .lobe import Lobe
from .peaks import Peak, scalar
from .specs import roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) needs neither JAX
np = module("numpy")  # nor NumPy

__all__ = ["RoughPlastic", "transmittance", "internal_reflectance", "smooth_internal_reflectance",
           "internal_reflectance_table", "cosines", "TABLE_TOLERANCE",
           "MIN_ETA", "MAX_ETA"]

# MI_ROUGH_TRANSMITTANCE_RES: the cosines at which the plugin tabulates T.
TRANSMITTANCE_NODES = 64
# The plugin refuses int_ior == ext_ior; 1.01 (F at normal incidence 2.5e-5) to 3 (0.25) covers the dielectrics
# (glTF's KHR_materials_ior range, brdffit's `gltf` model, ends at 3 too).
MIN_ETA, MAX_ETA = 1.01, 3.0
# The table of R_smooth (`scripts/roughplastic_table.py`): nodes uniform in √α and in √(η − 1).
TABLE_FILE = "data/roughplastic_internal_reflectance.npz"  # inside the package (package data)
# How far the table's cubic interpolation may depart from R_smooth between its nodes (tests/test_roughplastic.py).
TABLE_TOLERANCE = 1e-3

# The specular term: GGX, separable Smith, the dielectric Fresnel term (brdffit's cook-torrance lobe, unit ks).
_SPECULAR = CookTorrance(distribution="ggx", shadowing="smith", fresnel="dielectric")


def cosines():
    """The plugin's 64 cosines μ_j = max(1e-6, j/63) at which it tabulates T."""
    return np.maximum(1e-6, np.linspace(0.0, 1.0, TRANSMITTANCE_NODES))


@functools.cache
def _quadrature(n: int):
    """The plugin's n × n Gauss-Legendre rule over the sampling's unit square (``quad::gauss_legendre``, nodes
    x ↦ x/2 + 1/2, weights w_x w_y/4), as flat arrays: the nodes already mapped to the unit disk by Shirley &
    Chiu's concentric map (Mitsuba's ``warp::square_to_uniform_disk_concentric``), the first step of GGX's
    ``sample_visible_11``, and the weights (summing to 1). The same for every α and η: computed once."""
    x, w = np.polynomial.legendre.leggauss(n)
    u1, u2 = np.meshgrid(x, x, indexing="xy")  # 2 (x/2 + 1/2) − 1 = x
    w1, w2 = np.meshgrid(w, w, indexing="xy")
    u1, u2 = u1.ravel(), u2.ravel()
    steep = np.abs(u1) < np.abs(u2)
    r = np.where(steep, u2, u1)
    phi = 0.25 * math.pi * np.where(steep, u1, u2) / r
    phi = np.where(steep, 0.5 * math.pi - phi, phi)
    return r * np.cos(phi), r * np.sin(phi), (0.25 * w1 * w2).ravel()


def _sqrt(x, xp):
    """Mitsuba's ``safe_sqrt``, √max(x, 0) (`brdffit.geometry.safe_sqrt` with no threshold)."""
    return safe_sqrt(x, xp, tiny=0.0)


def _visible_normals(mu, alpha, px, py, xp):
    """The GGX visible normals of directions (√(1 − μ²), 0, μ) at the quadrature's samples (on the unit disk,
    `_quadrature`): Mitsuba's ``MicrofacetDistribution::sample`` with visible-normal sampling (Heitz & d'Eon 2014,
    GGX's ``sample_visible_11``), for a direction in the x-z plane (its azimuth rotation is the identity).

    Returns:
        (mx, my, mz), each of shape ``mu.shape + px.shape`` (``mu`` on a leading axis).
    """
    mu = mu[:, None]
    sx = alpha * _sqrt(1.0 - mu * mu, xp)
    cos_theta = mu / xp.sqrt(sx * sx + mu * mu)  # the stretched direction's cosine
    px, py = xp.asarray(px), xp.asarray(py)
    s = 0.5 * (1.0 + cos_theta)
    edge = _sqrt(1.0 - px * px, xp)
    py = edge + (py - edge) * s
    pz = _sqrt(1.0 - px * px - py * py, xp)
    sin_theta = _sqrt(1.0 - cos_theta * cos_theta, xp)
    norm = 1.0 / (sin_theta * py + cos_theta * pz)
    slope_x = (cos_theta * py - sin_theta * pz) * norm * alpha
    slope_y = px * norm * alpha
    length = xp.sqrt(slope_x * slope_x + slope_y * slope_y + 1.0)
    return -slope_x / length, -slope_y / length, 1.0 / length


def _smith_g1(vx, vy, vz, m_dot_v, alpha, xp):
    """Mitsuba's GGX ``smith_g1(v, m)``: 2/(1 + √(1 + α² tan²θv)), 0 where v sees the back of m (v·m vz ≤ 0)."""
    tan2 = alpha * alpha * (vx * vx + vy * vy) / xp.maximum(vz * vz, 1e-30)
    g1 = 2.0 / (1.0 + xp.sqrt(1.0 + tan2))
    return xp.where(m_dot_v * vz <= 0.0, 0.0, g1)


def _expectation(mu, alpha, eta, refracted: bool, xp):
    """The plugin's ``eval_transmittance`` (``refracted``) or ``eval_reflectance`` at cosines ``mu``, on its rule
    for η: 32 × 32 nodes for η > 1 (the transmittance from outside), 128 × 128 otherwise (the reflectance from
    inside, η < 1). η is a Python float below 1 only in the NumPy reflectance; the lobe's traced η is declared
    above 1."""
    px, py, w = _quadrature(128 if isinstance(eta, float) and eta < 1.0 else 32)
    mx, my, mz = _visible_normals(xp.asarray(mu), alpha, px, py, xp)
    mu_ = xp.asarray(mu)[:, None]
    sx = _sqrt(1.0 - mu_ * mu_, xp)
    c = sx * mx + mu_ * mz  # ωi·m
    f = dielectric(c, 1.0, eta, xp)  # Mitsuba's fresnel(c, η) for c >= 0 (the visible normals face ωi)
    if refracted:
        eta_ti = 1.0 / eta
        cos_t = -_sqrt(1.0 - (1.0 - c * c) * eta_ti * eta_ti, xp)  # the refracted cosine, below m
        scale = c * eta_ti + cos_t  # Mitsuba's refract: m (c η_ti + cos θt) − ωi η_ti
        ox, oy, oz = mx * scale - sx * eta_ti, my * scale, mz * scale - mu_ * eta_ti
        value = _smith_g1(ox, oy, oz, mx * ox + my * oy + mz * oz, alpha, xp) * (1.0 - f)
        value = xp.where(oz * mu_ >= 0.0, 0.0, value)
    else:
        ox, oy, oz = 2.0 * c * mx - sx, 2.0 * c * my, 2.0 * c * mz - mu_
        value = _smith_g1(ox, oy, oz, c, alpha, xp) * f
        value = xp.where(oz <= 0.0, 0.0, value)
    return xp.sum(value * xp.asarray(w), axis=-1)


def transmittance(alpha, eta, xp=np):
    """T at the plugin's 64 cosines (`cosines`) (``m_external_transmittance``).

    Arguments:
        alpha: the GGX width (scalar; a traced one under ``xp`` = ``jax.numpy``).
        eta: int_ior / ext_ior, above 1 (the plugin's 32 × 32 rule; the lobe passes a traced η, declared from
            1.01).
        xp: ``numpy`` or ``jax.numpy``.

    Returns:
        ``(64,)`` transmittances in [0, 1].
    """
    return _expectation(cosines(), alpha, eta, True, xp)


def internal_reflectance(alpha: float, eta: float) -> float:
    """R_int as the plugin computes it (``m_internal_reflectance``): 2 mean_j(R(μ_j; 1/η) μ_j), in NumPy.

    Arguments:
        alpha: the GGX width.
        eta: int_ior / ext_ior.

    Returns:
        R_int in [0, 1].
    """
    return float(2.0 * np.mean(_expectation(cosines(), float(alpha), 1.0 / float(eta), False, np) * cosines()))


def smooth_internal_reflectance(alpha: float, eta: float, nodes: int = 48) -> float:
    """The plugin's R_int without its jags: what its rule gives for an integrand without a kink.

    The plugin's R_int = 2 mean_j g(μ_j), g(μ) = R(μ; 1/η) μ at μ_j = j/63, is (63/64) times twice the trapezoid
    rule of g plus g(0)/64 + g(1)/64 (g(0) = 0); for a smooth g the trapezoid rule is ∫₀¹ g to O(1/63²). So

        R_smooth = (63/64) · 2 ∫₀¹ R(μ; 1/η) μ dμ + R(1; 1/η)/64,

    the integral by Gauss-Legendre quadrature on each side of the critical cosine √(1 − 1/η²), below which a smooth
    interface reflects totally (``nodes`` points each; R by the plugin's 128 × 128 rule). g has a kink there, which
    the plugin's evenly spaced cosines step over: its R_int departs from R_smooth by up to 6e-3 where α is near 0
    and by 1.5e-4 from α = 0.05 on (tests/test_roughplastic.py); 2 ∫ g is the interface's hemispherical internal
    reflectance (0.5963 for a smooth interface of η = 1.5, as 1 − (1 − 0.0918)/η²).

    Arguments:
        alpha: the GGX width.
        eta: int_ior / ext_ior, above 1.
        nodes: Gauss-Legendre points on each side of the critical cosine.

    Returns:
        R_smooth in [0, 1].
    """
    critical = math.sqrt(max(1.0 - 1.0 / (eta * eta), 0.0))
    x, w = np.polynomial.legendre.leggauss(nodes)
    integral = 0.0
    for lo, hi in ((0.0, critical), (critical, 1.0)):
        if hi > lo:
            mu = np.maximum(lo + (hi - lo) * (0.5 * x + 0.5), 1e-6)
            integral += 0.5 * (hi - lo) * float(np.sum(w * _expectation(mu, float(alpha), 1.0 / float(eta), False,
                                                                        np) * mu))
    normal = float(_expectation(np.ones(1), float(alpha), 1.0 / float(eta), False, np)[0])
    return (TRANSMITTANCE_NODES - 1) / TRANSMITTANCE_NODES * 2.0 * integral + normal / TRANSMITTANCE_NODES


@functools.cache
def _table():
    """(√α nodes, √(η − 1) nodes, R_smooth values) of the table `scripts/roughplastic_table.py` writes."""
    from importlib import resources  # here, not at import: the registry (`brdffit models`) does not read the table

    with resources.files("brdffit").joinpath(TABLE_FILE).open("rb") as handle:
        data = np.load(handle)
        return data["sqrt_alpha"], data["sqrt_eta_minus_1"], data["values"]


def internal_reflectance_table(alpha, eta, xp=None):
    """R_smooth(α, η) (`smooth_internal_reflectance`) read from its table by cubic convolution in √α and √(η − 1)
    (R_smooth rises from 0 at η = 1 like (η − 1)^(3/2)); within `TABLE_TOLERANCE` of it over the declared ranges
    (tests/test_roughplastic.py).

    Arguments:
        alpha, eta: scalars (traced under JAX).
        xp: ``numpy`` or ``jax.numpy`` (default).

    Returns:
        R_int, a scalar.
    """
    xp = jnp if xp is None else xp
    sqrt_alpha, sqrt_eta, values = _table()
    values = xp.asarray(values)
    i, s = cubic.cell(sqrt_alpha, xp.sqrt(alpha), xp)
    j, t = cubic.cell(sqrt_eta, xp.sqrt(xp.maximum(eta - 1.0, 0.0)), xp)
    rows = [xp.clip(i + k, 0, len(sqrt_alpha) - 1) for k in (-1, 0, 1, 2)]
    cols = [xp.clip(j + k, 0, len(sqrt_eta) - 1) for k in (-1, 0, 1, 2)]
    value = 0.0
    for wa, row in zip(cubic.weights(s), rows):
        for we, col in zip(cubic.weights(t), cols):
            value = value + wa * we * values[row, col]
    return value


@dataclasses.dataclass(frozen=True)
class RoughPlastic(Lobe):
    """Mitsuba 3's ``roughplastic`` (GGX, ``nonlinear`` false): ks F D G1 G1/(4 ci co) + ρ/(1 − R_int) T(ci) T(co)
    /(π η²) (module doc)."""

    name = "roughplastic"
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("Mitsuba 3's roughplastic plugin (src/bsdfs/roughplastic.cpp, include/mitsuba/render/microfacet.h); "
                 "Weidlich & Wilkie, Arbitrarily layered micro-facet surfaces, GRAPHITE 2007; Walter et al., EGSR "
                 "2007")

    def param_specs(self):
        return (
            ParamSpec("diffuse_reflectance", 0.5, 0.0, 1.0, colour=True, linear=True,
                      doc="ρ, the diffuse base's albedo (the Mitsuba export corrects it for the plugin's internal "
                          "reflectance: docs/export.md)"),
            ParamSpec("specular_reflectance", 1.0, 0.0, 1.0, colour=True, linear=True,
                      doc="ks, the factor on the interface's specular reflection (1 for a physical interface)"),
            roughness("alpha", default=0.1, doc="the GGX width α of the interface"),
            ParamSpec("int_ior", 1.49, MIN_ETA, MAX_ETA, unit="1",
                      doc="η, the interface's index of refraction (ext_ior 1)"),
        )

    def amplitude_partners(self, amplitude):
        # α and η act on both terms (T and R_int shape the diffuse one): neither amplitude alone leaves them free.
        return ()

    def peaks(self, params):
        return (Peak("half", scalar(params, "alpha")),)

    def __call__(self, params, pair: LocalPair):
        alpha, eta = params["alpha"], params["int_ior"]
        specular = _SPECULAR({"ks": 1.0, "m": alpha, "eta": eta}, pair)
        table = transmittance(alpha, eta, xp=jnp)
        ti, to = _lerp_gather(table, pair.cos_i), _lerp_gather(table, pair.cos_o)
        diffuse = ti * to / (math.pi * eta * eta * (1.0 - internal_reflectance_table(alpha, eta)))
        return params["specular_reflectance"] * specular + params["diffuse_reflectance"] * diffuse[..., None]


def _lerp_gather(table, cos_theta):
    """The plugin's ``lerp_gather``: T at a cosine by linear interpolation between its 64 nodes at j/63."""
    x = jnp.clip(cos_theta, 0.0, 1.0) * (TRANSMITTANCE_NODES - 1)
    j = jnp.minimum(jnp.floor(x), TRANSMITTANCE_NODES - 2).astype(jnp.int32)
    return table[j] + (table[j + 1] - table[j]) * (x - j)
