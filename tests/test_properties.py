"""Tests of brdffit.properties: the albedo quadrature against exact values, closed forms, 1-d scipy integrals and
seeded Monte Carlo estimates; reciprocity, isotropy and energy conservation of the lobes."""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

import brdffit
from brdffit import models
from brdffit import properties as props

DEG = math.pi / 180.0


def albedo(model, theta_i, phi_i=0.0, resolution=props.DEFAULT_RESOLUTION):
    return np.asarray(props.directional_albedo(model, theta_i, phi_i, resolution=resolution))


# ----------------------------------------------------------------------------------------------------------------
# Independent Monte Carlo: a defensive mixture of cosine-weighted hemisphere sampling and lobe-shaped proposals,
# written here in NumPy without the quadrature's half-vector construction.


def _frame(axis):
    helper = np.where(np.abs(axis[..., 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(axis, e1)


def _sample_power(rng, axis, k, n):
    """Directions with density (k+1)/(2π) cos^k α about ``axis`` (α < π/2)."""
    cos_a = rng.random(n) ** (1.0 / (k + 1.0))
    sin_a = np.sqrt(1.0 - cos_a**2)
    beta = rng.uniform(0, 2 * np.pi, n)
    e1, e2 = _frame(np.broadcast_to(axis, (n, 3)))
    return cos_a[:, None] * axis + sin_a[:, None] * (np.cos(beta)[:, None] * e1 + np.sin(beta)[:, None] * e2)


def _ggx_d(cos_h, a):
    return a * a / (np.pi * (cos_h**2 * (a * a - 1.0) + 1.0) ** 2)


class Proposal:
    """One component of the mixture: ``draw(rng, wi, n)`` gives ωo, ``pdf(wi, wo)`` its solid-angle density."""

    def __init__(self, kind, k=0.0):
        self.kind, self.k = kind, k

    def draw(self, rng, wi, n):
        if self.kind == "cosine":
            u1, u2 = rng.random(n), rng.random(n)
            r = np.sqrt(u1)
            return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2), np.sqrt(1 - u1)], -1)
        if self.kind in ("mirror", "retro"):
            axis = wi * np.array([-1.0, -1.0, 1.0]) if self.kind == "mirror" else wi
            return _sample_power(rng, axis, self.k, n)
        if self.kind == "half":  # h ~ (k+1)/(2π) cos^k θh, ωo the reflection of ωi about h
            h = _sample_power(rng, np.array([0.0, 0.0, 1.0]), self.k, n)
        else:  # "ggx": h ~ D_GGX(h) cosθh (Walter et al. 2007, Eq. 35-36)
            u1, u2 = rng.random(n), rng.random(n)
            tan2 = self.k**2 * u1 / (1.0 - u1)
            c = 1.0 / np.sqrt(1.0 + tan2)
            s = np.sqrt(1.0 - c * c)
            h = np.stack([s * np.cos(2 * np.pi * u2), s * np.sin(2 * np.pi * u2), c], -1)
        return 2.0 * (h @ wi)[:, None] * h - wi

    def pdf(self, wi, wo):
        if self.kind == "cosine":
            return np.maximum(wo[:, 2], 0.0) / np.pi
        if self.kind in ("mirror", "retro"):
            axis = wi * np.array([-1.0, -1.0, 1.0]) if self.kind == "mirror" else wi
            return (self.k + 1.0) / (2 * np.pi) * np.maximum(wo @ axis, 0.0) ** self.k
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        c = np.maximum(h[:, 2], 0.0)
        pdf_h = (self.k + 1.0) / (2 * np.pi) * c**self.k if self.kind == "half" else _ggx_d(c, self.k) * c
        return pdf_h / (4.0 * np.maximum(np.abs(np.sum(wo * h, axis=-1)), 1e-300))


def mc_albedo(model, theta_i, phi_i=0.0, proposals=(), n=100_000, seed=0):
    """Seeded Monte Carlo estimate of the albedo and its standard error, per channel.

    A quarter of the samples (all of them if ``proposals`` is empty) are cosine-weighted; the rest are split among
    ``proposals``. Every sample is weighted by the mixture density (multiple importance sampling, balance
    heuristic), so the estimator is unbiased whatever the proposals."""
    rng = np.random.default_rng(seed)
    wi = np.array([math.sin(theta_i) * math.cos(phi_i), math.sin(theta_i) * math.sin(phi_i), math.cos(theta_i)])
    comps = [Proposal("cosine")] + list(proposals)
    shares = [1.0] if not proposals else [0.25] + [0.75 / len(proposals)] * len(proposals)
    counts = [int(round(s * n)) for s in shares]
    wo = np.concatenate([c.draw(rng, wi, m) for c, m in zip(comps, counts)])
    pdf = sum(s * c.pdf(wi, wo) for s, c in zip(shares, comps))
    f = np.asarray(brdffit.evaluate_dirs(model, jnp.asarray(np.broadcast_to(wi, wo.shape)), jnp.asarray(wo)))
    above = wo[:, 2] > 0
    x = np.where(above[:, None], f * np.maximum(wo[:, 2:3], 0.0) / np.where(above, pdf, 1.0)[:, None], 0.0)
    return x.mean(axis=0), x.std(axis=0) / math.sqrt(len(x))


