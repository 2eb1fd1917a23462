"""A fit for a renderer (`brdffit.select(..., target=)`, ``brdffit fit --for``): the choice is among the target's
own models (exact in it, every parameter in its ranges), the unconstrained choice and its held-out error stay in
the selection beside it, and the export of the choice is exact and in range."""

import json
from pathlib import Path

import numpy as np
import pytest

from brdffit import models, select, synth
from brdffit.cli import EXIT_BAD_INPUT, EXIT_OK, main
from brdffit.export import TARGETS, export_details
from brdffit.export.gltf import read_material

SYNTHETIC = Path(__file__).resolve().parents[1] / "data" / "synthetic"
TRUTH = dict(base_color=[0.6, 0.35, 0.2], metallic=0.0, roughness=0.35, specular=0.9, ior=1.5)


@pytest.fixture(scope="module")
def gltf_data():
    truth = models.get("gltf", **TRUTH)
    return synth.generate(truth, pattern="half-diff", n=3000, noise="relative:0.01", seed=4)


@pytest.fixture(scope="module")
def gltf_selection(gltf_data):
    return select(gltf_data, ["lambert", "lambert+ggx"], criterion="heldout", target="gltf")


def test_target_choice_is_its_model_and_recovers_the_truth(gltf_selection):
    assert gltf_selection.chosen == "gltf" and gltf_selection.target == "gltf"
    result = gltf_selection.result
    assert result.spec == "gltf" and result.n_samples == 3000 * 3  # refitted to all the data, not the screen
    np.testing.assert_allclose(result.params["base_color"], TRUTH["base_color"], rtol=0.02)
    assert float(result.params["roughness"]) == pytest.approx(TRUTH["roughness"], rel=0.03)


def test_unconstrained_choice_and_the_renderers_cost_are_stated(gltf_selection):
    rows = {row["spec"]: row for row in gltf_selection.table}
    assert set(rows) == {"lambert", "lambert+ggx", "gltf"}
    # On data of the glTF material itself, its own model predicts best: the criterion's choice is it too.
    assert gltf_selection.chosen_by_criterion == "gltf"
    assert rows["gltf"]["heldout_error"] < rows["lambert+ggx"]["heldout_error"]
    assert gltf_selection.verdict().startswith("verdict: gltf for gltf: error on unseen directions")
    assert "chosen for gltf" in gltf_selection.summary()


def test_renderers_cost_on_a_material_it_cannot_represent():
    """The README's plastic (Lambert + Cook-Torrance with ks(1 − f0) = 1.34) is brighter at the highlight than
    any in-range glTF dielectric: the verdict names the unconstrained choice and the ratio of the errors."""
    from brdffit import io

    selection = select(io.load(SYNTHETIC / "plastic.h5"), ["lambert", "lambert+cook-torrance"], target="gltf")
    rows = {row["spec"]: row for row in selection.table}
    assert selection.chosen == "gltf" and selection.chosen_by_criterion == "lambert+cook-torrance"
    ratio = rows["gltf"]["heldout_error"] / rows["lambert+cook-torrance"]["heldout_error"]
    assert ratio > 2
    assert f"lambert+cook-torrance, has {rows['lambert+cook-torrance']['heldout_error']:.4g} ({ratio:.2f}x)" in (
        selection.verdict())
    # In range whatever the data: every parameter within the declared (the file's) bounds.
    params, declared = selection.result.params, selection.result.model.param_specs
    for name, value in params.items():
        assert np.all(declared[name].lower <= np.asarray(value)) and np.all(np.asarray(value) <= declared[name].upper)


@pytest.fixture(scope="module")
def mitsuba_fit(gltf_data):
    """``fit(data, target="mitsuba")``: the selection among Mitsuba's own models, made once for the two tests that
    look at it (the held-out criterion's choice for Mitsuba: `test_mitsuba_roughconductor_is_its_own_model`)."""
    from brdffit import fit

    return fit(gltf_data, target="mitsuba")


def test_mitsuba_target_exports_exactly_without_unbounded_values(mitsuba_fit):
    assert mitsuba_fit.spec in TARGETS["mitsuba"].renders
    details = export_details(mitsuba_fit, "mitsuba")
    assert details.exact and "unbounded" not in details.text and "blendbsdf" not in details.text


def _unbounded_slots(text: str) -> set:
    """The parameter names that an exported Mitsuba document writes through an unbounded texture."""
    import re

    return set(re.findall(r'<texture type="srgb" name="(\w+)">\s*<rgb name="color" value="[^"]*"/>\s*'
                          r'<boolean name="unbounded" value="true"/>', text))


