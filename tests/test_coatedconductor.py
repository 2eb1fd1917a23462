"""pbrt-v4's ``coatedconductor`` under a smooth interface (`brdffit.models.coatedconductor`): the lobe against a
NumPy transcription of pbrt-v4's random walk (tests/pbrt_layered_walk.py, which does not import brdffit), its
quadrature and tables against finer ones, its albedo, and a fit that recovers a synthetic material."""

import jax.numpy as jnp
import numpy as np
import pytest

import brdffit
from brdffit.geometry import LocalPair
from brdffit.models import coatedconductor as cc
from brdffit.models.fresnel import dielectric

from pbrt_layered_walk import EXIT, MIRROR, coated_conductor_f, coated_conductor_sample, reflectance_index


def _direction(theta, phi):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _cosine_rule(cosines: int, azimuths: int):
    """A product rule for ∫ g(ωi) cosθi dωi over the hemisphere: Gauss-Legendre in cosθi, midpoints in φ. Returns
    the directions ``(n, 3)`` and their weights (cosθi included) ``(n,)``."""
    x, w = np.polynomial.legendre.leggauss(cosines)
    mu, phi = (x + 1) / 2, (np.arange(azimuths) + 0.5) * 2 * np.pi / azimuths
    m, p = np.meshgrid(mu, phi, indexing="ij")
    return _direction(np.arccos(m), p).reshape(3, -1).T, (w[:, None] / 2 * m * (2 * np.pi / azimuths)).ravel()


def _lobe(pairs_wi, pairs_wo, reflectance, alpha, eta):
    """The lobe evaluated eagerly (module constants read at call time, unlike a compiled program)."""
    params = {"reflectance": jnp.asarray(reflectance, dtype=float), "conductor_roughness": jnp.asarray(alpha),
              "interface_eta": jnp.asarray(eta)}
    return np.asarray(cc.CoatedConductor()(params, LocalPair.from_dirs(jnp.asarray(pairs_wi), jnp.asarray(pairs_wo))))


@pytest.mark.parametrize("reflectance, alpha, eta", [([0.95, 0.7, 0.4], 0.3, 1.5), ([0.9, 0.5, 0.2], 0.1, 1.5),
                                                     ([0.8, 0.6, 0.99], 0.7, 1.8)])
def test_lobe_is_the_expectation_of_pbrts_walk(reflectance, alpha, eta):
    # Six pairs: near the mirror direction (where the conductor's own highlight, seen through the coat, is), off
    # it, across, forward and near grazing. The walk's mean of 200,000 walks has a standard error of 0.02-0.5 %; the
    # lobe agrees within four of them plus 0.3 % (its rules: test_rules_converge).
    pairs = [(20, 20, 180), (40, 30, 150), (60, 60, 180), (30, 60, 90), (70, 20, 0), (80, 75, 170)]
    eta_c, k_c = reflectance_index(reflectance)
    for ti, to, dphi in pairs:
        wi, wo = _direction(np.radians(ti), 0.0), _direction(np.radians(to), np.radians(dphi))
        mean, se = coated_conductor_f(wo, wi, eta_c, k_c, alpha, eta, walks=200_000, seed=ti + to)
        got = _lobe(wi[None], wo[None], reflectance, alpha, eta)[0]
        assert np.all(np.abs(got - mean) <= 4.0 * se + 3e-3 * mean), (ti, to, dphi, got, mean, se)


@pytest.mark.parametrize("reflectance, alpha, eta, theta_o", [([0.9, 0.6, 0.3], 0.3, 1.5, 30.0),
                                                              ([0.95, 0.7, 0.4], 0.1, 1.5, 60.0),
                                                              ([0.8, 0.6, 0.99], 0.7, 1.8, 45.0)])
def test_pbrts_sampling_walk_has_the_lobes_expectation(reflectance, alpha, eta, theta_o):
    # pbrt-v4 renders f where it samples a light and Sample_f's walk where it samples the BSDF (indirect light, part
    # of area and environment lights); for coateddiffuse the two disagree (docs/export.md). Under a smooth coat the
    # walk's weights f cosθi/pdf, over its samples that leave the coat, average to ∫ f cosθi g dωi of the lobe for
    # any g: here g = 1 (the directional albedo without the mirror), a bump around the mirror direction and a
    # weight on grazing exits, within four standard errors (0.07-0.7 % with 200,000 samples) plus the lobe's
    # 0.3 %. The interface's mirror is sampled with probability R(ωo) and weight 1.
    wo = _direction(np.radians(theta_o), 0.0)
    kind, weight, wi = coated_conductor_sample(wo, *reflectance_index(reflectance), alpha, eta, samples=200_000,
                                               seed=int(theta_o))
    nodes, rule = _cosine_rule(256, 512)
    f = _lobe(nodes, np.broadcast_to(wo, nodes.shape), reflectance, alpha, eta)
    mirror = np.array([-wo[0], -wo[1], wo[2]])
    for g in (lambda d: np.ones(len(d)), lambda d: np.maximum(0.0, d @ mirror) ** 8, lambda d: 1.0 - d[:, 2] ** 2):
        values = np.where((kind == EXIT)[:, None], weight * g(wi)[:, None], 0.0)
        mean, se = values.mean(axis=0), values.std(axis=0) / np.sqrt(len(values))
        expected = (rule * g(nodes)) @ f
        assert np.all(np.abs(mean - expected) <= 4.0 * se + 3e-3 * expected), (mean, se, expected)
    fresnel = dielectric(np.asarray(wo[2]), 1.0, eta, np)
    assert np.mean(kind == MIRROR) == pytest.approx(float(fresnel), abs=4.0 * np.sqrt(fresnel / 200_000))
    np.testing.assert_allclose(weight[kind == MIRROR], 1.0, rtol=1e-12)


