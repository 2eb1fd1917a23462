"""KHR_materials_sheen in the gltf model: the BRDF against an independent NumPy re-derivation of the extension
(tests/reference_brdfs.py), the sheen albedo table against its definition, a refined quadrature and the Enterprise
PBR Shading Model's published table, and a synthetic sheen recovered by a fit."""

import numpy as np
import pytest

import brdffit
import reference_brdfs as ref
from brdffit import fit, models, synth
from brdffit.models import gltf as gm
from brdffit.models.sheen import charlie_distribution, charlie_visibility

BASE = dict(base_color=[0.7, 0.4, 0.15], metallic=0.3, roughness=0.45, specular=0.8, ior=1.6,
            specular_color=[0.9, 0.8, 1.0])
SHEENS = {
    "velvet": dict(sheen_color=[0.8, 0.5, 0.3], sheen_roughness=0.37),
    "sharp, clamped albedo": dict(sheen_color=[1.0, 0.9, 0.95], sheen_roughness=0.12),
    "rough": dict(sheen_color=[0.2, 0.6, 0.4], sheen_roughness=1.0),
    "under a clearcoat": dict(sheen_color=[0.5, 0.5, 0.7], sheen_roughness=0.6, clearcoat=0.4,
                              clearcoat_roughness=0.2),
}

# The Enterprise PBR Shading Model's sheen albedo table (github.com/DassaultSystemes-Technology/
# EnterprisePBRShadingModel, res/pbrlut.hpp, Sheen_E at commit caa87e0, the revision with Estevez & Kulla's Λ that
# KHR_materials_sheen points to): rows at sheenRoughness (i + ½)/16 (α = sheenRoughness²), columns at μ (j + ½)/16.
PUBLISHED = {
    4: [0.8218456506729126, 0.5622840523719788, 0.40967702865600586, 0.30711719393730164, 0.22861593961715698,
        0.171523779630661, 0.12601399421691895, 0.08956242352724075, 0.06517376005649567, 0.045824017375707626,
        0.031210197135806084, 0.020252376794815063, 0.01240608748048544, 0.007095975801348686,
        0.0034258917439728975, 0.001227691536769271],
    8: [0.7417517900466919, 0.5932353734970093, 0.4864296317100525, 0.4136654734611511, 0.35378748178482056,
        0.30031970143318176, 0.25858211517333984, 0.21927706897258759, 0.18758133053779602, 0.1579517275094986,
        0.13387905061244965, 0.11140773445367813, 0.09149481356143951, 0.07323236763477325, 0.056905996054410934,
        0.04181522876024246],
    12: [0.8519750237464905, 0.6969841718673706, 0.5994836688041687, 0.5246270895004272, 0.4638378620147705,
         0.4127595126628876, 0.3678489029407501, 0.32887783646583557, 0.2919199466705322, 0.2596365213394165,
         0.23348666727542877, 0.20735688507556915, 0.18318457901477814, 0.15976014733314514, 0.13943739235401154,
         0.12046696990728378],
    15: [0.8900160193443298, 0.7335103750228882, 0.6401863694190979, 0.5661664605140686, 0.5070709586143494,
         0.4567585289478302, 0.4112672209739685, 0.37068185210227966, 0.3379805088043213, 0.30604782700538635,
         0.2790229022502899, 0.25321924686431885, 0.23038427531719208, 0.20822153985500336, 0.18735115230083466,
         0.16750502586364746],
}


def _albedo(mu, sheen_roughness):
    """brdffit's quadrature of E (the rule its table uses), unclamped."""
    cos_i, cos_h, weights = gm.sheen_quadrature(mu)
    alpha = sheen_roughness ** 2
    brdf = charlie_distribution(cos_h, alpha, np) * charlie_visibility(cos_i, mu, alpha, np)
    return float(np.sum(brdf * cos_i * weights))


def _angles(n=400, seed=12):
    rng = np.random.default_rng(seed)
    return (np.arccos(rng.uniform(0.1, 1.0, n)), rng.uniform(-np.pi, np.pi, n),
            np.arccos(rng.uniform(0.1, 1.0, n)), rng.uniform(-np.pi, np.pi, n))


@pytest.mark.parametrize("sheen", SHEENS.values(), ids=SHEENS.keys())
def test_sheen_matches_the_reference_at_random_directions(sheen):
    params = {**BASE, **sheen}
    angles = _angles()
    got = np.asarray(brdffit.evaluate(models.get("gltf", **params), *angles))
    want = ref.gltf(*angles, **params)
    assert np.all(want > 0)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    # The sheen is there: against the same material without it.
    plain = ref.gltf(*angles, **{k: v for k, v in params.items() if not k.startswith("sheen")})
    assert np.max(np.abs(want / plain - 1.0)) > 0.05


def test_zero_sheen_colour_leaves_the_material_as_it_was():
    angles = _angles(200, seed=3)
    plain = np.asarray(brdffit.evaluate(models.get("gltf", **BASE), *angles))
    for rough in (0.1, 0.5, 1.0):
        with_zero = models.get("gltf", **BASE, sheen_color=[0.0, 0.0, 0.0], sheen_roughness=rough)
        np.testing.assert_array_equal(np.asarray(brdffit.evaluate(with_zero, *angles)), plain)