# ----------------------------------------------------------------------------------------------------------------
# The cases. One compiled quadrature serves many of them: a model is linear in its lobes, so the sum of the cases'
# lobes, with one channel per case (lobe k's colour parameters nonzero in channel k only), gives every case's albedo
# in its own channel. Ashikhmin-Shirley's Schlick term is not zero when rs is, so its cases are run alone.


@dataclasses.dataclass(frozen=True, eq=False)
class Case:
    id: str
    spec: str
    params: dict
    proposals: tuple | None = ()  # Monte Carlo proposal components (cosine sampling is always mixed in); None: no MC
    stack: str | None = "a"  # cases with the same stack share one model; None: run alone

    def model(self):
        return models.get(self.spec, channels=1, **self.params)


def P(kind, k=0.0):
    return Proposal(kind, k)


CASES = [
    Case("phong-20", "phong", dict(ks=1.0, n=20.0), (P("mirror", 20),)),
    Case("phong-1", "phong", dict(ks=0.7, n=1.0), None),
    Case("phong-1000", "phong", dict(ks=0.7, n=1000.0), (P("mirror", 1000),)),
    Case("blinn-phong-20", "blinn-phong", dict(ks=1.0, n=20.0), (P("half", 20),)),
    Case("blinn-phong-1000", "blinn-phong", dict(ks=1.0, n=1000.0), (P("half", 1000),)),
    Case("ward-0.2", "ward", dict(ks=1.0, alpha=0.2), (P("half", 48),)),
    Case("ward-0.5", "ward", dict(ks=1.0, alpha=0.5), (P("half", 6),)),
    Case("ward-0.02", "ward", dict(ks=1.0, alpha=0.02), (P("half", 2 / 0.02**2 - 2),)),
    Case("ward-duer-0.2", "ward-duer", dict(ks=1.0, alpha=0.2), (P("half", 48),)),
    Case("ward-duer-0.02", "ward-duer", dict(ks=1.0, alpha=0.02), (P("half", 2 / 0.02**2 - 2),)),
    Case("cook-torrance-0.3", "cook-torrance", dict(ks=1.0, m=0.3, f0=0.5), (P("half", 20),)),
    Case("cook-torrance-0.4", "cook-torrance", dict(ks=1.0, m=0.4, f0=0.5), None),
    Case("cook-torrance-0.02", "cook-torrance", dict(ks=1.0, m=0.02, f0=0.5), (P("half", 2 / 0.02**2 - 2),)),
    Case("ggx-0.3", "ggx", dict(ks=1.0, alpha=0.3, f0=1.0), (P("ggx", 0.3),)),
    Case("ggx-0.5", "ggx", dict(ks=1.0, alpha=0.5, f0=1.0), None),
    Case("ggx-0.02", "ggx", dict(ks=1.0, alpha=0.02, f0=1.0), (P("ggx", 0.02),)),
    Case("oren-nayar", "oren-nayar", dict(rho_d=0.8, sigma=0.5), ()),
    Case("toon-diffuse", "toon-diffuse", dict(rho_d=0.8, rho_shade=0.1), ()),
    Case("toon-specular", "toon-specular", dict(ks=1.0), (P("mirror", 10),)),
    Case("ward-aniso", "ward-aniso", dict(ks=1.0, alpha_x=0.1, alpha_y=0.4), (P("half", 20),)),
    # Lafortune lobes share parameter names with repeated lobes (ks_2, n_2), so they get their own stack.
    Case("lafortune-2-lobes", "lafortune(lobes=2)",
         dict(ks_1=0.6, n_1=30.0, ks_2=0.4, cxy_2=0.8, cz_2=0.8, n_2=10.0), (P("mirror", 30), P("retro", 10)), "b"),
    Case("lafortune-phong-1000", "lafortune", dict(ks_1=0.7, n_1=1000.0), None, "b"),
    Case("lafortune-aniso", "lafortune(anisotropic=true)", dict(ks_1=1.0, cx_1=-1.0, cy_1=-0.6, cz_1=1.0, n_1=20.0),
         (P("mirror", 5),), "b"),
    Case("ashikhmin-shirley-100", "ashikhmin-shirley", dict(rs=0.5, n=100.0), (P("half", 100),), None),
    Case("ashikhmin-shirley-1000", "ashikhmin-shirley", dict(rs=1.0, n=1000.0), (P("half", 1000),), None),
    Case("ashikhmin-shirley-1000-rs0.3", "ashikhmin-shirley", dict(rs=0.3, n=1000.0), None, None),
]
CASE = {case.id: case for case in CASES}

