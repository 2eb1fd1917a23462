r"""pbrt-v4's ``coateddiffuse``: a rough dielectric interface over a Lambertian base, as pbrt-v4 evaluates it.

pbrt-v4 (github.com/mmp/pbrt-v4; Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed., 2023, §14.3)
renders ``coateddiffuse`` as ``LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>`` (``src/pbrt/bxdfs.h``,
``LayeredBxDF::f``; ``src/pbrt/materials.cpp``, ``CoatedDiffuseMaterial``): a stochastic estimate of the BSDF by
a random walk between the interface (a Trowbridge-Reitz dielectric of width α and index η, ``DielectricBxDF``) and
the diffuse base of reflectance ρ, through a slab of ``thickness`` with ``albedo`` 0, at most ``maxdepth``
scattering events, next-event estimation at the base and at the exit weighted by the power heuristic, and Russian
roulette (unbiased). Its expectation, for ωo and ωi above the surface, is

    f(ωo, ωi) = f_R(ωo, ωi) + (ρ/π) · X(ωo)/η² · Y(ωi) · Σ_{k=0}^{K−1} (ρ R)^k,   K = maxdepth / 2,

- f_R: the interface's reflection, F(ωo·h; η) D(h) G(ωo, ωi)/(4 cosθo cosθi) with the height-correlated G
  (``DielectricBxDF::f``; brdffit's Cook-Torrance lobe with those options);
- X(ω) = ∫ f_T(ω → ω') |cos ω'| Tr(ω') dω' over the refracted directions ω' (the transmission sampled at the
  walk's start; f_T in importance mode, the factor 1/η² of radiance mode written apart), with
  Tr(ω) = exp(−thickness/|cos ω|), the slab's transmittance along ω (``Tr``: albedo 0 leaves only this factor);
- Y(ω): the same integral weighted by the sum of the two power-heuristic weights pbrt-v4 gives the contributions
  that reach the base along ω' and leave towards ω: ph(p_T(ω → ω'), |cos ω'|/π) for the next-event estimate
  along the presampled ω', ph(|cos ω'|/π, p_T(ω' → ω)) for the base's cosine sample that leaves through the
  interface (p_T the density of sampling the transmission alone, ``Sample_f`` and ``PDF`` with
  ``BxDFReflTransFlags::Transmission``; ph(a, b) = a²/(a² + b²)). The two densities of the second weight are
  densities of different variables, so the weights do not sum to 1 (taken as 1, f falls by 3-16 % at the test's
  settings, tests/test_coateddiffuse.py);
- R = ∫ (|cos ω2|/π) Tr(ω2) ∫ f_R^inside(ω2 → ω3) |cos ω3| Tr(ω3) dω3 dω2: the interface's reflection, from
  inside (index 1/η, total internal reflection included), of the light the base scatters, back to the base;
- one bottom bounce every two scattering events: K = 5 for pbrt's ``maxdepth`` 10.

X and Y depend on the cosine μ of their direction only (α is isotropic): the lobe computes both at `COSINE_NODES`
cosines evenly spaced in √μ (dense towards the horizon, where they change fastest) and interpolates in √μ (Keys'
cubic convolution); R is an integral over the cosine of ω2, split at the
interface's critical cosine. The integrals over ω' are taken over the microfacet normal m, where
f_T |cos ω'| dω' = T D G |ω·m| / |cos ω| dm: GGX's inverse CDF tan²θm = α² ξ/(1 − ξ) turns D cosθm dm into
dξ dφ/(2π), and ξ = 1 − s² removes the 1/cosθm singularity at ξ → 1; Gauss-Legendre in s, the midpoint rule in φ
over [0, π] (the integrands are even in φ), `NORMAL_NODES` each. The cut at ω·m ≤ 0, where the integrands vanish
continuously, costs the rule its spectral convergence but not much: tests/test_coateddiffuse.py holds the rule to
a finer one, the interpolation to the rule and the lobe to a NumPy transcription of pbrt-v4's walk.

What pbrt-v4 renders is not this alone: its path tracer calls ``f`` where it samples a light, and
``LayeredBxDF::Sample_f`` where it samples the BSDF (every indirect bounce, and part of an area or environment
light under multiple importance sampling). ``Sample_f`` is a walk of f/pdf weights whose expectation is the physical
layered BRDF: this formula with both weights 1 (Y = X), reciprocal and lower (pbrt-v4 issue #187, open, reports the
disagreement). The lobe is ``f``'s expectation: a render's direct light from point and distant lights follows it
exactly; its indirect light follows the lower one (docs/export.md).

Not reciprocal (pbrt-v4's estimator treats ωo and ωi differently: X against Y). ρ enters through the geometric
series: a nonlinear colour parameter. The slab's thickness, albedo and scattering asymmetry are pbrt-v4's defaults
(0.01, 0, 0), and ``maxdepth`` its default 10; the export writes them (`brdffit.export.pbrt`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

from .._lazy import module
from ..geometry import LocalPair, safe_sqrt
from ..params import ParamSpec
from . import cubic
from .cook_torrance import CookTorrance
from .fresnel import dielectric
from .lobe import Lobe
from .peaks import Peak, scalar
from .specs import roughness

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) needs neither JAX
np = module("numpy")  # nor NumPy

__all__ = ["CoatedDiffuse", "slab_transmittance", "transmission", "internal_reflectance", "bottom_series", "cosines",
           "THICKNESS", "MAX_DEPTH", "MIN_ETA", "MAX_ETA", "COSINE_NODES", "NORMAL_NODES", "REFLECTION_NODES"]

# pbrt-v4's defaults for the slab (CoatedDiffuseMaterial::Create): thickness 0.01, maxdepth 10 (albedo 0, g 0).
THICKNESS = 0.01
MAX_DEPTH = 10
# η = 1 is pbrt's index-matched interface (no refraction at all); 1.01 to 3 covers the dielectrics, as the
# roughplastic lobe's range does.
MIN_ETA, MAX_ETA = 1.01, 3.0
# Cosines at which X and Y are computed (uniform on [0, 1]), and the microfacet normals' rule (per axis).
COSINE_NODES = 64
NORMAL_NODES = 32
# Gauss-Legendre nodes of R's outer integral on each side of the critical cosine.
REFLECTION_NODES = 24

# The interface's reflection: GGX, height-correlated Smith, the dielectric Fresnel term (unit ks).
_REFLECTION = CookTorrance(distribution="ggx", shadowing="smith-correlated", fresnel="dielectric")


@functools.cache
def _rule(n: int):
    """The microfacet rule's nodes before α: s in (0, 1) (Gauss-Legendre), φ in (0, π) (midpoints), and the
    weights, summing to 1, of ∫ g dξ dφ/(2π) with ξ = 1 − s² (dξ = 2s ds), φ's half range doubled by symmetry."""
    x, w = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (x + 1.0)
    phi = (np.arange(n) + 0.5) * math.pi / n
    weight = np.outer(w * s, np.full(n, 1.0 / n))  # 0.5 w (interval) · 2 s (dξ/ds) · 1/n (φ's mean)
    s, phi = np.meshgrid(s, phi, indexing="ij")
    return s.ravel(), phi.ravel(), weight.ravel()


