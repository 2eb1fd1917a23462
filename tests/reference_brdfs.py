"""Independent NumPy re-derivations of every brdffit lobe, written from the papers' formulas.

Nothing here imports brdffit: the formulas are written again from the papers (and from the specification in
issue 2), in the plain spherical-angle form the papers use wherever they use one, so that a slip in the library
(a wrong sign, a swapped angle, a missing factor) shows up as a disagreement with these functions.

Convention (docs/conventions.md): θ is the polar angle from the normal z, φ the azimuth from the tangent x,
ωi points to the light and ωo to the detector; the BRDF is f_r in 1/sr without the cosine factor and is zero
unless cosθi > 0 and cosθo > 0.

Every lobe function takes ``(theta_i, phi_i, theta_o, phi_o)`` in radians (broadcastable arrays, flattened to
shape ``(N,)``) followed by the lobe's parameters (colour parameters as ``(C,)`` arrays, shape parameters as
floats), and returns ``(N, C)`` in 1/sr.
"""

from __future__ import annotations

import cmath
import functools
import math

import numpy as np
from scipy import integrate, special

__all__ = [
    "Pair",
    "lambert",
    "oren_nayar",
    "phong",
    "blinn_phong",
    "ward",
    "ward_duer",
    "cook_torrance",
    "ashikhmin_shirley",
    "lafortune",
    "burley",
    "abc_smooth",
    "abc_microfacet",
    "sgd",
    "principled",
    "gltf",
    "gltf_sheen_brdf",
    "gltf_sheen_albedo",
    "gltf_sheen_table",
    "gltf_sheen_lookup",
    "blender",
    "openpbr",
    "pbrt",
    "roughplastic",
    "mitsuba_rough_transmittance",
    "coateddiffuse",
    "coatedconductor",
    "coated_transmission",
    "coated_internal_reflectance",
    "sheen",
    "charlie_sheen",
    "charlie_lambda",
    "toon_diffuse",
    "toon_specular",
    "fresnel_schlick",
    "fresnel_dielectric",
    "fresnel_conductor",
    "fresnel_conductor_scalar",
    "microfacet_D",
    "microfacet_D_aniso",
    "std_D",
    "std_lambda",
    "std_marginal",
    "gtr_D",
    "gtr_lambda",
    "smith_lambda",
    "smith_lambda_aniso",
    "smith_G1",
    "smith_lambda_numeric",
    "slope_marginal",
    "REFERENCES",
]


class Pair:
    """Angles of a direction pair in the forms the papers use.

    Attributes:
        ti, pi_, to, po: the spherical angles, shape ``(N,)``.
        ci, co, si, so: cosines and sines of θi and θo.
        dphi: φi − φo.
        cos_io: ωi·ωo = cosθi cosθo + sinθi sinθo cos(φi − φo) (spherical law of cosines).
        cos_d: cosθd = ωi·h = √((1 + ωi·ωo)/2): h bisects ωi and ωo, so θd is half the angle between them.
        hx, hy, hz: the half vector (ωi + ωo)/(2 cosθd).
        th, ph: θh (from atan2, accurate near 0) and φh of the half vector.
        above: cosθi > 0 and cosθo > 0.
    """

    def __init__(self, theta_i, phi_i, theta_o, phi_o):
        ti, pi_, to, po = (np.ravel(a).astype(float) for a in np.broadcast_arrays(theta_i, phi_i, theta_o, phi_o))
        self.ti, self.pi_, self.to, self.po = ti, pi_, to, po
        self.ci, self.co, self.si, self.so = np.cos(ti), np.cos(to), np.sin(ti), np.sin(to)
        self.dphi = pi_ - po
        self.cos_io = self.ci * self.co + self.si * self.so * np.cos(self.dphi)
        self.cos_d = np.sqrt(np.clip(0.5 * (1.0 + self.cos_io), 0.0, 1.0))
        two_cd = 2.0 * self.cos_d
        with np.errstate(all="ignore"):  # ωi = −ωo only happens below the horizon
            self.hx = (self.si * np.cos(pi_) + self.so * np.cos(po)) / two_cd
            self.hy = (self.si * np.sin(pi_) + self.so * np.sin(po)) / two_cd
            self.hz = (self.ci + self.co) / two_cd
        self.th = np.arctan2(np.hypot(self.hx, self.hy), self.hz)
        self.ph = np.arctan2(self.hy, self.hx)
        self.above = (self.ci > 0) & (self.co > 0)


def _quiet(func):
    """Run ``func`` with NumPy's floating-point warnings off: below the horizon the formulas may produce NaN or
    inf, which `_masked` discards."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with np.errstate(all="ignore"):
            return func(*args, **kwargs)

    return wrapper


def _channels(*params):
    return max([np.size(p) for p in params] + [1])


def _col(p):
    """A colour parameter as a ``(1, C)`` row (scalars broadcast)."""
    return np.atleast_1d(np.asarray(p, dtype=float))[None, :]


def _masked(pair: Pair, value):
    """Zero below the horizon; ``value`` is ``(N, C)`` (NaN or inf there are discarded, never above it)."""
    return np.where(pair.above[:, None], np.asarray(value, dtype=float), 0.0)


def _pow_pos(x, n):
    """max(0, x)^n (x = 0 gives 0 for n > 0)."""
    return np.where(x > 0, np.abs(x) ** n, 0.0)


# --------------------------------------------------------------------------------------------------------------
# Diffuse lobes


@_quiet
def lambert(theta_i, phi_i, theta_o, phi_o, rho_d):
    """Lambert (Photometria, 1760): f = ρd/π."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    return _masked(g, np.ones_like(g.ti)[:, None] * _col(rho_d) / math.pi)


@_quiet
def oren_nayar(theta_i, phi_i, theta_o, phi_o, rho_d, sigma):
    """Oren & Nayar, Generalization of Lambert's reflectance model, SIGGRAPH 1994, Eq. 30 (qualitative model):
    f = ρ/π (A + B max(0, cos(φi − φo)) sinα tanβ), A = 1 − 0.5σ²/(σ² + 0.33), B = 0.45σ²/(σ² + 0.09),
    α = max(θi, θo), β = min(θi, θo). Written with the explicit angles, as in the paper."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    s2 = sigma * sigma
    a = 1.0 - 0.5 * s2 / (s2 + 0.33)
    b = 0.45 * s2 / (s2 + 0.09)
    alpha = np.maximum(g.ti, g.to)
    beta = np.minimum(g.ti, g.to)
    with np.errstate(all="ignore"):
        shape = a + b * np.maximum(0.0, np.cos(g.dphi)) * np.sin(alpha) * np.tan(beta)
    return _masked(g, _col(rho_d) / math.pi * shape[:, None])


# --------------------------------------------------------------------------------------------------------------
# Cosine-power lobes


@_quiet
def phong(theta_i, phi_i, theta_o, phi_o, ks, n):
    """Modified Phong, Lafortune & Willems 1994 (Report CW197), Eq. 6: f = ks (n + 2)/(2π) cos^n ψ, ψ the angle
    between ωo and the mirror direction of ωi; cosψ = cosθi cosθo − sinθi sinθo cos(φi − φo) since the mirror
    direction has polar angle θi and azimuth φi + π."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    cos_psi = g.ci * g.co - g.si * g.so * np.cos(g.dphi)
    return _masked(g, _col(ks) * ((n + 2.0) / (2.0 * math.pi) * _pow_pos(cos_psi, n))[:, None])


@_quiet
def blinn_phong(theta_i, phi_i, theta_o, phi_o, ks, n):
    """Normalised Blinn-Phong (Blinn 1977; normalisation (n + 8)/(8π), Akenine-Möller et al., Real-Time Rendering
    3rd ed., Eq. 7.48): f = ks (n + 8)/(8π) cos^n θh."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    return _masked(g, _col(ks) * ((n + 8.0) / (8.0 * math.pi) * np.cos(g.th) ** n)[:, None])


# --------------------------------------------------------------------------------------------------------------
# Ward


@_quiet
def ward(theta_i, phi_i, theta_o, phi_o, ks, alpha_x, alpha_y=None):
    """Ward, Measuring and modeling anisotropic reflection, SIGGRAPH 1992, Eq. 5a (elliptical Gaussian):
    f = ks exp(−tan²θh (cos²φh/αx² + sin²φh/αy²)) / (4π αx αy √(cosθi cosθo)); the isotropic lobe (Eq. 4a)
    has αx = αy = α and the exponent −tan²θh/α²."""
    alpha_y = alpha_x if alpha_y is None else alpha_y
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    with np.errstate(all="ignore"):
        expo = -np.tan(g.th) ** 2 * (np.cos(g.ph) ** 2 / alpha_x**2 + np.sin(g.ph) ** 2 / alpha_y**2)
        shape = np.exp(expo) / (4.0 * math.pi * alpha_x * alpha_y * np.sqrt(g.ci * g.co))
    return _masked(g, _col(ks) * shape[:, None])


@_quiet
def ward_duer(theta_i, phi_i, theta_o, phi_o, ks, alpha):
    """Dür, An improved normalization for the Ward reflectance model, JGT 11(1), 2006: Ward's isotropic lobe with
    cosθi cosθo in place of √(cosθi cosθo): f = ks exp(−tan²θh/α²)/(4π α² cosθi cosθo)."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    with np.errstate(all="ignore"):
        shape = np.exp(-np.tan(g.th) ** 2 / alpha**2) / (4.0 * math.pi * alpha**2 * g.ci * g.co)
    return _masked(g, _col(ks) * shape[:, None])


# --------------------------------------------------------------------------------------------------------------
# Fresnel


def fresnel_schlick(cos_theta, f0):
    """Schlick, An inexpensive BRDF model for physically-based rendering, CGF 13(3), 1994, Eq. 24:
    F = f0 + (1 − f0)(1 − cosθ)⁵."""
    return f0 + (1.0 - f0) * (1.0 - cos_theta) ** 5


def fresnel_dielectric(theta_i, eta_i, eta_t):
    """Unpolarised Fresnel reflectance of a dielectric interface from Fresnel's sine and tangent laws
    (Born & Wolf, Principles of Optics, Sec. 1.5.2, Eq. 21a): with Snell's ηi sinθi = ηt sinθt,
    r_s = −sin(θi − θt)/sin(θi + θt), r_p = tan(θi − θt)/tan(θi + θt), F = (r_s² + r_p²)/2.
    At normal incidence (0/0) the limit ((ηi − ηt)/(ηi + ηt))²; beyond the critical angle F = 1."""
    theta_i = np.asarray(theta_i, dtype=float)
    sin_t = eta_i * np.sin(theta_i) / eta_t
    total = sin_t >= 1.0
    with np.errstate(all="ignore"):
        theta_t = np.arcsin(np.where(total, 0.0, sin_t))
        rs = -np.sin(theta_i - theta_t) / np.sin(theta_i + theta_t)
        rp = np.tan(theta_i - theta_t) / np.tan(theta_i + theta_t)
        f = 0.5 * (rs * rs + rp * rp)
    normal = ((eta_i - eta_t) / (eta_i + eta_t)) ** 2
    return np.where(total, 1.0, np.where(theta_i == 0.0, normal, f))


