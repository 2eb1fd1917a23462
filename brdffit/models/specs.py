"""Parameter declarations that several lobes share (declared once, used by each lobe that has the parameter)."""

from __future__ import annotations

import math

from ..params import ParamSpec

__all__ = ["RHO_D", "KS", "exponent", "roughness"]

RHO_D = ParamSpec("rho_d", 0.5, 0.0, 1.0, colour=True, unit="1", doc="diffuse albedo (reflectance)",
                  linear=True)
KS = ParamSpec("ks", 0.2, 0.0, math.inf, colour=True, unit="1", doc="specular amplitude", scale=True,
               linear=True)

# Smallest roughness width a lobe accepts: narrower lobes are mirrors for any gonio-reflectometer (pbrt-v4 treats
# α < 1e-3 as perfectly smooth, TrowbridgeReitzDistribution::EffectivelySmooth).
MIN_ROUGHNESS = 1e-3


def exponent(name: str = "n", default: float = 20.0, doc: str = "specular exponent (sharpness)") -> ParamSpec:
    """A cosine-power exponent: shape parameter in (0, ∞)."""
    return ParamSpec(name, default, 0.0, math.inf, colour=False, unit="1", doc=doc, scale=True)


def roughness(name: str = "m", default: float = 0.2, doc: str = "microfacet roughness (RMS slope width)") -> ParamSpec:
    """A microfacet width: shape parameter in [MIN_ROUGHNESS, 1]."""
    return ParamSpec(name, default, MIN_ROUGHNESS, 1.0, colour=False, unit="1", doc=doc, scale=True)
