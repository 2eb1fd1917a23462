"""Two-tone (toon) lobes for non-photorealistic materials: a shaded/lit diffuse and a hard specular highlight.

The hard edge of cel shading is a logistic step S(x) = 1/(1 + e^(−x)) of width ``width`` (default 0.02, held
fixed by fits unless freed), so the lobes stay differentiable. The diffuse lobe is not reciprocal: it switches on cosθi
alone, so swapping ωi and ωo changes the result. The specular lobe depends on r·ωo, which is symmetric in ωi
and ωo, so it is reciprocal.
"""

from __future__ import annotations

import dataclasses
import math

from .._lazy import module
from ..geometry import LocalPair, logistic, mirror
from ..params import ParamSpec
from .lobe import Lobe
from .peaks import MIRROR, Peak, scalar
from .specs import KS, RHO_D

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX

__all__ = ["ToonDiffuse", "ToonSpecular"]

_REFERENCE = "Lake et al., Stylized rendering techniques for scalable real-time 3D animation, NPAR 2000"


def _width() -> ParamSpec:
    return ParamSpec("width", 0.02, 0.0, 1.0, unit="1", doc="width of the logistic transition", fixed=True)


@dataclasses.dataclass(frozen=True)
class ToonDiffuse(Lobe):
    """(rho_shade + (rho_d − rho_shade) S((cosθi − threshold)/width))/π: lit above the threshold, shaded below."""

    name = "toon-diffuse"
    stand_in = "lambert"
    reference = _REFERENCE
    reciprocal = False

    def param_specs(self):
        return (
            RHO_D,
            ParamSpec("rho_shade", 0.1, 0.0, 1.0, colour=True, unit="1", doc="albedo of the shaded tone", linear=True),
            ParamSpec("threshold", 0.3, 0.0, 1.0, unit="1", doc="cosθi at which the tone switches"),
            _width(),
        )

    def __call__(self, params, pair: LocalPair):
        step = logistic((pair.cos_i - params["threshold"]) / params["width"])[..., None]
        return (params["rho_shade"] + (params["rho_d"] - params["rho_shade"]) * step) / jnp.pi


@dataclasses.dataclass(frozen=True)
class ToonSpecular(Lobe):
    """ks S((r·ωo − threshold)/width)/π with r the mirror direction of ωi: a flat highlight disc."""

    name = "toon-specular"
    reference = _REFERENCE

    def param_specs(self):
        return (
            KS,
            ParamSpec("threshold", 0.95, 0.0, 1.0, unit="1", doc="r·ωo above which the highlight is on"),
            _width(),
        )

    def peaks(self, params):
        """A disc r·ωo > threshold about the mirror direction: a cone as wide as the disc."""
        threshold = min(max(scalar(params, "threshold"), 1e-6), 1.0 - 1e-12)
        return (Peak("cone", math.tan(math.acos(threshold)), MIRROR),)

    def __call__(self, params, pair: LocalPair):
        r_dot_o = jnp.sum(mirror(pair.wi) * pair.wo, axis=-1)
        return params["ks"] * logistic((r_dot_o - params["threshold"]) / params["width"])[..., None] / jnp.pi