def fresnel_conductor_scalar(theta_i: float, eta: float, k: float) -> float:
    """Unpolarised Fresnel reflectance of a conductor of complex index N = η + iκ seen from vacuum, with Python
    complex numbers (Born & Wolf, Sec. 14.2, Eq. 14.2(1)-(3)): N cosθt = √(N² − sin²θi) (principal root, so
    the transmitted wave decays), r_s = (cosθi − N cosθt)/(cosθi + N cosθt),
    r_p = (N cosθi − cosθt)/(N cosθi + cosθt) = (N² cosθi − N cosθt)/(N² cosθi + N cosθt),
    F = (|r_s|² + |r_p|²)/2."""
    n = complex(eta, k)
    ci = math.cos(theta_i)
    n_ct = cmath.sqrt(n * n - math.sin(theta_i) ** 2)
    rs = (ci - n_ct) / (ci + n_ct)
    rp = (n * n * ci - n_ct) / (n * n * ci + n_ct)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def fresnel_conductor(theta_i, eta, k):
    """`fresnel_conductor_scalar` over broadcast arrays, with NumPy complex arithmetic (same equations)."""
    theta_i, eta, k = np.broadcast_arrays(np.asarray(theta_i, float), np.asarray(eta, float), np.asarray(k, float))
    n = eta + 1j * k
    ci = np.cos(theta_i).astype(complex)
    n_ct = np.sqrt(n * n - np.sin(theta_i) ** 2)
    rs = (ci - n_ct) / (ci + n_ct)
    rp = (n * n * ci - n_ct) / (n * n * ci + n_ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


# --------------------------------------------------------------------------------------------------------------
# Microfacet distributions and Smith shadowing (Walter, Marschner, Li & Torrance, Microfacet models for
# refraction through rough surfaces, EGSR 2007)


def blinn_exponent(m):
    """Walter et al. 2007, Sec. 5.2: the Phong exponent equivalent to Beckmann width m, αp = 2/m² − 2."""
    return 2.0 / (m * m) - 2.0


def std_D(theta_h, phi_h, alpha_x, alpha_y, gamma):
    """Ribardière, Bringier, Meneveaux & Simonot, STD: Student's t-distribution of slopes for microfacet based
    BSDFs, CGF 36(2), 2017, Eq. 9 (with Heitz 2014's anisotropic stretch):
    D = (γ − 1)^γ / (π αx αy cos⁴θh (γ − 1 + tan²θh (cos²φh/αx² + sin²φh/αy²))^γ)."""
    theta_h, phi_h = np.asarray(theta_h, dtype=float), np.asarray(phi_h, dtype=float)
    e = np.tan(theta_h) ** 2 * (np.cos(phi_h) ** 2 / alpha_x**2 + np.sin(phi_h) ** 2 / alpha_y**2)
    return (gamma - 1.0) ** gamma / (math.pi * alpha_x * alpha_y * np.cos(theta_h) ** 4 * (gamma - 1.0 + e) ** gamma)


def std_lambda(theta_v, phi_v, alpha_x, alpha_y, gamma):
    """Smith's Λ of the STD, with SciPy: Ribardière et al. 2017, Eq. 13, Λ = (1/μ) ∫_μ^∞ (q − μ) P2(q) dq,
    μ = 1/(α(φ) tanθ), with the marginal P2(q) = c (γ − 1 + q²)^(½−γ), c = (γ − 1)^γ Γ(γ − ½)/(√π Γ(γ)):
    the first moment in closed form, c (γ − 1 + μ²)^(3/2−γ)/(2γ − 3), and the tail as the Student-t survival
    function with 2γ − 2 degrees of freedom at μ√2 (scipy.stats.t)."""
    from scipy import stats

    alpha = np.sqrt(np.cos(phi_v) ** 2 * alpha_x**2 + np.sin(phi_v) ** 2 * alpha_y**2)
    with np.errstate(divide="ignore"):
        mu = 1.0 / (alpha * np.tan(np.asarray(theta_v, dtype=float)))
    c = (gamma - 1.0) ** gamma * special.gamma(gamma - 0.5) / (math.sqrt(math.pi) * special.gamma(gamma))
    first = c * (gamma - 1.0 + mu * mu) ** (1.5 - gamma) / ((2.0 * gamma - 3.0) * mu)
    return np.where(np.isinf(mu), 0.0, first - stats.t.sf(mu * math.sqrt(2.0), 2.0 * gamma - 2.0))


def std_marginal(q, m, gamma):
    """The one-slope marginal of the isotropic STD, P2(q) = ∫ P22(q, y) dy (P22 = D cos⁴θh), integrated by
    quadrature (scipy.integrate.quad), not in closed form: what `std_lambda` assumes is checked against it."""
    # P22 = (γ − 1)^γ (γ − 1 + r²/m²)^−γ / (π m²); over y with y = c tan u, c² = m²(γ − 1) + q², the integrand
    # becomes the bounded, smooth (c²/(m²(γ − 1)))^−γ cos^(2γ−2)u · c/(π m²) on [0, π/2) (twice, for y < 0).
    c2 = m * m * (gamma - 1.0) + q * q
    scale = math.exp(-gamma * math.log(c2 / (m * m * (gamma - 1.0)))) * math.sqrt(c2) / (math.pi * m * m)
    value, _ = integrate.quad(lambda u: math.cos(u) ** (2.0 * gamma - 2.0), 0.0, 0.5 * math.pi, epsabs=0.0,
                              epsrel=1e-12, limit=200)
    value = 2.0 * scale * value
    return value


def _gtr_c(a2, gamma):
    if a2 == 1.0:  # D = c: uniform in cosθh
        return 1.0 / math.pi
    if gamma == 1.0:
        return (a2 - 1.0) / (math.pi * math.log(a2))
    return (gamma - 1.0) * (a2 - 1.0) / (math.pi * (1.0 - a2 ** (1.0 - gamma)))


def gtr_D(theta_h, alpha, gamma):
    """Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes, App. B, Eqs. 4-5:
    D = c/(α² cos²θh + sin²θh)^γ, c = (γ − 1)(α² − 1)/(π (1 − (α²)^(1−γ))) (γ ≠ 1), (α² − 1)/(π ln α²) (γ = 1)."""
    a2 = alpha * alpha
    c = _gtr_c(a2, gamma)
    theta_h = np.asarray(theta_h, dtype=float)
    return c / (a2 * np.cos(theta_h) ** 2 + np.sin(theta_h) ** 2) ** gamma


def gtr_lambda(theta_v, alpha, gamma):
    """Smith's Λ of the GTR from its definition over slopes, Λ = (1/μ) ∫∫_{x>μ} (x − μ) P22 dx dy, μ = cotθ,
    P22(r) = D cos⁴θh = c (1 + r²)^(γ−2)/(α² + r²)^γ, by SciPy's adaptive quadrature in polar slopes (r, φ), the
    φ integral as quad too (not done by hand as brdffit does it)."""
    a2 = alpha * alpha
    c = _gtr_c(a2, gamma)
    out = []
    for theta in np.ravel(theta_v):
        if theta <= 0.0 or theta >= 0.5 * math.pi:  # at the normal; below the horizon (masked by the caller)
            out.append(0.0 if theta <= 0.0 else math.nan)
            continue
        mu = 1.0 / math.tan(theta)

        def radial(r):
            phi0 = math.acos(min(1.0, mu / r))
            inner, _ = integrate.quad(lambda phi: r * math.cos(phi) - mu, -phi0, phi0, epsabs=0.0, epsrel=1e-13)
            return inner * c * (1.0 + r * r) ** (gamma - 2.0) / (a2 + r * r) ** gamma * r

        scale = max(mu, alpha)
        value, _ = integrate.quad(lambda t: radial(mu + t * scale) * scale, 0.0, math.inf, epsabs=0.0,
                                  epsrel=1e-11, limit=400)
        out.append(value / mu)
    return np.reshape(out, np.shape(theta_v))


def microfacet_D(distribution: str, theta_h, m):
    """Normal distribution functions of Walter et al. 2007 as functions of θh:

    - beckmann, Eq. 25: D = exp(−tan²θh/m²)/(π m² cos⁴θh)
    - ggx, Eq. 33: D = α²/(π cos⁴θh (α² + tan²θh)²)  (the tan form of the paper; equal to α²/(π (cos²θh (α² − 1) + 1)²))
    - blinn (power-cosine), Eq. 30: D = (αp + 2)/(2π) cos^αp θh with αp = 2/m² − 2
    """
    theta_h = np.asarray(theta_h, dtype=float)
    c = np.cos(theta_h)
    t2 = np.tan(theta_h) ** 2
    if distribution == "beckmann":
        return np.exp(-t2 / m**2) / (math.pi * m**2 * c**4)
    if distribution == "ggx":
        return m**2 / (math.pi * c**4 * (m**2 + t2) ** 2)
    if distribution == "blinn":
        ap = blinn_exponent(m)
        return (ap + 2.0) / (2.0 * math.pi) * c**ap
    raise ValueError(distribution)


def _beckmann_lambda_a(a):
    """Walter et al. 2007, Eq. 27 (Smith for Beckmann, integrated): Λ(a) = (erf(a) − 1)/2 + exp(−a²)/(2a√π)."""
    a = np.asarray(a, dtype=float)
    with np.errstate(all="ignore"):
        lam = 0.5 * (special.erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * math.sqrt(math.pi))
    return np.where(np.isinf(a), 0.0, lam)


def smith_lambda(distribution: str, theta_v, m):
    """Smith's Λ of a direction with polar angle θv (Walter et al. 2007, Sec. 5):

    - beckmann: a = 1/(m tanθv), Λ = (erf(a) − 1)/2 + exp(−a²)/(2a√π)
    - ggx (Eq. 34): Λ = (√(1 + α² tan²θv) − 1)/2, i.e. G1 = 2/(1 + √(1 + α² tan²θv))
    - blinn: no closed form; Walter et al. use the Beckmann function with a = √(αp/2 + 1)/tanθv (Sec. 5.2)
    """
    theta_v = np.asarray(theta_v, dtype=float)
    t = np.tan(theta_v)
    with np.errstate(divide="ignore"):
        if distribution == "beckmann":
            return _beckmann_lambda_a(1.0 / (m * t))
        if distribution == "ggx":
            return 0.5 * (np.sqrt(1.0 + m * m * t * t) - 1.0)
        if distribution == "blinn":
            return _beckmann_lambda_a(np.sqrt(0.5 * blinn_exponent(m) + 1.0) / t)
    raise ValueError(distribution)


def smith_G1(distribution: str, theta_v, m):
    """Smith masking G1 = 1/(1 + Λ) (Walter et al. 2007, Eq. 23 with Λ of `smith_lambda`)."""
    return 1.0 / (1.0 + smith_lambda(distribution, theta_v, m))


def microfacet_D_aniso(distribution: str, theta_h, phi_h, alpha_x, alpha_y):
    """Anisotropic Beckmann and GGX of Heitz, Understanding the masking-shadowing function in microfacet-based
    BRDFs, JCGT 3(2), 2014, Eqs. 83 and 85, as functions of (θh, φh), with
    e = tan²θh (cos²φh/αx² + sin²φh/αy²):

    - beckmann: D = exp(−e)/(π αx αy cos⁴θh)
    - ggx: D = 1/(π αx αy cos⁴θh (1 + e)²)
    """
    theta_h, phi_h = np.asarray(theta_h, dtype=float), np.asarray(phi_h, dtype=float)
    c4 = np.cos(theta_h) ** 4
    e = np.tan(theta_h) ** 2 * (np.cos(phi_h) ** 2 / alpha_x**2 + np.sin(phi_h) ** 2 / alpha_y**2)
    if distribution == "beckmann":
        return np.exp(-e) / (math.pi * alpha_x * alpha_y * c4)
    if distribution == "ggx":
        return 1.0 / (math.pi * alpha_x * alpha_y * c4 * (1.0 + e) ** 2)
    raise ValueError(distribution)


def smith_lambda_aniso(distribution: str, theta_v, phi_v, alpha_x, alpha_y):
    """Smith's Λ of the anisotropic distributions (Heitz 2014, Eq. 80 and §5.3): the isotropic Λ of
    `smith_lambda` at the projected roughness α(φv) = √(cos²φv αx² + sin²φv αy²)."""
    alpha = np.sqrt(np.cos(phi_v) ** 2 * alpha_x**2 + np.sin(phi_v) ** 2 * alpha_y**2)
    return smith_lambda(distribution, theta_v, alpha)


def slope_marginal(distribution: str, q, m):
    """Marginal density P2(q) of one slope component (x-slope q) of the isotropic microfacet slope distribution
    P22(x, y) = D(h) cos⁴θh (tan²θh = x² + y²), integrated over the other slope by hand:

    - beckmann: P22 = exp(−r²/m²)/(π m²)  ->  P2 = exp(−q²/m²)/(m√π)
    - ggx: P22 = 1/(π α² (1 + r²/α²)²)  ->  P2 = 1/(2α (1 + q²/α²)^{3/2})
    - blinn: P22 = (αp + 2)/(2π) (1 + r²)^{−s}, s = αp/2 + 2  ->  P2 = (αp + 2)/(2√π) Γ(s − ½)/Γ(s) (1 + q²)^{½−s}
    """
    if distribution == "beckmann":
        return math.exp(-q * q / (m * m)) / (m * math.sqrt(math.pi))
    if distribution == "ggx":
        return 1.0 / (2.0 * m * (1.0 + q * q / (m * m)) ** 1.5)
    if distribution == "blinn":
        ap = blinn_exponent(m)
        s = 0.5 * ap + 2.0
        log_c = math.log(ap + 2.0) - math.log(2.0 * math.sqrt(math.pi)) + math.lgamma(s - 0.5) - math.lgamma(s)
        return math.exp(log_c + (0.5 - s) * math.log1p(q * q))
    raise ValueError(distribution)


def smith_lambda_numeric(distribution: str, theta_v: float, m: float) -> float:
    """Smith's Λ from its definition (Smith 1967; Walter et al. 2007, Eq. 18 written over slopes):
    Λ(μ) = (1/μ) ∫_μ^∞ (q − μ) P2(q) dq with μ = cotθv, by adaptive quadrature."""
    mu = 1.0 / math.tan(theta_v)
    value, _ = integrate.quad(lambda q: (q - mu) * slope_marginal(distribution, q, m), mu, math.inf,
                              epsabs=0.0, epsrel=1e-12, limit=200)
    return value / mu


# --------------------------------------------------------------------------------------------------------------
# Microfacet lobes


@_quiet
def cook_torrance(theta_i, phi_i, theta_o, phi_o, ks, m, *, distribution="beckmann", shadowing="v-cavity",
                  fresnel="schlick", f0=None, eta=None, k=None, gamma=None):
    """Cook & Torrance, A reflectance model for computer graphics, ACM TOG 1(1), 1982, with Walter et al. 2007's
    normalisation (Eq. 20): f = ks F(θd) D(θh) G / (4 cosθi cosθo).

    ``m``: the width, or a pair (αx, αy) for the anisotropic distributions (`microfacet_D_aniso`,
    `smith_lambda_aniso`); ``distribution="std"`` with its tail exponent ``gamma`` (`std_D`, `std_lambda`).
    G: ``v-cavity`` Cook & Torrance 1982, p. 10: G = min(1, 2 cosθh cosθo/cosθd, 2 cosθh cosθi/cosθd);
    ``smith`` Walter et al. 2007, Eq. 23: G1(θi) G1(θo); ``smith-correlated`` Heitz 2014, Eq. 99:
    1/(1 + Λ(ωi) + Λ(ωo)); ``none``: 1.
    F at cosθd = ωo·h: Schlick (f0), exact dielectric from vacuum into η (`fresnel_dielectric`) or exact
    conductor η + iκ (`fresnel_conductor`, complex arithmetic).
    """
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    with np.errstate(all="ignore"):
        if distribution == "gtr":
            d = gtr_D(g.th, m, gamma)
            lam_i, lam_o = gtr_lambda(g.ti, m, gamma), gtr_lambda(g.to, m, gamma)
        elif distribution == "std":
            ax, ay = m if isinstance(m, tuple) else (m, m)
            d = std_D(g.th, g.ph, ax, ay, gamma)
            lam_i, lam_o = std_lambda(g.ti, g.pi_, ax, ay, gamma), std_lambda(g.to, g.po, ax, ay, gamma)
        elif isinstance(m, tuple):
            d = microfacet_D_aniso(distribution, g.th, g.ph, *m)
            lam_i = smith_lambda_aniso(distribution, g.ti, g.pi_, *m)
            lam_o = smith_lambda_aniso(distribution, g.to, g.po, *m)
        else:
            d = microfacet_D(distribution, g.th, m)
            lam_i, lam_o = smith_lambda(distribution, g.ti, m), smith_lambda(distribution, g.to, m)
        if shadowing == "v-cavity":
            ch = np.cos(g.th)
            gg = np.minimum(1.0, np.minimum(2 * ch * g.co / g.cos_d, 2 * ch * g.ci / g.cos_d))
        elif shadowing == "smith":
            gg = 1.0 / (1.0 + lam_i) / (1.0 + lam_o)
        elif shadowing == "smith-correlated":
            gg = 1.0 / (1.0 + lam_i + lam_o)
        elif shadowing == "none":
            gg = np.ones_like(g.th)
        else:
            raise ValueError(shadowing)
        theta_d = np.arccos(g.cos_d)
        if fresnel == "schlick":
            f = fresnel_schlick(g.cos_d, f0)[:, None] * np.ones((1, _channels(ks)))
        elif fresnel == "dielectric":
            f = fresnel_dielectric(theta_d, 1.0, eta)[:, None] * np.ones((1, _channels(ks)))
        elif fresnel == "conductor":
            f = fresnel_conductor(theta_d[:, None], _col(eta), _col(k))
        else:
            raise ValueError(fresnel)
        value = _col(ks) * f * (d * gg / (4.0 * g.ci * g.co))[:, None]
    return _masked(g, value)


@_quiet
def ashikhmin_shirley(theta_i, phi_i, theta_o, phi_o, rs, nu, nv=None):
    """Ashikhmin & Shirley, An anisotropic Phong BRDF model, JGT 5(2), 2000, Eq. 4 (specular term):
    f = √((nu + 1)(nv + 1))/(8π) cosθh^(nu cos²φh + nv sin²φh) / (cosθd max(cosθi, cosθo)) F(cosθd),
    F Schlick's with normal reflectance rs (their Eq. 5). nv = nu for the isotropic lobe."""
    nv = nu if nv is None else nv
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    e = nu * np.cos(g.ph) ** 2 + nv * np.sin(g.ph) ** 2
    with np.errstate(all="ignore"):
        shape = (math.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * math.pi) * np.cos(g.th) ** e
                 / (g.cos_d * np.maximum(g.ci, g.co)))
    f = fresnel_schlick(g.cos_d[:, None], _col(rs))
    return _masked(g, shape[:, None] * f)


