"""The ``roughplastic`` lobe against Mitsuba 3's ``roughplastic`` plugin, which its export claims to reproduce
exactly; its transmittance against an independent quadrature of its definition; its table of the internal
reflectance against the plugin's computation; gradients, reciprocity and recovery by a fit. The comparisons with
Mitsuba are tests/mitsuba_plugins.py's.
"""

import math

import numpy as np
import pytest

import brdffit
from brdffit import models, synth
from brdffit.export import export
from brdffit.export.terms import random_pairs
from brdffit.models import roughplastic as rp
from brdffit.models.model import Model, evaluate_dirs
from mitsuba_plugins import TOLERANCE, both, deviations, relative, synth_fit_export

PARAMETER_SETS = {
    "glossy plastic": dict(diffuse_reflectance=[0.8, 0.3, 0.1], alpha=0.05, int_ior=1.5),
    "rough plastic": dict(diffuse_reflectance=[0.2, 0.5, 0.9], alpha=0.6, int_ior=1.3),
    "tinted coat, high index": dict(diffuse_reflectance=[0.9, 0.9, 0.85], specular_reflectance=[0.6, 0.8, 1.0],
                                    alpha=0.2, int_ior=2.6),
    "nearly smooth, low index": dict(diffuse_reflectance=[0.05, 0.1, 0.2], alpha=0.002, int_ior=1.05),
}




@pytest.mark.parametrize("name", PARAMETER_SETS)
def test_the_export_evaluates_in_mitsuba_as_the_lobe(mi, name):
    model = models.get("roughplastic", **PARAMETER_SETS[name])
    text = export(model, "mitsuba")
    assert 'type="roughplastic"' in text and "blendbsdf" not in text and "unbounded" not in text, text
    f, g = both(model, text, seed=3)
    assert np.all(g >= 0) and np.mean(g > 0) > 0.99
    rel = relative(f, g)
    assert np.percentile(rel, 95) <= TOLERANCE and np.median(rel) < 1e-5, (np.percentile(rel, 95), rel.max())


def test_a_white_base_at_the_bound_is_written_in_range_with_its_deviation(mi):
    """ρ = 1 where the plugin's R_int lies below the table's needs a written reflectance above 1: the export clips
    it to the plugin's range, says so, and states the deviation that Mitsuba then shows (at most the clipped
    factor's excess, on the diffuse part)."""
    alpha, eta = 0.1, 1.9  # the plugin's R_int 3.4e-4 below the table's
    factor = (1.0 - rp.internal_reflectance(alpha, eta)) / (1.0 - float(rp.internal_reflectance_table(alpha, eta,
                                                                                                      xp=np)))
    assert factor > 1.0
    model = models.get("roughplastic", diffuse_reflectance=1.0, alpha=alpha, int_ior=eta)
    text = export(model, "mitsuba")
    assert '<rgb name="diffuse_reflectance" value="1, 1, 1"/>' in text and "clipped to 1" in text
    rel = deviations(model, text, seed=3)
    assert np.max(rel) <= (factor - 1.0) + 1e-5
    stated = float(text.split("largest relative error ")[1].split(" ")[0])
    assert 0.1 * (factor - 1.0) <= stated <= (factor - 1.0) + 1e-5


def test_the_written_diffuse_reflectance_carries_the_plugins_internal_reflectance():
    """ρ_written = ρ (1 − R_int)/(1 − R_table), R_int computed as the plugin does, stays inside [0, 1]."""
    params = PARAMETER_SETS["glossy plastic"]
    text = export(models.get("roughplastic", **params), "mitsuba")
    factor = ((1.0 - rp.internal_reflectance(params["alpha"], params["int_ior"]))
              / (1.0 - float(rp.internal_reflectance_table(params["alpha"], params["int_ior"], xp=np))))
    written = [float(v) for v in text.split('name="diffuse_reflectance" value="')[1].split('"')[0].split(",")]
    np.testing.assert_allclose(written, np.asarray(params["diffuse_reflectance"]) * factor, rtol=1e-6)
    assert abs(factor - 1.0) < 1e-3  # R_int near R_smooth at α = 0.05 (1 − R ≈ 0.4)


