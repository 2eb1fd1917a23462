"""brdffit's ``coateddiffuse`` lobe against pbrt-v4's ``coateddiffuse``: the lobe is the expectation of pbrt-v4's
random walk (`LayeredBxDF::f`, transcribed in tests/pbrt_layered_walk.py, which does not import brdffit), its
quadrature is held to a finer one and to the smooth interface's closed forms, a fit recovers known parameters, and
the pbrt export writes the material as it is."""

import math

import numpy as np
import pytest
from scipy import integrate

import brdffit
from brdffit import models, synth
from brdffit.export import export_details
from brdffit.export import pbrt_reference as pr
from brdffit.export import terms as tm
from brdffit.models import coateddiffuse as cd

import pbrt_layered_walk as walk


def _direction(theta, phi=0.0):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def _lobe(rho, alpha, eta, theta_i, phi_i, theta_o):
    model = models.get("coateddiffuse", reflectance=rho, roughness=alpha, eta=eta, channels=1)
    return float(np.asarray(brdffit.evaluate(model, np.array([theta_i]), np.array([phi_i]), np.array([theta_o]),
                                             np.array([0.0])))[0, 0])


# (θo, θi, φi, ρ, η, α): a plastic, a near-smooth white coat at grazing light, a very rough low-index coat, a
# high-index coat seen near grazing.
WALK_CASES = [(0.5, 0.9, 2.2, 0.7, 1.5, 0.3), (0.2, 1.2, 0.4, 0.9, 1.5, 0.05), (1.0, 0.3, 3.0, 0.5, 1.33, 0.8),
              (1.3, 1.1, 0.1, 0.95, 2.2, 0.12)]


@pytest.mark.parametrize("case", WALK_CASES, ids=range(len(WALK_CASES)))
def test_lobe_is_the_expectation_of_pbrts_walk(case):
    """The mean of 150,000 walks of pbrt-v4's estimator (its standard error 0.06-0.45 % here) within 4 standard
    errors of the lobe: the estimator's power-heuristic weights, the slab's transmittance at every crossing and the
    five bottom bounces of maxdepth 10 are all in the formula (taking the weights as 1 lowers it by 7.4, 3.4, 5.6
    and 16.2 % at these settings)."""
    theta_o, theta_i, phi_i, rho, eta, alpha = case
    mean, se = walk.coated_diffuse_f(_direction(theta_o), _direction(theta_i, phi_i), rho, eta, alpha,
                                     walks=150_000, seed=11)
    assert se < 5e-3 * mean
    assert abs(_lobe(rho, alpha, eta, theta_i, phi_i, theta_o) - mean) < 4.0 * se


def test_maxdepth_bounds_the_bottom_bounces():
    """With maxdepth 2 pbrt's walk reaches the base once: the lobe's formula with one term of the series."""
    theta_o, theta_i, phi_i, rho, eta, alpha = WALK_CASES[0]
    mean, se = walk.coated_diffuse_f(_direction(theta_o), _direction(theta_i, phi_i), rho, eta, alpha, max_depth=2,
                                     walks=150_000, seed=12)
    full = _lobe(rho, alpha, eta, theta_i, phi_i, theta_o)
    series = cd.bottom_series(rho, float(cd.internal_reflectance(alpha, eta, xp=np)))
    reflection = _lobe(0.0, alpha, eta, theta_i, phi_i, theta_o)
    one_bounce = reflection + (full - reflection) / series
    assert abs(one_bounce - mean) < 4.0 * se and abs(full - mean) > 20.0 * se


@pytest.mark.parametrize("alpha, eta", [(1e-3, 1.5), (0.05, 1.2), (0.2, 1.5), (0.5, 2.0), (1.0, 3.0), (0.3, 1.01)])
def test_quadrature_against_a_finer_rule(alpha, eta, monkeypatch):
    """X and Y at the lobe's 32 × 32 normals within 1e-4 (relative) of a 160 × 160 rule for cosines from 0.1 (θ up
    to 84°) and within 2e-3 below; R within 3e-4 of the finer rule with 96 cosines a side."""
    mu = np.linspace(0.0, 1.0, 101)[1:]
    x, y = cd.transmission(mu, alpha, eta, xp=np)
    r = float(cd.internal_reflectance(alpha, eta, xp=np))
    monkeypatch.setattr(cd, "NORMAL_NODES", 160)
    monkeypatch.setattr(cd, "REFLECTION_NODES", 96)
    fine_x, fine_y = cd.transmission(mu, alpha, eta, xp=np)
    for got, want in ((x, fine_x), (y, fine_y)):
        error = np.abs(got - want) / np.maximum(want, 1e-3)
        assert np.max(error[mu >= 0.1]) < 1e-4 and np.max(error) < 2e-3
    assert abs(r - float(cd.internal_reflectance(alpha, eta, xp=np))) < 3e-4


