"""Löw et al.'s ABC models: the smooth-surface model and the microfacet model with the ABC distribution (Löw,
Kronander, Ynnerman & Unger, BRDF models for accurate and efficient rendering of glossy surfaces, ACM TOG 31(1),
2012), as the BRDF benchmark BBM (Ngan, Löw, Bagher fits; bsdfbenchmark/bbm) evaluates them.

Both scale an unnormalised ABC curve S(x) = (1 + B x)^(−C) (a K-correlation spectrum: A its height, B its width,
C its fall-off) by an amplitude A and the exact dielectric Fresnel term of index η.
"""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import LocalPair, safe_sqrt
from ..params import ParamSpec
from . import fresnel as fr
from .lobe import Lobe
from .microfacet import v_cavity
from .peaks import Peak, scalar

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["ABCSmooth", "ABCMicrofacet"]

AMPLITUDE = ParamSpec("A", 1.0, 0.0, math.inf, colour=True, unit="1/sr", doc="height of the ABC curve",
                      scale=True, linear=True)
WIDTH = ParamSpec("B", 100.0, 1e-3, 1e7, unit="1", doc="inverse width of the ABC curve", scale=True)
FALL_OFF = ParamSpec("C", 1.0, 1e-3, 20.0, unit="1", doc="fall-off exponent of the ABC curve", scale=True)
ETA = ParamSpec("eta", 1.5, 1.0, 4.0, unit="1", doc="refractive index of the Fresnel term")
# Both models' parameters, in order.
PARAMETERS = (AMPLITUDE, WIDTH, FALL_OFF, ETA)


def _abc(x, b, c):
    """S(x) = (1 + B x)^(−C), as exp(−C log1p(B x)) (x ≥ 0)."""
    return jnp.exp(-c * jnp.log1p(b * x))


@dataclasses.dataclass(frozen=True)
class ABCSmooth(Lobe):
    """Löw et al. 2012's smooth-surface model (their Eqs. 10, 12, 14): f = A S(‖ωi,xy + ωo,xy‖²) F(cosθd, η) with
    cosθd = √(1 − ‖ωi,xy − ωo,xy‖²/4), the projected difference of the two directions (no shadowing). Its peak
    sits where the projections cancel: the mirror direction."""

    name = "abc-smooth"
    reference = ("Löw, Kronander, Ynnerman & Unger, BRDF models for accurate and efficient rendering of glossy "
                 "surfaces, ACM TOG 31(1), 2012, Eqs. 10-14")

    def param_specs(self):
        return PARAMETERS

    def peaks(self, params):
        """A half-vector peak: ωi + ωo = 2 cosθd h, so ‖ωi,xy + ωo,xy‖² = 4 cos²θd sin²θh, and S = (1 + B x)^−C ≈
        exp(−BC x) for small x: a Beckmann fall-off exp(−θh²/m²) of width m = 1/(2 cosθd √(BC)), at least
        1/(2√(BC))."""
        return (Peak("half", 0.5 / math.sqrt(scalar(params, "B") * scalar(params, "C"))),)

    def __call__(self, params, pair: LocalPair):
        sx, sy = pair.wi[..., 0] + pair.wo[..., 0], pair.wi[..., 1] + pair.wo[..., 1]
        dx, dy = pair.wi[..., 0] - pair.wo[..., 0], pair.wi[..., 1] - pair.wo[..., 1]
        cos_d = safe_sqrt(1.0 - 0.25 * (dx * dx + dy * dy))
        shape = _abc(sx * sx + sy * sy, params["B"], params["C"])
        return params["A"] * (shape[..., None] * fr.dielectric(cos_d[..., None], 1.0, params["eta"]))


@dataclasses.dataclass(frozen=True)
class ABCMicrofacet(Lobe):
    """Löw et al. 2012's microfacet model (their Eq. 15) with the ABC distribution D(h) = S(1 − cosθh), unnormalised
    (A absorbs the scale), Cook & Torrance's V-cavity shadowing and the exact dielectric Fresnel term at θd:
    f = A S(1 − cosθh) F(cosθd, η) G / (π cosθi cosθo), the π of Cook & Torrance's form as BBM and Löw et al.'s
    supplemental MERL fits use it."""

    name = "abc-microfacet"
    reference = ("Löw, Kronander, Ynnerman & Unger, BRDF models for accurate and efficient rendering of glossy "
                 "surfaces, ACM TOG 31(1), 2012, Eq. 15")

    def param_specs(self):
        return PARAMETERS

    def peaks(self, params):
        """A half-vector peak: 1 − cosθh ≈ θh²/2 and S ≈ exp(−BC x) for small x, a Beckmann fall-off
        exp(−θh²/m²) with m = √(2/(BC))."""
        return (Peak("half", math.sqrt(2.0 / (scalar(params, "B") * scalar(params, "C")))),)

    def __call__(self, params, pair: LocalPair):
        d = _abc(1.0 - pair.cos_h, params["B"], params["C"])
        g = v_cavity(pair, None, None)
        geometric = d * g / (jnp.pi * pair.cos_i * pair.cos_o)
        return params["A"] * (geometric[..., None] * fr.dielectric(pair.cos_d[..., None], 1.0, params["eta"]))
