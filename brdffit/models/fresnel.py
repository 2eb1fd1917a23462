"""Fresnel reflectance: Schlick's approximation and the exact unpolarised dielectric and conductor terms.

All functions take the cosine of the angle between the incident direction and the (micro)surface normal and
return the unpolarised reflectance, the mean of the s- and p-polarised reflectances.
"""

from __future__ import annotations

from .._lazy import module
from ..geometry import TINY, safe_sqrt

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["schlick", "schlick_weight", "f82_tint", "normal_reflectance", "dielectric", "conductor", "CONDUCTORS",
           "DIELECTRICS"]

# Complex refractive indices (eta, k) of conductors at about 550 nm, as used in the issue specification.
CONDUCTORS = {
    "gold": (0.370, 2.820),
    "silver": (0.177, 3.638),
    "copper": (0.617, 2.63),
    "steel": (2.485, 3.433),
}

# Real refractive indices of dielectrics.
DIELECTRICS = {
    "vacuum": 1.0,
    "air": 1.00029,
    "ice": 1.31,
    "water": 1.333,
    "fused-quartz": 1.46,
    "glass": 1.5,
    "sapphire": 1.77,
    "diamond": 2.42,
}


def schlick_weight(cos_theta):
    """Schlick's (1994) weight (1 − cosθ)⁵ of a cosine clipped to [0, 1]: the grazing rise of his Fresnel term, and of
    the terms built on it (Burley's diffuse and sheen, SGD's Fresnel term)."""
    return (1.0 - jnp.clip(cos_theta, 0.0, 1.0)) ** 5


def schlick(cos_theta, f0):
    r"""Schlick (1994), Eq. 24: F = f0 + (1 − f0)(1 − cosθ)^5.

    Arguments:
        cos_theta: cosine of the incidence angle on the microsurface, in [0, 1].
        f0: reflectance at normal incidence (broadcastable).

    Returns:
        The reflectance, broadcast shape.
    """
    return f0 + (1.0 - f0) * schlick_weight(cos_theta)


# The angle of Hoffman's F82 tint: cos θ = 1/7 (θ ≈ 82°).
_COS_82 = 1.0 / 7.0


def f82_tint(cos_theta, f0, f82):
    r"""Schlick's term with Hoffman's F82 tint (Hoffman 2023, "Generalization of Adobe's Fresnel model", Eq. 2 with
    F90 = 1 and exponent 5; MaterialX's ``mx_fresnel_hoffman_schlick``): F = S(cosθ; f0) − a cosθ (1 − cosθ)⁶ with
    a = S(1/7; f0) (1 − f82) / ((1/7)(6/7)⁶), S `schlick`'s term, so that F(1/7) = f82 · S(1/7; f0).

    Arguments:
        cos_theta: cosine of the incidence angle on the microsurface (clipped to [0, 1]).
        f0: reflectance at normal incidence; f82: the tint at θ ≈ 82° (broadcastable with ``f0``).

    Returns:
        The reflectance, broadcast shape.
    """
    x = jnp.clip(cos_theta, 0.0, 1.0)
    a = schlick(_COS_82, f0) * (1.0 - f82) / (_COS_82 * (1.0 - _COS_82) ** 6)
    return schlick(x, f0) - a * x * (1.0 - x) ** 6


def normal_reflectance(eta):
    """The dielectric term at normal incidence from air, ((η − 1)/(η + 1))² (Born & Wolf, Sec. 1.5.2): Schlick's f0
    of an index of refraction (glTF's KHR_materials_ior, Cycles' and the principled BRDF's specular)."""
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def dielectric(cos_theta_i, eta_i, eta_t, xp=None):
    r"""Exact unpolarised Fresnel reflectance of a dielectric interface (Born & Wolf, Sec. 1.5.2).

    Snell: η_i sinθi = η_t sinθt; r_s = (η_i cosθi − η_t cosθt)/(η_i cosθi + η_t cosθt),
    r_p = (η_t cosθi − η_i cosθt)/(η_t cosθi + η_i cosθt); F = (r_s² + r_p²)/2, and F = 1 under total internal
    reflection (sinθt >= 1).

    Arguments:
        cos_theta_i: cosine of the incidence angle, in [0, 1].
        eta_i: refractive index of the incident medium.
        eta_t: refractive index of the transmitting medium.
        xp: the array module: ``jax.numpy`` (default) or ``numpy`` (host tables).

    Returns:
        The reflectance in [0, 1].
    """
    xp = jnp if xp is None else xp
    ci = xp.clip(cos_theta_i, 0.0, 1.0)
    sin_t2 = (eta_i / eta_t) ** 2 * (1.0 - ci * ci)
    total = sin_t2 >= 1.0
    ct = safe_sqrt(1.0 - xp.where(total, 0.0, sin_t2), xp)
    rs = (eta_i * ci - eta_t * ct) / xp.maximum(eta_i * ci + eta_t * ct, TINY)
    rp = (eta_t * ci - eta_i * ct) / xp.maximum(eta_t * ci + eta_i * ct, TINY)
    return xp.where(total, 1.0, 0.5 * (rs * rs + rp * rp))


def conductor(cos_theta_i, eta, k):
    r"""Exact unpolarised Fresnel reflectance of a conductor with complex index η + ik, from a medium of index 1.

    The real-arithmetic form of pbrt-v3 (Pharr, Jakob & Humphreys, 3rd ed., Sec. 8.2.1, FrConductor):
    a² + b² = √((η² − k² − sin²θ)² + 4η²k²), a = √((a² + b² + η² − k² − sin²θ)/2),
    R_s = (a² + b² − 2a cosθ + cos²θ)/(a² + b² + 2a cosθ + cos²θ),
    R_p = R_s (cos²θ (a² + b²) − 2a cosθ sin²θ + sin⁴θ)/(cos²θ (a² + b²) + 2a cosθ sin²θ + sin⁴θ),
    F = (R_s + R_p)/2. At normal incidence F = ((η − 1)² + k²)/((η + 1)² + k²).

    Arguments:
        cos_theta_i: cosine of the incidence angle, in [0, 1].
        eta: real part of the relative index (broadcastable).
        k: extinction coefficient (broadcastable).

    Returns:
        The reflectance in [0, 1].
    """
    c = jnp.clip(cos_theta_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t0 = eta * eta - k * k - s2
    a2b2 = safe_sqrt(t0 * t0 + 4.0 * eta * eta * k * k)
    a = safe_sqrt(0.5 * (a2b2 + t0))
    rs = (a2b2 - 2.0 * a * c + c2) / jnp.maximum(a2b2 + 2.0 * a * c + c2, TINY)
    t1 = c2 * a2b2 + s2 * s2
    t2 = 2.0 * a * c * s2
    rp = rs * (t1 - t2) / jnp.maximum(t1 + t2, TINY)
    return 0.5 * (rs + rp)
