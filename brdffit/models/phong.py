"""Cosine-power lobes: the modified (normalised) Phong and Blinn-Phong lobes."""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair, mirror, safe_pow
from .lobe import Lobe
from .peaks import MIRROR, Peak, power_width, scalar
from .specs import KS, exponent

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Phong", "BlinnPhong"]


@dataclasses.dataclass(frozen=True)
class Phong(Lobe):
    """Modified Phong, Lafortune & Willems (1994), Eq. 6: f = ks (n + 2)/(2π) max(0, r·ωo)^n, r = 2(n·ωi)n − ωi.

    Reciprocal (r·ωo is symmetric in ωi, ωo) and energy conserving for ks <= 1.
    """

    name = "phong"
    reference = "Lafortune & Willems, Using the modified Phong reflectance model for physically based rendering, 1994"

    def param_specs(self):
        return (KS, exponent())

    def peaks(self, params):
        return (Peak("cone", power_width(scalar(params, "n")), MIRROR),)  # (r·ωo)ⁿ about the mirror direction r

    def __call__(self, params, pair: LocalPair):
        r_dot_o = jnp.sum(mirror(pair.wi) * pair.wo, axis=-1)
        n = params["n"]
        return params["ks"] * ((n + 2.0) / (2.0 * jnp.pi) * safe_pow(r_dot_o, n))[..., None]


@dataclasses.dataclass(frozen=True)
class BlinnPhong(Lobe):
    """Normalised Blinn-Phong: f = ks (n + 8)/(8π) (n·h)^n (Akenine-Möller et al., Real-Time Rendering, 3rd ed.,
    Eq. 7.48; Blinn 1977 for the half-vector lobe). Reciprocal; the (n + 8)/(8π) factor is an approximate
    normalisation, so albedo can exceed ks slightly."""

    name = "blinn-phong"
    reference = "Blinn, Models of light reflection for computer synthesized pictures, SIGGRAPH 1977"

    def param_specs(self):
        return (KS, exponent())

    def peaks(self, params):
        return (Peak("half", power_width(scalar(params, "n"))),)

    def __call__(self, params, pair: LocalPair):
        n = params["n"]
        return params["ks"] * ((n + 8.0) / (8.0 * jnp.pi) * safe_pow(pair.cos_h, n))[..., None]
