r"""pbrt-v4's ``mix`` of a ``diffuse`` and a ``conductor`` material, as pbrt-v4 evaluates it.

pbrt-v4 (github.com/mmp/pbrt-v4; Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed., 2023):

- ``diffuse`` (``src/pbrt/materials.h``, ``DiffuseMaterial``; ``src/pbrt/bxdfs.h``, ``DiffuseBxDF::f``;
  book §9.2): R/π, with ``rgb reflectance`` R an albedo spectrum (the scene parser refuses an RGB component
  outside [0, 1], ``src/pbrt/paramdict.cpp``);
- ``conductor`` (``ConductorMaterial``, ``ConductorBxDF::f``; book §9.4, §9.6): with ``bool remaproughness`` false
  the ``float roughness`` is the Trowbridge-Reitz α itself, and
  f = F_complex(|ωo·h|; η + ik) D(h) G(ωi, ωo) / (4 cosθi cosθo), D the Trowbridge-Reitz distribution
  1/(π α² cos⁴θh (1 + tan²θh/α²)²), G = 1/(1 + Λ(ωi) + Λ(ωo)) the height-correlated Smith term with
  Λ = (√(1 + α² tan²θ) − 1)/2 (``src/pbrt/util/scattering.h``, ``TrowbridgeReitzDistribution::D``, ``Lambda``,
  ``G``; book §9.6.1-9.6.3), F_complex the Fresnel reflectance of the complex index η + ik (``FrComplex``; book
  §9.3.6); k = 0 gives a dielectric's Fresnel term. A distribution with α < 1e-3 is a perfect mirror
  (``TrowbridgeReitzDistribution::EffectivelySmooth``), whose f is 0 off the delta: α is declared from 1e-3;
- ``mix`` (``MixMaterial::ChooseMaterial``, ``src/pbrt/materials.h``; book §10.5): at each shading point pbrt picks
  ``materials[1]`` when a hash of the point and ωo falls below ``float amount`` t, else ``materials[0]``: a
  stochastic choice whose expected BSDF, over the points of a pixel, is the convex combination.

So, with the diffuse first and the conductor second,

    f = (1 − t) R/π + t F_complex(ωo·h; η, k) D(h; α) G(ωi, ωo) / (4 cosθi cosθo),

reciprocal, and affine in R channel by channel (R is a linear amplitude with basis (1 − t)/π). Every parameter is
declared in the range pbrt-v4 takes, so a fit is a material the exporter writes as it is (`brdffit.export.pbrt`).
The conductor term is brdffit's Cook-Torrance lobe with the GGX (Trowbridge-Reitz) distribution, height-correlated
Smith masking and the conductor Fresnel term (`brdffit.models.cook_torrance`), evaluated with unit amplitude.
"""

from __future__ import annotations

import dataclasses

from .._lazy import module
from ..geometry import LocalPair
from ..params import ParamSpec
from .cook_torrance import CookTorrance
from .lobe import Lobe
from .peaks import Peak, scalar
from .specs import roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["PbrtMaterial", "conductor_bxdf", "MAX_ETA", "MIN_ETA", "MAX_K"]

# pbrt-v4 takes any non-negative RGB for the conductor's "rgb eta" and "rgb k" (unbounded spectra); η = 0 with
# k = 0 would divide by zero in FrComplex, so η starts just above it. [1e-3, 10] covers the metals' indices (silver's
# η ≈ 0.05-0.16 over the visible, aluminium's k ≈ 6-8) and, with k = 0, every dielectric; k up to 20 as brdffit's
# conductor Fresnel term declares it.
MIN_ETA, MAX_ETA, MAX_K = 1e-3, 10.0, 20.0

# pbrt-v4's conductor BxDF in brdffit's terms: Trowbridge-Reitz (GGX) D, height-correlated Smith G, FrComplex.
_CONDUCTOR = CookTorrance(distribution="ggx", shadowing="smith-correlated", fresnel="conductor")


def conductor_bxdf(alpha, eta, k):
    """pbrt-v4's ``ConductorBxDF::f`` of Trowbridge-Reitz width α and complex index η + ik, as a function of a
    `brdffit.geometry.LocalPair` returning ``(..., C)`` (η, k of shape ``(C,)``)."""
    return lambda pair: _CONDUCTOR({"ks": 1.0, "m": alpha, "eta": eta, "k": k}, pair)


@dataclasses.dataclass(frozen=True)
class PbrtMaterial(Lobe):
    """pbrt-v4's ``mix`` (amount t) of a ``diffuse`` (reflectance R) and a ``conductor`` (η, k, roughness α with
    ``remaproughness`` false): f = (1 − t) R/π + t F_complex D G/(4 cosθi cosθo) (module doc)."""

    name = "pbrt"
    stand_in = "lambert+ggx(fresnel=conductor)"
    reference = ("pbrt-v4 (Pharr, Jakob & Humphreys, Physically Based Rendering, 4th ed., §9.2, §9.3.6, §9.4, §9.6, "
                 "§10.5): MixMaterial of DiffuseMaterial and ConductorMaterial, src/pbrt/materials.h, bxdfs.h, "
                 "util/scattering.h")
    offset = True  # the conductor term does not scale with R

    def param_specs(self):
        return (
            ParamSpec("reflectance", 0.5, 0.0, 1.0, colour=True, linear=True,
                      doc='diffuse "rgb reflectance" R: the diffuse part reflects (1 − amount) R/π'),
            ParamSpec("amount", 0.5, 0.0, 1.0,
                      doc='mix "float amount" t: the probability of the conductor, its weight in the mix'),
            roughness("roughness", default=0.2,
                      doc='conductor "float roughness" with "bool remaproughness" false: the Trowbridge-Reitz α'),
            ParamSpec("eta", 1.5, MIN_ETA, MAX_ETA, colour=True,
                      doc='conductor "rgb eta": real part of the complex index'),
            ParamSpec("k", 0.0, 0.0, MAX_K, colour=True,
                      doc='conductor "rgb k": extinction coefficient (0: a dielectric\'s Fresnel term)'),
        )

    def peaks(self, params):
        return (Peak("half", scalar(params, "roughness")),)  # the conductor's α (remaproughness false)

    def __call__(self, params, pair: LocalPair):
        t = params["amount"]
        conductor = conductor_bxdf(params["roughness"], params["eta"], params["k"])(pair)
        return (1.0 - t) * params["reflectance"] / jnp.pi + t * conductor
