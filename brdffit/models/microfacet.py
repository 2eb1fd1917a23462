"""Microfacet distributions and shadowing-masking, defined once and used by every microfacet model.

Each distribution bundles, as pbrt-v4's microfacet distributions do, the normal distribution D(h) and Smith's
auxiliary function Λ(ω), from which G1 and the separable G follow. Roughness is Walter et al.'s (2007) width
parameter (Beckmann m, GGX α). The Beckmann and GGX distributions also have their anisotropic forms, widths αx along
the tangent x and αy along the bitangent y of docs/conventions.md (Heitz, Understanding the masking-shadowing
function in microfacet-based BRDFs, JCGT 3(2), 2014, §5.3 and Eqs. 80-86: the slopes stretched by (αx, αy), and Λ
that of the isotropic distribution at the projected width α(φ) = √(cos²φ αx² + sin²φ αy²)).

A roughness ``m`` below is a scalar (isotropic) or a pair ``(αx, αy)``; `lambda_of` and `density_of` take either.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
from typing import ClassVar

from .._lazy import module
from ..geometry import TINY, LocalPair, safe_div, safe_sqrt
from ..params import ParamSpec

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX
jax_special = module("jax.scipy.special")
jax_lax = module("jax.lax")

__all__ = ["Distribution", "Beckmann", "GGX", "BlinnPhong", "StudentT", "GTR", "DISTRIBUTIONS", "ANISOTROPIC",
           "v_cavity", "smith", "smith_correlated", "SHADOWING"]

# Above this Beckmann a = 1/(m tanθ) the shadowing is 1 to double precision (erfc(27) ~ 1e-319).
_BECKMANN_A_MAX = 27.0


def _tan2(cos_theta):
    c2 = cos_theta * cos_theta
    # Finite where cosθ -> 0, so exp(−tan²θ/m²) has the finite derivative 0 there rather than 0·inf = NaN.
    return safe_div(1.0 - c2, c2, fallback=1.0 / TINY)


def _beckmann_lambda(cos_v, m):
    # Walter et al. 2007, Eq. 25 integrated: Λ(a) = (erf(a) − 1)/2 + exp(−a²)/(2a√π), a = 1/(m tanθv).
    sin_v = safe_sqrt(1.0 - cos_v * cos_v)
    return _beckmann_lambda_of_a(safe_div(cos_v, m * sin_v, fallback=_BECKMANN_A_MAX))


def _beckmann_lambda_of_a(a):
    # Walter et al. 2007's Λ(a), written with erfc so that both terms vanish smoothly for large a.
    a = jnp.minimum(a, _BECKMANN_A_MAX)
    return 0.5 * (jnp.exp(-a * a) / (a * jnp.sqrt(jnp.pi)) - jax_special.erfc(a))


def _stretched(w, m):
    """(ωx αx)² + (ωy αy)² and ωz of the unit vectors ``w`` (..., 3) for widths ``m = (αx, αy)``: α(φ)² tan²θ is
    the first over the square of the second (Heitz 2014, Eq. 80). ωz is clamped to TINY, as `LocalPair`'s cosines
    are, so that Λ stays finite (and its gradient defined) at the horizon."""
    ax, ay = m
    wx, wy = w[..., 0], w[..., 1]
    return (wx * ax) ** 2 + (wy * ay) ** 2, jnp.maximum(w[..., 2], TINY)


@dataclasses.dataclass(frozen=True)
class Distribution(abc.ABC):
    """A microfacet normal distribution with its Smith shadowing function.

    A distribution with a shape parameter of its own besides the width (the Student-t's tail exponent γ) declares
    it as `tail`; its functions then take its value as ``tail`` (None for the others)."""

    name = ""
    tail: ClassVar[ParamSpec | None] = None

    @abc.abstractmethod
    def D(self, cos_h, m, tail=None):
        """Normalised distribution of microfacet normals, ∫ D(h) cosθh dωh = 1."""

    @abc.abstractmethod
    def Lambda(self, cos_v, m, tail=None):
        """Smith's Λ for a direction with cosine ``cos_v`` (Walter et al. 2007, Eq. 18)."""

    def D_aniso(self, h, m, tail=None):
        """The anisotropic distribution at unit half vectors ``h`` (..., 3), widths ``m = (αx, αy)``; normalised as
        `D`. Only the distributions in `ANISOTROPIC` have one."""
        raise NotImplementedError(f"the {self.name} distribution has no anisotropic form")

    def Lambda_aniso(self, w, m, tail=None):
        """Smith's Λ of the anisotropic distribution for unit directions ``w`` (..., 3), widths ``m = (αx, αy)``."""
        raise NotImplementedError(f"the {self.name} distribution has no anisotropic form")

    def density_of(self, pair: LocalPair, m, tail=None):
        """D(h) of a pair, isotropic for a scalar ``m`` and anisotropic for a pair ``(αx, αy)``."""
        return self.D_aniso(pair.h, m, tail) if isinstance(m, tuple) else self.D(pair.cos_h, m, tail)

    def lambda_of(self, w, cos_v, m, tail=None):
        """Λ of the direction ``w`` (cosine ``cos_v``), isotropic for a scalar ``m``, anisotropic for a pair."""
        return self.Lambda_aniso(w, m, tail) if isinstance(m, tuple) else self.Lambda(cos_v, m, tail)

    def G1(self, cos_v, m, tail=None):
        """Smith masking of one direction, G1 = 1/(1 + Λ)."""
        return 1.0 / (1.0 + self.Lambda(cos_v, m, tail))

    def G(self, cos_i, cos_o, m, tail=None):
        """Separable Smith shadowing-masking G1(ωi) G1(ωo) (Walter et al. 2007, Eq. 23)."""
        return self.G1(cos_i, m, tail) * self.G1(cos_o, m, tail)


@dataclasses.dataclass(frozen=True)
class Beckmann(Distribution):
    """Beckmann distribution, Walter et al. 2007, Eq. 25: D = exp(−tan²θh/m²)/(π m² cos⁴θh)."""

    name = "beckmann"

    def D(self, cos_h, m, tail=None):
        c2 = cos_h * cos_h
        return jnp.exp(-_tan2(cos_h) / (m * m)) / (jnp.pi * m * m * c2 * c2)

    def Lambda(self, cos_v, m, tail=None):
        return _beckmann_lambda(cos_v, m)

    def D_aniso(self, h, m, tail=None):
        # Heitz 2014, Eq. 81: exp(−(hx²/αx² + hy²/αy²)/hz²)/(π αx αy hz⁴).
        ax, ay = m
        hx, hy, hz = h[..., 0], h[..., 1], jnp.maximum(h[..., 2], TINY)
        z2 = hz * hz
        return jnp.exp(-((hx / ax) ** 2 + (hy / ay) ** 2) / z2) / (jnp.pi * ax * ay * z2 * z2)

    def Lambda_aniso(self, w, m, tail=None):
        # Heitz 2014, Eqs. 80 and 86: the isotropic Λ(a) at a = 1/(α(φ) tanθ) = ωz/√((ωx αx)² + (ωy αy)²).
        across, z = _stretched(w, m)
        return _beckmann_lambda_of_a(safe_div(z, safe_sqrt(across), fallback=_BECKMANN_A_MAX))


@dataclasses.dataclass(frozen=True)
class GGX(Distribution):
    """GGX / Trowbridge-Reitz, Walter et al. 2007, Eq. 33: D = α²/(π (cos²θh (α² − 1) + 1)²)."""

    name = "ggx"

    def D(self, cos_h, m, tail=None):
        a2 = m * m
        t = cos_h * cos_h * (a2 - 1.0) + 1.0
        return a2 / (jnp.pi * t * t)

    def Lambda(self, cos_v, m, tail=None):
        # Walter et al. 2007, Eq. 34: G1 = 2/(1 + √(1 + α² tan²θv)), i.e. Λ = (√(1 + α² tan²θv) − 1)/2.
        c2 = jnp.maximum(cos_v * cos_v, 1e-30)
        return 0.5 * (jnp.sqrt(1.0 + m * m * (1.0 - c2) / c2) - 1.0)

    def D_aniso(self, h, m, tail=None):
        # Heitz 2014, Eq. 85: 1/(π αx αy hz⁴ (1 + (hx²/αx² + hy²/αy²)/hz²)²) = 1/(π αx αy (hx²/αx² + hy²/αy² + hz²)²).
        ax, ay = m
        t = (h[..., 0] / ax) ** 2 + (h[..., 1] / ay) ** 2 + h[..., 2] ** 2
        return 1.0 / (jnp.pi * ax * ay * t * t)

    def Lambda_aniso(self, w, m, tail=None):
        # Heitz 2014, Eq. 86: (−1 + √(1 + α(φ)² tan²θ))/2.
        across, z = _stretched(w, m)
        return 0.5 * (jnp.sqrt(1.0 + across / jnp.maximum(z * z, 1e-30)) - 1.0)


@dataclasses.dataclass(frozen=True)
class BlinnPhong(Distribution):
    """Normalised power-cosine (Blinn) distribution, Walter et al. 2007, Eq. 30, with exponent αp = 2/m² − 2.

    D = (αp + 2)/(2π) cos^αp θh. Its Smith term uses Walter's Beckmann approximation with
    a = √(αp/2 + 1)/tanθv, which for αp = 2/m² − 2 is the Beckmann a = 1/(m tanθv).
    """

    name = "blinn"

    def D(self, cos_h, m, tail=None):
        exponent = 2.0 / (m * m) - 2.0
        return (exponent + 2.0) / (2.0 * jnp.pi) * jnp.exp(exponent * jnp.log(cos_h))

    def Lambda(self, cos_v, m, tail=None):
        return _beckmann_lambda(cos_v, m)


# The largest μ = 1/(α tanθ) the Student-t Λ is evaluated at (normal incidence, where Λ = 0 to double precision).
_STD_MU_MAX = 1e100


# Terms of the incomplete beta function's continued fraction (`_half_beta`): for b = ½ and a in the STD's range
# (γ − 1 in [0.51, 39]) 30 give it to 1.3e-13 relative over x in [0, 1] against SciPy's betainc.
_BETA_CF_TERMS = 32
# Lentz's guard against a vanishing denominator (Numerical Recipes' FPMIN).
_LENTZ_FLOOR = 1e-300


def _beta_continued_fraction(a, b, x):
    """The continued fraction of I_x(a, b) (Numerical Recipes, 3rd ed., §6.4, Eq. 6.4.5, evaluated by the modified
    Lentz method) with a fixed number of terms, `_BETA_CF_TERMS`: plain arithmetic, so that JAX differentiates it
    in a and b as well as x, and vectorised without a loop that waits for the slowest element (JAX's own betainc
    iterates up to convergence, about 15 times slower here, and has no derivative in a)."""
    def guard(v):
        return jnp.where(jnp.abs(v) < _LENTZ_FLOOR, _LENTZ_FLOOR, v)

    def step(numerator, c, d, h):
        d = 1.0 / guard(1.0 + numerator * d)
        c = guard(1.0 + numerator / c)
        return c, d, h * d * c

    def term(m, state):
        c, d, h = state
        c, d, h = step(m * (b - m) * x / ((a - 1.0 + 2 * m) * (a + 2 * m)), c, d, h)
        return step(-(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 1.0 + 2 * m)), c, d, h)

    d = 1.0 / guard(1.0 - (a + b) * x / (a + 1.0))
    return jax_lax.fori_loop(1, _BETA_CF_TERMS + 1, term, (jnp.ones_like(x), d, d))[2]