@pytest.mark.parametrize("alpha, eta", [(0.05, 1.5), (0.3, 1.5), (1.0, 1.3)])
def test_rules_converge(alpha, eta, monkeypatch):
    # Every rule three times finer (the cosines', the azimuths', the end directions' and the table's): the lobe
    # moves by at most 1 % at any of 2,000 random pairs, 0.05 % in the cosine-weighted norm (its worst case is the
    # sharpest conductor, α = 0.05, whose bounces' sharp azimuthal profile the 64 harmonics resolve least well).
    rng = np.random.default_rng(4)
    ti, to, po = np.arccos(rng.random(2000)), np.arccos(rng.random(2000)), rng.uniform(0, 2 * np.pi, 2000)
    wi, wo = _direction(ti, 0.0 * ti).T, _direction(to, po).T
    reflectance = [0.9, 0.7, 0.4]
    coarse = _lobe(wi, wo, reflectance, alpha, eta)
    for name, value in dict(COSINE_NODES=48, AZIMUTH_NODES=192, END_NODES=97, TABLE_AZIMUTHS=193).items():
        monkeypatch.setattr(cc, name, value)
    fine = _lobe(wi, wo, reflectance, alpha, eta)
    assert np.max(np.abs(coarse - fine) / fine) < 1e-2
    weight = np.cos(ti)[:, None]
    assert np.linalg.norm((coarse - fine) * weight) / np.linalg.norm(fine * weight) < 5e-4


def test_albedo_stays_below_one_and_grows_with_the_metals_reflectance():
    # The directional albedo ∫ f cosθi dωi by a product rule (Gauss-Legendre in cosθi, 128 azimuths): at most 1
    # and ordered by r; for the brightest metal pbrt takes (r = 0.9999) under a nearly smooth conductor, seen from
    # the normal, the coat's two transmissions (0.96 each) and the slab's transmittance are most of what is lost.
    # A rough conductor returns less: its single scattering loses energy, and what it sends beyond the critical
    # angle is trapped for the walk's five visits (0.22 at α = 0.8, the walk's value too).
    wi, weight = _cosine_rule(64, 128)
    for theta_o in np.radians([0.0, 45.0, 80.0]):
        wo = np.broadcast_to(_direction(theta_o, np.pi), wi.shape)
        smooth, rough = (weight @ _lobe(wi, wo, [0.9999, 0.9, 0.5], alpha, 1.5) for alpha in (0.05, 0.8))
        for albedo in (smooth, rough):
            assert np.all(albedo <= 1.0) and albedo[0] > albedo[1] > albedo[2] > 0.0, (theta_o, albedo)
        assert np.all(rough < smooth)
        if theta_o == 0.0:
            assert smooth[0] > 0.9


def test_a_fit_recovers_a_coated_metal():
    truth = brdffit.models.get("coatedconductor", reflectance=[0.9, 0.7, 0.4], conductor_roughness=0.25,
                               interface_eta=1.6)
    data = brdffit.synth.generate(truth, n=3000, noise="relative:0.01", seed=2)
    result = brdffit.fit(data, "coatedconductor")
    assert result.converged
    np.testing.assert_allclose(result.params["reflectance"], [0.9, 0.7, 0.4], rtol=0.01)
    assert float(result.params["conductor_roughness"]) == pytest.approx(0.25, rel=0.02)
    assert float(result.params["interface_eta"]) == pytest.approx(1.6, rel=0.02)


@pytest.mark.parametrize("reflectance, alpha, eta", [([0.9, 0.6, 0.3], 0.2, 1.6), ([0.9999, 0.0, 0.5], 1e-3, 3.0),
                                                     ([0.05, 0.97, 0.4], 1.0, 1.01)])
