"""brdffit.models.microfacet: normalisation of D, Smith shadowing against closed forms and its definition.

References: Walter, Marschner, Li & Torrance, Microfacet models for refraction through rough surfaces, EGSR 2007
(D: Eqs. 25, 30, 33; Smith G1: Eqs. 18, 23, 27, 34); Smith, Geometrical shadowing of a random rough surface,
IEEE Trans. Antennas Propag. 1967 (Λ as an integral over the slope distribution).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

import brdffit  # noqa: F401  (float64)
from brdffit.models import microfacet as mf

import reference_brdfs as ref

NAMES = sorted(name for name, dist in mf.DISTRIBUTIONS.items() if dist.tail is None)  # STD: its own tests below
ROUGHNESS = [0.05, 0.2, 0.5, 1.0]
THETAS = np.radians([1.0, 10.0, 30.0, 50.0, 70.0, 80.0, 85.0, 89.0, 89.9])


def test_distribution_table():
    assert NAMES == ["beckmann", "blinn", "ggx"] and sorted(mf.DISTRIBUTIONS) == ["beckmann", "blinn", "ggx", "gtr",
                                                                                   "std"]
    assert set(mf.SHADOWING) == {"v-cavity", "smith", "smith-correlated", "none"}


@pytest.mark.parametrize("m", ROUGHNESS)
@pytest.mark.parametrize("name", NAMES)
def test_distribution_is_normalised(name, m):
    """∫ D(h) cosθh dωh = 2π ∫_0^{π/2} D(θ) cosθ sinθ dθ = 1 (projected microfacet area = macro area)."""
    dist = mf.DISTRIBUTIONS[name]
    d = jax.jit(lambda c: dist.D(c, m))

    def integrand(theta):
        return float(d(math.cos(theta))) * math.cos(theta) * math.sin(theta)

    # break the range where the lobe lives so that quad resolves narrow lobes
    points = [p for p in (m / 4, m, 3 * m) if p < math.pi / 2]
    total, err = integrate.quad(integrand, 0.0, math.pi / 2, points=points, limit=200, epsabs=1e-13, epsrel=1e-12)
    assert err < 1e-9
    np.testing.assert_allclose(2 * math.pi * total, 1.0, rtol=1e-9)


@pytest.mark.parametrize("m", ROUGHNESS)
@pytest.mark.parametrize("name", NAMES)
def test_distribution_matches_paper_formula(name, m):
    theta_h = np.radians(np.linspace(0.0, 85.0, 35))
    got = np.asarray(mf.DISTRIBUTIONS[name].D(np.cos(theta_h), m))
    np.testing.assert_allclose(got, ref.microfacet_D(name, theta_h, m), rtol=1e-10, atol=1e-300)


def test_distributions_at_the_normal():
    m = 0.3
    np.testing.assert_allclose(mf.DISTRIBUTIONS["beckmann"].D(1.0, m), 1 / (math.pi * m * m), rtol=1e-14)
    np.testing.assert_allclose(mf.DISTRIBUTIONS["ggx"].D(1.0, m), 1 / (math.pi * m * m), rtol=1e-14)
    ap = 2 / m**2 - 2
    np.testing.assert_allclose(mf.DISTRIBUTIONS["blinn"].D(1.0, m), (ap + 2) / (2 * math.pi), rtol=1e-14)


def test_blinn_approaches_beckmann_for_small_roughness():
    """Walter et al. 2007, Sec. 5.2: with αp = 2/m² − 2 the two distributions nearly coincide for small m."""
    theta_h = np.radians(np.linspace(0.0, 6.0, 13))
    blinn = np.asarray(mf.DISTRIBUTIONS["blinn"].D(np.cos(theta_h), 0.05))
    beckmann = np.asarray(mf.DISTRIBUTIONS["beckmann"].D(np.cos(theta_h), 0.05))
    np.testing.assert_allclose(blinn, beckmann, rtol=5e-3, atol=1e-3 * beckmann[0])


# --------------------------------------------------------------------------------------------------------------
# Smith shadowing


@pytest.mark.parametrize("m", ROUGHNESS)
@pytest.mark.parametrize("name", NAMES)
def test_smith_G1_range_normal_and_grazing(name, m):
    dist = mf.DISTRIBUTIONS[name]
    g1 = np.asarray(dist.G1(np.cos(THETAS), m))
    assert np.all((g1 >= 0) & (g1 <= 1))
    assert np.all(np.diff(g1) <= 0)  # more masking towards grazing
    assert float(dist.G1(1.0, m)) == pytest.approx(1.0, abs=1e-15)
    assert float(dist.G1(1e-9, m)) < 1e-7
    assert float(dist.G1(0.0, m)) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(dist.G(np.cos(0.3), np.cos(1.2), m), dist.G1(np.cos(0.3), m) * dist.G1(np.cos(1.2), m),
                               rtol=1e-15)


@pytest.mark.parametrize("m", ROUGHNESS)
def test_ggx_G1_closed_form(m):
    """Walter et al. 2007, Eq. 34: G1 = 2/(1 + √(1 + α² tan²θv))."""
    got = np.asarray(mf.DISTRIBUTIONS["ggx"].G1(np.cos(THETAS), m))
    want = 2.0 / (1.0 + np.sqrt(1.0 + m * m * np.tan(THETAS) ** 2))
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("m", ROUGHNESS)
def test_beckmann_lambda_erf_closed_form(m):
    """Λ(a) = (erf(a) − 1)/2 + exp(−a²)/(2a√π), a = 1/(m tanθv) (integrated Walter et al. 2007, Eq. 25)."""
    got = np.asarray(mf.DISTRIBUTIONS["beckmann"].Lambda(np.cos(THETAS), m))
    want = ref.smith_lambda("beckmann", THETAS, m)
    # atol: for large a both terms are ~erfc(a) and cancel; the erf form of the reference loses ~1e-16 absolute.
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize("m", [0.1, 0.3, 0.7])
@pytest.mark.parametrize("name", ["beckmann", "ggx"])
def test_smith_lambda_matches_its_definition(name, m):
    """Λ(μ) = (1/μ) ∫_μ^∞ (q − μ) P2(q) dq, μ = cotθv, with P2 the marginal slope density of D, by quadrature:
    the closed forms are exact for these two distributions."""
    for theta in np.radians([20.0, 60.0, 80.0, 88.0]):
        got = float(mf.DISTRIBUTIONS[name].Lambda(math.cos(theta), m))
        np.testing.assert_allclose(got, ref.smith_lambda_numeric(name, theta, m), rtol=1e-8, atol=1e-14)


@pytest.mark.parametrize("m", ROUGHNESS)
def test_blinn_smith_uses_walters_beckmann_approximation(m):
    """The power-cosine distribution has no closed-form Smith Λ; like Walter et al. 2007 (Sec. 5.2) the library uses
    Beckmann's Λ with a = √(αp/2 + 1)/tanθv, which is the Beckmann a = 1/(m tanθv) for αp = 2/m² − 2."""
    got = np.asarray(mf.DISTRIBUTIONS["blinn"].Lambda(np.cos(THETAS), m))
    np.testing.assert_allclose(got, ref.smith_lambda("blinn", THETAS, m), rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize("m, tolerance", [(0.05, 1e-3), (0.2, 1.5e-2), (0.5, 0.11)])
def test_blinn_smith_approximation_error_against_exact_smith(m, tolerance):
    """How far that approximation is from the exact Smith G1 of the power-cosine distribution (by quadrature of
    its slope density): fine for narrow lobes, growing with roughness (at m = 0.5 about 10 % at 89°)."""
    for theta in np.radians([10.0, 40.0, 70.0, 85.0, 89.0]):
        exact = 1.0 / (1.0 + ref.smith_lambda_numeric("blinn", theta, m))
        got = float(mf.DISTRIBUTIONS["blinn"].G1(math.cos(theta), m))
        assert abs(got - exact) / exact <= tolerance, (math.degrees(theta), got, exact)


def test_smith_weak_white_furnace():
    """Projected-area identity of a Smith microsurface (Heitz 2014, Eq. 9): ∫ G1(v) max(0, v·h) D(h) dωh = cosθv,
    checked on a (θh, φh) grid for Beckmann and GGX; the kink at v·h = 0 limits the grid to ~1e-4."""
    th = np.linspace(0.0, np.pi / 2, 1201)[1:] - np.pi / 4 / 1200
    ph = np.linspace(0.0, 2 * np.pi, 721)[:-1]
    dth, dph = np.pi / 2 / 1200, 2 * np.pi / 720
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1)
    for name, m in (("beckmann", 0.4), ("ggx", 0.4)):
        d = np.asarray(mf.DISTRIBUTIONS[name].D(np.cos(tt), m))
        for theta_v in np.radians([0.0, 30.0, 60.0, 80.0]):
            v = np.array([np.sin(theta_v), 0.0, np.cos(theta_v)])
            integral = np.sum(np.maximum(h @ v, 0.0) * d * np.sin(tt)) * dth * dph
            g1 = float(mf.DISTRIBUTIONS[name].G1(np.cos(theta_v), m))
            np.testing.assert_allclose(g1 * integral, np.cos(theta_v), rtol=2e-4)