@_quiet
def lafortune(theta_i, phi_i, theta_o, phi_o, lobes):
    """Lafortune, Foo, Torrance & Greenberg, Non-linear approximation of reflectance functions, SIGGRAPH 1997,
    Eq. 3 (generalized cosine lobe ρ [Cx ui,x uo,x + Cy ui,y uo,y + Cz ui,z uo,z]^n), normalised as in Ngan,
    Durand & Matusik, Experimental analysis of BRDF models, EGSR 2005: each lobe is multiplied by
    (n + 2)/(2π) / max(|Cx|, |Cy|, |Cz|)^n.

    Arguments:
        lobes: list of dicts with ``ks`` (colour), ``cx``, ``cy``, ``cz``, ``n``.
    """
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    total = 0.0
    for lobe in lobes:
        cx, cy, cz, n = lobe["cx"], lobe["cy"], lobe["cz"], lobe["n"]
        dot = (cx * g.si * g.so * np.cos(g.pi_) * np.cos(g.po) + cy * g.si * g.so * np.sin(g.pi_) * np.sin(g.po)
               + cz * g.ci * g.co)
        norm = max(abs(cx), abs(cy), abs(cz)) ** n
        total = total + _col(lobe["ks"]) * ((n + 2.0) / (2.0 * math.pi) * _pow_pos(dot, n) / norm)[:, None]
    return _masked(g, total)


@_quiet
def burley(theta_i, phi_i, theta_o, phi_o, rho_d, roughness):
    """Burley, Physically-based shading at Disney, SIGGRAPH 2012 course notes, §5.3:
    f = ρd/π (1 + (F_D90 − 1)(1 − cosθi)⁵)(1 + (F_D90 − 1)(1 − cosθo)⁵), F_D90 = 0.5 + 2 roughness cos²θd."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    f90 = 0.5 + 2.0 * roughness * g.cos_d**2
    shape = (1.0 + (f90 - 1.0) * (1.0 - g.ci) ** 5) * (1.0 + (f90 - 1.0) * (1.0 - g.co) ** 5)
    return _masked(g, _col(rho_d) / math.pi * shape[:, None])


@_quiet
def sheen(theta_i, phi_i, theta_o, phi_o, ks):
    """The Disney BRDF's sheen (Burley 2012; BRDF Explorer, disney.brdf): f = ks (1 − cosθd)⁵."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    return _masked(g, _col(ks) * ((1.0 - g.cos_d) ** 5)[:, None])


def charlie_lambda(theta_v, alpha):
    """Estevez & Kulla, Production friendly microfacet sheen BRDF, 2017, Table 1: Λ(θ) = exp(L(cosθ)) for cosθ < ½,
    else exp(2 L(½) − L(1 − cosθ)), L(x) = a/(1 + b x^c) + d x + e, each coefficient interpolated linearly in
    r = (1 − α)² from (21.5473, 3.82987, 0.19823, −1.97760, −4.32054) at r = 0 to (25.3245, 3.32435, 0.16801,
    −1.27393, −4.85967) at r = 1."""
    r = (1.0 - alpha) ** 2
    a = 21.5473 + (25.3245 - 21.5473) * r
    b = 3.82987 + (3.32435 - 3.82987) * r
    c = 0.19823 + (0.16801 - 0.19823) * r
    d = -1.97760 + (-1.27393 + 1.97760) * r
    e = -4.32054 + (-4.85967 + 4.32054) * r

    def big_l(x):
        return a / (1.0 + b * x**c) + d * x + e

    mu = np.cos(np.asarray(theta_v, dtype=float))
    return np.where(mu < 0.5, np.exp(big_l(mu)), np.exp(2.0 * big_l(0.5) - big_l(1.0 - mu)))


@_quiet
def charlie_sheen(theta_i, phi_i, theta_o, phi_o, ks, alpha):
    """Estevez & Kulla 2017, Eqs. 2-3: f = ks D G/(4 cosθi cosθo), D = (2 + 1/α) sin^(1/α)θh/(2π),
    G = 1/(1 + Λ(θi) + Λ(θo)) with `charlie_lambda` (no terminator softening)."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    d = (2.0 + 1.0 / alpha) * np.sin(g.th) ** (1.0 / alpha) / (2.0 * math.pi)
    gg = 1.0 / (1.0 + charlie_lambda(g.ti, alpha) + charlie_lambda(g.to, alpha))
    return _masked(g, _col(ks) * (d * gg / (4.0 * g.ci * g.co))[:, None])


@_quiet
def abc_smooth(theta_i, phi_i, theta_o, phi_o, A, B, C, eta):
    """Löw, Kronander, Ynnerman & Unger, BRDF models for accurate and efficient rendering of glossy surfaces, TOG
    2012, smooth-surface model (Eqs. 10-14, as BBM evaluates it): f = A (1 + B Dp²)^(−C) F(θd, η), Dp the length
    of the sum of the directions' projections on the surface, cosθd = √(1 − |difference of projections|²/4)."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    ix, iy = g.si * np.cos(g.pi_), g.si * np.sin(g.pi_)
    ox, oy = g.so * np.cos(g.po), g.so * np.sin(g.po)
    dp2 = (ix + ox) ** 2 + (iy + oy) ** 2
    cos_d = np.sqrt(np.clip(1.0 - 0.25 * ((ix - ox) ** 2 + (iy - oy) ** 2), 0.0, 1.0))
    f = fresnel_dielectric(np.arccos(cos_d), 1.0, eta)
    return _masked(g, _col(A) * ((1.0 + B * dp2) ** (-C) * f)[:, None])


@_quiet
def abc_microfacet(theta_i, phi_i, theta_o, phi_o, A, B, C, eta):
    """Löw et al. 2012, Eq. 15 with Cook & Torrance's form (π, V-cavity G, exact dielectric F at θd):
    f = A (1 + B (1 − cosθh))^(−C) F(θd, η) G / (π cosθi cosθo)."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    ch = np.cos(g.th)
    gg = np.minimum(1.0, np.minimum(2 * ch * g.co / g.cos_d, 2 * ch * g.ci / g.cos_d))
    f = fresnel_dielectric(np.arccos(g.cos_d), 1.0, eta)
    return _masked(g, _col(A) * ((1.0 + B * (1.0 - ch)) ** (-C) * f * gg / (math.pi * g.ci * g.co))[:, None])


@_quiet
def sgd(theta_i, phi_i, theta_o, phi_o, ks, alpha, p, f0, f1, shadow_lambda, shadow_c, shadow_k, shadow_theta0):
    """Bagher, Soler & Holzschuch, CGF 31(4) 2012, as BBM evaluates it: f = ks F D G1 G1 / (π cosθi cosθo),
    D = K exp(−(α + tan²θh/α)) (α + tan²θh/α)^(−p) / (π cos⁴θh) with K = 1/(α Γ(1 − p, α)) (SciPy's gamma and
    gammaincc), F = f0 + (1 − f0)(1 − cosθd)⁵ − f1 cosθd, G1(θ) = 1 + Λ (1 − e^(c (θ − θ0)^k)) beyond θ0."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    k_norm = 1.0 / (alpha * special.gamma(1.0 - p) * special.gammaincc(1.0 - p, alpha))
    shifted = alpha + np.tan(g.th) ** 2 / alpha
    d = k_norm * np.exp(-shifted) * shifted ** (-p) / (math.pi * np.cos(g.th) ** 4)

    def g1(theta):
        return np.where(theta > shadow_theta0,
                        1.0 + shadow_lambda * (1.0 - np.exp(shadow_c * np.abs(theta - shadow_theta0) ** shadow_k)), 1.0)

    f = f0 + (1.0 - f0) * (1.0 - g.cos_d) ** 5 - f1 * g.cos_d
    return _masked(g, _col(ks) * (f * d * g1(g.ti) * g1(g.to) / (math.pi * g.ci * g.co))[:, None])


