"""Parameter declarations that several lobes share (declared once, used by each lobe that has the parameter)."""

from __future__ import annotations

import math

from ..params import ParamSpec

__all__ = ["RHO_D", "KS", "exponent", "roughness", "base_color", "metallic", "perceptual_roughness"]

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


def base_color(doc: str) -> ParamSpec:
    """The base colour of a metallic-roughness material (glTF, Blender): a colour in [0, 1], a linear amplitude
    (those materials are affine in it, channel by channel)."""
    return ParamSpec("base_color", 0.5, 0.0, 1.0, colour=True, linear=True, doc=doc)


def metallic(doc: str) -> ParamSpec:
    """The metalness of a metallic-roughness material: the weight in [0, 1] of its metal against its dielectric."""
    return ParamSpec("metallic", 0.0, 0.0, 1.0, doc=doc)


def perceptual_roughness(doc: str) -> ParamSpec:
    """The roughness r of a metallic-roughness material, GGX α = r² (Burley 2012): in [√MIN_ROUGHNESS, 1], so that
    α stays at least `MIN_ROUGHNESS`."""
    return ParamSpec("roughness", 0.5, math.sqrt(MIN_ROUGHNESS), 1.0, scale=True, doc=doc)