def _half_beta(a, x):
    """The regularised incomplete beta function I_x(a, ½): the continued fraction where it converges fast,
    x < (a + 1)/(a + 5/2), else 1 − I_{1−x}(½, a) (Numerical Recipes §6.4)."""
    b = 0.5
    inside = jnp.clip(x, 1e-300, 1.0 - 1e-16)
    front = jnp.exp(a * jnp.log(inside) + b * jnp.log1p(-inside) - jax_special.gammaln(a)
                    - jax_special.gammaln(b) + jax_special.gammaln(a + b))
    swap = x > (a + 1.0) / (a + b + 2.0)
    direct = front * _beta_continued_fraction(a, b, jnp.where(swap, 0.5, x)) / a
    other = 1.0 - front * _beta_continued_fraction(b, a, jnp.where(swap, 1.0 - x, 0.5)) / b
    return jnp.where(x <= 0.0, 0.0, jnp.where(x >= 1.0, 1.0, jnp.where(swap, other, direct)))


def _std_lambda_of_mu(mu, gamma):
    """Smith's Λ of the Student-t slope distribution at μ = 1/(α tanθ) (Ribardière et al. 2017, Eqs. 13-15),
    exactly: Λ = (1/μ) ∫_μ^∞ (q − μ) P2(q) dq with the one-slope marginal
    P2(q) = c (γ − 1 + q²)^(½−γ), c = (γ − 1)^γ Γ(γ − ½)/(√π Γ(γ)), so that

        Λ = c (γ − 1 + μ²)^(3/2−γ) / ((2γ − 3) μ) − S(μ),

    S(μ) = ∫_μ^∞ P2 the Student-t tail with 2γ − 2 degrees of freedom at μ√2, ½ I_x(γ − 1, ½) with
    x = (γ − 1)/(γ − 1 + μ²) (`_half_beta`). (The paper approximates the second integral by a fitted rational
    function.)"""
    g1 = gamma - 1.0
    mu = jnp.minimum(mu, _STD_MU_MAX)
    log_c = gamma * jnp.log(g1) + jax_special.gammaln(gamma - 0.5) - jax_special.gammaln(gamma) \
        - 0.5 * jnp.log(jnp.pi)
    first = jnp.exp(log_c + (1.5 - gamma) * jnp.log(g1 + mu * mu)) / ((2.0 * gamma - 3.0) * mu)
    return first - 0.5 * _half_beta(g1, g1 / (g1 + mu * mu))