@pytest.mark.parametrize("alpha", [1e-3, 0.01, 0.2, 1.0])
def test_interpolation_between_the_cosines_against_the_rule(alpha):
    """X and Y read between their 64 cosines (even in √μ, cubic convolution) against the rule itself at 400
    cosines down to 1e-4 (θ 89.99°): within 1e-3 (relative) from α = 0.01 on; at α = 1e-3, within 1e-4 for θ up to
    84° and 3e-2 beyond, where the rule itself is erratic (a near-mirror interface seen at grazing)."""
    from brdffit.models import cubic

    mu = np.concatenate([np.geomspace(1e-4, 0.1, 200), np.linspace(0.1, 1.0, 200)])
    nodes = cd.cosine_roots()
    for eta in (1.01, 1.5, 3.0):
        tables = cd.transmission(cd.cosines(), alpha, eta, xp=np)
        direct = cd.transmission(mu, alpha, eta, xp=np)
        for table, want in zip(tables, direct):
            error = np.abs(cubic.read(table, nodes, np.sqrt(mu), np) - want) / np.maximum(want, 1e-3)
            if alpha >= 0.01:
                assert np.max(error) < 1e-3
            else:
                assert np.max(error[mu >= 0.1]) < 1e-4 and np.max(error) < 3e-2


def test_near_smooth_interface_against_fresnel_closed_forms():
    """As α → 0 the interface refracts by Snell's law: X(μ) = (1 − F(μ)) Tr(μt), Y → X (pbrt's first weight → 1,
    the second → 0: a delta density against a finite one), and R = ∫ 2μ Tr(μ)² F_inside(μ) dμ (the mirror
    direction has the same cosine); at α = 1e-3 within 2e-3."""
    eta = 1.5

    def fresnel(c, n):
        s2 = (1.0 - c * c) / (n * n)
        if s2 >= 1.0:
            return 1.0
        t = math.sqrt(1.0 - s2)
        return 0.5 * (((n * c - t) / (n * c + t)) ** 2 + ((c - n * t) / (c + n * t)) ** 2)

    def refracted(mu):
        return math.sqrt(1.0 - (1.0 - mu * mu) / eta**2)

    mu = np.array([0.2, 0.5, 0.8, 1.0])
    x, y = cd.transmission(mu, 1e-3, eta, xp=np)
    want = np.array([(1.0 - fresnel(m, eta)) * math.exp(-cd.THICKNESS / refracted(m)) for m in mu])
    np.testing.assert_allclose(x, want, rtol=2e-3)
    np.testing.assert_allclose(y, want, rtol=2e-3)
    r, _ = integrate.quad(lambda m: 2.0 * m * math.exp(-2.0 * cd.THICKNESS / m) * fresnel(m, 1.0 / eta), 1e-9, 1.0,
                          points=[math.sqrt(1.0 - 1.0 / eta**2)], epsabs=1e-12, limit=200)
    assert float(cd.internal_reflectance(1e-3, eta, xp=np)) == pytest.approx(r, abs=2e-3)


@pytest.mark.parametrize("alpha, eta", [(0.05, 1.5), (0.4, 1.3), (1.0, 2.5)])
def test_energy_is_conserved_with_a_white_base(alpha, eta):
    """The directional albedo of a white base under the coat (ρ = 1), by quadrature over ωi, stays below 1 and
    above the coat's own reflection (ρ = 0): pbrt's walk loses light to the slab's transmittance and to the
    bounces beyond maxdepth, never creates it."""
    x, w = np.polynomial.legendre.leggauss(48)
    mu, mw = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(48) + 0.5) * 2.0 * np.pi / 48
    mu_, phi_ = np.meshgrid(mu, phi, indexing="ij")
    weight = np.outer(mw, np.full(48, 2.0 * np.pi / 48)).ravel() * mu_.ravel()
    for theta_o in (0.1, 0.8, 1.3):
        albedo = []
        for rho in (0.0, 1.0):
            model = models.get("coateddiffuse", reflectance=rho, roughness=alpha, eta=eta, channels=1)
            f = np.asarray(brdffit.evaluate(model, np.arccos(mu_.ravel()), phi_.ravel(), np.full(mu_.size, theta_o),
                                            np.zeros(mu_.size)))[:, 0]
            albedo.append(float(np.sum(f * weight)))
        assert 0.0 < albedo[0] < albedo[0] + 0.1 < albedo[1] < 1.0


