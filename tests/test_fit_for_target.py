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


def test_mitsuba_target_exports_exactly_without_unbounded_values(gltf_data):
    selection = select(gltf_data, ["lambert"], criterion="heldout", target="mitsuba")
    assert selection.chosen in TARGETS["mitsuba"].renders
    details = export_details(selection.result, "mitsuba")
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
    with pytest.raises(ValueError, match="no fit can be made for 'pbrt'"):
        select(gltf_data, ["lambert"], target="pbrt")


def test_cli_fit_for_gltf_then_export(tmp_path):
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
    free = rows[selection["chosen_by_criterion"]]["heldout_error"]
    assert free < rows["gltf"]["heldout_error"]
    target = tmp_path / "plastic.gltf"
    assert main(["export", str(out / "result.h5"), "--to", "gltf", "--quiet", "--out", str(target)]) == EXIT_OK
    written = read_material(target.read_text())
    assert all(0.0 <= v <= 1.0 for v in written["base_color"]) and 1.0 <= written["ior"] <= 3.0


@pytest.mark.parametrize("argv", [["--for", "pbrt"], ["--for", "gltf", "--model", "lambert"]])
def test_cli_refuses_a_target_it_cannot_fit_for(tmp_path, argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        code = main(["fit", str(SYNTHETIC / "plastic.h5"), *argv, "--out", str(tmp_path / "o")])
        raise SystemExit(code)
    assert exit_.value.code == EXIT_BAD_INPUT
    assert "--for" in capsys.readouterr().err


def test_api_fit_for_a_target(gltf_data):
    from brdffit import fit

    assert fit(gltf_data, target="gltf").spec == "gltf"
    assert fit(gltf_data, target="mitsuba").spec in TARGETS["mitsuba"].renders
    with pytest.raises(ValueError, match="chooses the model"):
        fit(gltf_data, "lambert", target="gltf")
    with pytest.raises(TypeError, match="needs a model"):
        fit(gltf_data)