def test_mitsuba_roughconductor_is_its_own_model():
    """A metal fitted for Mitsuba is its roughconductor: the target's choice, recovered, written as that one
    plugin, exact, and unbounded only in the complex index's slots (η and k are not reflectances: Mitsuba takes
    them through an unbounded texture)."""
    spec, plugin = "ggx(fresnel=conductor, bounded=true)", "roughconductor"
    truth = dict(ks=[0.95, 0.8, 0.55], alpha=0.18, eta=[0.2, 0.45, 1.3], k=[3.6, 2.5, 2.1])
    data = synth.generate(models.get(spec, **truth), pattern="half-diff", n=2000, noise="relative:0.01", seed=6)
    selection = select(data, ["lambert", "lambert+ggx"], criterion="heldout", target="mitsuba")
    assert selection.chosen == spec
    result = selection.result
    np.testing.assert_allclose(result.params["ks"], truth["ks"], rtol=0.05)
    assert float(result.params["alpha"]) == pytest.approx(truth["alpha"], rel=0.05)
    details = export_details(result, "mitsuba")
    assert details.exact and f'type="{plugin}"' in details.text and "blendbsdf" not in details.text
    assert _unbounded_slots(details.text) <= {"eta", "k"}
    assert '<rgb name="specular_reflectance"' in details.text  # ks in [0, 1]: a plain reflectance


def test_unknown_or_undeclared_target_is_refused(gltf_data):
    with pytest.raises(ValueError, match="no fit can be made for 'json'"):
        select(gltf_data, ["lambert"], target="json")


PBRT_TRUTH = dict(reflectance=[0.6, 0.35, 0.2], amount=0.3, roughness=0.2, eta=[0.25, 0.6, 1.3], k=[3.4, 2.6, 2.0])


@pytest.fixture(scope="module")
def pbrt_data():
    return synth.generate(models.get("pbrt", **PBRT_TRUTH), pattern="half-diff", n=500, noise="relative:0.01",
                          seed=5)


def test_pbrt_target_is_its_mix_recovered_and_written_exactly(pbrt_data):
    """pbrt-v4's model is the mix of a diffuse and a conductor (`brdffit.models.pbrt`): the target's choice,
    recovered from its own data and written as it is. A metal's (η, k) trade off against each other within a
    channel (the Fresnel curve of a large k changes little along a valley of pairs), so the recovery is checked on
    the Fresnel reflectance they give from normal incidence to 85°."""
    from brdffit.export.pbrt_reference import fr_complex, parse

    selection = select(pbrt_data, ["lambert"], criterion="heldout", target="pbrt")
    assert selection.chosen == "pbrt" and selection.target == "pbrt"
    params = selection.result.params
    np.testing.assert_allclose(params["reflectance"], PBRT_TRUTH["reflectance"], rtol=0.02)
    assert float(params["amount"]) == pytest.approx(PBRT_TRUTH["amount"], rel=0.03)
    assert float(params["roughness"]) == pytest.approx(PBRT_TRUTH["roughness"], rel=0.03)
    cos = np.cos(np.radians(np.arange(0.0, 86.0, 5.0)))[:, None]
    np.testing.assert_allclose(fr_complex(cos, params["eta"], params["k"]),
                               fr_complex(cos, PBRT_TRUTH["eta"], PBRT_TRUTH["k"]), rtol=0.01)
    details = export_details(selection.result, "pbrt")
    assert details.exact and parse(details.text)["material"]["type"] == "mix"


COATED_TRUTH = dict(reflectance=[0.55, 0.3, 0.1], roughness=0.12, eta=1.6)


def test_pbrt_target_chooses_a_coated_diffuse_for_its_data():
    """Data of pbrt-v4's coateddiffuse: the pbrt target fits both of its models and chooses the coated diffuse on
    held-out directions (the mix of a diffuse and a k = 0 conductor cannot dim the base by the coat's
    transmittance), recovered and written as pbrt's coateddiffuse."""
    from brdffit.export.pbrt_reference import parse

    data = synth.generate(models.get("coateddiffuse", **COATED_TRUTH), pattern="half-diff", n=800,
                          noise="relative:0.01", seed=6)
    selection = select(data, ["lambert"], criterion="heldout", target="pbrt")
    assert selection.chosen == "coateddiffuse"
    rows = {row["spec"]: row for row in selection.table}
    assert rows["coateddiffuse"]["heldout_error"] < 0.8 * rows["pbrt"]["heldout_error"]
    # Within three of the fit's own standard errors (800 samples with 1% noise leave the blue base, ρ = 0.1 under
    # the coat's reflection, known to ±0.016) and, for the interface, within 3%.
    result = selection.result
    for name, truth in COATED_TRUTH.items():
        error = np.abs(np.asarray(result.params[name]) - truth)
        assert np.all(error < 3.0 * np.asarray(result.stderr[name])), name
    assert float(result.params["roughness"]) == pytest.approx(COATED_TRUTH["roughness"], rel=0.03)
    assert float(result.params["eta"]) == pytest.approx(COATED_TRUTH["eta"], rel=0.03)
    details = export_details(selection.result, "pbrt")
    assert details.exact and parse(details.text)["material"]["type"] == "coateddiffuse"