@_quiet
def principled(theta_i, phi_i, theta_o, phi_o, base_color, metallic, roughness, specular, spec_tint, anisotropic,
               sheen, sheen_tint, clearcoat, clearcoat_gloss):
    """The Disney principled BRDF as Mitsuba 3's ``principled`` plugin evaluates its reflection (Burley 2012 and
    2015; src/bsdfs/principled.cpp, principledhelpers.h), written from the plugin's terms with w(c) = (1 − c)⁵:

    diffuse (1 − metallic) base/π ((1 − w(ci)/2)(1 − w(co)/2) + R (w(ci) + w(co) + w(ci) w(co)(R − 1))),
    R = 2 roughness cos²θd; sheen (1 − metallic) w(cosθd) (1 + sheen_tint (base/lum − 1)), lum the Rec. 709
    luminance; specular F D G/(4 ci co) with anisotropic GGX D and separable Smith G at αx = max(10⁻³, r²/a),
    αy = max(10⁻³, r² a), a = √(1 − 0.9 anisotropic), F = (1 − metallic)(1 − spec_tint) F_dielectric(θd, η)
    + metallic Schlick(base) + (1 − metallic) spec_tint Schlick(base/lum · R0(η)), η = 2/(1 − √(0.08 specular)) − 1;
    clearcoat ¼ clearcoat Schlick(0.04) D_GTR1 G1(θi) G1(θo), GTR1 width 0.1 + gloss (0.001 − 0.1), D_GTR1 =
    (α² − 1)/(π ln α² (1 + (α² − 1) cos²θh)), G1 GGX's of width 0.25 (no 1/(4 ci co), as the plugin)."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    base = _col(base_color)
    lum = base[:, 0] * 0.212671 + base[:, 1] * 0.715160 + base[:, 2] * 0.072169 if base.shape[1] == 3 else base[:, 0]
    tint = base / lum[:, None]

    def w(c):
        return (1.0 - c) ** 5

    wi, wo, wd = w(g.ci), w(g.co), w(g.cos_d)
    rr = 2.0 * roughness * g.cos_d**2
    diffuse = (1.0 - metallic) * base / math.pi * ((1 - wi / 2) * (1 - wo / 2) + rr * (wi + wo + wi * wo * (rr - 1)))[:, None]
    sheen_term = sheen * (1.0 - metallic) * wd[:, None] * (1.0 + sheen_tint * (tint - 1.0))
    aspect = math.sqrt(1.0 - 0.9 * anisotropic)
    ax, ay = max(1e-3, roughness**2 / aspect), max(1e-3, roughness**2 * aspect)
    d = microfacet_D_aniso("ggx", g.th, g.ph, ax, ay)
    gg = 1.0 / (1.0 + smith_lambda_aniso("ggx", g.ti, g.pi_, ax, ay)) / (1.0 + smith_lambda_aniso("ggx", g.to, g.po, ax, ay))
    eta = 2.0 / (1.0 - math.sqrt(0.08 * specular)) - 1.0
    r0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    fd = fresnel_dielectric(np.arccos(g.cos_d), 1.0, eta)[:, None]
    c = g.cos_d[:, None]
    f = ((1 - metallic) * (1 - spec_tint) * fd + metallic * fresnel_schlick(c, base)
         + (1 - metallic) * spec_tint * fresnel_schlick(c, tint * r0))
    spec = f * (d * gg / (4.0 * g.ci * g.co))[:, None]
    a = 0.1 + clearcoat_gloss * (0.001 - 0.1)
    d_cc = (a * a - 1.0) / (math.pi * math.log(a * a) * (1.0 + (a * a - 1.0) * np.cos(g.th) ** 2))
    g_cc = smith_G1("ggx", g.ti, 0.25) * smith_G1("ggx", g.to, 0.25)
    cc = 0.25 * clearcoat * fresnel_schlick(g.cos_d, 0.04) * d_cc * g_cc
    return _masked(g, diffuse + sheen_term + spec + cc[:, None])


# --------------------------------------------------------------------------------------------------------------
# Two-tone (toon) lobes, issue 2's definition (after Lake et al., NPAR 2000, with a logistic step)


@_quiet
def toon_diffuse(theta_i, phi_i, theta_o, phi_o, rho_d, rho_shade, threshold, width):
    """f = (ρshade + (ρd − ρshade) S((cosθi − threshold)/width))/π, S(u) = 1/(1 + e^(−u))."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    step = special.expit((g.ci - threshold) / width)[:, None]
    return _masked(g, (_col(rho_shade) + (_col(rho_d) - _col(rho_shade)) * step) / math.pi)


@_quiet
def toon_specular(theta_i, phi_i, theta_o, phi_o, ks, threshold, width):
    """f = ks S((cosψ − threshold)/width)/π, ψ the angle between ωo and the mirror direction of ωi."""
    g = Pair(theta_i, phi_i, theta_o, phi_o)
    cos_psi = g.ci * g.co - g.si * g.so * np.cos(g.dphi)
    return _masked(g, _col(ks) * special.expit((cos_psi - threshold) / width)[:, None] / math.pi)


# --------------------------------------------------------------------------------------------------------------
# Reference of a single registered lobe, from its brdffit name, options and (model-level) parameter dict


def _lafortune_ref(ti, pi_, to, po, p, lobes=1, anisotropic=False):
    spec = []
    for j in range(1, lobes + 1):
        cx = p[f"cx_{j}"] if anisotropic else p[f"cxy_{j}"]
        cy = p[f"cy_{j}"] if anisotropic else p[f"cxy_{j}"]
        spec.append({"ks": p[f"ks_{j}"], "cx": cx, "cy": cy, "cz": p[f"cz_{j}"], "n": p[f"n_{j}"]})
    return lafortune(ti, pi_, to, po, spec)


def _ct_ref(ti, pi_, to, po, p, roughness="m", distribution="beckmann", shadowing="v-cavity", fresnel="schlick",
            anisotropic=False):
    width = (p[f"{roughness}_x"], p[f"{roughness}_y"]) if anisotropic else p[roughness]
    return cook_torrance(ti, pi_, to, po, p["ks"], width, distribution=distribution, shadowing=shadowing,
                         fresnel=fresnel, f0=p.get("f0"), eta=p.get("eta"), k=p.get("k"), gamma=p.get("gamma"))


def gltf_sheen_brdf(theta_i, theta_o, theta_h, sheen_roughness):
    """KHR_materials_sheen, "Implementation Notes": the Charlie sheen BRDF of a white sheen colour, D_s ν_s with
    α = sheenRoughness², D_s = (2 + 1/α) sin(θh)^(1/α)/(2π) and
    ν_s = 1/((1 + λ(N·V) + λ(N·L)) 4 (N·V)(N·L)), λ Estevez & Kulla's fit (`charlie_lambda`)."""
    alpha = sheen_roughness ** 2
    d = (2.0 + 1.0 / alpha) * np.sin(theta_h) ** (1.0 / alpha) / (2.0 * np.pi)
    vis = 1.0 / ((1.0 + charlie_lambda(theta_o, alpha) + charlie_lambda(theta_i, alpha))
                 * (4.0 * np.cos(theta_o) * np.cos(theta_i)))
    return d * vis


def _cubed_legendre(n: int, scale: float):
    """Gauss-Legendre on [0, 1] in u with x = scale u³: nodes x and weights (3 scale u² du)."""
    t, wt = np.polynomial.legendre.leggauss(n)
    u, wu = (t + 1.0) / 2.0, wt / 2.0
    return scale * u ** 3, 3.0 * scale * u ** 2 * wu


def gltf_sheen_albedo(mu: float, sheen_roughness, cos_nodes: int = 64, phi_nodes: int = 64):
    """E(μ) = ∫ D_s ν_s cosθi dωi over the upper hemisphere with the view at cosθo = μ (azimuth 0) and ωi at
    (θi, φi): Gauss-Legendre in cosθi on [0, ½] and [½, 1] (cosθi = ½u³ and 1 − ½u³) and in φi on [0, π]
    (φi = π v³, the integrand even in φi: doubled). ``sheen_roughness``: a float or a 1-D array (E for each)."""
    low, w_low = _cubed_legendre(cos_nodes, 0.5)
    cos_i = np.concatenate([low, 1.0 - low])[:, None]
    w_cos = np.concatenate([w_low, w_low])[:, None]
    phi, w_phi = _cubed_legendre(phi_nodes, np.pi)
    theta_i = np.arccos(cos_i)
    theta_o = math.acos(mu)
    # h ∝ ωi + ωo; θh from its components.
    hx = np.sin(theta_i) * np.cos(phi)[None, :] + math.sin(theta_o)
    hy = np.sin(theta_i) * np.sin(phi)[None, :]
    hz = cos_i + mu
    theta_h = np.arctan2(np.hypot(hx, hy), hz)
    rough = np.atleast_1d(np.asarray(sheen_roughness, dtype=float))[:, None, None]
    f = gltf_sheen_brdf(theta_i, theta_o, theta_h, rough)
    e = np.sum(f * cos_i * w_cos * 2.0 * w_phi[None, :], axis=(1, 2))
    return e if np.ndim(sheen_roughness) else float(e[0])


@functools.lru_cache(maxsize=1)
def gltf_sheen_table() -> np.ndarray:
    """brdffit's sheen albedo table written again from its stated definition (brdffit.models.gltf): 32 × 32 nodes,
    μ = i/31 (the first at 1e-4) and sheen roughness uniform on [0.1, 1], `gltf_sheen_albedo` at each, clamped to
    [0, 1]. Indexed [sheen roughness, μ]."""
    mus = np.maximum(np.arange(32) / 31.0, 1e-4)
    rough = 0.1 + 0.9 * np.arange(32) / 31.0
    return np.clip(np.stack([gltf_sheen_albedo(m, rough) for m in mus], axis=1), 0.0, 1.0)


def gltf_sheen_lookup(mu, sheen_roughness):
    """Bilinear interpolation of `gltf_sheen_table` in (μ, (sheen roughness − 0.1)/0.9), both over nodes
    i/31."""
    table = gltf_sheen_table()
    x = np.clip(np.asarray(mu, dtype=float), 0.0, 1.0) * 31.0
    y = min(max((sheen_roughness - 0.1) / 0.9, 0.0), 1.0) * 31.0
    i, j = np.minimum(np.floor(x), 30).astype(int), min(int(math.floor(y)), 30)
    tx, ty = x - i, y - j
    row = lambda k: table[k, i] * (1.0 - tx) + table[k, i + 1] * tx  # noqa: E731
    return row(j) * (1.0 - ty) + row(j + 1) * ty


@_quiet
def gltf(theta_i, phi_i, theta_o, phi_o, base_color, metallic, roughness, specular, ior, specular_color,
         clearcoat=0.0, clearcoat_roughness=0.1, sheen_color=0.0, sheen_roughness=0.5):
    """The glTF 2.0 metallic-roughness material (glTF 2.0 Specification, Appendix B, "Specular BRDF", "Fresnel" and
    "Metal BRDF and Dielectric BRDF") with KHR_materials_ior and KHR_materials_specular ("Implementation"), written
    from the specification's visibility form: with α = roughness², L = ωi, V = ωo,

        Vis = 1 / (2 (|N·V| √(α² + (1 − α²)(N·L)²) + |N·L| √(α² + (1 − α²)(N·V)²))),
        D = α² / (π ((N·H)²(α² − 1) + 1)²),   specular_brdf = Vis D,
        fr = f0 + (1 − f0)(1 − |V·H|)⁵,  f0 = min(((1 − ior)/(1 + ior))² specular_color, 1),
        dielectric = (1 − specular max(fr)) base_color/π + specular fr specular_brdf,
        metal = specular_brdf (base_color + (1 − base_color)(1 − |V·H|)⁵),
        material = (1 − metallic) dielectric + metallic metal,
        sheened = sheen_color D_s ν_s + material min(1 − max(sheen_color) E(N·V), 1 − max(sheen_color) E(N·L))
                                                                                   (KHR_materials_sheen),
        coated = mix(sheened, Vis_c D_c, clearcoat (0.04 + 0.96 (1 − |N·V|)⁵))   (KHR_materials_clearcoat),
    Vis_c, D_c those of α = clearcoat_roughness², D_s ν_s `gltf_sheen_brdf`, E `gltf_sheen_lookup`.
    """
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    base, tint = _col(base_color), _col(specular_color)
    a2 = roughness ** 4
    nl, nv = pair.ci[:, None], pair.co[:, None]
    vis = 1.0 / (2.0 * (nv * np.sqrt(a2 + (1.0 - a2) * nl ** 2) + nl * np.sqrt(a2 + (1.0 - a2) * nv ** 2)))
    d = a2 / (np.pi * (np.cos(pair.th)[:, None] ** 2 * (a2 - 1.0) + 1.0) ** 2)
    brdf = vis * d
    schlick = (1.0 - pair.cos_d[:, None]) ** 5
    f0 = np.minimum(((1.0 - ior) / (1.0 + ior)) ** 2 * tint, 1.0)
    fresnel = f0 + (1.0 - f0) * schlick
    dielectric = (1.0 - specular * fresnel.max(axis=1, keepdims=True)) * base / np.pi + specular * fresnel * brdf
    metal = brdf * (base + (1.0 - base) * schlick)
    material = (1.0 - metallic) * dielectric + metallic * metal
    sheen = _col(sheen_color)
    strength = float(np.max(sheen))
    if strength > 0:  # "If sheenColorFactor is zero, the whole sheen layer is disabled."
        scaling = np.minimum(1.0 - strength * gltf_sheen_lookup(pair.co, sheen_roughness),
                             1.0 - strength * gltf_sheen_lookup(pair.ci, sheen_roughness))[:, None]
        material = sheen * gltf_sheen_brdf(pair.ti, pair.to, pair.th, sheen_roughness)[:, None] + material * scaling
    c2 = clearcoat_roughness ** 4
    vis_c = 1.0 / (2.0 * (nv * np.sqrt(c2 + (1.0 - c2) * nl ** 2) + nl * np.sqrt(c2 + (1.0 - c2) * nv ** 2)))
    d_c = c2 / (np.pi * (np.cos(pair.th)[:, None] ** 2 * (c2 - 1.0) + 1.0) ** 2)
    weight = clearcoat * (0.04 + 0.96 * (1.0 - nv) ** 5)
    return _masked(pair, (1.0 - weight) * material + weight * vis_c * d_c)