TABLE_THETA = np.array([0.0, 10.0, 20.0, 30.0, 40.0, 60.0, 75.0, 80.0, 85.0]) * DEG
TABLE_PHI = 0.6  # any azimuth: the isotropic cases do not depend on it
MC_THETA_INDEX = [2, 5, 8]  # 20°, 60°, 85°
RESOLUTIONS = (props.DEFAULT_RESOLUTION, 2 * props.DEFAULT_RESOLUTION)  # the table's rule, and twice its nodes


def stacked_model(cases):
    """The sum of the cases' lobes, with case k's colour parameters in channel k only."""
    base = models.get("+".join(case.spec for case in cases), channels=len(cases))
    names = [name for lobe_names in base.names_by_lobe for name in lobe_names]
    assert len(set(names)) == len(names), f"parameter names collide: {names}"
    values = {}
    for k, (case, lobe, lobe_names) in enumerate(zip(cases, base.lobes, base.names_by_lobe)):
        for spec, name in zip(lobe.param_specs(), lobe_names):
            value = case.params.get(spec.name, spec.default)
            values[name] = np.eye(len(cases))[k] * value if spec.colour else value
    return base.replace(**values)


@functools.lru_cache(maxsize=None)
def albedo_table():
    """case id -> (albedo at the default resolution, albedo at twice it), each over TABLE_THETA."""
    table = {}
    stacks = {}
    for case in CASES:
        if case.stack is None:
            table[case.id] = tuple(albedo(case.model(), TABLE_THETA, TABLE_PHI, r)[:, 0] for r in RESOLUTIONS)
        else:
            stacks.setdefault(case.stack, []).append(case)
    for cases in stacks.values():
        model = stacked_model(cases)
        values = [albedo(model, TABLE_THETA, TABLE_PHI, r) for r in RESOLUTIONS]
        for k, case in enumerate(cases):
            table[case.id] = tuple(v[:, k] for v in values)
    return table


def table_albedo(case_id):
    return albedo_table()[case_id][0]


def test_stacked_model_gives_each_lobe_its_own_channel():
    # The stacked channel equals the lobe evaluated alone (a model of its own, one channel).
    for case_id in ("ward-0.2", "toon-diffuse"):
        alone = albedo(CASE[case_id].model(), TABLE_THETA, TABLE_PHI)[:, 0]
        np.testing.assert_allclose(table_albedo(case_id), alone, rtol=1e-13, atol=1e-15)


# ----------------------------------------------------------------------------------------------------------------
# Exact values, closed forms and 1-d references


def test_lambert_albedo_is_rho_d_exactly():
    model = models.get("lambert", rho_d=[0.1, 0.5, 1.0])
    theta = np.array([0.0, 0.3, 45 * DEG, 1.2, 85 * DEG, 89.5 * DEG])
    a = albedo(model, theta)
    assert a.shape == (len(theta), 3)
    np.testing.assert_allclose(a, np.broadcast_to([0.1, 0.5, 1.0], a.shape), atol=1e-6)
    assert np.max(np.abs(a - [0.1, 0.5, 1.0])) < 1e-12  # measured: round-off


def test_shapes_and_scalar_input():
    model = models.get("lambert")
    assert albedo(model, 0.4).shape == (3,)
    assert albedo(model, [0.4]).shape == (1, 3)
    assert albedo(model, [0.4, 0.5], 1.0).shape == (2, 3)
    # θi = π/2: no light above the horizon.
    np.testing.assert_array_equal(albedo(model, [0.5 * math.pi]), 0.0)


@pytest.mark.parametrize("bad", [-0.1, 95 * DEG, 45.0, float("nan")])
def test_invalid_theta_is_rejected(bad):
    with pytest.raises(ValueError, match="theta_i"):
        props.directional_albedo(models.get("lambert"), bad)


@pytest.mark.parametrize("resolution", [4, 10.0, True, (128,), (128, 4), "128"])
def test_invalid_resolution_is_rejected(resolution):
    with pytest.raises(ValueError, match="resolution"):
        props.directional_albedo(models.get("lambert"), 0.1, resolution=resolution)


def test_toon_diffuse_albedo_closed_form_over_many_chunks():
    # The toon-diffuse value does not depend on ωo, so a(θi) = rho_shade + (rho_d − rho_shade) S((cosθi − t)/w).
    # 40 angles, some inside the 0.02-wide step, span several jitted chunks (the last one padded).
    model = models.get("toon-diffuse", channels=1, rho_d=0.8, rho_shade=0.1, threshold=0.3)
    theta = np.arccos(np.concatenate([np.linspace(0.25, 0.35, 20), np.linspace(0.01, 1.0, 20)]))
    expected = 0.1 + 0.7 / (1.0 + np.exp(-(np.cos(theta) - 0.3) / 0.02))
    np.testing.assert_allclose(albedo(model, theta)[:, 0], expected, atol=1e-10)
    np.testing.assert_allclose(table_albedo("toon-diffuse"),
                               0.1 + 0.7 / (1.0 + np.exp(-(np.cos(TABLE_THETA) - 0.3) / 0.02)), atol=1e-10)