def _transmittance_by_quadrature(mu: float, alpha: float, eta: float, n: int = 400) -> float:
    """T(μ) = ∫ (1 − F(ωi·m)) G1(ωt, m) D_ωi(m) dm re-derived from the definitions, not from the plugin's sampling:
    the visible-normal density D_ωi(m) = G1(ωi) max(0, ωi·m) D(m)/cosθi (Heitz 2014, "Understanding the masking-
    shadowing function", Eq. 38), the integral over the normals' projected measure D(m) cosθm dω taken in
    GGX's own coordinates u = s/(1 + s), s = tan²θm/α² (uniform for that measure), and the azimuth, by
    Gauss-Legendre rules of n × 2n nodes; F Fresnel's unpolarised dielectric reflectance (Born & Wolf §1.5.2), ωt
    the direction refracted into η, G1 = 2/(1 + √(1 + α² tan²θ)) (Walter et al. 2007, Eq. 34)."""
    x, w = np.polynomial.legendre.leggauss(n)
    u, wu = 0.5 * x + 0.5, 0.5 * w
    x2, w2 = np.polynomial.legendre.leggauss(2 * n)
    phi, wphi = math.pi * (x2 + 1.0), math.pi * w2
    u, phi = np.meshgrid(u, phi, indexing="ij")
    weight = np.outer(wu, wphi) / (2.0 * math.pi)
    tan_m = alpha * np.sqrt(u / (1.0 - u))
    cos_m = 1.0 / np.sqrt(1.0 + tan_m**2)
    m = np.stack([tan_m * cos_m * np.cos(phi), tan_m * cos_m * np.sin(phi), cos_m], axis=-1)
    wi = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
    c = m @ wi

    def g1(v):
        return 2.0 / (1.0 + np.sqrt(1.0 + alpha**2 * (v[..., 0] ** 2 + v[..., 1] ** 2) / v[..., 2] ** 2))

    cos_t = np.sqrt(np.maximum(1.0 - (1.0 - c * c) / eta**2, 0.0))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp_ = (eta * c - cos_t) / (eta * c + cos_t)
    fresnel = 0.5 * (rs**2 + rp_**2)
    wt = (c / eta - cos_t)[..., None] * m - wi / eta
    masked = (c > 0) & (wt[..., 2] < 0)
    value = np.where(masked, (1.0 - fresnel) * g1(wt) * g1(wi[None, None, :]) * np.maximum(c, 0.0) / (cos_m * mu),
                     0.0)
    return float(np.sum(value * weight))


@pytest.mark.parametrize("alpha, eta", [(0.05, 1.5), (0.4, 1.3), (0.9, 2.5)])
def test_the_transmittance_is_its_integral(alpha, eta):
    """The plugin's 32 × 32 quadrature over the visible-normal samples (replicated) against the integral in the
    normals' own coordinates; the difference is the two quadratures' error, largest at grazing incidence."""
    table = rp.transmittance(alpha, eta)
    for j in (63, 40, 20, 8):
        mu = rp.cosines()[j]
        assert table[j] == pytest.approx(_transmittance_by_quadrature(mu, alpha, eta), abs=2e-3), (j, mu)


def test_the_table_holds_the_smooth_internal_reflectance():
    """R_table within its stated tolerance of R_smooth at random (α, η) in the declared ranges (between the nodes:
    the interpolation's error), and equal to it at a node."""
    rng = np.random.default_rng(11)
    for _ in range(10):
        alpha = math.exp(rng.uniform(math.log(1e-3), 0.0))
        eta = rng.uniform(rp.MIN_ETA, rp.MAX_ETA)
        assert float(rp.internal_reflectance_table(alpha, eta, xp=np)) == pytest.approx(
            rp.smooth_internal_reflectance(alpha, eta), abs=rp.TABLE_TOLERANCE), (alpha, eta)
    assert float(rp.internal_reflectance_table(0.25, 1.49, xp=np)) == pytest.approx(  # √α = 0.5, √(η − 1) = 0.7
        rp.smooth_internal_reflectance(0.25, 1.49), abs=1e-12)


