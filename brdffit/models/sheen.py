"""Sheen lobes for cloth and felt: Burley's Schlick-shaped sheen and the "Charlie" microfacet sheen of Estevez and
Kulla; and the maths of Zeltner et al.'s microfibre sheen, which the OpenPBR and Blender models layer over a base."""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import TINY, LocalPair, safe_sqrt
from ..params import ParamSpec
from .fresnel import schlick_weight
from .lobe import Lobe
from .specs import KS

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Sheen", "CharlieSheen", "charlie_lambda", "charlie_distribution", "charlie_visibility",
           "zeltner_sheen_fit", "zeltner_sheen"]

# Estevez & Kulla (2017), Table 1: the coefficients (a, b, c, d, e) of their fit of the Charlie distribution's
# log Λ, at r = (1 − α)² = 0 and at r = 1 (linearly interpolated between).
_CHARLIE_FIT = ((21.5473, 3.82987, 0.19823, -1.97760, -4.32054),
                (25.3245, 3.32435, 0.16801, -1.27393, -4.85967))


@dataclasses.dataclass(frozen=True)
class Sheen(Lobe):
    """Burley's sheen (Physically-based shading at Disney, SIGGRAPH 2012 course notes, and its reference code, the
    BRDF Explorer's disney.brdf): f = ks (1 − cosθd)⁵, θd the angle between ωi and the half vector, a Schlick-shaped grazing
    retro-reflection added to the diffuse (the Disney BRDF's ks = sheen · mix(1, tint, sheen_tint), without 1/π).
    Reciprocal."""

    name = "sheen"
    reference = "Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes (the Disney BRDF's sheen)"

    def param_specs(self):
        return (dataclasses.replace(KS, doc="sheen amplitude"),)

    def __call__(self, params, pair: LocalPair):
        return params["ks"] * schlick_weight(pair.cos_d)[..., None]


def charlie_lambda(cos_v, alpha, xp=jnp):
    """Smith's Λ of the Charlie distribution, Estevez & Kulla (2017)'s fit: exp(L(cosθ)) for cosθ < 1/2, else
    exp(2 L(1/2) − L(1 − cosθ)), L(x) = a/(1 + b x^c) + d x + e, (a, ..., e) interpolated linearly in (1 − α)²
    between the rows of their Table 1 (`_CHARLIE_FIT`). ``xp``: ``jax.numpy``, or ``numpy`` for tables computed
    on the host."""
    r = (1.0 - alpha) ** 2
    a, b, c, d, e = (lo + (hi - lo) * r for lo, hi in zip(*_CHARLIE_FIT))

    def log_lambda(x):
        # x^c as 0 at x = 0 (normal incidence, where 1 − cosθ = 0), with the gradient 0 there (x^c ln x: NaN).
        positive = x > 0.0
        power = xp.where(positive, xp.exp(c * xp.log(xp.where(positive, x, 1.0))), 0.0)
        return a / (1.0 + b * power) + d * x + e

    low = cos_v < 0.5
    return xp.exp(xp.where(low, log_lambda(cos_v), 2.0 * log_lambda(0.5) - log_lambda(1.0 - cos_v)))


def charlie_distribution(cos_h, alpha, xp=jnp):
    """The Charlie distribution of fibre normals, Estevez & Kulla (2017), Eq. 2: D(h) = (2 + 1/α) sin^(1/α)θh/(2π).

    Arguments:
        cos_h: n·h, any shape.
        alpha: the fibre roughness α in (0, 1], broadcastable against ``cos_h``.
        xp: ``jax.numpy``, or ``numpy`` for tables computed on the host.

    Returns:
        D in 1/sr, the shape of the broadcast; sin²θh is floored at TINY, so the value and its gradient stay finite
        at θh = 0.
    """
    sin2 = xp.maximum(1.0 - cos_h * cos_h, TINY)
    return (2.0 + 1.0 / alpha) * xp.exp(0.5 / alpha * xp.log(sin2)) / (2.0 * math.pi)


def charlie_visibility(cos_i, cos_o, alpha, xp=jnp):
    """The Charlie sheen's visibility V = G/(4 cosθi cosθo), G = 1/(1 + Λ(ωi) + Λ(ωo)) the height-correlated Smith
    term with Estevez & Kulla's fitted Λ (`charlie_lambda`): the "sheen visibility" of KHR_materials_sheen
    ("Sheen visibility").

    Arguments:
        cos_i, cos_o: n·ωi and n·ωo (positive), broadcastable.
        alpha: the fibre roughness α.
        xp: ``jax.numpy``, or ``numpy``.

    Returns:
        V, the factor that multiplies D to give the sheen BRDF D V.
    """
    lam_i, lam_o = charlie_lambda(cos_i, alpha, xp), charlie_lambda(cos_o, alpha, xp)
    return 1.0 / ((1.0 + lam_i + lam_o) * (4.0 * cos_i * cos_o))