@functools.lru_cache(maxsize=1)
def cycles_layering_table(u_nodes: int = 96, phi_nodes: int = 64) -> np.ndarray:
    """Cycles' ``ggx_gen_schlick_ior_s`` (``app/cycles_precompute.cpp``): at roughness r and μ = i/15 (clamped to
    [1e-4, 1]) and z = i/15 (clamped to [1e-4, 0.99], η = (1 + z²)/(1 − z²)), the mean over the GGX visible normals h
    of a view v at cosine μ (Heitz 2014, Eq. 38: G1(v) (v·h)⁺ D(h)/μ) of the blend factor
    (F_dielectric(v·h) − F0)/(1 − F0), counting 0 where the mirror direction 2(v·h)h − v is below the surface.
    Gauss-Legendre in t = tan²θh/(α² + tan²θh), where D cosθh dω = dt dφ/(2π), and in φ ∈ [0, 2π).
    Returns the table indexed [z, μ, r]."""
    nodes = np.arange(16) / 15.0
    t, wt = np.polynomial.legendre.leggauss(u_nodes)
    t, wt = (t + 1.0) / 2.0, wt / 2.0
    p, wp = np.polynomial.legendre.leggauss(phi_nodes)
    p, wp = (p + 1.0) * np.pi / 2.0, wp * np.pi / 2.0  # half the circle; the integrand is even in φ
    out = np.zeros((16, 16, 16))
    for ir, r in enumerate(np.clip(nodes, 1e-4, 1.0)):
        alpha2 = r ** 4
        theta_h = np.arctan(np.sqrt(alpha2 * t / (1.0 - t)))
        h = np.stack([np.sin(theta_h)[:, None] * np.cos(p)[None, :], np.sin(theta_h)[:, None] * np.sin(p)[None, :],
                      np.cos(theta_h)[:, None] * np.ones(phi_nodes)[None, :]], axis=-1)
        w = (wt[:, None] * wp[None, :]) / np.pi  # 2 (both halves) / (2π)
        for im, mu in enumerate(np.clip(nodes, 1e-4, 1.0)):
            v = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
            vh = h @ v
            mirror_z = 2.0 * vh * h[..., 2] - mu
            g1 = 1.0 / (1.0 + 0.5 * (math.sqrt(1.0 + alpha2 * (1.0 - mu * mu) / mu ** 2) - 1.0))
            keep = (vh > 0) & (mirror_z > 0)
            for iz, z in enumerate(np.clip(nodes, 1e-4, 0.99)):
                eta = (1.0 + z * z) / (1.0 - z * z)
                f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
                cos_t = np.sqrt(np.clip(1.0 - (1.0 - np.clip(vh, 0, 1) ** 2) / eta ** 2, 0.0, 1.0))
                c = np.clip(vh, 0, 1)
                fresnel = 0.5 * (((c - eta * cos_t) / (c + eta * cos_t)) ** 2
                                 + ((eta * c - cos_t) / (eta * c + cos_t)) ** 2)
                blend = np.clip((fresnel - f0) / (1.0 - f0), 0.0, 1.0)
                s = float(np.sum(np.where(keep, w * g1 * vh / (mu * h[..., 2]) * blend, 0.0)))
                out[iz, im, ir] = min(max(s, 0.0), 1.0)
    return out


def _lookup3(table, x, y, z):
    """Cycles' ``lookup_table_read_3D`` (kernel/util/lookup_table.h): linear per axis over nodes i/(n − 1)."""
    n = table.shape[0]

    def axis(c):
        c = np.clip(c, 0.0, 1.0) * (n - 1)
        i = np.minimum(c.astype(int), n - 1)
        return i, np.minimum(i + 1, n - 1), c - i

    (x0, x1, tx), (y0, y1, ty), (z0, z1, tz) = (axis(np.asarray(c, float)) for c in (x, y, z))

    def plane(k):
        row0 = table[k, y0, x0] * (1 - tx) + table[k, y0, x1] * tx
        row1 = table[k, y1, x0] * (1 - tx) + table[k, y1, x1] * tx
        return row0 * (1 - ty) + row1 * ty

    return plane(z0) * (1 - tz) + plane(z1) * tz


@_quiet
def blender(theta_i, phi_i, theta_o, phi_o, base_color, metallic, roughness, ior, coat_weight=0.0,
            coat_roughness=0.1, coat_ior=1.5, coat_tint=1.0, sheen_weight=0.0, sheen_tint=1.0, sheen_roughness=0.5):
    """Blender's Principled BSDF with distribution GGX as Cycles evaluates it (intern/cycles/kernel/svm/closure.h,
    kernel/closure/bsdf_microfacet.h): with V = ωo (the view), L = ωi, α = roughness²,

        spec = D G2 / (4 |N·L| |N·V|),  G2 = 1/(1 + Λ(L) + Λ(V)),  Λ = (√(1 + α² tan²θ) − 1)/2,
        metal = Schlick(base_color, V·H) spec,  dielectric = F_dielectric(V·H, ior) spec,
        diffuse = (1 − E) base_color/π,  E = F0 + (1 − F0) S(roughness, N·V, √((ior − 1)/(ior + 1))),
        f = metallic metal + (1 − metallic)(dielectric + diffuse),

    S Cycles' table `cycles_layering_table`, read by `_lookup3`. A coat of weight w (Cycles 4.2's closure.h, its
    second layer, over the rest): a GGX closure of weight w, α_c = coat_roughness², with the dielectric Fresnel term
    of coat_ior and no energy compensation (4.2's bsdf_microfacet_setup_fresnel_dielectric); the layers beneath
    weighted by closure_layering_weight = clamp(1 − w F_dielectric(N·V), 0, 1) (bsdf_albedo: the closure's weight
    times the smooth-surface Fresnel term at the view, bsdf_microfacet_estimate_albedo) and by
    mix(1, coat_tint^(1/cosNT), w), cosNT = √(1 − (1 − (N·V)²)/η²). A sheen of weight w_s (closure.h's first
    layer, over everything, bsdf_sheen.h): w_s sheen_tint E D_LTC(L)/(N·L) with the layers beneath weighted by
    clamp(1 − max(w_s sheen_tint) E, 0, 1), E and the LTC's coefficients here MaterialX's fits (`_zeltner_sheen`),
    where Cycles reads its table (not shipped by bpy)."""
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    base = _col(base_color)
    a2 = roughness ** 4
    ch = np.cos(pair.th)
    d = a2 / (np.pi * (ch ** 2 * (a2 - 1.0) + 1.0) ** 2)

    def lam(c):
        return 0.5 * (np.sqrt(1.0 + a2 * (1.0 - c * c) / (c * c)) - 1.0)

    spec = (d / (1.0 + lam(pair.ci) + lam(pair.co)) / (4.0 * pair.ci * pair.co))[:, None]
    c = pair.cos_d[:, None]
    schlick = base + (1.0 - base) * (1.0 - c) ** 5
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / ior ** 2)
    dielectric = 0.5 * (((c - ior * cos_t) / (c + ior * cos_t)) ** 2 + ((ior * c - cos_t) / (ior * c + cos_t)) ** 2)
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    s = _lookup3(cycles_layering_table(), roughness, pair.co, math.sqrt((ior - 1.0) / (ior + 1.0)))
    albedo = f0 + (1.0 - f0) * s
    diffuse = np.clip(1.0 - albedo, 0.0, 1.0)[:, None] * base / np.pi
    response = metallic * schlick * spec + (1.0 - metallic) * (dielectric * spec + diffuse)
    if coat_weight > 1e-5:  # CLOSURE_WEIGHT_CUTOFF
        a2c = coat_roughness ** 4
        d_c = a2c / (np.pi * (ch ** 2 * (a2c - 1.0) + 1.0) ** 2)

        def lam_c(c):
            return 0.5 * (np.sqrt(1.0 + a2c * (1.0 - c * c) / (c * c)) - 1.0)

        spec_c = d_c / (1.0 + lam_c(pair.ci) + lam_c(pair.co)) / (4.0 * pair.ci * pair.co)
        cos_tc = np.sqrt(1.0 - (1.0 - pair.cos_d ** 2) / coat_ior ** 2)
        fresnel_c = 0.5 * (((pair.cos_d - coat_ior * cos_tc) / (pair.cos_d + coat_ior * cos_tc)) ** 2
                           + ((coat_ior * pair.cos_d - cos_tc) / (coat_ior * pair.cos_d + cos_tc)) ** 2)
        coat = coat_weight * fresnel_c * spec_c
        cos_nt = np.sqrt(1.0 - (1.0 - pair.co ** 2) / coat_ior ** 2)
        fresnel_v = 0.5 * (((pair.co - coat_ior * cos_nt) / (pair.co + coat_ior * cos_nt)) ** 2
                           + ((coat_ior * pair.co - cos_nt) / (coat_ior * pair.co + cos_nt)) ** 2)
        layering = np.clip(1.0 - coat_weight * fresnel_v, 0.0, 1.0)
        tint = 1.0 + coat_weight * (_col(coat_tint) ** (1.0 / cos_nt)[:, None] - 1.0)
        response = coat[:, None] + (layering[:, None] * tint) * response
    if sheen_weight > 1e-5:  # CLOSURE_WEIGHT_CUTOFF
        sheen, sheen_albedo = _zeltner_sheen(pair, pair.co, sheen_roughness)
        colour = sheen_weight * _col(sheen_tint)
        layering = np.clip(1.0 - np.max(colour) * sheen_albedo, 0.0, 1.0)  # closure_layering_weight
        response = colour * (sheen / pair.ci)[:, None] + layering[:, None] * response
    return _masked(pair, response)


# MaterialX's rational fit of the GGX directional albedo (libraries/pbrlib/genglsl/lib/mx_microfacet_specular.glsl,
# mx_ggx_dir_albedo_analytic), its vec4 coefficients per monomial, in the order the GLSL adds them.
_MX_ALBEDO = [
    ((0.1003, 0.9345, 1.0, 1.0), lambda x, y: 1.0),
    ((-0.6303, -2.323, -1.765, 0.2281), lambda x, y: x),
    ((9.748, 2.229, 8.263, 15.94), lambda x, y: y),
    ((-2.038, -3.748, 11.53, -55.83), lambda x, y: x * y),
    ((29.34, 1.424, 28.96, 13.08), lambda x, y: x * x),
    ((-8.245, -0.7684, -7.507, 41.26), lambda x, y: y * y),
    ((-26.44, 1.436, -36.11, 54.9), lambda x, y: x * x * y),
    ((19.99, 0.2913, 15.86, 300.2), lambda x, y: x * y * y),
    ((-5.448, 0.6286, 33.37, -285.1), lambda x, y: x * x * y * y),
]


