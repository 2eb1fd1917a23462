r"""pbrt-v4's ``coatedconductor`` under a smooth coat: a rough conductor beneath a flat dielectric interface.

pbrt-v4 (github.com/mmp/pbrt-v4; Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed., 2023, §14.3)
renders ``coatedconductor`` as ``LayeredBxDF<DielectricBxDF, ConductorBxDF, true>`` (``src/pbrt/bxdfs.h``,
``LayeredBxDF::f``; ``src/pbrt/materials.cpp``, ``CoatedConductorMaterial::GetBxDF``): a random walk between the
interface (index η, ``interface.eta``) and a Trowbridge-Reitz conductor of width α (``conductor.roughness``) whose
complex index is the one given divided by the coat's (``ce /= ieta; ck /= ieta``: the metal is seen from inside
the coat), through a slab of ``thickness`` 0.01 with albedo 0, at most ``maxdepth`` 10 scattering events.

With the interface smooth (``interface.roughness`` 0, pbrt-v4's default: ``EffectivelySmooth``), every step of the
walk but the conductor's is deterministic: ωo refracts into the slab along u0 (the direction whose horizontal
component is ωo's divided by η; radiance mode, so the weight is T(ωo)/η², T = 1 − F the interface's Fresnel
transmittance), the direction presampled from ωi refracts along ui (importance mode: T(ωi)), the next-event
estimate at the conductor has weight 1 (the exit interface is specular: no multiple importance sampling), a
sample of the conductor leaving along v comes back, mirrored by the interface with weight R(v) (total internal
reflection beyond the critical angle), along the direction flip(v) (v with its azimuth turned by π), and the walk's
transmittance exp(−thickness/|cos|) applies at every crossing. The interface reflects nothing off its mirror
direction (a delta that ``f`` does not return). The expectation of the estimate is, for ωo and ωi above the surface,

    f(ωo, ωi) = T(ωo) T(ωi)/η² · Tr(u0) Tr(ui) · [f_c(u0, ui) + Σ_{k=1}^{K−1} (𝒦^k f_c(·, ui))(u0)],

- f_c the conductor (``ConductorBxDF::f``: FrComplex(|u·h|; (η_c + i k_c)/η) D(h) G(u, v)/(4 cosθu cosθv),
  Trowbridge-Reitz D, height-correlated Smith G; brdffit's Cook-Torrance lobe with those options);
- 𝒦 g(u) = ∫ f_c(u, v) |cos v| Tr(v)² R(v) g(flip(v)) dv, one more bounce at the conductor and its return from the
  interface;
- K = maxdepth/2 = 5 visits of the conductor (one every two scattering events).

Every quantity is rotation-invariant about the normal, so 𝒦 is diagonal in the Fourier series of the azimuth
difference: with f_c(u, v) = Σ_m F_m(μu, μv) cos(m Δφ) (midpoint rule over Δφ in [0, π], `AZIMUTH_NODES`),
composing two such kernels over the intermediate direction multiplies their coefficients, (A∘B)_m = c_m A_m W B_m,
c_0 = 2π, c_m = π, W the cosine rule's weights (Gauss-Legendre, `COSINE_NODES` on each side of the critical cosine
√(1 − 1/η²), where R has a kink), and the flip is a factor (−1)^m. The end directions u0, ui are read from nodes
evenly spaced in the sine of the outside direction (`END_NODES`: u0 and ui are its refractions), and the sum over
k ≥ 1 is tabulated over (sinθo, sinθi, Δφ) and read by Keys' cubic convolution (`brdffit.models.cubic`); the
first term, f_c(u0, ui), which holds the sharp highlight, is evaluated at the pair itself. tests/test_coatedconductor.py
holds the rules to finer ones and the lobe to a NumPy transcription of pbrt-v4's walk (tests/pbrt_layered_walk.py).

Not modelled: a rough interface (pbrt-v4's walk then samples the interface's transmission and weights two
next-event estimates by the power heuristic, integrals over four more dimensions), the slab's medium (albedo,
g), an anisotropic conductor. pbrt-v4 renders the interface's mirror reflection besides f (``Sample_f``), and
where it samples the BSDF, ``Sample_f``'s walk, whose expectation under a smooth coat is the same f (no power
heuristic weighs two estimates; tests/test_coatedconductor.py holds a transcription of that walk to the lobe).
"""