def test_the_smooth_internal_reflectance_follows_the_plugins_without_bias():
    """R_smooth against the plugin's R_int along η (steps of 0.025): the plugin's value jumps about it by up to
    6.2e-3 for a smooth interface (its evenly spaced cosines stepping over the critical angle's kink), by 1.5e-4 from
    α = 0.05 on, and the differences average out (no bias, which a plain integral would have: 1e-2 at η = 1.75)."""
    etas = np.arange(1.5, 2.0, 0.025)
    for alpha, jump in [(0.0, 6.5e-3), (0.05, 1.5e-4)]:
        diff = np.array([rp.internal_reflectance(alpha, eta) - rp.smooth_internal_reflectance(alpha, eta)
                         for eta in etas])
        assert np.max(np.abs(diff)) <= jump, (alpha, np.max(np.abs(diff)))
        assert abs(np.mean(diff)) <= jump / 2, (alpha, np.mean(diff))
    # a smooth interface's hemispherical internal reflectance: 1 − (1 − R_ext)/η², R_ext = 0.0918 at η = 1.5
    integral = (rp.smooth_internal_reflectance(0.0, 1.5) - 0.04 / 64) * 64 / 63
    assert integral == pytest.approx(1.0 - (1.0 - 0.0918) / 2.25, abs=2e-4)


def test_reciprocal_and_finite_gradients_at_the_bounds():
    import jax
    import jax.numpy as jnp

    wi, wo = random_pairs(300, seed=5)
    wi[:10, 2] = 1e-4  # grazing
    wi = wi / np.linalg.norm(wi, axis=1, keepdims=True)
    for alpha, eta in [(1e-3, rp.MIN_ETA), (1.0, rp.MAX_ETA), (0.3, 1.5)]:
        model = models.get("roughplastic", diffuse_reflectance=0.7, alpha=alpha, int_ior=eta)
        np.testing.assert_allclose(np.asarray(evaluate_dirs(model, wi, wo)), np.asarray(evaluate_dirs(model, wo, wi)),
                                   rtol=1e-12, atol=0.0)

        def total(values, model=model):
            params = dict(model.params, alpha=values[0], int_ior=values[1])
            return jnp.sum(evaluate_dirs(Model(params=params, lobes=model.lobes, channels=model.channels), wi, wo))

        grad = jax.grad(total)(jnp.array([alpha, eta]))
        assert np.all(np.isfinite(np.asarray(grad))), (alpha, eta, grad)


def test_a_rough_plastic_is_recovered_by_a_fit():
    truth = dict(diffuse_reflectance=[0.6, 0.3, 0.15], specular_reflectance=[1.0, 1.0, 1.0], alpha=0.15,
                 int_ior=1.6)
    measured = synth.generate(models.get("roughplastic", **truth), pattern="half-diff", n=3000, noise="relative:0.01",
                              seed=2)
    result = brdffit.fit(measured, "roughplastic")
    assert result.converged, result.summary()
    assert float(result.params["alpha"]) == pytest.approx(truth["alpha"], rel=0.03)
    assert float(result.params["int_ior"]) == pytest.approx(truth["int_ior"], rel=0.03)
    np.testing.assert_allclose(np.asarray(result.params["diffuse_reflectance"]), truth["diffuse_reflectance"],
                               rtol=0.03)


def test_synth_fit_export_round_trip_through_the_cli(mi, tmp_path):
    """A rough plastic synthesised, fitted and exported with the CLI: the parameters come back and Mitsuba's plugin,
    read from the export, evaluates the fitted model."""
    result, text = synth_fit_export(tmp_path, "roughplastic",
                                    dict(diffuse_reflectance=[0.5, 0.35, 0.2], alpha=0.25, int_ior=1.45), n=3000)
    assert result.converged, result.summary()
    assert float(result.params["alpha"]) == pytest.approx(0.25, rel=0.03)
    assert float(result.params["int_ior"]) == pytest.approx(1.45, rel=0.03)
    assert 'type="roughplastic"' in text and "exact" in text and "blendbsdf" not in text
    assert np.percentile(deviations(result.model, text, seed=8), 95) <= TOLERANCE