@dataclasses.dataclass(frozen=True)
class StudentT(Distribution):
    """The Student-t distribution of slopes, "STD" (Ribardière, Bringier, Meneveaux & Simonot, STD: Student's
    t-distribution of slopes for microfacet based BSDFs, Computer Graphics Forum 36(2), 2017, Eq. 9):

        D = (1 + tan²θh/(α² (γ − 1)))^(−γ) / (π α² cos⁴θh),

    a tail exponent γ > 3/2 between GGX (γ = 2, exactly) and Beckmann (γ → ∞, its limit); Λ exact
    (`_std_lambda_of_mu`). Anisotropic: tan²θh/α² becomes (hx²/αx² + hy²/αy²)/hz² (Heitz 2014, §5.3)."""

    name = "std"
    tail: ClassVar[ParamSpec] = ParamSpec("gamma", 2.0, 1.51, 40.0, unit="1",
                                          doc="tail exponent γ of the Student-t slopes (2: GGX; large: Beckmann)")

    def _density(self, e, ax, ay, cos_h, gamma):
        c2 = cos_h * cos_h
        return jnp.exp(-gamma * jnp.log1p(e / (gamma - 1.0))) / (jnp.pi * ax * ay * c2 * c2)

    def D(self, cos_h, m, tail=None):
        return self._density(_tan2(cos_h) / (m * m), m, m, cos_h, tail)

    def Lambda(self, cos_v, m, tail=None):
        sin_v = safe_sqrt(1.0 - cos_v * cos_v)
        return _std_lambda_of_mu(safe_div(cos_v, m * sin_v, fallback=_STD_MU_MAX), tail)

    def D_aniso(self, h, m, tail=None):
        ax, ay = m
        hz = jnp.maximum(h[..., 2], TINY)
        return self._density(((h[..., 0] / ax) ** 2 + (h[..., 1] / ay) ** 2) / (hz * hz), ax, ay, hz, tail)

    def Lambda_aniso(self, w, m, tail=None):
        across, z = _stretched(w, m)
        return _std_lambda_of_mu(safe_div(z, safe_sqrt(across), fallback=_STD_MU_MAX), tail)


