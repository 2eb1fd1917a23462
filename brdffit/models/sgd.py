"""Bagher, Soler & Holzschuch's shifted gamma distribution (SGD) microfacet lobe, with their modified Schlick
Fresnel term and fitted shadowing function (Accurate fitting of measured reflectances using a shifted gamma
micro-facet distribution, Computer Graphics Forum 31(4), 2012), as the BRDF benchmark BBM (bsdfbenchmark/bbm)
evaluates it:

    f = ks F(cosθd) D(h) G1(θi) G1(θo) / (π cosθi cosθo),
    D = K P22(tan²θh) / (π cos⁴θh),  P22(x) = exp(−(α + x/α)) / (α + x/α)^p,
    F = f0 + (1 − f0)(1 − cosθd)⁵ − f1 cosθd,
    G1(θ) = 1 + Λ (1 − exp(c (θ − θ0)^k)) for θ > θ0, else 1.

K normalises D exactly (∫ D cosθh dωh = 1): over the slope plane ∫ P22 dA = π α Γ(1 − p, α), Γ the upper
incomplete gamma function, so K = 1/(α Γ(1 − p, α)) (the paper and BBM fit K; here it follows from α and p). The
shadowing parameters (Λ, c, k, θ0) and f1 are held at values that turn them off unless a fit frees them.
"""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import TINY, LocalPair
from ..params import ParamSpec
from .fresnel import schlick
from .lobe import Lobe
from .peaks import Peak, scalar
from .specs import KS

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX
jax_special = module("jax.scipy.special")

__all__ = ["SGD", "sgd_normalisation"]


def sgd_normalisation(alpha, p):
    """K = 1/(α Γ(1 − p, α)), Γ(s, x) = Γ(s) Q(s, x) the upper incomplete gamma function (p < 1)."""
    s = 1.0 - p
    return 1.0 / (alpha * jnp.exp(jax_special.gammaln(s)) * jax_special.gammaincc(s, alpha))


def _shadowing(cos_v, lam, c, k, theta0):
    """Bagher et al.'s fitted G1: 1 + Λ (1 − exp(c (θ − θ0)^k)) beyond θ0, 1 before."""
    theta = jnp.arccos(jnp.clip(cos_v, -1.0, 1.0))
    beyond = theta > theta0
    excess = jnp.where(beyond, theta - theta0, 1.0)
    return jnp.where(beyond, 1.0 + lam * (1.0 - jnp.exp(c * jnp.exp(k * jnp.log(excess)))), 1.0)


@dataclasses.dataclass(frozen=True)
class SGD(Lobe):
    """The shifted gamma distribution lobe of Bagher et al. 2012 (module doc)."""

    name = "sgd"
    reference = ("Bagher, Soler & Holzschuch, Accurate fitting of measured reflectances using a shifted gamma "
                 "micro-facet distribution, CGF 31(4), 2012")

    def param_specs(self):
        return (
            KS,
            ParamSpec("alpha", 0.1, 1e-4, 1.0, unit="1", doc="SGD shape α (the distribution's width)", scale=True),
            ParamSpec("p", 0.64, 0.01, 0.99, unit="1", doc="SGD shape p (the gamma shift's power; < 1)"),
            ParamSpec("f0", 0.04, 0.0, 1.0, unit="1", doc="Fresnel reflectance at normal incidence"),
            ParamSpec("f1", 0.0, -1.0, 1.0, unit="1", doc="Bagher's Fresnel correction: − f1 cosθd",
                      fixed=True),
            ParamSpec("shadow_lambda", 0.0, -10.0, 10.0, unit="1", doc="fitted shadowing: amplitude Λ",
                      fixed=True),
            ParamSpec("shadow_c", 1.0, -50.0, 50.0, unit="1", doc="fitted shadowing: rate c", fixed=True),
            ParamSpec("shadow_k", 1.0, 0.1, 10.0, unit="1", doc="fitted shadowing: power k", fixed=True),
            ParamSpec("shadow_theta0", math.pi / 2, 0.0, math.pi / 2, unit="rad",
                      doc="fitted shadowing: onset angle θ0 (π/2: no shadowing)", fixed=True),
        )

    def peaks(self, params):
        """A half-vector peak of width √α: P22's exp(−x/α) in x = tan²θh falls like Beckmann's exp(−tan²θh/m²)
        with m² = α (the (α + x/α)^−p factor only lengthens the tail)."""
        return (Peak("half", math.sqrt(scalar(params, "alpha"))),)

    def __call__(self, params, pair: LocalPair):
        alpha, p = params["alpha"], params["p"]
        c2 = pair.cos_h * pair.cos_h
        tan2 = jnp.maximum(1.0 - c2, 0.0) / jnp.maximum(c2, TINY)
        shifted = alpha + tan2 / alpha
        d = sgd_normalisation(alpha, p) * jnp.exp(-shifted - p * jnp.log(shifted)) / (jnp.pi * c2 * c2)
        shadow = (params["shadow_lambda"], params["shadow_c"], params["shadow_k"], params["shadow_theta0"])
        g = _shadowing(pair.cos_i, *shadow) * _shadowing(pair.cos_o, *shadow)
        fresnel = schlick(pair.cos_d, params["f0"]) - params["f1"] * pair.cos_d
        return params["ks"] * (fresnel * d * g / (jnp.pi * pair.cos_i * pair.cos_o))[..., None]
