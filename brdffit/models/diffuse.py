"""Diffuse lobes: Lambert, Oren-Nayar and Burley's diffuse with retro-reflection."""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from .fresnel import schlick_weight
from .lobe import Lobe
from .specs import RHO_D

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["Lambert", "OrenNayar", "Burley", "burley_shape"]


@dataclasses.dataclass(frozen=True)
class Lambert(Lobe):
    """Lambertian diffuse reflection: f = ρd/π."""

    name = "lambert"
    stand_in = "lambert"
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
    stand_in = "lambert"
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


def burley_shape(pair: LocalPair, roughness):
    """Burley's diffuse factor (1 + (F_D90 − 1) w(cosθi))(1 + (F_D90 − 1) w(cosθo)), F_D90 = 0.5 + 2 r cos²θd, w the
    Schlick weight (`brdffit.models.fresnel.schlick_weight`); shape ``S``. Burley 2015 writes the same product as a
    diffuse and a retro-reflection term (Mitsuba 3's principled evaluates that form)."""
    f90 = 0.5 + 2.0 * roughness * pair.cos_d * pair.cos_d
    return (1.0 + (f90 - 1.0) * schlick_weight(pair.cos_i)) * (1.0 + (f90 - 1.0) * schlick_weight(pair.cos_o))


@dataclasses.dataclass(frozen=True)
class Burley(Lobe):
    """Burley's diffuse (Physically-based shading at Disney, SIGGRAPH 2012 course, §5.3), the diffuse of the
    Disney BRDF and of Mitsuba 3's and Blender's principled BSDFs:

    f = ρd/π (1 + (F_D90 − 1)(1 − cosθi)⁵)(1 + (F_D90 − 1)(1 − cosθo)⁵),  F_D90 = 0.5 + 2 r cos²θd,

    θd the angle between ωi and the half vector. A rough surface (r = 1) brightens towards grazing on the retro-
    reflective side (F_D90 up to 2.5); a smooth one darkens towards grazing (F_D90 = 0.5). Reciprocal; not energy
    conserving at grazing incidence for large r (Burley's own remark)."""

    name = "burley"
    reference = "Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes, §5.3"

    def param_specs(self):
        return (RHO_D, ParamSpec("roughness", 0.5, 0.0, 1.0, unit="1",
                                 doc="roughness of the retro-reflection term (F_D90 = 0.5 + 2 r cos²θd)"))

    def __call__(self, params, pair: LocalPair):
        return params["rho_d"] / jnp.pi * burley_shape(pair, params["roughness"])[..., None]