from __future__ import annotations

import dataclasses
import functools
import math

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from . import cubic
from .coateddiffuse import MAX_ETA as MAX_INTERFACE_ETA, MIN_ETA as MIN_INTERFACE_ETA, MAX_DEPTH
from .coateddiffuse import slab_transmittance
from .fresnel import dielectric
from .lobe import Lobe
from .pbrt import conductor_bxdf
from .peaks import Peak, scalar
from .specs import roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) needs neither JAX
np = module("numpy")  # nor NumPy

__all__ = ["CoatedConductor", "beneath", "MAX_REFLECTANCE", "COSINE_NODES", "AZIMUTH_NODES", "END_NODES",
           "TABLE_AZIMUTHS"]

# pbrt-v4 clamps the conductor's reflectance to [0, 0.9999] ("Avoid r==1 NaN case").
MAX_REFLECTANCE = 0.9999

# Gauss-Legendre nodes on each side of the critical cosine, midpoints over the azimuth difference in [0, π], the
# sines of the outside end directions, and the azimuths at which the bounces' sum is tabulated (tests hold each to
# a finer rule).
COSINE_NODES = 12
AZIMUTH_NODES = 64
END_NODES = 33
TABLE_AZIMUTHS = 65


@functools.cache
def _legendre(n: int):
    """Gauss-Legendre nodes and weights of n points on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@functools.cache
def _azimuths(n: int):
    """Midpoints φ_j over [0, π] and the matrix taking samples at them to cosine coefficients (m = 0..n − 1)."""
    phi = (np.arange(n) + 0.5) * math.pi / n
    m = np.arange(n)[:, None]
    to_coefficients = np.cos(m * phi[None, :]) * np.where(m == 0, 1.0, 2.0) / n
    return phi, to_coefficients


def _kernel_coefficients(a, b, conductor, xp):
    """F_m(μa, μb): the cosine coefficients in Δφ of f_c(u, v) for u of (sine, cosine) ``a`` = (sa, μa), v of ``b``,
    ``(M, A, B, C)`` (the sines given, not derived: √(1 − μ²) has no derivative at μ = 1)."""
    phi, to_coefficients = _azimuths(AZIMUTH_NODES)
    (sa, mu_a), (sb, mu_b) = a, b
    cos, sin = np.cos(phi)[:, None, None], np.sin(phi)[:, None, None]
    shape = (phi.shape[0], mu_a.shape[0], mu_b.shape[0])
    u = xp.stack(xp.broadcast_arrays(sa[:, None], xp.zeros(shape), mu_a[:, None]), axis=-1)
    v = xp.stack(xp.broadcast_arrays(sb * cos, sb * sin, mu_b), axis=-1)
    # The azimuths on the leading axis: the projection is then one product with the samples as they lie (twice as
    # fast a fit as with them third).
    samples = conductor(LocalPair.from_dirs(v, u, xp=xp))  # (φ, A, B, C)
    return xp.einsum("mj,jabc->mabc", xp.asarray(to_coefficients), samples)


def _bounces(eta, conductor, xp):
    """Σ_{k=1}^{K−1} 𝒦^k f_c (module doc) between end directions refracted from the outside sines ``s_j`` =
    j/(`END_NODES` − 1), as cosine coefficients in Δφ, ``(M, E, E, C)``."""
    x, w = _legendre(COSINE_NODES)
    critical = xp.sqrt(1.0 - 1.0 / (eta * eta))
    mu = xp.concatenate([critical * x, critical + (1.0 - critical) * x])
    width = xp.concatenate([critical * w, (1.0 - critical) * w])
    nodes = (xp.sqrt(1.0 - mu * mu), mu)
    s = np.linspace(0.0, 1.0, END_NODES) / eta  # the refracted sines
    ends = (s, xp.sqrt(1.0 - s * s))
    # 𝒦's weight of the intermediate direction: the cosine rule, |cos v| Tr(v)² from the two crossings, and the
    # interface's reflection from inside (total beyond the critical angle).
    weight = width * mu * slab_transmittance(mu, xp) ** 2 * dielectric(mu, eta, 1.0, xp)
    m = np.arange(AZIMUTH_NODES)
    factor = xp.asarray(np.where(m == 0, 2.0 * math.pi, math.pi) * (-1.0) ** m)[:, None, None, None]
    middle = factor * _kernel_coefficients(nodes, nodes, conductor, xp) * weight[None, None, :, None]  # (M, G, G, C)
    to_ends = _kernel_coefficients(ends, nodes, conductor, xp)  # (M, E, G, C)
    first = factor * to_ends * weight[None, None, :, None]
    last = xp.swapaxes(to_ends, 1, 2)  # f_c is reciprocal: (M, G, E, C)
    chain, total = last, last
    for _ in range(MAX_DEPTH // 2 - 2):
        chain = xp.einsum("mabc,mbdc->madc", middle, chain)
        total = total + chain
    return xp.einsum("mabc,mbdc->madc", first, total)


def _table(coefficients, xp):
    """The bounces' sum at `TABLE_AZIMUTHS` azimuth differences evenly spaced over [0, π], with one node mirrored
    beyond each end (the sum is even and 2π-periodic in Δφ), ``(E, E, TABLE_AZIMUTHS + 2, C)``."""
    psi = np.linspace(0.0, math.pi, TABLE_AZIMUTHS)
    step = psi[1]
    psi = np.concatenate([[-step], psi, [math.pi + step]])
    basis = np.cos(np.arange(AZIMUTH_NODES)[:, None] * psi[None, :])
    return xp.einsum("mt,mabc->abtc", xp.asarray(basis), coefficients)


def _extended(table, axis: int, xp):
    """The table with one node more beyond each end of an axis, by Keys' boundary condition (Keys 1981, Eqs. 25-26:
    f(x₋₁) = 3 f(x₀) − 3 f(x₁) + f(x₂)), which keeps the interpolation's third order up to the ends."""
    table = xp.moveaxis(table, axis, 0)
    low = 3.0 * table[0] - 3.0 * table[1] + table[2]
    high = 3.0 * table[-1] - 3.0 * table[-2] + table[-3]
    return xp.moveaxis(xp.concatenate([low[None], table, high[None]], axis=0), 0, axis)