def test_pbrt_export_is_the_material_as_it_is(reflectance, alpha, eta):
    """pbrt-v4's coatedconductor with the model's own values (round trip): a smooth interface, the metal's index
    from its reflectance, remaproughness false, the slab stated; read back by pbrt-v4's formulas (its
    ``ConductorBxDF::f``, not brdffit's lobe) it evaluates to the model; pbrt's newer ``reflectance`` parameter
    reads back the same."""
    from brdffit.export import export_details
    from brdffit.export import pbrt_reference as pr
    from brdffit.export import terms as tm

    model = brdffit.models.get("coatedconductor", reflectance=reflectance, conductor_roughness=alpha,
                               interface_eta=eta)
    details = export_details(model, "pbrt", name="m")
    assert details.exact and "# exact: " in details.text
    material = pr.parse(details.text)["m"]
    assert material["type"] == "coatedconductor" and material["remaproughness"] is False
    assert (material["interface.roughness"], material["interface.eta"], material["conductor.roughness"]) == (
        0.0, eta, alpha)
    assert material["conductor.eta"] == [1.0, 1.0, 1.0] and min(material["conductor.k"]) >= 0.0
    r = np.asarray(reflectance)
    np.testing.assert_allclose(material["conductor.k"], 2 * np.sqrt(r) / np.sqrt(1 - r), rtol=1e-15)
    assert (material["thickness"], material["albedo"], material["g"], material["maxdepth"], material["nsamples"]) \
        == (0.01, [0.0, 0.0, 0.0], 0.0, 10, 1)
    pairs = tm.deviation_pairs([tm.Peak("half", alpha * eta)], n=600, seed=7, per_peak=600)
    want = np.asarray(tm.evaluate_dirs(model, pairs.wi, pairs.wo))
    # At α = 1e-3 the conductor's D changes by 4θh/α² per radian of θh near its peak: brdffit's half vector and
    # the transcription's normalize(ωi + ωo), equal to rounding (1e-16), give D values 0.3 % apart at the sharpest
    # pairs (f ~ 3,000/sr); elsewhere the two evaluations agree to 1e-10.
    rtol = 1e-10 if alpha >= 0.01 else 5e-3
    np.testing.assert_allclose(pr.evaluate(pr.parse(details.text), "m", pairs.wi, pairs.wo), want, rtol=rtol,
                               atol=1e-14)
    newer = (f'MakeNamedMaterial "n" "string type" [ "coatedconductor" ] "float interface.eta" [ {eta!r} ] '
             f'"rgb reflectance" [ {" ".join(map(repr, reflectance))} ] "float conductor.roughness" [ {alpha!r} ] '
             '"bool remaproughness" [ false ]')
    np.testing.assert_allclose(pr.evaluate(pr.parse(newer), "n", pairs.wi, pairs.wo), want, rtol=rtol, atol=1e-14)


def test_pbrt_reader_refuses_a_rough_coat_and_a_named_metal():
    from brdffit.export import export_details
    from brdffit.export import pbrt_reference as pr
    from brdffit.export import terms as tm

    text = export_details(brdffit.models.get("coatedconductor"), "pbrt", name="m").text
    up = np.array([[0.0, 0.0, 1.0]])
    rough = text.replace('"float interface.roughness" [ 0.0 ]', '"float interface.roughness" [ 0.1 ]')
    with pytest.raises(tm.ExportError, match="interface roughness 0.1, .* cover a smooth interface"):
        pr.evaluate(pr.parse(rough), "m", up, up)
    copper = 'MakeNamedMaterial "c" "string type" [ "coatedconductor" ] "float conductor.roughness" [ 0.2 ]'
    with pytest.raises(tm.ExportError, match="copper's named spectra, is not covered"):
        pr.evaluate(pr.parse(copper), "c", up, up)


def test_pbrt_target_chooses_a_coated_conductor_for_its_data():
    """Data of pbrt-v4's coatedconductor: the pbrt target fits its three models and chooses the coated conductor on
    held-out directions (neither the mix of a diffuse and a conductor nor the coated diffuse dims and narrows a
    metal's highlight as the coat does), recovered and written as pbrt's coatedconductor."""
    from brdffit import select
    from brdffit.export import export_details
    from brdffit.export.pbrt_reference import parse

    truth = dict(reflectance=[0.85, 0.55, 0.25], conductor_roughness=0.15, interface_eta=1.5)
    data = brdffit.synth.generate(brdffit.models.get("coatedconductor", **truth), pattern="half-diff", n=800,
                                  noise="relative:0.01", seed=6)
    selection = select(data, ["lambert"], criterion="heldout", target="pbrt")
    assert selection.chosen == "coatedconductor"
    rows = {row["spec"]: row for row in selection.table}
    assert rows["coatedconductor"]["heldout_error"] < 0.5 * min(rows["pbrt"]["heldout_error"],
                                                              rows["coateddiffuse"]["heldout_error"])
    params = selection.result.params
    np.testing.assert_allclose(params["reflectance"], truth["reflectance"], rtol=0.03)
    assert float(params["conductor_roughness"]) == pytest.approx(truth["conductor_roughness"], rel=0.03)
    assert float(params["interface_eta"]) == pytest.approx(truth["interface_eta"], rel=0.03)
    details = export_details(selection.result, "pbrt")
    assert details.exact and parse(details.text)["material"]["type"] == "coatedconductor"