def test_phong_albedo_closed_form():
    # Lafortune & Willems (1994): at θi = 0 the lobe lies entirely above the horizon and
    # a = ks (n+2)/(2π) ∫ cos^n θ cosθ dω = ks (n+2)/(n+2) = ks. For any θi whose lobe stays above the horizon the
    # cosθo factor averages to cosθi over the lobe: a = ks cosθi (cos^1000 of 15° is 1e-15, so up to θi = 75° for
    # n = 1000).
    for case_id in ("phong-1", "phong-20", "phong-1000", "lafortune-phong-1000"):
        assert abs(table_albedo(case_id)[0] - CASE[case_id].params.get("ks", 0.7)) < 1e-10
    up_to_75 = TABLE_THETA <= 75 * DEG
    for case_id in ("phong-1000", "lafortune-phong-1000"):  # the same lobe written as Lafortune's (cxy = −1, cz = 1)
        np.testing.assert_allclose(table_albedo(case_id)[up_to_75], 0.7 * np.cos(TABLE_THETA[up_to_75]), atol=1e-10)


@pytest.mark.parametrize("n", [20.0, 1000.0])
def test_blinn_phong_albedo_closed_form(n):
    # At θi = 0, θh = θo/2; with u = cos(θo/2): cosθo = 2u² − 1 and sinθo dθo = −4u du, so
    # a = ks (n+8)/(8π) 2π ∫_{1/√2}^{1} u^n (2u² − 1) 4u du
    #   = ks (n+8) [2 u^{n+4}/(n+4) − u^{n+2}/(n+2)]_{1/√2}^{1}, which is ks n(n+8)/((n+2)(n+4)) for large n.
    def antiderivative(u):
        return 2 * u ** (n + 4) / (n + 4) - u ** (n + 2) / (n + 2)

    expected = (n + 8) * (antiderivative(1.0) - antiderivative(2**-0.5))
    assert abs(table_albedo(f"blinn-phong-{n:.0f}")[0] - expected) < 1e-10
    assert expected > 1.0  # the (n+8)/(8π) normalisation is approximate: the albedo exceeds ks


def _normal_incidence_reference(f_of_theta_o, width, kinks=()):
    """a(0) = 2π ∫_0^{π/2} f(θo) cosθo sinθo dθo for a lobe symmetric about the normal (scipy.quad, with
    breakpoints at multiples of the lobe width and at the kinks)."""
    points = [p for p in (width, 2 * width, 4 * width, 8 * width, 16 * width, *kinks) if p < 0.5 * math.pi]
    value, err = integrate.quad(lambda t: f_of_theta_o(t) * math.cos(t) * math.sin(t), 0.0, 0.5 * math.pi,
                                points=sorted(points), epsabs=1e-13, epsrel=1e-12, limit=500)
    assert err < 1e-9
    return 2 * math.pi * value


def _schlick(c, f0):
    return f0 + (1 - f0) * (1 - c) ** 5


# Each lobe at normal incidence, re-derived here from its paper as a function of θo alone (θh = θo/2,
# ωi·h = cos θh, cosθi = 1).
def _ward_ref(alpha, duer):
    return lambda t: math.exp(-math.tan(t / 2) ** 2 / alpha**2) / (
        4 * math.pi * alpha**2 * (math.cos(t) if duer else math.sqrt(math.cos(t))))


def _beckmann_vcavity_ref(m, f0):
    def f(t):
        ch, co = math.cos(t / 2), math.cos(t)
        d = math.exp(-math.tan(t / 2) ** 2 / m**2) / (math.pi * m**2 * ch**4)
        g = min(1.0, 2 * ch * co / ch, 2 * ch / ch)  # Cook & Torrance (1982) with ωo·h = cos θh
        return _schlick(ch, f0) * d * g / (4 * co)
    return f


def _ggx_smith_ref(a, f0):
    def f(t):
        ch, co = math.cos(t / 2), math.cos(t)
        g1 = 2 / (1 + math.sqrt(1 + a * a * math.tan(t) ** 2))  # Walter et al. (2007), Eq. 34; G1(ωi) = 1
        return _schlick(ch, f0) * _ggx_d(ch, a) * g1 / (4 * co)
    return f


def _ashikhmin_shirley_ref(n, rs):
    # Ashikhmin & Shirley (2000), Eq. 4 with nu = nv = n, max(cosθi, cosθo) = 1 and ωi·h = cos θh.
    return lambda t: (n + 1) / (8 * math.pi) * math.cos(t / 2) ** n / math.cos(t / 2) * _schlick(math.cos(t / 2), rs)