def _normals(alpha, xp):
    """The microfacet normals (mx, my, mz), GGX's D(m) and the rule's weights for width α (`_rule`)."""
    s, phi, weight = _rule(NORMAL_NODES)
    s2 = s * s
    q = s2 + alpha * alpha * (1.0 - s2)  # s² + α²(1 − s²) = s²/cos²θm
    cos_m = s / xp.sqrt(q)
    sin_m = alpha * xp.sqrt(1.0 - s2) / xp.sqrt(q)
    d = q * q / (math.pi * alpha * alpha)  # 1/(π α² cos⁴θm (1 + tan²θm/α²)²) with tan²θm/α² = (1 − s²)/s²
    return sin_m * np.cos(phi), sin_m * np.sin(phi), cos_m, d, weight


def _smith_lambda(z2, alpha):
    """Λ of a direction whose cosine squared is ``z2`` (Trowbridge-Reitz: (√(1 + α² tan²θ) − 1)/2)."""
    tan2 = (1.0 - z2) / z2
    return 0.5 * ((1.0 + alpha * alpha * tan2) ** 0.5 - 1.0)


def slab_transmittance(cos_theta, xp):
    """Tr = exp(−thickness/|cosθ|), 0 at the horizon."""
    c = xp.abs(cos_theta)
    return xp.where(c > 0.0, xp.exp(-THICKNESS / xp.where(c > 0.0, c, 1.0)), 0.0)


def _direction(mu, xp):
    """(sinθ, μ) of directions in the x-z plane with cosines ``mu``, on a leading axis against the normals."""
    mu = xp.asarray(mu)[:, None]
    return safe_sqrt(1.0 - mu * mu, xp, tiny=0.0), mu