def _read(table, s_o, s_i, dphi, xp):
    """The table read at the pairs' outside sines and azimuth differences (Keys' cubic convolution on each axis;
    the sines' axes extended by `_extended`, the azimuths' by the mirrored nodes of `_table`)."""
    ends = np.linspace(0.0, 1.0, END_NODES)
    table = _extended(_extended(table, 0, xp), 1, xp)
    io, to = cubic.cell(ends, s_o, xp)
    ii, ti = cubic.cell(ends, s_i, xp)
    # The azimuth axis carries one mirrored node beyond each end: its cells are indexed from the first inner node.
    step = math.pi / (TABLE_AZIMUTHS - 1)
    c = xp.clip(dphi / step, 0.0, TABLE_AZIMUTHS - 1.0)
    ip = xp.minimum(xp.floor(c), TABLE_AZIMUTHS - 2).astype("int32")
    tp = c - ip
    # The 4 × 4 × 4 nodes around each pair in one gather from the flattened table (every axis carries one node
    # before its first: index + k).
    shape = table.shape
    k = np.arange(4)
    index = (((io[..., None, None, None] + k[:, None, None]) * shape[1] + ii[..., None, None, None] + k[:, None])
             * shape[2] + ip[..., None, None, None] + k)
    weight = (xp.stack(cubic.weights(to), -1)[..., :, None, None] * xp.stack(cubic.weights(ti), -1)[..., None, :, None]
              * xp.stack(cubic.weights(tp), -1)[..., None, None, :])
    nodes = table.reshape(-1, shape[3])[index.reshape(index.shape[:-3] + (64,))]  # (..., 64, C)
    return xp.einsum("...n,...nc->...c", weight.reshape(weight.shape[:-3] + (64,)), nodes)