@_quiet
def openpbr(theta_i, phi_i, theta_o, phi_o, base_color, base_metalness, base_diffuse_roughness, specular_weight,
            specular_color, specular_roughness, specular_ior, coat_weight=0.0, coat_color=1.0, coat_roughness=0.0,
            coat_ior=1.6, coat_darkening=1.0, fuzz_weight=0.0, fuzz_color=1.0, fuzz_roughness=0.5):
    """OpenPBR Surface (opaque, uncoated, isotropic, base_weight 1) as MaterialX 1.39 evaluates it, transcribed
    from MaterialX's GLSL (libraries/pbrlib/genglsl: mx_dielectric_bsdf, mx_generalized_schlick_bsdf,
    mx_oren_nayar_diffuse_bsdf, mx_sheen_bsdf, mx_layer_bsdf, mx_mix_bsdf, lib/mx_microfacet_specular.glsl,
    lib/mx_microfacet_diffuse.glsl, lib/mx_microfacet_sheen.glsl) and the graph NG_open_pbr_surface_surfaceshader
    (libraries/bxdf): each BSDF's ``response`` is f cosθi, so f = response / (N·L); L = ωi, V = ωo, EPS =
    M_FLOAT_EPS = 1e-8. The coat (weight 0: none) is the graph's ``coat_layer`` over the darkened, attenuated base
    substrate, and the fuzz layer (weight 0: none) its ``fuzz_layer`` over that."""
    eps = 1e-8
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    base, tint = _col(base_color), _col(specular_color)
    n_l, n_v = np.clip(pair.ci, eps, 1.0), np.clip(pair.co, eps, 1.0)
    v_h = np.clip(pair.cos_d, eps, 1.0)
    # The graph's effective_specular_roughness: mix(bg = specular_roughness, fg = coat_affected, coat_weight).
    coat_affected = min(1.0, 2.0 * coat_roughness ** 4 + specular_roughness ** 4) ** 0.25
    effective = specular_roughness * (1.0 - coat_weight) + coat_affected * coat_weight
    # open_pbr_anisotropy at anisotropy 0: alpha = roughness^2 * sqrt(2 / (1 + 1)); safeAlpha, avgAlpha.
    alpha = min(max(effective ** 2, eps), 1.0)
    he2 = (pair.hx ** 2 + pair.hy ** 2) / alpha ** 2
    d = 1.0 / (np.pi * alpha * alpha * (he2 + pair.hz ** 2) ** 2)  # mx_ggx_NDF
    lam_l = np.sqrt(alpha ** 2 + (1.0 - alpha ** 2) * n_l ** 2)
    lam_v = np.sqrt(alpha ** 2 + (1.0 - alpha ** 2) * n_v ** 2)
    g = 2.0 * n_l * n_v / (lam_l * n_v + lam_v * n_l)  # mx_ggx_smith_G2

    def dir_albedo(f0, f90):  # mx_ggx_dir_albedo_analytic at (N.V, alpha)
        r = [sum(c[k] * m(n_v, alpha) for c, m in _MX_ALBEDO) for k in range(4)]
        return f0 * np.clip(r[0] / r[2], 0.0, 1.0) + f90 * np.clip(r[1] / r[3], 0.0, 1.0)

    e_ss = dir_albedo(1.0, 1.0)[:, None]

    def comp(f):  # mx_ggx_energy_compensation
        return 1.0 + f * (1.0 - e_ss) / e_ss

    # The graph's eta_s (specular_to_coat_ior_ratio_tir_fix: ifgreater(ratio, 1, ratio, 1 / ratio) mixed by
    # coat_weight with specular_ior) and modulated_eta_s.
    ratio = specular_ior / coat_ior
    eta_s = specular_ior * (1.0 - coat_weight) + (ratio if ratio > 1.0 else coat_ior / specular_ior) * coat_weight
    f0 = ((eta_s - 1.0) / (eta_s + 1.0)) ** 2
    epsilon = np.sign(eta_s - 1.0) * np.sqrt(np.clip(specular_weight * f0, 0.0, 0.99999))
    eta = (1.0 + epsilon) / (1.0 - epsilon)
    # mx_fresnel_dielectric (Lagarde's form).
    g2 = eta * eta + v_h * v_h - 1.0
    gg = np.sqrt(g2)
    fresnel = 0.5 * ((gg - v_h) / (gg + v_h)) ** 2 * (1.0 + (((gg + v_h) * v_h - 1.0) / ((gg - v_h) * v_h + 1.0)) ** 2)
    fresnel = np.where(g2 < 0.0, 1.0, fresnel)[:, None]
    k_d = comp(fresnel)
    spec_response = (d * g / (4.0 * n_v))[:, None] * fresnel * k_d * tint
    throughput = 1.0 - dir_albedo(((eta - 1.0) / (eta + 1.0)) ** 2, 1.0)[:, None] * k_d
    # mx_oren_nayar_compensated_diffuse, energy_compensation true, weight base_weight = 1.
    r = base_diffuse_roughness
    l_v = np.clip(pair.cos_io, eps, 1.0)
    s = l_v - n_l * n_v
    stinv = np.where(s > 0.0, s / np.maximum(n_l, n_v), s)
    c1, c2 = 0.5 - 2.0 / (3.0 * np.pi), 2.0 / 3.0 - 28.0 / (15.0 * np.pi)
    a = 1.0 / (1.0 + c1 * r)

    def fujii(cos_t):
        si = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
        gf = si * (np.arccos(np.clip(cos_t, -1.0, 1.0)) - si * cos_t) + 2.0 * ((si / cos_t) * (1.0 - si ** 3) - si) / 3.0
        return a + r * a * gf / np.pi

    single = base * (a * (1.0 + r * stinv))[:, None]
    avg = a * (1.0 + c2 * r)
    colour_ms = base ** 2 * avg / (1.0 - base * max(0.0, 1.0 - avg))
    multi = colour_ms * (np.maximum(eps, 1.0 - fujii(n_v)) * np.maximum(eps, 1.0 - fujii(n_l))
                         / max(eps, 1.0 - avg))[:, None]
    diffuse_response = (single + multi) * n_l[:, None] / np.pi
    dielectric = spec_response + throughput * diffuse_response  # mx_layer_bsdf
    # mx_generalized_schlick_bsdf: color0 = base_color, color82 = specular_color, color90 = 1, exponent 5.
    x = np.clip(v_h, 0.0, 1.0)[:, None]
    cos_max = 1.0 / 7.0
    factor = 1.0 / (cos_max * (1.0 - cos_max) ** 6)
    a82 = (base + (1.0 - base) * (1.0 - cos_max) ** 5) * (1.0 - tint) * factor
    f82 = base + (1.0 - base) * (1.0 - x) ** 5 - a82 * x * (1.0 - x) ** 6  # mx_fresnel_hoffman_schlick
    metal = (d * g / (4.0 * n_v))[:, None] * f82 * comp(f82) * specular_weight
    response = (1.0 - base_metalness) * dielectric + base_metalness * metal  # mx_mix_bsdf: base_substrate
    if coat_weight >= eps:  # mx_dielectric_bsdf returns nothing (throughput 1) below M_FLOAT_EPS
        coat_f0 = ((coat_ior - 1.0) / (coat_ior + 1.0)) ** 2
        k_coat = 1.0 - (1.0 - coat_f0) / coat_ior ** 2
        e_base = base * (1.0 - base_metalness) + base * specular_weight * base_metalness
        darkening = (1.0 - k_coat) / (1.0 - e_base * k_coat)
        amount = coat_weight * coat_darkening
        substrate = response * (darkening * amount + (1.0 - amount)) * (_col(coat_color) * coat_weight
                                                                         + (1.0 - coat_weight))
        c_alpha = min(max(coat_roughness ** 2, eps), 1.0)
        c_d = 1.0 / (np.pi * c_alpha ** 2 * ((pair.hx ** 2 + pair.hy ** 2) / c_alpha ** 2 + pair.hz ** 2) ** 2)
        c_lam_l = np.sqrt(c_alpha ** 2 + (1.0 - c_alpha ** 2) * n_l ** 2)
        c_lam_v = np.sqrt(c_alpha ** 2 + (1.0 - c_alpha ** 2) * n_v ** 2)
        c_g = 2.0 * n_l * n_v / (c_lam_l * n_v + c_lam_v * n_l)
        r = [sum(c[k] * m(n_v, c_alpha) for c, m in _MX_ALBEDO) for k in range(4)]
        c_a, c_b = np.clip(r[0] / r[2], 0.0, 1.0), np.clip(r[1] / r[3], 0.0, 1.0)
        g2 = coat_ior ** 2 + v_h ** 2 - 1.0
        gg = np.sqrt(g2)
        c_fresnel = 0.5 * ((gg - v_h) / (gg + v_h)) ** 2 * (1.0 + (((gg + v_h) * v_h - 1.0)
                                                                  / ((gg - v_h) * v_h + 1.0)) ** 2)
        c_comp = 1.0 + c_fresnel * (1.0 - (c_a + c_b)) / (c_a + c_b)
        coat_response = c_d * c_fresnel * c_g * c_comp * coat_weight / (4.0 * n_v)
        coat_throughput = 1.0 - (coat_f0 * c_a + c_b) * c_comp * coat_weight
        response = coat_response[:, None] + coat_throughput[:, None] * substrate  # mx_layer_bsdf: coat_layer
    if fuzz_weight >= eps:  # mx_sheen_bsdf returns nothing (throughput 1) below M_FLOAT_EPS
        sheen_response, sheen_albedo = _zeltner_sheen(pair, n_v, fuzz_roughness)
        response = (fuzz_weight * _col(fuzz_color) * sheen_response[:, None]
                    + (1.0 - sheen_albedo * fuzz_weight)[:, None] * response)  # mx_layer_bsdf
    return _masked(pair, response / n_l[:, None])


def _zeltner_sheen(pair, n_v, roughness):
    """``mx_sheen_bsdf`` in its zeltner mode with white colour and weight 1: (response, dirAlbedo), built with the
    GLSL's vectors (mx_orthonormal_basis_ltc: X = normalize(V − N N·V), Y = N × X; toLTC its transpose)."""
    roughness = min(max(roughness, 0.01), 1.0)
    x, y = n_v, roughness
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    dir_albedo = np.exp(-0.5 * ((x - m) / s) ** 2) / (s * np.sqrt(2.0 * np.pi)) + o
    a_inv = (2.58126 * x + 0.813703 * y) * y / (1.0 + 0.310327 * x * x + 2.60994 * x * y)
    b_inv = np.sqrt(1.0 - x) * (y - 1.0) * y * y * y / (0.0000254053 + 1.71228 * x - 1.71506 * x * y
                                                          + 1.34174 * y * y)
    light = np.stack([pair.si * np.cos(pair.pi_), pair.si * np.sin(pair.pi_), pair.ci], axis=-1)
    view = np.stack([pair.so * np.cos(pair.po), pair.so * np.sin(pair.po), pair.co], axis=-1)
    normal = np.array([0.0, 0.0, 1.0])
    tangent = view - normal * (view @ normal)[:, None]
    length2 = np.sum(tangent * tangent, axis=-1)
    # V = N: mx_orthonormal_basis(N); any frame gives the same value there, as b_inv = 0.
    tangent = np.where((length2 > 0.0)[:, None], tangent / np.sqrt(np.where(length2 > 0.0, length2, 1.0))[:, None],
                       np.array([1.0, 0.0, 0.0]))
    bitangent = np.cross(normal, tangent)
    w = np.stack([np.sum(light * tangent, -1), np.sum(light * bitangent, -1), light @ normal], axis=-1)
    wo = np.stack([a_inv * w[:, 0] + b_inv * w[:, 2], a_inv * w[:, 1], w[:, 2]], axis=-1)
    len_sqr = np.sum(wo * wo, axis=-1)
    ltc = np.maximum(wo[:, 2], 0.0) / np.pi * (a_inv / len_sqr) ** 2  # mx_cosine_hemisphere_PDF(wo.z) (aInv/|wo|²)²
    return dir_albedo * ltc, dir_albedo


@_quiet
def pbrt(theta_i, phi_i, theta_o, phi_o, reflectance, amount, roughness, eta, k):
    """pbrt-v4's ``mix`` (amount t) of a ``diffuse`` (R) and a ``conductor`` (η, k, roughness α, remaproughness
    false), transcribed from pbrt-v4's source (github.com/mmp/pbrt-v4): ``DiffuseBxDF::f`` = R/π;
    ``ConductorBxDF::f`` = FrComplex(|ωo·h|, η + ik) D(h) G(ωo, ωi)/(4 cosθi cosθo) (``src/pbrt/bxdfs.h``) with
    ``TrowbridgeReitzDistribution`` (``src/pbrt/util/scattering.h``): D = 1/(π α² cos⁴θh (1 + tan²θh/α²)²),
    Λ(ω) = (√(1 + α² tan²θ) − 1)/2, G = 1/(1 + Λ(ωo) + Λ(ωi)); ``FrComplex``: sin²θt = sin²θ/η², cosθt = √(1 − sin²θt)
    (complex, principal root), r_∥ = (η cosθ − cosθt)/(η cosθ + cosθt), r_⊥ = (cosθ − η cosθt)/(cosθ + η cosθt),
    F = (|r_∥|² + |r_⊥|²)/2 with η the complex index; ``MixMaterial`` picks the conductor with probability t, so
    the expected f is (1 − t) R/π + t f_conductor."""
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    a2 = roughness * roughness
    tan2_h, cos4_h = np.tan(pair.th) ** 2, np.cos(pair.th) ** 4
    d = 1.0 / (np.pi * a2 * cos4_h * (1.0 + tan2_h / a2) ** 2)

    def lam(theta):
        return (np.sqrt(1.0 + a2 * np.tan(theta) ** 2) - 1.0) / 2.0

    g = 1.0 / (1.0 + lam(pair.to) + lam(pair.ti))
    n = _col(eta) + 1j * _col(k)
    c = np.clip(pair.cos_d, 0.0, 1.0)[:, None]
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (n * n))
    r_parl = (n * c - cos_t) / (n * c + cos_t)
    r_perp = (c - n * cos_t) / (c + n * cos_t)
    fresnel = (np.abs(r_parl) ** 2 + np.abs(r_perp) ** 2) / 2.0
    conductor = fresnel * (d * g / (4.0 * pair.ci * pair.co))[:, None]
    return _masked(pair, (1.0 - amount) * _col(reflectance) / np.pi + amount * conductor)


