"""Microfacet distributions and shadowing-masking, defined once and used by every microfacet model.

Each distribution bundles, as pbrt-v4's microfacet distributions do, the normal distribution D(h) and Smith's
auxiliary function Λ(ω), from which G1 and the separable G follow. Roughness is Walter et al.'s (2007) width
parameter (Beckmann m, GGX α).
"""

from __future__ import annotations

import abc
import dataclasses

from .._lazy import module
from ..geometry import TINY, LocalPair, safe_div, safe_sqrt

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX
jax_special = module("jax.scipy.special")

__all__ = ["Distribution", "Beckmann", "GGX", "BlinnPhong", "DISTRIBUTIONS", "v_cavity", "smith", "SHADOWING"]

# Above this Beckmann a = 1/(m tanθ) the shadowing is 1 to double precision (erfc(27) ~ 1e-319).
_BECKMANN_A_MAX = 27.0


def _tan2(cos_theta):
    c2 = cos_theta * cos_theta
    # Finite where cosθ -> 0, so exp(−tan²θ/m²) has the finite derivative 0 there rather than 0·inf = NaN.
    return safe_div(1.0 - c2, c2, fallback=1.0 / TINY)


def _beckmann_lambda(cos_v, m):
    # Walter et al. 2007, Eq. 25 integrated: Λ(a) = (erf(a) − 1)/2 + exp(−a²)/(2a√π), a = 1/(m tanθv),
    # written with erfc so that both terms vanish smoothly for large a.
    sin_v = safe_sqrt(1.0 - cos_v * cos_v)
    a = jnp.minimum(safe_div(cos_v, m * sin_v, fallback=_BECKMANN_A_MAX), _BECKMANN_A_MAX)
    return 0.5 * (jnp.exp(-a * a) / (a * jnp.sqrt(jnp.pi)) - jax_special.erfc(a))


@dataclasses.dataclass(frozen=True)
class Distribution(abc.ABC):
    """A microfacet normal distribution with its Smith shadowing function."""

    name = ""

    @abc.abstractmethod
    def D(self, cos_h, m):
        """Normalised distribution of microfacet normals, ∫ D(h) cosθh dωh = 1."""

    @abc.abstractmethod
    def Lambda(self, cos_v, m):
        """Smith's Λ for a direction with cosine ``cos_v`` (Walter et al. 2007, Eq. 18)."""

    def G1(self, cos_v, m):
        """Smith masking of one direction, G1 = 1/(1 + Λ)."""
        return 1.0 / (1.0 + self.Lambda(cos_v, m))

    def G(self, cos_i, cos_o, m):
        """Separable Smith shadowing-masking G1(ωi) G1(ωo) (Walter et al. 2007, Eq. 23)."""
        return self.G1(cos_i, m) * self.G1(cos_o, m)


@dataclasses.dataclass(frozen=True)
class Beckmann(Distribution):
    """Beckmann distribution, Walter et al. 2007, Eq. 25: D = exp(−tan²θh/m²)/(π m² cos⁴θh)."""

    name = "beckmann"

    def D(self, cos_h, m):
        c2 = cos_h * cos_h
        return jnp.exp(-_tan2(cos_h) / (m * m)) / (jnp.pi * m * m * c2 * c2)

    def Lambda(self, cos_v, m):
        return _beckmann_lambda(cos_v, m)


@dataclasses.dataclass(frozen=True)
class GGX(Distribution):
    """GGX / Trowbridge-Reitz, Walter et al. 2007, Eq. 33: D = α²/(π (cos²θh (α² − 1) + 1)²)."""

    name = "ggx"

    def D(self, cos_h, m):
        a2 = m * m
        t = cos_h * cos_h * (a2 - 1.0) + 1.0
        return a2 / (jnp.pi * t * t)

    def Lambda(self, cos_v, m):
        # Walter et al. 2007, Eq. 34: G1 = 2/(1 + √(1 + α² tan²θv)), i.e. Λ = (√(1 + α² tan²θv) − 1)/2.
        c2 = jnp.maximum(cos_v * cos_v, 1e-30)
        return 0.5 * (jnp.sqrt(1.0 + m * m * (1.0 - c2) / c2) - 1.0)


@dataclasses.dataclass(frozen=True)
class BlinnPhong(Distribution):
    """Normalised power-cosine (Blinn) distribution, Walter et al. 2007, Eq. 30, with exponent αp = 2/m² − 2.

    D = (αp + 2)/(2π) cos^αp θh. Its Smith term uses Walter's Beckmann approximation with
    a = √(αp/2 + 1)/tanθv, which for αp = 2/m² − 2 is the Beckmann a = 1/(m tanθv).
    """

    name = "blinn"

    def D(self, cos_h, m):
        exponent = 2.0 / (m * m) - 2.0
        return (exponent + 2.0) / (2.0 * jnp.pi) * jnp.exp(exponent * jnp.log(cos_h))

    def Lambda(self, cos_v, m):
        return _beckmann_lambda(cos_v, m)


DISTRIBUTIONS = {d.name: d for d in (Beckmann(), GGX(), BlinnPhong())}


def v_cavity(pair: LocalPair, distribution: Distribution, m):
    """Cook & Torrance (1982) V-cavity shadowing: min(1, 2 ch co/(ωo·h), 2 ch ci/(ωo·h)); independent of D."""
    g_o = 2.0 * pair.cos_h * pair.cos_o / pair.cos_d
    g_i = 2.0 * pair.cos_h * pair.cos_i / pair.cos_d
    return jnp.minimum(1.0, jnp.minimum(g_o, g_i))


def smith(pair: LocalPair, distribution: Distribution, m):
    """Separable Smith shadowing-masking of ``distribution`` (Walter et al. 2007, Eq. 23)."""
    return distribution.G(pair.cos_i, pair.cos_o, m)


def no_shadowing(pair: LocalPair, distribution: Distribution, m):
    """No shadowing-masking: G = 1."""
    return jnp.ones_like(pair.cos_h)


SHADOWING = {"v-cavity": v_cavity, "smith": smith, "none": no_shadowing}