NORMAL_INCIDENCE = [
    # (case id, reference f(θo), lobe width, kinks of f, tolerance)
    ("ward-0.02", _ward_ref(0.02, False), 0.02, (), 1e-6),
    ("ward-0.5", _ward_ref(0.5, False), 0.5, (), 1e-6),
    ("ward-duer-0.02", _ward_ref(0.02, True), 0.02, (), 1e-6),
    ("cook-torrance-0.02", _beckmann_vcavity_ref(0.02, 0.5), 0.02, (), 1e-6),
    # V-cavity shadowing has a kink where 2 cosθo = 1; measured error 1.3e-5 at the default resolution.
    ("cook-torrance-0.4", _beckmann_vcavity_ref(0.4, 0.5), 0.4, (math.pi / 3,), 5e-5),
    ("ggx-0.02", _ggx_smith_ref(0.02, 1.0), 0.02, (), 1e-6),
    ("ggx-0.5", _ggx_smith_ref(0.5, 1.0), 0.5, (), 1e-6),
    ("ashikhmin-shirley-1000-rs0.3", _ashikhmin_shirley_ref(1000.0, 0.3), 0.03, (), 1e-6),
]


@pytest.mark.parametrize("case_id,reference,width,kinks,tol", NORMAL_INCIDENCE, ids=[c[0] for c in NORMAL_INCIDENCE])
def test_albedo_at_normal_incidence_matches_1d_integral(case_id, reference, width, kinks, tol):
    expected = _normal_incidence_reference(reference, width, kinks)
    assert abs(table_albedo(case_id)[0] - expected) < tol


def test_oren_nayar_matches_dblquad():
    # Oren & Nayar (1994), Eq. 30, with angles: f = ρ/π (A + B max(0, cos(φi − φo)) sinα tanβ).
    rho, sigma = CASE["oren-nayar"].params["rho_d"], CASE["oren-nayar"].params["sigma"]
    s2 = sigma**2
    a_coef, b_coef = 1 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    for index in (0, 4, 7):  # 0°, 40°, 80°
        theta_i = TABLE_THETA[index]

        def integrand(theta_o, phi_o):
            alpha, beta = max(theta_i, theta_o), min(theta_i, theta_o)
            f = rho / math.pi * (a_coef + b_coef * max(0.0, math.cos(phi_o)) * math.sin(alpha) * math.tan(beta))
            return f * math.cos(theta_o) * math.sin(theta_o)

        # φo relative to φi; split where the integrand has kinks: cos φo = 0 and θo = θi.
        total = 0.0
        for p0, p1 in ((-0.5 * math.pi, 0.5 * math.pi), (0.5 * math.pi, 1.5 * math.pi)):
            for t0, t1 in ((0.0, theta_i), (theta_i, 0.5 * math.pi)):
                if t1 > t0:
                    total += integrate.dblquad(integrand, p0, p1, t0, t1, epsabs=1e-10, epsrel=1e-10)[0]
        assert abs(table_albedo("oren-nayar")[index] - total) < 1e-4  # measured 1.6e-5 at most


# ----------------------------------------------------------------------------------------------------------------
# Monte Carlo comparisons and the resolution-doubling check

MC_CASES = [case for case in CASES if case.proposals is not None]


@pytest.mark.parametrize("case", MC_CASES, ids=[case.id for case in MC_CASES])
def test_albedo_matches_monte_carlo(case):
    model = case.model()
    for k, index in enumerate(MC_THETA_INDEX):
        theta_i = TABLE_THETA[index]
        mean, se = mc_albedo(model, theta_i, TABLE_PHI, case.proposals, seed=k)
        quad = table_albedo(case.id)[index]
        assert se[0] < 0.005, f"Monte Carlo too noisy to be a check: se = {se[0]}"
        assert abs(quad - mean[0]) <= 4 * se[0] + 1e-9, (
            f"θi = {theta_i / DEG:.0f}°: quadrature {quad:.6f}, Monte Carlo {mean[0]:.6f} ± {se[0]:.6f}")


@pytest.mark.parametrize("case", CASES, ids=[case.id for case in CASES])
def test_doubling_the_resolution_changes_the_albedo_by_less_than_1e_3(case):
    base, doubled = albedo_table()[case.id]
    assert np.max(np.abs(doubled - base)) < 1e-3


# ----------------------------------------------------------------------------------------------------------------
# Reciprocity and isotropy

# Lobes whose non-reciprocity comes from a term their defaults switch off: evaluated with it on.
_SWITCHED_ON = {"gltf": {"clearcoat": 0.5}}
DEFAULT_LOBES = [models.get(name, **_SWITCHED_ON.get(name, {})) for name in models.names()]
VARIANTS = [
    models.get("cook-torrance(shadowing=smith, fresnel=conductor)"),
    models.get("cook-torrance(distribution=blinn, fresnel=dielectric, shadowing=none)"),
    models.get("cook-torrance(distribution=ggx)", m=0.02),
    models.get("phong", n=1000.0),
    models.get("ward", alpha=0.02),
    models.get("lafortune(lobes=3)", cxy_2=0.7, cz_2=0.7, cxy_3=0.0),
    models.get("lafortune(anisotropic=true)", cx_1=-0.9, cy_1=-0.4),
    models.get("ward-aniso", alpha_x=0.05, alpha_y=0.4),
    models.get("ashikhmin-shirley-aniso", nu=5.0, nv=1000.0),
    models.get("lambert+ggx+ward"),
]