def test_sheen_keeps_the_material_reciprocal():
    """D_s V_s is symmetric and the albedo scaling takes the smaller weight of both directions; only the
    clearcoat's Fresnel weight (the view's) breaks reciprocity."""
    ti, pi_, to, po = _angles(300, seed=7)
    model = models.get("gltf", **BASE, **SHEENS["velvet"])
    forward = np.asarray(brdffit.evaluate(model, ti, pi_, to, po))
    np.testing.assert_allclose(np.asarray(brdffit.evaluate(model, to, po, ti, pi_)), forward, rtol=1e-12)
    coated = models.get("gltf", **BASE, **SHEENS["under a clearcoat"])
    assert not np.allclose(np.asarray(brdffit.evaluate(coated, ti, pi_, to, po)),
                           np.asarray(brdffit.evaluate(coated, to, po, ti, pi_)))


def test_albedo_table_is_its_stated_definition():
    """The reference computes the table again from the definition the model's docstring states (nodes,
    quadrature rule, clamp), independently of brdffit's code."""
    np.testing.assert_allclose(gm.sheen_albedo_table(), ref.gltf_sheen_table(), rtol=0, atol=1e-13)


@pytest.mark.parametrize("mu", [1e-4, 1 / 31, 0.3, 0.7, 1.0])
def test_albedo_table_against_a_refined_quadrature(mu):
    """At nodes of the table, 4x the quadrature nodes in each direction change E by under 5e-7."""
    mus, rough = gm.sheen_table_nodes()
    j = int(np.argmin(np.abs(mus - mu)))
    picks = [0, 7, 15, 31]
    fine = np.clip(ref.gltf_sheen_albedo(mus[j], rough[picks], cos_nodes=256, phi_nodes=256), 0.0, 1.0)
    np.testing.assert_allclose(gm.sheen_albedo_table()[picks, j], fine, rtol=0, atol=5e-7)


def test_albedo_lookup_interpolates_within_the_stated_error():
    """Bilinear interpolation at the centres of the table's cells against the quadrature there: within 0.011 from
    the third μ cell on, 0.10 in the first two (the module doc's figures)."""
    mus, rough = gm.sheen_table_nodes()
    mu_c = (np.arange(31) + 0.5) / 31
    centres = 0.5 * (rough[[0, 14, 29]] + rough[[1, 15, 30]])
    direct = np.clip(np.stack([ref.gltf_sheen_albedo(m, centres) for m in mu_c], axis=1), 0.0, 1.0)
    lookup = np.stack([np.asarray(gm.sheen_albedo(mu_c, r)) for r in centres])
    assert np.max(np.abs(lookup - direct)[:, 2:]) < 0.011
    assert np.max(np.abs(lookup - direct)[:, :2]) < 0.105
    # At the nodes the lookup is the table.
    np.testing.assert_allclose(np.asarray(gm.sheen_albedo(np.arange(32) / 31, rough[3])), gm.sheen_albedo_table()[3],
                               rtol=0, atol=1e-15)


def test_albedo_agrees_with_the_published_table():
    """The Enterprise PBR table, Monte Carlo estimates in float32, agrees within its noise where its roughness is
    not clamped (sheenRoughness ≥ 0.28)."""
    nodes = (np.arange(16) + 0.5) / 16
    errors = np.array([[_albedo(mu, nodes[i]) - value for mu, value in zip(nodes, row)]
                       for i, row in PUBLISHED.items()])
    assert np.max(np.abs(errors)) < 0.011
    assert np.sqrt(np.mean(errors ** 2)) < 0.003


def test_albedo_is_clamped_where_the_fitted_lambda_exceeds_one():
    mus, rough = gm.sheen_table_nodes()
    assert _albedo(mus[1], 0.1) > 1.3 and gm.sheen_albedo_table()[0, 1] == 1.0
    assert max(_albedo(mu, 0.26) for mu in np.linspace(1e-4, 0.2, 100)) < 1.0
    assert np.all(gm.sheen_albedo_table() <= 1.0) and np.all(gm.sheen_albedo_table() >= 0.0)


def test_sheen_is_recovered_when_freed():
    """A cloth-like glTF material with a sheen; the sheen's colour and roughness are held at 0 unless freed, and
    freed they are recovered from data with 1% noise."""
    truth = models.get("gltf", base_color=[0.45, 0.3, 0.2], metallic=0.0, roughness=0.7, specular=1.0, ior=1.5,
                       sheen_color=[0.8, 0.6, 0.5], sheen_roughness=0.45)
    data = synth.generate(truth, pattern="uniform", n=3000, noise="relative:0.01", seed=2)
    result = fit(data, "gltf", loss="sigma", fixed=["metallic", "specular", "ior"],
                 free=["sheen_color", "sheen_roughness"])
    assert result.converged, result.summary()
    got = result.model.params
    np.testing.assert_allclose(got["sheen_color"], truth.params["sheen_color"], rtol=0.01)
    assert float(got["sheen_roughness"]) == pytest.approx(0.45, rel=0.02)
    np.testing.assert_allclose(got["base_color"], truth.params["base_color"], rtol=0.01)
    assert float(got["roughness"]) == pytest.approx(0.7, rel=0.02)