def test_cli_fit_for_gltf_then_export(tmp_path, monkeypatch):
    """``brdffit fit FILE --for gltf`` with its report, then ``brdffit export --to gltf``. The default candidates
    are cut to Lambert and the plastic's own model, Lambert + Cook-Torrance (as for pbrt below): the free choice
    the report compares with is still the unconstrained truth, and the default selection on this file is
    `tests/test_cli.py::test_quick_start_fit_recovers_the_shipped_plastic`'s."""
    import importlib

    monkeypatch.setattr(importlib.import_module("brdffit.select"), "DEFAULT_CANDIDATES",
                        ("lambert", "lambert+cook-torrance"))
    out = tmp_path / "fit"
    assert main(["fit", str(SYNTHETIC / "plastic.h5"), "--for", "gltf", "--quiet", "--out", str(out)]) == EXIT_OK
    assert (out / "summary.txt").read_text().startswith("verdict: gltf for gltf: ")
    selection = json.loads((out / "selection.json").read_text())
    assert selection["target"] == "gltf"
    # The report's renderer view: the data, the free choice and the glTF fit, with both held-out errors.
    rows = {row["spec"]: row for row in selection["table"]}
    report = (out / "report.md").read_text()
    assert (out / "renderer.png").stat().st_size > 10_000 and "](renderer.png)" in report
    assert "| gltf | direct | exact | 0 | 0 |" in report
    assert selection["chosen_by_criterion"] == "lambert+cook-torrance"
    free = rows[selection["chosen_by_criterion"]]["heldout_error"]
    assert free < rows["gltf"]["heldout_error"]
    target = tmp_path / "plastic.gltf"
    assert main(["export", str(out / "result.h5"), "--to", "gltf", "--quiet", "--out", str(target)]) == EXIT_OK
    written = read_material(target.read_text())
    assert all(0.0 <= v <= 1.0 for v in written["base_color"]) and 1.0 <= written["ior"] <= 3.0


def test_cli_fit_for_pbrt_then_export(tmp_path, monkeypatch):
    """``brdffit fit FILE --for pbrt`` then ``brdffit export --to pbrt``: both succeed and every value written is in
    pbrt-v4's ranges. The default candidates are cut to Lambert here (the selection itself is tested above), so the
    command's path is tested in a few seconds."""
    from brdffit import io
    from brdffit.export.pbrt_reference import parse

    import importlib

    monkeypatch.setattr(importlib.import_module("brdffit.select"), "DEFAULT_CANDIDATES", ("lambert",))
    data = synth.generate(models.get("pbrt", **PBRT_TRUTH), pattern="half-diff", n=300, noise="relative:0.01", seed=2)
    io.save(data, tmp_path / "mix.h5")
    out = tmp_path / "fit"
    argv = ["fit", str(tmp_path / "mix.h5"), "--for", "pbrt", "--quiet", "--no-report", "--out", str(out)]
    assert main(argv) == EXIT_OK
    assert (out / "summary.txt").read_text().startswith("verdict: pbrt for pbrt: ")
    target = tmp_path / "mix.pbrt"
    assert main(["export", str(out / "result.h5"), "--to", "pbrt", "--quiet", "--out", str(target)]) == EXIT_OK
    text = target.read_text()
    assert "# exact: " in text and "approximation" not in text
    materials = parse(text)
    mix, diffuse, conductor = (materials[f"material{part}"] for part in ("", ":diffuse-1", ":conductor-2"))
    assert 0.0 <= mix["amount"] <= 1.0 and all(0.0 <= v <= 1.0 for v in diffuse["reflectance"])
    assert all(1e-3 <= v <= 10.0 for v in conductor["eta"]) and all(0.0 <= v <= 20.0 for v in conductor["k"])
    assert 1e-3 <= conductor["roughness"] <= 1.0 and conductor["remaproughness"] is False


@pytest.mark.parametrize("argv", [["--for", "json"], ["--for", "gltf", "--model", "lambert"]])
def test_cli_refuses_a_target_it_cannot_fit_for(tmp_path, argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        code = main(["fit", str(SYNTHETIC / "plastic.h5"), *argv, "--out", str(tmp_path / "o")])
        raise SystemExit(code)
    assert exit_.value.code == EXIT_BAD_INPUT
    assert "--for" in capsys.readouterr().err


def test_api_fit_for_a_target(gltf_data, mitsuba_fit):
    from brdffit import fit

    assert fit(gltf_data, target="gltf").spec == "gltf"
    assert mitsuba_fit.spec in TARGETS["mitsuba"].renders  # fit(gltf_data, target="mitsuba")
    with pytest.raises(ValueError, match="chooses the model"):
        fit(gltf_data, "lambert", target="gltf")
    with pytest.raises(TypeError, match="needs a model"):
        fit(gltf_data)