@pytest.mark.parametrize("model", DEFAULT_LOBES + VARIANTS, ids=lambda m: m.spec)
def test_reciprocity_matches_declaration(model):
    error = props.reciprocity_error(model)
    if model.reciprocal:
        assert error < 1e-10
    else:
        assert error > 0.1


def test_toon_diffuse_is_not_reciprocal_even_in_a_sum():
    assert not models.get("lambert+toon-diffuse").reciprocal
    assert props.reciprocity_error(models.get("lambert+toon-diffuse")) > 0.1


@pytest.mark.parametrize("model", DEFAULT_LOBES, ids=lambda m: m.spec)
def test_isotropy_of_default_lobes(model):
    # Every lobe is isotropic with its defaults (the anisotropic ones have alpha_x = alpha_y, nu = nv, cx = cy);
    # what is left is round-off (at most 4e-10, from the toon lobes' logistic step).
    assert props.isotropy_error(model) < 1e-8


@pytest.mark.parametrize("model", [
    models.get("ward-aniso", alpha_x=0.1, alpha_y=0.3),
    models.get("lafortune(anisotropic=true)", cx_1=-1.0, cy_1=-0.6),
    models.get("ashikhmin-shirley-aniso", nu=10.0, nv=200.0),
], ids=lambda m: m.spec)
def test_anisotropic_lobes_are_detected(model):
    assert props.isotropy_error(model) > 0.1


def test_strongly_anisotropic_lobe_gets_more_azimuth_nodes_by_default():
    # αy/αx = 50: a sliver in azimuth. The default rule uses 512 azimuth nodes per half circle for an anisotropic
    # model (measured error 3e-5); 128 would be 6e-2 off.
    model = models.get("ward-aniso", channels=1, ks=1.0, alpha_x=0.01, alpha_y=0.5)
    theta, phi = np.deg2rad([0.0, 60.0, 85.0, 0.0, 60.0, 85.0]), np.deg2rad([0.0, 0.0, 0.0, 60.0, 60.0, 60.0])
    default = np.asarray(props.directional_albedo(model, theta, phi))[:, 0]
    reference = albedo(model, theta, phi, resolution=(128, 1024))[:, 0]
    assert np.max(np.abs(default - reference)) < 1e-4


def test_anisotropic_albedo_depends_on_phi_i():
    model = models.get("ward-aniso", channels=1, ks=1.0, alpha_x=0.1, alpha_y=0.4)
    a = albedo(model, [70 * DEG, 70 * DEG], [0.0, 0.5 * math.pi])[:, 0]
    assert abs(a[0] - a[1]) > 0.01
    # ... but not for an isotropic model.
    iso = models.get("ward", channels=1, ks=1.0, alpha=0.3)
    b = albedo(iso, [70 * DEG, 70 * DEG], [0.0, 1.0])[:, 0]
    assert abs(b[0] - b[1]) < 1e-9


def test_direction_pairs_are_seeded_unit_and_above_the_horizon():
    wi, wo = props.direction_pairs(999, seed=3)
    wi2, _ = props.direction_pairs(999, seed=3)
    np.testing.assert_array_equal(wi, wi2)
    for w in (wi, wo):
        assert w.shape == (999, 3)
        np.testing.assert_allclose(np.linalg.norm(w, axis=-1), 1.0, atol=1e-12)
        assert np.all(w[:, 2] > 0)


# ----------------------------------------------------------------------------------------------------------------
# Energy conservation

COARSE = np.deg2rad(np.concatenate([np.arange(0.0, 89.0, 4.0), [89.0, 89.5]]))