def _power(a, b, xp):
    """pbrt-v4's ``PowerHeuristic(1, a, 1, b)``: a²/(a² + b²) (0 where both vanish)."""
    a2, b2 = a * a, b * b
    total = a2 + b2
    return xp.where(total > 0.0, a2 / xp.where(total > 0.0, total, 1.0), 0.0)


def transmission(mu, alpha, eta, xp=None):
    """X(μ) and Y(μ) (module doc) at cosines ``mu``.

    Arguments:
        mu: cosines in [0, 1] ``(n,)``.
        alpha: the interface's GGX width (scalar; traced under JAX).
        eta: its index of refraction, above 1.
        xp: ``numpy`` or ``jax.numpy`` (default).

    Returns:
        ``(X, Y)``, each ``(n,)``.
    """
    xp = jnp if xp is None else xp
    mx, my, mz, d, weight = _normals(alpha, xp)
    sin_t, mu = _direction(mu, xp)
    c = sin_t * mx + mu * mz  # ω·m
    front = c > 0.0
    c = xp.where(front, c, 1.0)
    cos_t = xp.sqrt(1.0 - (1.0 - c * c) / (eta * eta))  # the refracted cosine against m (η > 1: no total reflection)
    scale = c / eta - cos_t  # ω' = −ω/η + (c/η − cos_t) m
    ox, oy, oz = scale * mx - sin_t / eta, scale * my, scale * mz - mu / eta
    down = front & (oz < 0.0)
    oz2 = xp.where(down, oz * oz, 0.5)
    mu_safe = xp.where(mu > 0.0, mu, 1.0)
    lam_i = _smith_lambda(xp.maximum(mu_safe * mu_safe, 1e-300), alpha)
    lam_t = _smith_lambda(oz2, alpha)
    g2 = 1.0 / (1.0 + lam_i + lam_t)
    t = 1.0 - dielectric(c, 1.0, eta, xp)
    value = xp.where(down & (mu > 0.0),
                     t * g2 * c / (mu_safe * mz) * slab_transmittance(xp.where(down, oz, -1.0), xp), 0.0)
    # The power-heuristic weights of Y: the transmission's density from ω, p = G1(ω) D c / μ · |ω'·m| / (ω'·m +
    # c/η)², and from ω' back out to ω, p' = G1(ω') D |ω'·m| / |cos ω'| · c / (c + η ω'·m)²; the base's cosine
    # density |cos ω'|/π.
    o_dot_m = ox * mx + oy * my + oz * mz  # negative: ω' leaves m's far side
    into = xp.where(down, (o_dot_m + c / eta) ** 2, 1.0)
    out = xp.where(down, (c + eta * o_dot_m) ** 2, 1.0)
    abs_oz = xp.sqrt(oz2)
    p_in = d * c / (mu_safe * (1.0 + lam_i)) * xp.abs(o_dot_m) / into
    p_out = d * xp.abs(o_dot_m) / (abs_oz * (1.0 + lam_t)) * c / out
    base = abs_oz / math.pi
    weights = _power(p_in, base, xp) + _power(base, p_out, xp)
    weight = xp.asarray(weight)
    return xp.sum(value * weight, axis=-1), xp.sum(value * weights * weight, axis=-1)


def _inside_reflection(mu, alpha, eta, xp):
    """Z(μ) = ∫ f_R(ω → ω3) |cos ω3| Tr(ω3) dω3 for ω inside the slab going up with cosine μ (relative index 1/η:
    total internal reflection included), in the frame flipped so that ω is above."""
    mx, my, mz, _, weight = _normals(alpha, xp)
    sin_t, mu = _direction(mu, xp)
    c = sin_t * mx + mu * mz
    rz = 2.0 * c * mz - mu  # the cosine of ω3 = 2 (ω·m) m − ω
    valid = (c > 0.0) & (rz > 0.0)
    rz2 = xp.where(valid, rz * rz, 0.5)
    g2 = 1.0 / (1.0 + _smith_lambda(mu * mu, alpha) + _smith_lambda(rz2, alpha))
    f = dielectric(xp.where(valid, c, 1.0), eta, 1.0, xp)  # from the dense side: F = 1 beyond the critical angle
    value = xp.where(valid, f * g2 * c / (mu * mz) * slab_transmittance(xp.where(valid, rz, 1.0), xp), 0.0)
    return xp.sum(value * xp.asarray(weight), axis=-1)