def _mitsuba_square_to_disk(u, v):
    """Mitsuba 3 ``warp::square_to_uniform_disk_concentric`` (Shirley & Chiu 1997)."""
    x, y = 2.0 * u - 1.0, 2.0 * v - 1.0
    quadrant_1_or_3 = np.abs(x) < np.abs(y)
    r = np.where(quadrant_1_or_3, y, x)
    rp = np.where(quadrant_1_or_3, x, y)
    phi = 0.25 * np.pi * rp / r
    phi = np.where(quadrant_1_or_3, 0.5 * np.pi - phi, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _mitsuba_ggx_visible_normal(wi, alpha, u, v):
    """Mitsuba 3 ``MicrofacetDistribution::sample`` with visible normals, GGX (``sample_visible_11``; Heitz & d'Eon
    2014), transcribed step by step: stretch ωi, sample the slope of the unit distribution, rotate back by ωi's
    azimuth, unstretch, normalise (−slope, 1). ``wi`` (3,), ``u``, ``v`` arrays; returns m, shape u.shape + (3,)."""
    wp = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    wp = wp / np.linalg.norm(wp)
    sin2 = wp[0] ** 2 + wp[1] ** 2
    if sin2 <= 4.0 * np.finfo(float).eps:  # Frame3f::sincos_phi at the pole
        sin_phi, cos_phi = 0.0, 1.0
    else:
        sin_phi, cos_phi = np.clip(wp[1] / np.sqrt(sin2), -1, 1), np.clip(wp[0] / np.sqrt(sin2), -1, 1)
    cos_t = wp[2]
    px, py = _mitsuba_square_to_disk(u, v)
    s = 0.5 * (1.0 + cos_t)
    py = np.sqrt(np.maximum(1.0 - px * px, 0.0)) * (1.0 - s) + py * s
    pz = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
    sin_t = np.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    norm = 1.0 / (sin_t * py + cos_t * pz)
    sx, sy = (cos_t * py - sin_t * pz) * norm, px * norm
    sx, sy = (cos_phi * sx - sin_phi * sy) * alpha, (sin_phi * sx + cos_phi * sy) * alpha
    m = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


def _mitsuba_g1(w, m, alpha):
    """Mitsuba 3 GGX ``smith_g1(v, m)``: 2/(1 + √(1 + α² tan²θv)), 0 where v·m and cosθv differ in sign."""
    with np.errstate(all="ignore"):
        g = 2.0 / (1.0 + np.sqrt(1.0 + alpha**2 * (w[..., 0] ** 2 + w[..., 1] ** 2) / w[..., 2] ** 2))
    return np.where(np.sum(w * m, axis=-1) * w[..., 2] <= 0.0, 0.0, g)


def mitsuba_rough_transmittance(alpha: float, eta: float) -> np.ndarray:
    """Mitsuba 3's ``eval_transmittance`` (include/mitsuba/render/microfacet.h) at the 64 cosines
    max(1e-6, j/63) that ``roughplastic`` tabulates: Σ over the 32 × 32 Gauss-Legendre nodes mapped to [0, 1]² of
    w_x w_y/4 (1 − F(ωi·m)) G1(ωt, m), m the visible normal of the node, ωt = m (c/η − cosθt) − ωi/η the
    refracted direction (c = ωi·m, cosθt = √(1 − (1 − c²)/η²)), 0 where ωt does not cross the surface."""
    x, w = np.polynomial.legendre.leggauss(32)
    nx, ny = np.meshgrid(x, x)
    wx, wy = np.meshgrid(w, w)
    u, v, weight = 0.5 * nx + 0.5, 0.5 * ny + 0.5, 0.25 * wx * wy
    out = []
    for mu in np.maximum(1e-6, np.linspace(0.0, 1.0, 64)):
        wi = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
        m = _mitsuba_ggx_visible_normal(wi, alpha, u, v)
        c = m @ wi
        cos_t = np.sqrt(np.maximum(1.0 - (1.0 - c * c) / eta**2, 0.0))
        r_s = (c - eta * cos_t) / (c + eta * cos_t)
        r_p = (cos_t - eta * c) / (cos_t + eta * c)
        fresnel = 0.5 * (r_s**2 + r_p**2)
        wt = (c / eta - cos_t)[..., None] * m - wi / eta
        value = np.where(wt[..., 2] * wi[2] >= 0.0, 0.0, _mitsuba_g1(wt, m, alpha) * (1.0 - fresnel))
        out.append(np.sum(value * weight))
    return np.array(out)


@functools.lru_cache(maxsize=None)
def _roughplastic_table():
    """The R_smooth table shipped with brdffit (data: brdffit/data/roughplastic_internal_reflectance.npz)."""
    import pathlib

    path = pathlib.Path(__file__).resolve().parents[1] / "brdffit" / "data" / "roughplastic_internal_reflectance.npz"
    data = np.load(path)
    return data["sqrt_alpha"], data["sqrt_eta_minus_1"], data["values"]


def _keys_weight(s):
    """Keys' kernel W(s) (a = −1/2) at a distance ``s`` in node spacings."""
    s = np.abs(s)
    return np.where(s <= 1.0, 1.5 * s**3 - 2.5 * s**2 + 1.0,
                    np.where(s < 2.0, -0.5 * s**3 + 2.5 * s**2 - 4.0 * s + 2.0, 0.0))


def _keys_cubic(table_x, table_y, values, x, y):
    """Keys 1981 cubic convolution (a = −1/2) on a uniform grid, neighbours clamped at the edges: Σ over the 4 × 4
    nodes around (x, y) of W(x − x_i) W(y − y_j) v_ij, W(s) = 1.5|s|³ − 2.5|s|² + 1 for |s| ≤ 1 and
    −0.5|s|³ + 2.5|s|² − 4|s| + 2 for 1 < |s| < 2 (in node spacings)."""
    def kernel(s):
        return float(_keys_weight(s))

    def cell(nodes, t):
        h = nodes[1] - nodes[0]
        c = min(max((t - nodes[0]) / h, 0.0), len(nodes) - 1.0)
        i = min(math.floor(c), len(nodes) - 2)
        return i, c

    i, cx = cell(table_x, x)
    j, cy = cell(table_y, y)
    total = 0.0
    for a in range(i - 1, i + 3):
        for b in range(j - 1, j + 3):
            total += kernel(cx - a) * kernel(cy - b) * values[min(max(a, 0), len(table_x) - 1),
                                                                  min(max(b, 0), len(table_y) - 1)]
    return total


@_quiet
def roughplastic(theta_i, phi_i, theta_o, phi_o, diffuse_reflectance, specular_reflectance, alpha, int_ior):
    """Mitsuba 3's ``roughplastic`` (GGX, ``nonlinear`` false, ext_ior 1), transcribed from
    ``RoughPlastic::eval`` (src/bsdfs/roughplastic.cpp): ks F D G/(4 ci co) + ρ/(1 − R) π⁻¹ η⁻² T(ci) T(co), with
    D, G the GGX distribution and separable Smith masking and F the dielectric Fresnel term at ωi·h (the
    cook-torrance reference), T `mitsuba_rough_transmittance` read by ``lerp_gather`` (x = 63 c, index
    min(⌊x⌋, 62), linear), and R brdffit's tabulated R_smooth (docs/export.md) read by Keys' cubic convolution in
    √α and √(η − 1)."""
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    specular = cook_torrance(theta_i, phi_i, theta_o, phi_o, specular_reflectance, alpha,
                             distribution="ggx", shadowing="smith", fresnel="dielectric", eta=int_ior)
    table = mitsuba_rough_transmittance(alpha, int_ior)

    def lerp_gather(c):
        x = np.clip(c, 0.0, 1.0) * 63.0
        j = np.minimum(np.floor(x), 62).astype(int)
        return table[j] + (table[j + 1] - table[j]) * (x - j)

    r = _keys_cubic(*_roughplastic_table(), math.sqrt(alpha), math.sqrt(int_ior - 1.0))
    diffuse = (lerp_gather(pair.ci) * lerp_gather(pair.co) / (np.pi * int_ior**2 * (1.0 - r)))[:, None]
    return _masked(pair, specular + _col(diffuse_reflectance) * diffuse)


# pbrt-v4's coateddiffuse: the expectation of LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>::f by the quadrature
# brdffit's lobe uses (tests/test_coateddiffuse.py holds that quadrature to a finer one and to pbrt-v4's walk).
_COATED_THICKNESS = 0.01


def _coated_rule(alpha, n=32):
    """Microfacet normals over GGX's D cosθm dm = dξ dφ/(2π) (tan²θm = α² ξ/(1 − ξ), ξ = 1 − s²): Gauss-Legendre
    in s on [0, 1], midpoints in φ on [0, π] (the integrands are even in φ); as angles (θm, φm) and weights."""
    x, w = np.polynomial.legendre.leggauss(n)
    s, ws = (x + 1.0) / 2.0, w / 2.0
    theta = np.arctan(alpha * np.sqrt(1.0 - s * s) / s)
    phi = (np.arange(n) + 0.5) * np.pi / n
    theta, phi = np.meshgrid(theta, phi, indexing="ij")
    weight = np.outer(2.0 * s * ws, np.full(n, 1.0 / n))
    return theta.ravel(), phi.ravel(), weight.ravel()


def _trowbridge_reitz_lambda(cos_theta, alpha):
    return (np.sqrt(1.0 + alpha * alpha * np.tan(np.arccos(cos_theta)) ** 2) - 1.0) / 2.0


@_quiet
def coated_transmission(mu, alpha, eta):
    """X(μ) and Y(μ) of pbrt-v4's coateddiffuse (brdffit.models.coateddiffuse's module doc) at cosines ``mu``: the
    transmission through the rough dielectric (Walter et al. 2007's f_T in importance mode; pbrt-v4's
    ``DielectricBxDF``), ∫ T G(ω, ω') |ω·m| / (|cos ω| cos θm) Tr(ω') over the normals of `_coated_rule`, with
    ω' refracted by Snell's law and Tr = exp(−0.01/|cos ω'|); Y weighted by pbrt's power heuristics
    ph(p(ω → ω'), |cos ω'|/π) + ph(|cos ω'|/π, p(ω' → ω)), p the transmission sampling density
    G1 D |ω·m| / |cos ω| · |ω'·m| / (ω'·m + ω·m/η)² (and its mirror from ω')."""
    theta_m, phi_m, weight = _coated_rule(alpha)
    m = np.stack([np.sin(theta_m) * np.cos(phi_m), np.sin(theta_m) * np.sin(phi_m), np.cos(theta_m)], axis=-1)
    d = 1.0 / (np.pi * alpha**2 * np.cos(theta_m) ** 4 * (1.0 + np.tan(theta_m) ** 2 / alpha**2) ** 2)
    xs, ys = [], []
    for mu_ in np.atleast_1d(mu):
        w = np.array([np.sqrt(1.0 - mu_ * mu_), 0.0, mu_])
        c = m @ w
        theta_c = np.arccos(np.clip(c, -1.0, 1.0))
        cos_t = np.cos(np.arcsin(np.sin(theta_c) / eta))
        wt = -w / eta + (c / eta - cos_t)[:, None] * m
        ok = (c > 0.0) & (wt[:, 2] < 0.0)
        t = 1.0 - fresnel_dielectric(theta_c, 1.0, eta)
        zt = np.abs(wt[:, 2])
        lam_i, lam_t = _trowbridge_reitz_lambda(mu_, alpha), _trowbridge_reitz_lambda(zt, alpha)
        value = np.where(ok, t * c / (mu_ * np.cos(theta_m) * (1.0 + lam_i + lam_t)) * np.exp(-_COATED_THICKNESS / zt),
                         0.0)
        wt_m = np.abs(np.sum(wt * m, axis=1))
        p_in = d * c / (mu_ * (1.0 + lam_i)) * wt_m / (c / eta - wt_m) ** 2
        p_out = d * wt_m / (zt * (1.0 + lam_t)) * c / (c - eta * wt_m) ** 2
        base = zt / np.pi

        def ph(a, b):
            return np.where(a * a + b * b > 0.0, a * a / (a * a + b * b), 0.0)

        xs.append(np.sum(weight * value))
        ys.append(np.sum(weight * value * (ph(p_in, base) + ph(base, p_out))))
    return np.array(xs), np.array(ys)


@_quiet
def coated_internal_reflectance(alpha, eta, nodes=24):
    """R of pbrt-v4's coateddiffuse: ∫₀¹ 2μ Tr(μ) Z(μ) dμ, Z(μ) = ∫ F(ω·m; 1/η) G(ω, ω3) |ω·m| / (μ cosθm) Tr(ω3)
    over the normals of `_coated_rule` (ω3 the mirror of ω about m, F = 1 beyond the critical angle), by
    Gauss-Legendre on [0, μc] and [μc, 1], μc = √(1 − 1/η²)."""
    theta_m, phi_m, weight = _coated_rule(alpha)
    m = np.stack([np.sin(theta_m) * np.cos(phi_m), np.sin(theta_m) * np.sin(phi_m), np.cos(theta_m)], axis=-1)
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = (x + 1.0) / 2.0, w / 2.0
    critical = math.sqrt(1.0 - 1.0 / eta**2)
    total = 0.0
    for lo, hi in ((0.0, critical), (critical, 1.0)):
        for mu_, wm in zip(lo + (hi - lo) * x, (hi - lo) * w):
            v = np.array([np.sqrt(1.0 - mu_ * mu_), 0.0, mu_])
            c = m @ v
            r = 2.0 * c[:, None] * m - v
            ok = (c > 0.0) & (r[:, 2] > 0.0)
            g = 1.0 / (1.0 + _trowbridge_reitz_lambda(mu_, alpha) + _trowbridge_reitz_lambda(r[:, 2], alpha))
            f = fresnel_dielectric(np.arccos(np.clip(c, -1.0, 1.0)), eta, 1.0)
            z = np.sum(weight * np.where(ok, f * g * c / (mu_ * np.cos(theta_m)) * np.exp(-_COATED_THICKNESS / r[:, 2]),
                                         0.0))
            total += wm * 2.0 * mu_ * math.exp(-_COATED_THICKNESS / mu_) * z
    return total


def _keys_cubic_1d(values, x):
    """Keys 1981 cubic convolution of ``values`` at uniform nodes j/(n − 1) on [0, 1], at each x (`_keys_cubic`'s
    kernel, neighbours clamped)."""
    n = len(values)
    out = []
    for t in np.atleast_1d(x):
        out.append(_keys_cubic(np.linspace(0.0, 1.0, n), np.array([0.0, 1.0]), np.stack([values, values], axis=1), t, 0.0))
    return np.array(out)


@_quiet
def coateddiffuse(theta_i, phi_i, theta_o, phi_o, reflectance, roughness, eta):
    """pbrt-v4's ``coateddiffuse`` (roughness α, remaproughness false; thickness 0.01, albedo 0, maxdepth 10): the
    interface's reflection (``DielectricBxDF::f``: the pbrt reference's conductor term with k = 0) plus
    (ρ/π) X(cosθo) Y(cosθi)/η² Σ_{k<5} (ρR)^k, X and Y computed at max(1e-6, (j/63)²) (`coated_transmission`) and
    read by Keys' cubic convolution in √cosθ, R `coated_internal_reflectance`."""
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    rho = _col(reflectance)
    reflection = pbrt(theta_i, phi_i, theta_o, phi_o, 0.0, 1.0, roughness, eta, 0.0)
    x, y = coated_transmission(np.maximum(1e-6, np.linspace(0.0, 1.0, 64) ** 2), roughness, eta)
    co, ci = (np.sqrt(np.where(pair.above, c, 0.0)) for c in (pair.co, pair.ci))  # √μ; below the horizon: masked
    through = _keys_cubic_1d(x, co) * _keys_cubic_1d(y, ci) / eta**2
    r = coated_internal_reflectance(roughness, eta)
    series = sum((rho * r) ** k for k in range(5))
    return _masked(pair, reflection + rho / np.pi * series * through[:, None])


# pbrt-v4's coatedconductor under a smooth interface: the expectation of LayeredBxDF<DielectricBxDF, ConductorBxDF,
# true>::f by the rules brdffit's lobe uses (tests/test_coatedconductor.py holds those rules to finer ones and to
# pbrt-v4's walk), here in angles and with the conductor of the pbrt reference above (FrComplex in complex arithmetic).
def _keys_extended(table, axis):
    """One node more beyond each end of ``axis``: f₋₁ = 3 f₀ − 3 f₁ + f₂ (Keys 1981, Eqs. 25-26)."""
    t = np.moveaxis(table, axis, 0)
    return np.moveaxis(np.concatenate([(3 * t[0] - 3 * t[1] + t[2])[None], t, (3 * t[-1] - 3 * t[-2] + t[-3])[None]]),
                       0, axis)


def _keys_neighbours(x, step, count):
    """Indices (into an axis with one extra node before the first) and Keys weights of the 4 nodes around each x on
    the nodes j·step, j < count."""
    c = np.clip(x / step, 0.0, count - 1.0)
    i = np.minimum(np.floor(c), count - 2).astype(int)
    offsets = np.arange(-1, 3)
    return i[:, None] + offsets + 1, _keys_weight(c[:, None] - (i[:, None] + offsets))


@_quiet
def coatedconductor(theta_i, phi_i, theta_o, phi_o, reflectance, conductor_roughness, interface_eta):
    """pbrt-v4's ``coatedconductor`` with ``interface.roughness`` 0 (``reflectance`` r: conductor index
    (1 + i 2√r/√(1 − r))/η, roughness α; thickness 0.01, albedo 0, maxdepth 10): T(θo) T(θi)/η² Tr Tr (f_c(u0, ui) +
    Σ_{k=1}^{4} 𝒦^k f_c), u0 and ui refracted by Snell's law, 𝒦 one more bounce at the conductor and a mirror
    reflection by the interface from inside (R, 1 beyond the critical angle), the bounces by cosine coefficients in
    Δφ (64 midpoints over [0, π]) over Gauss-Legendre cosines (12 on each side of the critical cosine), tabulated at
    the outside sines j/32 and 65 azimuths over [0, π] and read by Keys' cubic convolution (brdffit.models.
    coatedconductor's module doc)."""
    pair = Pair(theta_i, phi_i, theta_o, phi_o)
    eta = interface_eta
    r = np.atleast_1d(np.asarray(reflectance, dtype=float))
    eta_c, k_c = np.full_like(r, 1.0 / eta), 2.0 * np.sqrt(r) / np.sqrt(1.0 - r) / eta

    def f_c(t_in, p_in, t_out, p_out):  # the conductor inside the coat, (N, C)
        return pbrt(t_in, p_in, t_out, p_out, 0.0, 1.0, conductor_roughness, eta_c, k_c)

    def tr(cos):
        return np.exp(-_COATED_THICKNESS / cos)

    def fresnel(cos, n1, n2):  # 1 under total internal reflection
        return fresnel_dielectric(np.arccos(cos), n1, n2)

    x, w = np.polynomial.legendre.leggauss(12)
    x, w = (x + 1.0) / 2.0, w / 2.0
    critical = np.sqrt(1.0 - 1.0 / eta**2)
    mu = np.concatenate([critical * x, critical + (1.0 - critical) * x])
    weight = np.concatenate([critical * w, (1.0 - critical) * w]) * mu * tr(mu) ** 2 * fresnel(mu, eta, 1.0)
    ends = np.arcsin(np.linspace(0.0, 1.0, 33) / eta)
    phi = (np.arange(64) + 0.5) * np.pi / 64
    harmonic = np.arange(64)

    def coefficients(theta_a, theta_b):  # (M, A, B, C)
        ta, tb, ph = (g.ravel() for g in np.meshgrid(theta_a, theta_b, phi, indexing="ij"))
        samples = f_c(tb, ph, ta, np.zeros_like(ta)).reshape(len(theta_a), len(theta_b), len(phi), -1)
        basis = np.cos(harmonic[:, None] * phi[None, :]) * np.where(harmonic == 0, 1.0, 2.0)[:, None] / 64
        return np.einsum("mj,abjc->mabc", basis, samples)

    factor = (np.where(harmonic == 0, 2.0 * np.pi, np.pi) * (-1.0) ** harmonic)[:, None, None, None]
    middle = factor * coefficients(np.arccos(mu), np.arccos(mu)) * weight[None, None, :, None]
    to_ends = coefficients(ends, np.arccos(mu))
    first, last = factor * to_ends * weight[None, None, :, None], np.swapaxes(to_ends, 1, 2)
    chain = total = last
    for _ in range(3):
        chain = np.einsum("mabc,mbdc->madc", middle, chain)
        total = total + chain
    bounces = np.einsum("mabc,mbdc->madc", first, total)
    step = np.pi / 64
    psi = np.arange(-1, 66) * step
    table = np.einsum("mt,mabc->abtc", np.cos(harmonic[:, None] * psi[None, :]), bounces)
    table = _keys_extended(_keys_extended(table, 0), 1)
    dphi = np.abs(np.angle(np.exp(1j * (pair.po - pair.pi_))))
    ia, wa = _keys_neighbours(pair.so, 1.0 / 32, 33)
    ib, wb = _keys_neighbours(pair.si, 1.0 / 32, 33)
    ip, wp = _keys_neighbours(dphi, step, 65)
    bounced = np.einsum("na,nb,np,nabpc->nc", wa, wb, wp,
                        table[ia[:, :, None, None], ib[:, None, :, None], ip[:, None, None, :]])
    t_o, t_i = np.arcsin(pair.so / eta), np.arcsin(pair.si / eta)
    direct = f_c(t_i, pair.pi_, t_o, pair.po)
    through = ((1.0 - fresnel(pair.co, 1.0, eta)) * (1.0 - fresnel(pair.ci, 1.0, eta)) / eta**2
               * tr(np.cos(t_o)) * tr(np.cos(t_i)))
    return _masked(pair, through[:, None] * (direct + bounced))


REFERENCES = {
    "lambert": lambda ti, pi_, to, po, p: lambert(ti, pi_, to, po, p["rho_d"]),
    "oren-nayar": lambda ti, pi_, to, po, p: oren_nayar(ti, pi_, to, po, p["rho_d"], p["sigma"]),
    "phong": lambda ti, pi_, to, po, p: phong(ti, pi_, to, po, p["ks"], p["n"]),
    "blinn-phong": lambda ti, pi_, to, po, p: blinn_phong(ti, pi_, to, po, p["ks"], p["n"]),
    "ward": lambda ti, pi_, to, po, p: ward(ti, pi_, to, po, p["ks"], p["alpha"]),
    "ward-aniso": lambda ti, pi_, to, po, p: ward(ti, pi_, to, po, p["ks"], p["alpha_x"], p["alpha_y"]),
    "ward-duer": lambda ti, pi_, to, po, p: ward_duer(ti, pi_, to, po, p["ks"], p["alpha"]),
    "cook-torrance": _ct_ref,
    "ggx": lambda ti, pi_, to, po, p, **o: _ct_ref(ti, pi_, to, po, p, roughness="alpha",
                                                   **{"distribution": "ggx", "shadowing": "smith", **o}),
    "ashikhmin-shirley": lambda ti, pi_, to, po, p: ashikhmin_shirley(ti, pi_, to, po, p["rs"], p["n"]),
    "ashikhmin-shirley-aniso": lambda ti, pi_, to, po, p: ashikhmin_shirley(ti, pi_, to, po, p["rs"], p["nu"],
                                                                            p["nv"]),
    "lafortune": _lafortune_ref,
    "burley": lambda ti, pi_, to, po, p: burley(ti, pi_, to, po, p["rho_d"], p["roughness"]),
    "sheen": lambda ti, pi_, to, po, p: sheen(ti, pi_, to, po, p["ks"]),
    "principled": lambda ti, pi_, to, po, p: principled(ti, pi_, to, po, **p),
    "gltf": lambda ti, pi_, to, po, p: gltf(ti, pi_, to, po, **p),
    "blender": lambda ti, pi_, to, po, p, coat=False, sheen=False: blender(ti, pi_, to, po, **p),
    "openpbr": lambda ti, pi_, to, po, p, coat=False, fuzz=False: openpbr(ti, pi_, to, po, **p),
    "pbrt": lambda ti, pi_, to, po, p: pbrt(ti, pi_, to, po, **p),
    "roughplastic": lambda ti, pi_, to, po, p: roughplastic(ti, pi_, to, po, **p),
    "coateddiffuse": lambda ti, pi_, to, po, p: coateddiffuse(ti, pi_, to, po, **p),
    "coatedconductor": lambda ti, pi_, to, po, p: coatedconductor(ti, pi_, to, po, **p),
    "abc-smooth": lambda ti, pi_, to, po, p: abc_smooth(ti, pi_, to, po, **p),
    "abc-microfacet": lambda ti, pi_, to, po, p: abc_microfacet(ti, pi_, to, po, **p),
    "sgd": lambda ti, pi_, to, po, p: sgd(ti, pi_, to, po, **p),
    "charlie-sheen": lambda ti, pi_, to, po, p: charlie_sheen(ti, pi_, to, po, p["ks"], p["alpha"]),
    "toon-diffuse": lambda ti, pi_, to, po, p: toon_diffuse(ti, pi_, to, po, p["rho_d"], p["rho_shade"],
                                                            p["threshold"], p["width"]),
    "toon-specular": lambda ti, pi_, to, po, p: toon_specular(ti, pi_, to, po, p["ks"], p["threshold"],
                                                              p["width"]),
}
"""Lobe name -> ``f(theta_i, phi_i, theta_o, phi_o, params, **options)`` returning ``(N, C)``."""
