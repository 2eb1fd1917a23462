"""brdffit's ``pbrt`` model (pbrt-v4's mix of a diffuse and a conductor) written to pbrt-v4 as it is: the text read
back (`brdffit.export.pbrt_reference.parse`) and evaluated with the NumPy transcription of pbrt-v4's formulas
(`brdffit.export.pbrt_reference`, which shares no code with the model) equals the model, every value is written
inside the ranges pbrt-v4 takes, and the export states itself exact."""

import numpy as np
import pytest

from brdffit import models
from brdffit.export import export_details
from brdffit.export import pbrt_reference as pr
from brdffit.export import terms as tm

# (reflectance, amount, roughness, eta, k): a coloured metal, a dielectric (k = 0), an index below 1, and the
# declared bounds (pbrt's smallest rough α, a mix of the conductor alone and of the diffuse alone).
CASES = [
    ([0.7, 0.4, 0.15], 0.35, 0.3, [0.2, 0.9, 1.45], [3.2, 0.6, 0.0]),
    ([0.5, 0.3, 0.2], 0.08, 0.12, [1.5, 1.5, 1.5], [0.0, 0.0, 0.0]),
    ([0.9, 0.9, 0.9], 0.6, 0.55, [0.05, 0.5, 0.9], [0.0, 1.5, 8.0]),
    ([1.0, 0.0, 0.3], 1.0, 1e-3, [1e-3, 10.0, 2.0], [20.0, 0.0, 4.0]),
    ([0.25, 0.5, 1.0], 0.0, 1.0, [10.0, 3.0, 0.4], [0.0, 20.0, 1.0]),
]


def _model(reflectance, amount, roughness, eta, k):
    return models.get("pbrt", reflectance=reflectance, amount=amount, roughness=roughness, eta=eta, k=k)


def _pairs(roughness):
    """Uniform pairs and pairs near the mirror direction of a GGX lobe of the conductor's width."""
    pairs = tm.deviation_pairs([tm.Peak("half", roughness)], n=600, seed=7, per_peak=600)
    return pairs.wi, pairs.wo


@pytest.mark.parametrize("case", CASES, ids=range(len(CASES)))
def test_export_read_back_by_pbrts_formulas_equals_the_model(case):
    model = _model(*case)
    details = export_details(model, "pbrt", name="m")
    assert details.exact and "# exact: " in details.text and "approximation" not in details.text
    materials = pr.parse(details.text)
    wi, wo = _pairs(case[2])
    want = np.asarray(tm.evaluate_dirs(model, wi, wo))
    got = pr.evaluate(materials, "m", wi, wo)
    assert np.all(want >= 0) and np.max(want) > 1.0 / np.pi * 0.1
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("case", CASES, ids=range(len(CASES)))
def test_every_written_value_is_the_models_own_and_in_pbrts_range(case):
    reflectance, amount, roughness, eta, k = case
    materials = pr.parse(export_details(_model(*case), "pbrt", name="m").text)
    assert set(materials) == {"m", "m:diffuse-1", "m:conductor-2"}
    mix, diffuse, conductor = materials["m"], materials["m:diffuse-1"], materials["m:conductor-2"]
    assert (mix["type"], mix["materials"], mix["amount"]) == ("mix", ["m:diffuse-1", "m:conductor-2"], amount)
    assert diffuse["type"] == "diffuse" and diffuse["reflectance"] == reflectance
    assert conductor["type"] == "conductor" and conductor["remaproughness"] is False
    assert (conductor["eta"], conductor["k"], conductor["roughness"]) == (eta, k, roughness)
    # pbrt-v4's ranges: an albedo RGB in [0, 1] (paramdict.cpp refuses others), unbounded RGB at least 0 (η > 0:
    # FrComplex divides by η), a roughness not below EffectivelySmooth's 1e-3, an amount in [0, 1].
    assert all(0.0 <= v <= 1.0 for v in diffuse["reflectance"]) and 0.0 <= mix["amount"] <= 1.0
    assert all(v > 0.0 for v in conductor["eta"]) and all(v >= 0.0 for v in conductor["k"])
    assert conductor["roughness"] >= 1e-3


def test_the_mix_is_the_convex_combination_of_its_parts():
    """MixMaterial picks materials[1] with probability amount: the model is (1 − t) diffuse + t conductor, each
    evaluated alone by pbrt's formulas."""
    model = _model(*CASES[0])
    materials = pr.parse(export_details(model, "pbrt", name="m").text)
    wi, wo = _pairs(0.3)
    parts = [pr.evaluate(materials, leaf, wi, wo) for leaf in ("m:diffuse-1", "m:conductor-2")]
    np.testing.assert_allclose(0.65 * parts[0] + 0.35 * parts[1], np.asarray(tm.evaluate_dirs(model, wi, wo)),
                               rtol=1e-12)
    np.testing.assert_allclose(parts[0], np.broadcast_to(np.array([0.7, 0.4, 0.15]) / np.pi, parts[0].shape))


def test_reciprocal():
    model = _model(*CASES[2])
    wi, wo = _pairs(0.55)
    np.testing.assert_allclose(np.asarray(tm.evaluate_dirs(model, wi, wo)), np.asarray(tm.evaluate_dirs(model, wo, wi)),
                               rtol=1e-12)


def test_pbrt_model_in_a_sum_is_refused_naming_what_pbrt_takes():
    with pytest.raises(tm.ExportError, match="or the pbrt, coateddiffuse or coatedconductor model alone"):
        export_details(models.get("lambert+pbrt"), "pbrt")


def test_mitsubas_fit_option_fits_a_diffuse_and_a_conductor_to_it():
    """Mitsuba has no height-correlated masking: its fit option (`brdffit.export.refit`) fits it a lambert and a
    conductor GGX lobe, the mix's two parts, and comes close (separable against correlated Smith)."""
    from brdffit.export.refit import exportable_specs

    model = _model(*CASES[0])
    assert exportable_specs(model) == ["lambert+ggx(fresnel=conductor)", "lambert"]
    details = export_details(model, "mitsuba", fit=True)
    assert details.mapped.spec == "lambert+ggx(fresnel=conductor)" and details.deviation.rms < 0.05