def internal_reflectance(alpha, eta, xp=None):
    """R = ∫₀¹ 2μ Tr(μ) Z(μ) dμ (module doc): Gauss-Legendre on each side of the critical cosine √(1 − 1/η²), where
    Z has a kink for a smooth interface.

    Arguments:
        alpha: the interface's GGX width.
        eta: its index of refraction, above 1.
        xp: ``numpy`` or ``jax.numpy`` (default).

    Returns:
        R, a scalar in [0, 1].
    """
    xp = jnp if xp is None else xp
    x, w = np.polynomial.legendre.leggauss(REFLECTION_NODES)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    critical = xp.sqrt(1.0 - 1.0 / (eta * eta))
    mu = xp.concatenate([critical * x, critical + (1.0 - critical) * x])
    width = xp.concatenate([critical * w, (1.0 - critical) * w])
    return xp.sum(width * 2.0 * mu * slab_transmittance(mu, xp) * _inside_reflection(mu, alpha, eta, xp))


def bottom_series(rho, r):
    """Σ_{k=0}^{K−1} (ρ R)^k, K = `MAX_DEPTH` / 2 bottom bounces."""
    x = rho * r
    total, term = 1.0, 1.0
    for _ in range(MAX_DEPTH // 2 - 1):
        term = term * x
        total = total + term
    return total


def cosine_roots():
    """√μ of the cosines μ at which the lobe computes X and Y: j/(n − 1), n = `COSINE_NODES` (the nodes of their
    interpolation, `through_the_base`)."""
    return np.linspace(0.0, 1.0, COSINE_NODES)


def cosines():
    """The cosines at which the lobe computes X and Y: `cosine_roots` squared, evenly spaced in √μ, the first moved
    to 1e-6 (X and Y have a limit at the horizon, where the direction itself is undefined)."""
    return np.maximum(1e-6, cosine_roots() ** 2)


@dataclasses.dataclass(frozen=True)
class CoatedDiffuse(Lobe):
    """pbrt-v4's ``coateddiffuse`` (``roughness`` = α with ``remaproughness`` false, thickness 0.01, albedo 0,
    maxdepth 10): f_R + (ρ/π) X(ωo) Y(ωi)/η² Σ_{k<5} (ρR)^k (module doc)."""

    name = "coateddiffuse"
    reciprocal = False
    stand_in = "lambert+ggx(fresnel=dielectric)"
    reference = ("pbrt-v4 (Pharr, Jakob & Humphreys, Physically Based Rendering, 4th ed., §14.3): CoatedDiffuseMaterial, "
                 "LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>::f, src/pbrt/materials.cpp, bxdfs.h; its "
                 "expectation by quadrature (brdffit.models.coateddiffuse)")

    def param_specs(self):
        return (
            ParamSpec("reflectance", 0.5, 0.0, 1.0, colour=True,
                      doc='"rgb reflectance" ρ, the diffuse base\'s albedo (pbrt-v4 clamps it to [0, 1])'),
            roughness("roughness", default=0.2,
                      doc='"float roughness" with "bool remaproughness" false: the interface\'s Trowbridge-Reitz α'),
            ParamSpec("eta", 1.5, MIN_ETA, MAX_ETA, unit="1", doc='"float eta": the interface\'s index of refraction'),
        )

    def peaks(self, params):
        return (Peak("half", scalar(params, "roughness")),)

    def __call__(self, params, pair: LocalPair):
        alpha, eta, rho = params["roughness"], params["eta"], params["reflectance"]
        reflection = _REFLECTION({"ks": 1.0, "m": alpha, "eta": eta}, pair)
        return reflection + through_the_base(pair.cos_o, pair.cos_i, rho, alpha, eta, jnp)


def through_the_base(cos_o, cos_i, rho, alpha, eta, xp):
    """(ρ/π) X(cosθo) Y(cosθi)/η² Σ_{k<K} (ρR)^k, the light that reaches the base (module doc), with X and Y read
    from their values at `cosines` by Keys' cubic convolution in √μ (`brdffit.models.cubic`).

    Arguments:
        cos_o, cos_i: the cosines of ωo and ωi ``(...)``.
        rho: the base's reflectance ``(C,)``.
        alpha, eta: the interface's GGX width and index of refraction.
        xp: ``numpy`` or ``jax.numpy``.

    Returns:
        ``(..., C)`` in 1/sr.
    """
    nodes = cosine_roots()
    x, y = transmission(cosines(), alpha, eta, xp=xp)
    root_o, root_i = (xp.sqrt(xp.clip(c, 0.0, 1.0)) for c in (cos_o, cos_i))
    through = cubic.read(x, nodes, root_o, xp) * cubic.read(y, nodes, root_i, xp) / (eta * eta)
    return rho * bottom_series(rho, internal_reflectance(alpha, eta, xp=xp)) * (through / math.pi)[..., None]