# --------------------------------------------------------------------------------------------------------------
# Gradients


def _gradient_cases():
    for name in NAMES + ["std", "gtr"]:
        for function in ("D", "Lambda", "G1"):
            for cos_v in (1.0, 0.999999, 0.5, 1.7e-3, 1e-9):
                yield pytest.param(name, function, cos_v, id=f"{name}-{function}-{cos_v:g}")


@pytest.mark.parametrize("name, function, cos_v", list(_gradient_cases()))
def test_gradients_finite(name, function, cos_v):
    """Derivatives w.r.t. the cosine and the roughness (and the STD's γ) are finite from the normal down to a
    horizontal direction."""
    fn = getattr(mf.DISTRIBUTIONS[name], function)
    if name in ("std", "gtr"):
        for gamma in ((1.51, 2.0, 7.0, 40.0) if name == "std" else (0.6, 1.0, 2.0, 10.0)):
            grads = jax.grad(fn, argnums=(0, 1, 2))(jnp.asarray(cos_v), 0.3, gamma)
            assert np.all(np.isfinite(np.asarray(grads))), gamma
        return
    grads = jax.grad(fn, argnums=(0, 1))(jnp.asarray(cos_v), 0.3)
    assert np.all(np.isfinite(np.asarray(grads)))


def test_beckmann_lambda_gradient_matches_finite_differences():
    dist, m, h = mf.DISTRIBUTIONS["beckmann"], 0.3, 1e-6
    for theta in np.radians([60.0, 75.0, 88.0]):
        got = jax.grad(dist.Lambda, argnums=1)(math.cos(theta), m)
        fd = (ref.smith_lambda("beckmann", theta, m + h) - ref.smith_lambda("beckmann", theta, m - h)) / (2 * h)
        np.testing.assert_allclose(got, fd, rtol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# Anisotropic distributions and height-correlated masking (Heitz, Understanding the masking-shadowing function in
# microfacet-based BRDFs, JCGT 3(2), 2014, §5.3 and Eq. 99)

ANISOTROPIC_WIDTHS = [(1e-3, 1.0), (0.05, 0.3), (0.2, 0.2), (0.5, 0.08), (1.0, 1.0)]
ANISOTROPIC = [name for name in mf.ANISOTROPIC if mf.DISTRIBUTIONS[name].tail is None]  # STD: its own tests


@functools.lru_cache(maxsize=None)
def _gauss_legendre(n):
    """NumPy's n-point Gauss-Legendre rule on [−1, 1], computed once per n for the file (an eigen-decomposition of
    an n × n matrix: 0.7 s for the 2000 nodes of the masking integrals, which a dozen tests use). Read-only."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.flags.writeable = w.flags.writeable = False
    return x, w


def _stretched_slope_quadrature(alpha_x, alpha_y, radial=800, angular=512):
    """Nodes and weights over the slope plane in stretched polar coordinates, x = αx s cosψ, y = αy s sinψ, with
    s = v/(1 − v) (Gauss-Legendre in v on [0, 1)) and ψ uniform (trapezoid, periodic): dx dy = αx αy s ds dψ.
    Returns the unit microfacet normals h = (−x, −y, 1)/√(1 + x² + y²), cosθh and the weights (dx dy)."""
    v, wv = _gauss_legendre(radial)
    v, wv = 0.5 * (v + 1.0), 0.5 * wv
    s, ds = v / (1.0 - v), wv / (1.0 - v) ** 2
    psi = np.linspace(0.0, 2.0 * math.pi, angular, endpoint=False)
    S, P = np.meshgrid(s, psi, indexing="ij")
    W = np.outer(ds * s, np.full(angular, 2.0 * math.pi / angular)) * alpha_x * alpha_y
    x, y = alpha_x * S * np.cos(P), alpha_y * S * np.sin(P)
    norm = np.sqrt(1.0 + x * x + y * y)
    h = np.stack([-x / norm, -y / norm, 1.0 / norm], axis=-1)
    return h, 1.0 / norm, W


@pytest.mark.parametrize("name", ANISOTROPIC)
@pytest.mark.parametrize("widths", ANISOTROPIC_WIDTHS)
def test_anisotropic_distribution_is_normalised(name, widths):
    """∫ D(h) cosθh dωh = 1, over the slope plane (dωh = cos³θh dx dy): from the narrowest to the widest width
    in the bounds, and as elongated as αx/αy = 1000."""
    h, cos_h, w = _stretched_slope_quadrature(*widths)
    d = np.asarray(mf.DISTRIBUTIONS[name].D_aniso(jnp.asarray(h), widths))
    assert np.sum(d * cos_h**4 * w) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("name", ANISOTROPIC)
def test_anisotropic_distribution_matches_paper_formula_and_isotropic_form(name):
    rng = np.random.default_rng(7)
    theta_h, phi_h = rng.uniform(0.0, 1.45, 200), rng.uniform(-math.pi, math.pi, 200)
    h = np.stack([np.sin(theta_h) * np.cos(phi_h), np.sin(theta_h) * np.sin(phi_h), np.cos(theta_h)], axis=-1)
    dist = mf.DISTRIBUTIONS[name]
    for widths in ANISOTROPIC_WIDTHS[1:]:
        got = np.asarray(dist.D_aniso(jnp.asarray(h), widths))
        want = ref.microfacet_D_aniso(name, theta_h, phi_h, *widths)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(np.asarray(dist.D_aniso(jnp.asarray(h), (0.3, 0.3))),
                               np.asarray(dist.D(jnp.asarray(np.cos(theta_h)), 0.3)), rtol=1e-12)


def _direction(theta, phi):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


@pytest.mark.parametrize("name", ANISOTROPIC)
@pytest.mark.parametrize("widths", [(0.05, 0.3), (0.5, 0.08), (0.6, 0.6)])
def test_anisotropic_smith_G1_equals_the_masking_integral(name, widths):
    """Smith's G1 = 1/(1 + Λ) against the masking of its own distribution, integrated: the projected area of the
    visible microfacets equals that of the surface, G1(ω) ∫ ⟨ω, h⟩⁺ D(h) dωh = cosθ (Heitz 2014, Eqs. 2 and 14).
    The integrand has a kink where ω·h = 0, so the quadrature is good to about 1e-6 only."""
    h, cos_h, w = _stretched_slope_quadrature(*widths, radial=2000, angular=1024)
    dist = mf.DISTRIBUTIONS[name]
    d = np.asarray(dist.D_aniso(jnp.asarray(h), widths)) * cos_h**3 * w
    for theta, phi in [(0.3, 0.0), (1.0, 0.7), (1.3, 2.0), (1.45, -1.2), (1.5, math.pi / 2)]:
        omega = _direction(theta, phi)
        projected = np.sum(np.maximum(h @ omega, 0.0) * d)
        g1 = 1.0 / (1.0 + float(dist.Lambda_aniso(jnp.asarray(omega), widths)))
        assert g1 == pytest.approx(math.cos(theta) / projected, rel=2e-6), (theta, phi)


@pytest.mark.parametrize("name", ANISOTROPIC)
def test_anisotropic_lambda_is_the_isotropic_one_at_the_projected_width(name):
    rng = np.random.default_rng(8)
    theta, phi = rng.uniform(0.0, 1.55, 300), rng.uniform(-math.pi, math.pi, 300)
    w = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    got = np.asarray(mf.DISTRIBUTIONS[name].Lambda_aniso(jnp.asarray(w), (0.07, 0.6)))
    # atol: the reference's Beckmann Λ is written with erf(a) − 1 as in the paper, which cancels where Λ is tiny
    # (brdffit's erfc form does not); Λ enters G1 as 1 + Λ, so 1e-15 absolute is below what G1 can show.
    np.testing.assert_allclose(got, ref.smith_lambda_aniso(name, theta, phi, 0.07, 0.6), rtol=1e-12, atol=1e-15)


def test_height_correlated_masking_is_never_below_the_separable_one():
    """1/(1 + Λi + Λo) ≥ 1/((1 + Λi)(1 + Λo)) since ΛiΛo ≥ 0 (Heitz 2014, §6.2): equal where either Λ is 0."""
    from brdffit.geometry import LocalPair

    rng = np.random.default_rng(9)
    ti, to = rng.uniform(0.0, 1.56, 500), rng.uniform(0.0, 1.56, 500)
    pi_, po = rng.uniform(-math.pi, math.pi, 500), rng.uniform(-math.pi, math.pi, 500)
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], axis=-1)
    pair = LocalPair.from_dirs(jnp.asarray(wi), jnp.asarray(wo))
    for name in ANISOTROPIC:
        for m in (0.3, (0.05, 0.7)):
            dist = mf.DISTRIBUTIONS[name]
            correlated = np.asarray(mf.smith_correlated(pair, dist, m))
            separable = np.asarray(mf.smith(pair, dist, m))
            a = np.asarray(dist.lambda_of(pair.wi, pair.cos_i, m))
            b = np.asarray(dist.lambda_of(pair.wo, pair.cos_o, m))
            assert np.all(correlated >= separable * (1.0 - 1e-15)) and np.all(correlated <= 1.0)
            # The difference is ΛiΛo/((1 + Λi + Λo)(1 + Λi)(1 + Λo)), positive wherever both Λ are.
            np.testing.assert_allclose(correlated - separable, a * b / ((1 + a + b) * (1 + a) * (1 + b)),
                                       rtol=1e-9, atol=1e-15)
            assert np.any(correlated - separable > 1e-3)


# ---------------------------------------------------------------------------------------------------------------
# The Student-t distribution of slopes (Ribardière et al. 2017)

STD = mf.DISTRIBUTIONS["std"]
GAMMAS = [1.6, 2.0, 3.5, 10.0, 40.0]


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("widths", [(1e-3, 1e-3), (0.05, 0.3), (0.5, 0.5), (1.0, 1.0)])
def test_std_is_normalised(gamma, widths):
    """∫ D cosθh dωh = 1 over the slope plane for tail exponents across the bounds. The heaviest tail (γ = 1.6:
    P22 ~ r^−3.2) converges slowly in the mapped radius, hence 1e-7 there."""
    h, cos_h, w = _stretched_slope_quadrature(*widths)
    d = np.asarray(STD.D_aniso(jnp.asarray(h), widths, gamma))
    assert np.sum(d * cos_h**4 * w) == pytest.approx(1.0, abs=1e-7 if gamma < 2 else 1e-9)


def test_std_matches_paper_formula_ggx_at_two_and_beckmann_in_the_limit():
    rng = np.random.default_rng(10)
    theta, phi = rng.uniform(0.0, 1.5, 300), rng.uniform(-math.pi, math.pi, 300)
    h = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    for gamma in GAMMAS:
        np.testing.assert_allclose(np.asarray(STD.D_aniso(jnp.asarray(h), (0.2, 0.6), gamma)),
                                   ref.std_D(theta, phi, 0.2, 0.6, gamma), rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(np.asarray(STD.D(jnp.asarray(np.cos(theta)), 0.3, gamma)),
                                   ref.std_D(theta, phi, 0.3, 0.3, gamma), rtol=1e-12, atol=1e-300)
    cos = jnp.asarray(np.cos(theta))
    np.testing.assert_allclose(np.asarray(STD.D(cos, 0.3, 2.0)), np.asarray(mf.DISTRIBUTIONS["ggx"].D(cos, 0.3)),
                               rtol=1e-12)
    np.testing.assert_allclose(np.asarray(STD.Lambda(cos, 0.3, 2.0)),
                               np.asarray(mf.DISTRIBUTIONS["ggx"].Lambda(cos, 0.3)), rtol=1e-11, atol=1e-15)
    # (1 + s/(γ − 1))^−γ -> e^−s: at γ = 1e6 within ~s²/γ of Beckmann where the density matters.
    near = theta < 0.6
    np.testing.assert_allclose(np.asarray(STD.D(cos, 0.3, 1e6))[near],
                               np.asarray(mf.DISTRIBUTIONS["beckmann"].D(cos, 0.3))[near], rtol=1e-4)


@pytest.mark.parametrize("gamma", GAMMAS)
def test_std_lambda_matches_scipy_and_its_definition(gamma):
    """Λ against SciPy's closed form (Student-t survival function), and against its definition
    (1/μ) ∫_μ^∞ (q − μ) P2(q) dq with P2 itself integrated by quadrature from the distribution."""
    rng = np.random.default_rng(11)
    theta, phi = rng.uniform(0.01, 1.565, 200), rng.uniform(-math.pi, math.pi, 200)
    w = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    got = np.asarray(STD.Lambda_aniso(jnp.asarray(w), (0.15, 0.7), gamma))
    np.testing.assert_allclose(got, ref.std_lambda(theta, phi, 0.15, 0.7, gamma), rtol=1e-10, atol=1e-15)
    m = 0.4
    for t in (0.4, 1.0, 1.4):
        mu = 1.0 / (m * math.tan(t))
        # P2 of the unit-width distribution at q/m, over m (the definition in slope space, width m).
        value, _ = integrate.quad(lambda q: (q - mu) * ref.std_marginal(q, 1.0, gamma), mu, math.inf,
                                  epsabs=0.0, epsrel=1e-10, limit=200)
        assert float(STD.Lambda(math.cos(t), m, gamma)) == pytest.approx(value / mu, rel=1e-7)


@pytest.mark.parametrize("gamma", [2.0, 2.5, 8.0])
def test_std_smith_G1_equals_the_masking_integral(gamma):
    """As for Beckmann and GGX. Below γ = 2 the projected area's tail beyond slope R falls only as R^(3 − 2γ),
    beyond what this quadrature reaches; there Λ is checked against its definition by adaptive quadrature
    (`test_std_lambda_matches_scipy_and_its_definition`)."""
    h, cos_h, w = _stretched_slope_quadrature(0.3, 0.12, radial=2000, angular=1024)
    d = np.asarray(STD.D_aniso(jnp.asarray(h), (0.3, 0.12), gamma)) * cos_h**3 * w
    for theta, phi in [(0.3, 0.0), (1.0, 0.7), (1.4, 2.0)]:
        omega = _direction(theta, phi)
        projected = np.sum(np.maximum(h @ omega, 0.0) * d)
        g1 = 1.0 / (1.0 + float(STD.Lambda_aniso(jnp.asarray(omega), (0.3, 0.12), gamma)))
        assert g1 == pytest.approx(math.cos(theta) / projected, rel=2e-6), (theta, phi)


def test_std_gamma_derivative_matches_finite_differences():
    """The derivative in γ, which JAX takes through the incomplete beta function's continued fraction, against
    SciPy's Λ differenced in γ."""
    for theta in (0.5, 1.1, 1.45):
        for gamma in (1.7, 3.0, 20.0):
            got = float(jax.grad(STD.Lambda, argnums=2)(math.cos(theta), 0.3, gamma))
            h = 1e-6 * gamma
            fd = (ref.std_lambda(theta, 0.0, 0.3, 0.3, gamma + h) - ref.std_lambda(theta, 0.0, 0.3, 0.3, gamma - h)) / (2 * h)
            assert got == pytest.approx(float(fd), rel=1e-6, abs=1e-14)


@pytest.mark.parametrize("alpha", [0.01, 0.1, 0.5, 1.0])
def test_charlie_distribution_is_normalised(alpha):
    """Estevez & Kulla's D = (2 + 1/α) sin^(1/α)θh/(2π): ∫ D cosθh dωh = 1 by quadrature over θh, for fibre
    roughness across its bounds (evaluated through the lobe with ks = 1 at ωi = ωo, where θh is the angle of both
    and the factor G/(4 cosθi cosθo) is divided out)."""
    from brdffit.models.sheen import charlie_lambda

    theta = np.linspace(0.0, 0.5 * math.pi, 200001)
    cos = np.cos(theta)
    w = np.stack([np.sin(theta), np.zeros_like(theta), cos], axis=-1)
    model = brdffit.models.get("charlie-sheen", channels=1, ks=1.0, alpha=alpha)
    from brdffit.models.model import evaluate_dirs

    f = np.asarray(evaluate_dirs(model, w, w))[:, 0]
    lam = np.asarray(charlie_lambda(jnp.asarray(cos), alpha))
    d = f * 4.0 * np.maximum(cos, 1e-12) ** 2 * (1.0 + 2.0 * lam)
    integrand = 2.0 * math.pi * d * cos * np.sin(theta)
    assert integrate.trapezoid(integrand[:-1], theta[:-1]) == pytest.approx(1.0, abs=2e-6)


# ---------------------------------------------------------------------------------------------------------------
# Burley's generalised Trowbridge-Reitz distribution (Burley 2012, App. B)

GTR = mf.DISTRIBUTIONS["gtr"]
GTR_GAMMAS = [0.6, 1.0, 1.5, 2.0, 4.0, 10.0]


@pytest.mark.parametrize("gamma", GTR_GAMMAS)
@pytest.mark.parametrize("m", [1e-3, 0.05, 0.3, 1.0])
def test_gtr_is_normalised(gamma, m):
    """∫ D cosθh dωh = 2π ∫ P22(r) r dr over the slope r = tanθh, P22 = D cos⁴θh, by adaptive quadrature in r/α."""
    def p22(r):
        c = math.cos(math.atan(r))
        return float(GTR.D(c, m, gamma)) * c**4

    value, _ = integrate.quad(lambda t: 2.0 * math.pi * p22(m * t) * m * m * t, 0.0, math.inf, epsabs=0.0,
                              epsrel=1e-10, limit=400)
    assert value == pytest.approx(1.0, abs=1e-8)


def test_gtr_is_ggx_at_two_and_burleys_formula_elsewhere():
    theta = np.radians(np.linspace(0.01, 89.99, 2000))
    cos = jnp.asarray(np.cos(theta))
    for m in (1e-3, 0.05, 0.3, 1.0):
        # 1e-11: c goes through ln(α²) and e^z − 1, which round differently from GGX's α²/π at α = 1e-3.
        np.testing.assert_allclose(np.asarray(GTR.D(cos, m, 2.0)), np.asarray(mf.DISTRIBUTIONS["ggx"].D(cos, m)),
                                   rtol=1e-11)
        # GGX's Λ written without cancellation: ε/(2(√(1 + ε) + 1)), ε = α² tan²θ. atol: next to the normal Λ
        # (< 1e-9) takes tan²θ from cosθ, where 1 − cos²θ cancels (3e-9 relative at 0.01°, 1e-19 absolute), far
        # below what 1 + Λ can show.
        e = m * m * np.tan(theta) ** 2
        np.testing.assert_allclose(np.asarray(GTR.Lambda(cos, m, 2.0)), 0.5 * e / (np.sqrt(1.0 + e) + 1.0),
                                   rtol=1e-11, atol=1e-15)
        # From 0.5° on: D takes cosθh alone, and 1 − cos²θh cancels next to the normal (sinθh of the reference does
        # not); at 0.5° that costs ~1e-12 relative.
        away = theta > np.radians(0.5)
        for gamma in (0.6, 1.0, 4.0):
            np.testing.assert_allclose(np.asarray(GTR.D(cos, m, gamma))[away], ref.gtr_D(theta, m, gamma)[away],
                                       rtol=1e-11)


@pytest.mark.parametrize("gamma", [0.6, 1.0, 1.5, 4.0, 10.0])
def test_gtr_lambda_matches_its_definition(gamma):
    theta = np.radians([0.1, 5.0, 30.0, 60.0, 80.0, 88.0, 89.5, 89.95])
    for m in (1e-3, 0.05, 0.4, 1.0):
        got = np.asarray(GTR.Lambda(jnp.asarray(np.cos(theta)), m, gamma))
        np.testing.assert_allclose(got, ref.gtr_lambda(theta, m, gamma), rtol=1e-10)


@pytest.mark.parametrize("gamma", [1.0, 1.5, 4.0])
def test_gtr_smith_G1_equals_the_masking_integral(gamma):
    h, cos_h, w = _stretched_slope_quadrature(0.2, 0.2, radial=2000, angular=1024)
    d = np.asarray(GTR.D(jnp.asarray(h[..., 2]), 0.2, gamma)) * cos_h**3 * w
    for theta in (0.3, 1.0, 1.4):
        omega = _direction(theta, 0.4)
        projected = np.sum(np.maximum(h @ omega, 0.0) * d)
        g1 = 1.0 / (1.0 + float(GTR.Lambda(math.cos(theta), 0.2, gamma)))
        assert g1 == pytest.approx(math.cos(theta) / projected, rel=2e-6), theta