ENERGY_CASES = [
    # (case, conserving on 0..89.5°, measured largest albedo on COARSE, θi of it in degrees)
    (Case("lambert", "lambert", dict(rho_d=1.0)), True, 1.0, None),
    (Case("phong-1", "phong", dict(ks=1.0, n=1.0)), True, 1.0, 0.0),  # a = ks cosθi at most
    (Case("phong-20", "phong", dict(ks=1.0, n=20.0)), True, 1.0, 0.0),
    (Case("phong-1000", "phong", dict(ks=1.0, n=1000.0)), True, 1.0, 0.0),
    (Case("blinn-phong-10", "blinn-phong", dict(ks=1.0, n=10.0)), False, 1.0748, 0.0),  # (n+8)/(8π) approximate
    (Case("ward-0.5", "ward", dict(ks=1.0, alpha=0.5)), True, 0.6818, 89.5),  # exceeds 1 only beyond 89.78°
    (Case("ward-duer-0.5", "ward-duer", dict(ks=1.0, alpha=0.5)), False, 9.9323, 89.5),  # a ~ 1/cosθi
    (Case("ward-duer-0.02", "ward-duer", dict(ks=1.0, alpha=0.02)), False, 1.2364, 89.5),
    (Case("cook-torrance-0.5", "cook-torrance", dict(ks=1.0, m=0.5, f0=1.0)), True, 0.9977, 89.5),  # V-cavity
    (Case("cook-torrance-smith-0.5", "cook-torrance(shadowing=smith)", dict(ks=1.0, m=0.5, f0=1.0)),
     True, 0.9577, 89.5),
    (Case("cook-torrance-none-0.3", "cook-torrance(shadowing=none)", dict(ks=1.0, m=0.3, f0=1.0)),
     False, 10.2034, 89.5),  # no shadowing: 1/(4 cosθi cosθo) unbounded at grazing
    (Case("ggx-0.02", "ggx", dict(ks=1.0, alpha=0.02, f0=1.0)), True, 0.9996, 0.0),
    (Case("oren-nayar-0.2", "oren-nayar", dict(rho_d=1.0, sigma=0.2)), False, 1.0148, 89.5),  # qualitative model
    (Case("toon-diffuse", "toon-diffuse", dict(rho_d=1.0, rho_shade=1.0)), True, 1.0, None),
    (Case("ashikhmin-shirley-1000", "ashikhmin-shirley", dict(rs=1.0, n=1000.0), stack=None), True, 0.9960, 0.0),
    # White furnace of the anisotropic and height-correlated microfacet terms (F = 1): at most 1, the correlated
    # form above the separable one (it shadows less). The anisotropic lobes have a stack of their own: a stack with
    # an anisotropic lobe is scanned over φi too, with the finer azimuth rule (`brdffit.properties.max_albedo`).
    (Case("ggx-aniso-smith", "ggx(anisotropic=true)", dict(ks=1.0, alpha_x=0.1, alpha_y=0.5, f0=1.0),
          stack="aniso"), True, 0.8798, 89.5),
    (Case("ggx-aniso-correlated", "ggx(anisotropic=true, shadowing=smith-correlated)",
          dict(ks=1.0, alpha_x=0.1, alpha_y=0.5, f0=1.0), stack="aniso"), True, 0.9872, 89.5),
    (Case("ggx-correlated-0.5", "ggx(shadowing=smith-correlated)", dict(ks=1.0, alpha=0.5, f0=1.0)),
     True, 0.9771, 89.5),
    (Case("beckmann-aniso-correlated", "cook-torrance(anisotropic=true, shadowing=smith-correlated)",
          dict(ks=1.0, m_x=0.3, m_y=0.08, f0=1.0), stack="aniso"), True, 0.9999, 0.0),
    (Case("std-correlated", "cook-torrance(distribution=std, shadowing=smith-correlated)",
          dict(ks=1.0, m=0.5, gamma=1.6, f0=1.0)), True, 0.6098, 89.5),
    (Case("gtr1-smith", "cook-torrance(distribution=gtr, shadowing=smith)", dict(ks=1.0, m=0.5, gamma=1.0, f0=1.0)),
     True, 0.7141, 89.5),
    # Burley's diffuse: 1 − 1/42 at normal incidence for roughness 0 (F_D90 = 1/2), retro-reflective gain beyond 1
    # at grazing for roughness 1 (Burley 2012 says it does not conserve energy there).
    (Case("burley-0", "burley", dict(rho_d=1.0, roughness=0.0)), True, 0.9762, 0.0),
    (Case("burley-1", "burley", dict(rho_d=1.0, roughness=1.0)), False, 1.5404, 89.5),
    (Case("sheen", "sheen", dict(ks=1.0)), True, 0.0863, 89.5),
    (Case("charlie-0.3", "charlie-sheen", dict(ks=1.0, alpha=0.3)), True, 0.8117, 89.5),
    (Case("charlie-1", "charlie-sheen", dict(ks=1.0, alpha=1.0)), True, 0.9415, 89.5),
]


@functools.lru_cache(maxsize=None)
def energy_table():
    """case id -> (largest albedo on COARSE, θi of it), from one model per stack (and the unstackable cases)."""
    table = {}
    stacks = {}
    for case, *_ in ENERGY_CASES:
        if case.stack is None:
            a, theta, _ = props.max_albedo(case.model(), theta_i=COARSE)
            table[case.id] = (a[0], theta[0])
        else:
            stacks.setdefault(case.stack, []).append(case)
    for cases in stacks.values():
        a, theta, _ = props.max_albedo(stacked_model(cases), theta_i=COARSE)
        for k, case in enumerate(cases):
            table[case.id] = (a[k], theta[k])
    return table


@pytest.mark.parametrize("case,conserving,measured,theta_deg", ENERGY_CASES, ids=[c[0].id for c in ENERGY_CASES])
def test_energy_conservation_of_each_lobe(case, conserving, measured, theta_deg):
    a, theta = energy_table()[case.id]
    assert bool(a <= 1.0 + 1e-3) is conserving
    assert a == pytest.approx(measured, abs=1e-4)
    if theta_deg is not None:
        assert theta / DEG == pytest.approx(theta_deg)