def _ratio_to_expm1(z):
    """z/(e^z − 1), 1 at z = 0 (smooth through it)."""
    small = jnp.abs(z) < 1e-8
    return jnp.where(small, 1.0 - 0.5 * z, z / jnp.expm1(jnp.where(small, 1.0, z)))


def _ratio_to_log(y, log):
    """y/log for y = e^log − 1 given both (each computed without cancellation), 1 + y/2 near y = 0."""
    small = jnp.abs(y) < 1e-8
    return jnp.where(small, 1.0 + 0.5 * y, y / jnp.where(small, 1.0, log))


# Gauss-Legendre nodes of each of the three panels of the GTR's Λ integral (`_gtr_lambda`); against GGX's closed
# form (GTR at γ = 2) it is measured in tests/test_microfacet.py.
_GTR_NODES = 48
# The GTR's Λ integral changes panels at this many times its two scales, μ and μ/α (`_gtr_lambda`).
_GTR_PEAK_WIDTHS = 8.0


@functools.lru_cache(maxsize=1)
def _legendre_on_unit_interval():
    import numpy as np

    x, w = np.polynomial.legendre.leggauss(_GTR_NODES)
    return 0.5 * (x + 1.0), 0.5 * w


def _gtr_normalisation(m, gamma):
    """c of D = c/(α² cos²θh + sin²θh)^γ (Burley 2012, App. B, Eqs. 4-5): (γ − 1)(α² − 1)/(π (1 − (α²)^(1−γ))),
    and (α² − 1)/(π ln α²) at γ = 1, written through z/(e^z − 1) and (α² − 1)/ln α² so that γ = 1 and α = 1 are
    ordinary points."""
    log_a2 = 2.0 * jnp.log(m)
    return _ratio_to_log(m * m - 1.0, log_a2) * _ratio_to_expm1((1.0 - gamma) * log_a2) / jnp.pi


