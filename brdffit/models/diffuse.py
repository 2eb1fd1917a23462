"""Diffuse lobes: Lambert and Oren-Nayar."""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from .lobe import Lobe
from .specs import RHO_D

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Lambert", "OrenNayar"]


@dataclasses.dataclass(frozen=True)
class Lambert(Lobe):
    """Lambertian diffuse reflection: f = ρd/π."""

    name = "lambert"
    reference = "Lambert, Photometria (1760)"

    def param_specs(self):
        return (RHO_D,)

    def __call__(self, params, pair: LocalPair):
        return params["rho_d"] / jnp.pi


@dataclasses.dataclass(frozen=True)
class OrenNayar(Lobe):
    """Oren & Nayar (1994), qualitative model (their Eq. 30).

    f = ρd/π (A + B max(0, cos(φi − φo)) sinα tanβ), A = 1 − 0.5σ²/(σ² + 0.33), B = 0.45σ²/(σ² + 0.09),
    α = max(θi, θo), β = min(θi, θo). Because {α, β} = {θi, θo}, cos(φi − φo) sinα tanβ equals
    (ωi,xy · ωo,xy)/max(cosθi, cosθo), which is how it is evaluated here: no azimuth is formed, so values and
    gradients stay finite at normal incidence.
    """

    name = "oren-nayar"
    reference = "Oren & Nayar, Generalization of Lambert's reflectance model, SIGGRAPH 1994, Eq. 30"

    def param_specs(self):
        return (
            RHO_D,
            ParamSpec("sigma", 0.3, 0.0, math.pi / 2, unit="rad", doc="standard deviation of facet slope angle"),
        )

    def __call__(self, params, pair: LocalPair):
        s2 = params["sigma"] ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        dot_xy = pair.wi[..., 0] * pair.wo[..., 0] + pair.wi[..., 1] * pair.wo[..., 1]
        term = jnp.maximum(dot_xy, 0.0) / jnp.maximum(pair.cos_i, pair.cos_o)
        return params["rho_d"] / jnp.pi * (a + b * term)[..., None]