def test_is_energy_conserving():
    assert props.is_energy_conserving(models.get("lambert", rho_d=[0.2, 0.9, 1.0]), theta_i=COARSE)
    too_bright = models.get("lambert", rho_d=[0.2, 0.9, 1.01])
    assert not props.is_energy_conserving(too_bright, theta_i=COARSE)
    assert props.is_energy_conserving(too_bright, tol=0.02, theta_i=COARSE)


def test_ward_exceeds_one_at_grazing():
    # Ward's 1/√(cosθi cosθo) makes the albedo grow like 1/√cosθi as θi -> 90°. With α = 0.5 and ks = 1 it is
    # 0.682 at 89.5° (the end of the default grid) and crosses 1 near 89.78°: 1.056 at 89.8°, 1.484 at 89.9°
    # (Monte Carlo with 2e6 samples agrees within its standard error of ~1e-3; docs/properties.md).
    model = models.get("ward", channels=1, ks=1.0, alpha=0.5)
    grid = np.deg2rad([0.0, 60.0, 89.5, 89.8, 89.9])
    a = albedo(model, grid)[:, 0]
    np.testing.assert_allclose(a, [0.58549, 0.35067, 0.68176, 1.05624, 1.48358], atol=2e-5)
    assert props.is_energy_conserving(model)
    assert not props.is_energy_conserving(model, theta_i=grid)
    report = props.check(model, theta_i=grid)
    assert not report.energy_conserving and report.theta_i_max == pytest.approx(89.9 * DEG)


# ----------------------------------------------------------------------------------------------------------------
# The report


def test_check_report():
    report = props.check(models.get("ward", channels=1, ks=1.0, alpha=0.5), theta_i=COARSE)
    assert report.reciprocal and report.declared_reciprocal and report.isotropic
    assert report.energy_conserving
    assert report.theta_i_max == pytest.approx(89.5 * DEG)
    assert report.max_albedo == pytest.approx(0.68176, abs=1e-4)
    assert report.channel_max_albedo == (report.max_albedo,)
    text = str(report)
    for word in ("ward", "reciprocity error", "isotropy error", "energy conserving", "89.5°", "0.6818"):
        assert word in text
    assert "NOT" not in text
    with pytest.raises(dataclasses.FrozenInstanceError):
        report.max_albedo = 0.0


def test_check_report_of_non_reciprocal_and_of_anisotropic_models():
    report = props.check(models.get("toon-diffuse", channels=1), theta_i=COARSE, n=3000)
    assert not report.reciprocal and not report.declared_reciprocal and report.isotropic
    assert "NOT reciprocal" in str(report)
    report = props.check(models.get("ward-aniso", channels=1, ks=1.0, alpha_x=0.5, alpha_y=0.2),
                         theta_i=np.deg2rad([0.0, 45.0, 89.5]), n=3000)
    assert report.reciprocal and not report.isotropic
    # Largest along the tangent, where the lobe is widest (docs/properties.md: 0.7970 at 89.5°, φi = 0).
    assert report.max_albedo == pytest.approx(0.7970, abs=1e-4)
    assert report.theta_i_max == pytest.approx(89.5 * DEG) and report.phi_i_max == 0.0
    assert "anisotropic" in str(report) and "φi = 0.0°" in str(report)


def test_albedo_is_differentiable_in_the_parameters():
    model = models.get("phong", channels=1, ks=0.4, n=50.0)
    grad = jax.grad(lambda m: props.directional_albedo(m, 0.0, resolution=32).sum())(model)
    assert grad.params["ks"][0] == pytest.approx(1.0, abs=1e-9)  # a(0) = ks exactly (quadrature error 1e-13)
    assert abs(grad.params["n"]) < 1e-8


def test_scan_albedo_keeps_its_rule_and_agrees_with_the_directional_albedo():
    """`scan_albedo` computes its quadrature's nodes once a grid (read-only, shared by every model) and gives the
    same albedo as `directional_albedo` (same rule, nodes computed in JAX) at each incidence, for two models in turn
    on one kept rule."""
    from brdffit.properties import _scan_rule, directional_albedo, scan_albedo

    theta, phi = np.radians([0.0, 35.0, 70.0, 89.0]), np.radians([0.0, 90.0])
    before = _scan_rule.cache_info()
    for spec, values in (("lambert+ggx", {"alpha": 0.3, "ks": 0.6, "f0": 0.04}), ("lafortune", {"n_1": 20.0})):
        model = models.get(spec, channels=1, **values)
        scanned = scan_albedo(model, theta, phi, resolution=24)
        for j, p in enumerate(phi):
            direct = np.asarray(directional_albedo(model, theta, p, resolution=24))
            np.testing.assert_allclose(scanned[:, j, :], direct.reshape(scanned[:, j, :].shape), rtol=1e-10,
                                       atol=1e-14)
    after = _scan_rule.cache_info()
    assert after.misses == before.misses + 1 and after.hits == before.hits + 1
    rule = _scan_rule(np.asarray(theta).tobytes(), np.asarray(phi).tobytes(), 24)
    assert not any(a.flags.writeable for a in rule)