def _gtr_lambda(cos_v, m, gamma):
    """Smith's Λ of the GTR distribution, which has no closed form (Burley gives none; GTR is not
    shape-invariant, so Λ depends on α and θ separately). From Smith's definition over the slopes,
    Λ = (1/μ) ∫∫_{x > μ} (x − μ) P22(x, y) dx dy with μ = cotθ, the angular integral done by hand in polar slopes
    leaves one dimension:

        Λ = 2μ² ∫_0^1 (√(1 − s²) − s acos s) · c (s² + μ²)^(γ−2) / (α² s² + μ²)^γ ds,   s = μ/r,

    a smooth integrand but for its two scales near s = 0 (μ and μ/α), power laws between them and beyond, and a
    (1 − s)^(3/2) branch at s = 1. Gauss-Legendre panels: [0, s_near], s_near = min(½, 8μ); [s_near, s_far] and
    [s_far, ½] in log s, s_far = min(½, 8μ/α); the edge [½, 1] in w with s = 1 − w²/2, where it is analytic."""
    c2 = jnp.clip(cos_v * cos_v, TINY, 1.0)
    mu = jnp.sqrt(c2 / jnp.maximum(1.0 - c2, TINY))[..., None]
    c = _gtr_normalisation(m, gamma)
    nodes, weights = (jnp.asarray(a) for a in _legendre_on_unit_interval())

    def integrand(s):
        bracket = jnp.sqrt(jnp.maximum(1.0 - s * s, 0.0)) - s * jnp.arccos(jnp.clip(s, -1.0, 1.0))
        return bracket * c * jnp.exp((gamma - 2.0) * jnp.log(s * s + mu * mu)
                                     - gamma * jnp.log(m * m * s * s + mu * mu))

    # Two scales: (s² + μ²)^(γ−2) turns at s ~ μ, (α²s² + μ²)^−γ at s ~ μ/α (the same at γ = 2).
    s_near = jnp.minimum(0.5, _GTR_PEAK_WIDTHS * mu)
    s_far = jnp.minimum(0.5, _GTR_PEAK_WIDTHS * mu / m)
    peak = s_near[..., 0] * jnp.sum(weights * integrand(s_near * nodes), axis=-1)

    def logarithmic(lower, upper):  # ∫ over [lower, upper] in log s, where the integrand is a power law
        span = jnp.log(upper / lower)
        points = lower * jnp.exp(span * nodes)
        return jnp.sum(weights * integrand(points) * points * span, axis=-1)

    tail = logarithmic(s_near, s_far) + logarithmic(s_far, 0.5)
    edge = jnp.sum(weights * integrand(1.0 - 0.5 * nodes * nodes) * nodes, axis=-1)
    return jnp.where(cos_v >= 1.0, 0.0, 2.0 * mu[..., 0] ** 2 * (peak + tail + edge))