def test_fit_recovers_known_parameters():
    truth = {"reflectance": [0.6, 0.35, 0.12], "roughness": 0.15, "eta": 1.6}
    measured = synth.generate(models.get("coateddiffuse", **truth), pattern="half-diff", n=3000,
                              noise="relative:0.01", seed=3)
    result = brdffit.fit(measured, "coateddiffuse")
    assert result.converged
    np.testing.assert_allclose(result.model.params["reflectance"], truth["reflectance"], rtol=0.03)
    assert float(result.model.params["roughness"]) == pytest.approx(0.15, rel=0.01)
    assert float(result.model.params["eta"]) == pytest.approx(1.6, rel=0.01)


CASES = [([0.7, 0.4, 0.15], 0.3, 1.5), ([1.0, 0.0, 0.5], 1e-3, 3.0), ([0.05, 0.9, 0.3], 1.0, 1.01)]


@pytest.mark.parametrize("case", CASES, ids=range(len(CASES)))
def test_pbrt_export_is_the_material_as_it_is(case):
    """The text names pbrt-v4's coateddiffuse with the model's own values (round trip), remaproughness false and
    the slab the lobe assumes stated; pbrt-v4's ranges hold; read back, it evaluates to the model."""
    reflectance, roughness, eta = case
    model = models.get("coateddiffuse", reflectance=reflectance, roughness=roughness, eta=eta)
    details = export_details(model, "pbrt", name="m")
    assert details.exact and "# exact: " in details.text
    material = pr.parse(details.text)["m"]
    assert material["type"] == "coateddiffuse" and material["remaproughness"] is False
    assert (material["reflectance"], material["roughness"], material["eta"]) == (reflectance, roughness, eta)
    assert (material["thickness"], material["albedo"], material["g"], material["maxdepth"], material["nsamples"]) \
        == (0.01, [0.0, 0.0, 0.0], 0.0, 10, 1)
    assert all(0.0 <= v <= 1.0 for v in material["reflectance"]) and material["roughness"] >= 1e-3
    pairs = tm.deviation_pairs([tm.Peak("half", roughness)], n=600, seed=7, per_peak=600)
    want = np.asarray(tm.evaluate_dirs(model, pairs.wi, pairs.wo))
    np.testing.assert_allclose(pr.evaluate(pr.parse(details.text), "m", pairs.wi, pairs.wo), want, rtol=1e-10,
                               atol=1e-14)


def test_pbrt_reader_refuses_a_slab_it_does_not_cover():
    text = export_details(models.get("coateddiffuse"), "pbrt", name="m").text.replace('"float thickness" [ 0.01 ]',
                                                                                     '"float thickness" [ 0.1 ]')
    with pytest.raises(tm.ExportError, match="thickness 0.1; the formulas here cover thickness 0.01"):
        pr.evaluate(pr.parse(text), "m", np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))


def test_a_coated_diffuse_in_a_sum_is_refused_naming_what_pbrt_takes():
    with pytest.raises(tm.ExportError, match="or the pbrt, coateddiffuse or coatedconductor model alone"):
        export_details(models.get("lambert+coateddiffuse"), "pbrt")


def test_pbrt_fit_option_writes_a_plastic_as_a_coated_diffuse():
    """Mitsuba's roughplastic (a layered plastic) exported to pbrt with the fit option: of the candidates (the
    lambert + GGX fit's mapping with pbrt's parameters refined, pbrt's mix and its coated diffuse fitted to the
    source), the coated diffuse comes closest (relative RMS 0.0914 against the mix's 0.0936 and the refined
    mapping's 0.153) and is written."""
    from brdffit.export import TARGETS, _export
    from brdffit.export.refit import fit_exportable

    plastic = models.get("roughplastic", diffuse_reflectance=[0.6, 0.3, 0.1], specular_reflectance=1.0, alpha=0.15,
                         int_ior=1.5)
    result = export_details(plastic, "pbrt", fit=True)
    assert pr.parse(result.text)["material"]["type"] == "coateddiffuse"
    assert "fit: coateddiffuse was fitted" in result.text
    others = {spec: _export(TARGETS["pbrt"], fit_exportable(plastic, spec=spec)[0], "material", [], plastic).deviation
              for spec in ("pbrt", "lambert+ggx(fresnel=dielectric)")}
    assert result.deviation.rms < others["pbrt"].rms and result.deviation.rms < 0.7 * others[
        "lambert+ggx(fresnel=dielectric)"].rms