def beneath(pair: LocalPair, eta, conductor, xp):
    """f(ωo, ωi) of the module doc at the pairs (all of it: the interface reflects nothing off its mirror direction).

    Arguments:
        pair: the direction pairs (`brdffit.geometry.LocalPair`, ``(...)``).
        eta: the interface's index of refraction (scalar, above 1).
        conductor: f_c as a function of a `LocalPair` inside the slab, returning ``(..., C)``.
        xp: ``numpy`` or ``jax.numpy``.

    Returns:
        ``(..., C)`` in 1/sr.
    """
    wo, wi = pair.wo, pair.wi
    mu_o, mu_i = xp.clip(wo[..., 2], 0.0, 1.0), xp.clip(wi[..., 2], 0.0, 1.0)
    s_o, s_i = xp.sqrt(1.0 - mu_o * mu_o), xp.sqrt(1.0 - mu_i * mu_i)
    # The refracted directions, pointing up: horizontal components divided by η (Snell), azimuths kept.
    cos_u0, cos_ui = xp.sqrt(1.0 - (s_o / eta) ** 2), xp.sqrt(1.0 - (s_i / eta) ** 2)
    u0 = xp.stack([wo[..., 0] / eta, wo[..., 1] / eta, cos_u0], axis=-1)
    ui = xp.stack([wi[..., 0] / eta, wi[..., 1] / eta, cos_ui], axis=-1)
    dphi = xp.arctan2(xp.abs(wo[..., 0] * wi[..., 1] - wo[..., 1] * wi[..., 0]),
                      wo[..., 0] * wi[..., 0] + wo[..., 1] * wi[..., 1])  # in [0, π]; 0 where a sine is 0
    direct = conductor(LocalPair.from_dirs(ui, u0, xp=xp))
    bounced = _read(_table(_bounces(eta, conductor, xp), xp), s_o, s_i, dphi, xp)
    through = ((1.0 - dielectric(mu_o, 1.0, eta, xp)) * (1.0 - dielectric(mu_i, 1.0, eta, xp)) / (eta * eta)
               * slab_transmittance(cos_u0, xp) * slab_transmittance(cos_ui, xp))
    above = (wo[..., 2] > 0.0) & (wi[..., 2] > 0.0)
    return xp.where(above[..., None], through[..., None] * (direct + bounced), 0.0)


@dataclasses.dataclass(frozen=True)
class CoatedConductor(Lobe):
    """pbrt-v4's ``coatedconductor`` with a smooth interface (``interface.roughness`` 0, ``interface.eta`` η) over a
    conductor (``conductor.eta``, ``conductor.k``, ``conductor.roughness`` = α with ``remaproughness`` false),
    thickness 0.01, albedo 0, maxdepth 10: the walk's expectation (module doc)."""

    name = "coatedconductor"
    stand_in = "ggx(fresnel=conductor)"
    reference = ("pbrt-v4 (Pharr, Jakob & Humphreys, Physically Based Rendering, 4th ed., §14.3): "
                 "CoatedConductorMaterial, LayeredBxDF<DielectricBxDF, ConductorBxDF, true>::f with a smooth "
                 "interface, src/pbrt/materials.cpp, bxdfs.h; its expectation by quadrature "
                 "(brdffit.models.coatedconductor)")

    def param_specs(self):
        return (
            ParamSpec("reflectance", 0.7, 0.0, MAX_REFLECTANCE, colour=True,
                      doc='the metal\'s normal reflectance in air r: "rgb conductor.eta" 1 and "rgb conductor.k" '
                          '2√r/√(1 − r), the index pbrt-v4\'s "reflectance" sets (divided by interface.eta)'),
            roughness("conductor_roughness", default=0.2,
                      doc='"float conductor.roughness" with "bool remaproughness" false: the metal\'s '
                          'Trowbridge-Reitz α'),
            ParamSpec("interface_eta", 1.5, MIN_INTERFACE_ETA, MAX_INTERFACE_ETA, unit="1",
                      doc='"float interface.eta": the smooth coat\'s index of refraction'),
        )

    def peaks(self, params):
        # The conductor's highlight, seen through the coat: refraction widens it about η times near the normal.
        return (Peak("half", scalar(params, "conductor_roughness") * scalar(params, "interface_eta")),)

    def __call__(self, params, pair: LocalPair):
        eta, r = params["interface_eta"], params["reflectance"]
        # CoatedConductorMaterial::GetBxDF: η_c = 1, k_c = 2√r/√(1 − r) (the index whose normal reflectance in air
        # is r), both divided by the coat's index.
        k = 2.0 * jnp.sqrt(r) / jnp.sqrt(1.0 - r)
        conductor = conductor_bxdf(params["conductor_roughness"], jnp.ones_like(r) / eta, k / eta)
        return beneath(pair, eta, conductor, jnp)