@dataclasses.dataclass(frozen=True)
class GTR(Distribution):
    """Burley's generalised Trowbridge-Reitz distribution (Physically-based shading at Disney, SIGGRAPH 2012 course
    notes, App. B, Eq. 4): D = c/(α² cos²θh + sin²θh)^γ, c normalising it (`_gtr_normalisation`). γ = 2 is GGX,
    γ = 1 the Disney clearcoat's GTR1; larger γ shorter tails. Its Smith Λ is integrated numerically
    (`_gtr_lambda`), Burley giving none. Isotropic only."""

    name = "gtr"
    tail: ClassVar[ParamSpec] = ParamSpec("gamma", 2.0, 0.6, 10.0, unit="1",
                                          doc="GTR exponent γ (1: GTR1, 2: GGX; larger: shorter tails)")

    def D(self, cos_h, m, tail=None):
        c2 = cos_h * cos_h
        return _gtr_normalisation(m, tail) * jnp.exp(-tail * jnp.log(1.0 + (m * m - 1.0) * c2))

    def Lambda(self, cos_v, m, tail=None):
        return _gtr_lambda(cos_v, m, tail)


DISTRIBUTIONS = {d.name: d for d in (Beckmann(), GGX(), BlinnPhong(), StudentT(), GTR())}
# The distributions with an anisotropic form (`Distribution.D_aniso`).
ANISOTROPIC = ("beckmann", "ggx", "std")


def v_cavity(pair: LocalPair, distribution: Distribution, m, tail=None):
    """Cook & Torrance (1982) V-cavity shadowing: min(1, 2 ch co/(ωo·h), 2 ch ci/(ωo·h)); independent of D."""
    g_o = 2.0 * pair.cos_h * pair.cos_o / pair.cos_d
    g_i = 2.0 * pair.cos_h * pair.cos_i / pair.cos_d
    return jnp.minimum(1.0, jnp.minimum(g_o, g_i))


def smith(pair: LocalPair, distribution: Distribution, m, tail=None):
    """Separable Smith shadowing-masking of ``distribution``, G1(ωi) G1(ωo) (Walter et al. 2007, Eq. 23)."""
    return (1.0 / (1.0 + distribution.lambda_of(pair.wi, pair.cos_i, m, tail))
            * (1.0 / (1.0 + distribution.lambda_of(pair.wo, pair.cos_o, m, tail))))


def smith_correlated(pair: LocalPair, distribution: Distribution, m, tail=None):
    """Height-correlated Smith shadowing-masking of ``distribution``, 1/(1 + Λ(ωi) + Λ(ωo)) (Heitz 2014, Eq. 99;
    pbrt-v4's ``TrowbridgeReitzDistribution::G``): a point seen from ωo is more likely lit from ωi, as both see
    the high points of the surface. Never below the separable form (Λ ≥ 0)."""
    return 1.0 / (1.0 + distribution.lambda_of(pair.wi, pair.cos_i, m, tail)
                  + distribution.lambda_of(pair.wo, pair.cos_o, m, tail))


def ggx_correlated(pair: LocalPair, alpha):
    """D(h) G2(ωi, ωo) / (4 cosθi cosθo) of the isotropic GGX distribution with height-correlated Smith masking
    (Heitz 2014, Eq. 99): the specular term V·D of the glTF 2.0 specification's Appendix B, and Cycles' and
    pbrt-v4's Trowbridge-Reitz microfacet term without its Fresnel factor.

    Arguments:
        pair: the direction pair.
        alpha: the GGX width α (the square of an artist's perceptual roughness).

    Returns:
        The term at the pair's leading shape, in 1/sr.
    """
    ggx = DISTRIBUTIONS["ggx"]
    return ggx.D(pair.cos_h, alpha) * smith_correlated(pair, ggx, alpha) / (4.0 * pair.cos_i * pair.cos_o)


def no_shadowing(pair: LocalPair, distribution: Distribution, m, tail=None):
    """No shadowing-masking: G = 1."""
    return jnp.ones_like(pair.cos_h)


SHADOWING = {"v-cavity": v_cavity, "smith": smith, "smith-correlated": smith_correlated, "none": no_shadowing}