@dataclasses.dataclass(frozen=True)
class CharlieSheen(Lobe):
    """The "Charlie" sheen of Estevez & Kulla (Production friendly microfacet sheen BRDF, Sony Imageworks 2017):
    a microfacet lobe of fibres, f = ks D(h) G / (4 cosθi cosθo), with the inverted-Gaussian-like distribution

    D(h) = (2 + 1/α) sin^(1/α)θh / (2π)

    and height-correlated Smith masking G = 1/(1 + Λ(ωi) + Λ(ωo)) with their fitted Λ (`charlie_lambda`). Their
    terminator softening (Λ raised to 1 + 2(1 − cosθ)⁸) is a shading-normal device and is left out, as glTF's
    KHR_materials_sheen and MaterialX's ``sheen_bsdf`` leave it out. Reciprocal."""

    name = "charlie-sheen"
    reference = ("Estevez & Kulla, Production friendly microfacet sheen BRDF, Sony Pictures Imageworks, 2017, "
                 "Eqs. 2-3 and Table 1")

    def param_specs(self):
        return (dataclasses.replace(KS, doc="sheen amplitude"),
                ParamSpec("alpha", 0.5, 0.01, 1.0, unit="1", scale=True,
                          doc="fibre roughness (1/α is the exponent of sinθh)"))

    def __call__(self, params, pair: LocalPair):
        alpha = params["alpha"]
        value = charlie_distribution(pair.cos_h, alpha) * charlie_visibility(pair.cos_i, pair.cos_o, alpha)
        return params["ks"] * value[..., None]


def zeltner_sheen_fit(mu, rough, xp=None):
    """MaterialX's fits of Zeltner et al.'s (2022) sheen at view cosine ``mu`` and roughness ``rough``: ``(E, a, b)``,
    the directional albedo (a Gaussian in μ plus an offset, ``mx_zeltner_sheen_dir_albedo``) and the inverse LTC
    matrix's entries (``mx_zeltner_sheen_ltc_aInv``, ``mx_zeltner_sheen_ltc_bInv`` in MaterialX's
    ``libraries/pbrlib/genglsl/lib/mx_microfacet_sheen.glsl``), as the GLSL computes them.

    Arguments:
        mu: cosine of the viewing direction; rough: the sheen roughness in [0.01, 1] (broadcastable).
        xp: the array module (default ``jax.numpy``).

    Returns:
        (E, a, b), each of the broadcast shape.
    """
    xp = jnp if xp is None else xp
    x, y = mu, rough
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    albedo = xp.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2.0 * math.pi)) + o
    a = (2.58126 * x + 0.813703 * y) * y / (1.0 + 0.310327 * x * x + 2.60994 * x * y)
    b = xp.sqrt(xp.maximum(1.0 - x, 0.0)) * (y - 1.0) * y ** 3 / (0.0000254053 + 1.71228 * x - 1.71506 * x * y
                                                                   + 1.34174 * y * y)
    return albedo, a, b


def zeltner_sheen(pair: LocalPair, mu_o, rough):
    """Zeltner et al.'s sheen at the pair, with MaterialX's fits (`zeltner_sheen_fit`): ``(E(μo), E D_LTC(ωi)/μi)``,
    its albedo at the view and its f without the colour. D_LTC is the linearly transformed cosine of the view: in
    the frame with X along ωo's projection on the surface and Y = n × X, ω = (ωi·X, ωi·Y, μi) maps to
    ω' = (a ω_x + b μi, a ω_y, μi) and D_LTC = (ω'_z/π) (a/|ω'|²)² (``mx_zeltner_sheen_brdf``; Cycles'
    ``bsdf_sheen_eval`` has the same form). D_LTC integrates to 1 over the hemisphere.

    Arguments:
        pair: the direction pairs; mu_o: the view cosines (clamped as the caller's renderer does).
        rough: the sheen roughness, clamped as the caller's renderer does.

    Returns:
        (E, f), each of the pairs' shape.
    """
    albedo, a, b = zeltner_sheen_fit(mu_o, rough)
    wi, wo = pair.wi, pair.wo
    # ωi in the LTC's frame: X along ωo's tangential part (any frame where ωo = n: there b = 0 and D_LTC depends
    # on the tangential length alone).
    tangential = safe_sqrt(wo[..., 0] ** 2 + wo[..., 1] ** 2, tiny=0.0)
    ok = tangential > 0.0
    scale = jnp.where(ok, 1.0 / jnp.where(ok, tangential, 1.0), 0.0)
    x_i = jnp.where(ok, (wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]) * scale, wi[..., 0])
    y_i = jnp.where(ok, (wo[..., 0] * wi[..., 1] - wo[..., 1] * wi[..., 0]) * scale, wi[..., 1])
    z_i = wi[..., 2]
    ox, oy = a * x_i + b * z_i, a * y_i
    length2 = ox * ox + oy * oy + z_i * z_i
    ltc = jnp.maximum(z_i, 0.0) / jnp.pi * (a / length2) ** 2
    return albedo, albedo * ltc / pair.cos_i
