"""brdffit.export.blender, verified in Blender itself: the exported script, run by the `bpy` module (Blender 4.2 as a
Python package, the test extra), builds a material that Cycles renders, on the CPU, as `brdffit.render.render_sphere`
renders the model: a unit sphere under brdffit's three default lights seen from +z (tests/clients/render_blender.py;
the comparison is tests/clients/cycles_comparison.py). The mean relative difference over the lit pixels must stay
within 3% (measured: 0.2% for the dielectrics, 0.8% for the metal at these samples; the rest is Cycles' sampling
noise, which halves with four times the samples)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from brdffit import FitResult, models
from brdffit.cli import EXIT_OK, main
from brdffit.export import ExportError, export, export_details
from clients.cycles_comparison import RESOLUTION, brdffit_render, cycles_render, difference

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = ROOT / "data" / "synthetic"
TOLERANCE = 0.03  # mean relative difference over the lit pixels (the bound)
MATERIALS = {
    "rough dielectric": ("blender", dict(base_color=[0.7, 0.4, 0.15], metallic=0.0, roughness=0.4, ior=1.5)),
    "metal": ("blender", dict(base_color=[0.9, 0.6, 0.3], metallic=1.0, roughness=0.3, ior=1.5)),
    "mixed, dense dielectric": ("blender", dict(base_color=[0.2, 0.5, 0.3], metallic=0.3, roughness=0.7, ior=1.8)),
    # A tinted lacquer over a rough red: the coat's energy compensation, layering weight and tint.
    "coated": ("blender(coat=true)", dict(base_color=[0.6, 0.12, 0.08], metallic=0.0, roughness=0.6, ior=1.5,
                                          coat_weight=0.8, coat_roughness=0.25, coat_ior=1.6,
                                          coat_tint=[0.9, 0.8, 0.6])),
}


def _cycles(script_text: str) -> np.ndarray:
    """Cycles' render of an exported material (skips without bpy)."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("Blender's bpy module (PyPI bpy 4.2, brdffit's test and blender extras; Python 3.11) is not "
                    "installed")
    return cycles_render(script_text)


@pytest.mark.parametrize("name", list(MATERIALS))
def test_cycles_renders_the_export_as_brdffit_renders_the_model(name):
    spec, values = MATERIALS[name]
    model = models.get(spec, **values)
    details = export_details(model, "blender", name=name)
    assert details.exact
    cycles, ours = _cycles(details.text), brdffit_render(model)
    assert cycles.shape == ours.shape
    assert difference(cycles, ours) <= TOLERANCE
    # The centre of the sphere faces the viewer, lit by the key and the fill lights: within 0.5% there.
    np.testing.assert_allclose(cycles[RESOLUTION // 2, RESOLUTION // 2], ours[RESOLUTION // 2, RESOLUTION // 2],
                               rtol=0.005)


# A sheen, which Cycles evaluates from Zeltner's table and brdffit from MaterialX's fits of it (`SHEEN_NOTE`): over a
# base, and alone (where the fits' error shows whole). Measured: 0.2% and 0.5% over the bases, 8.0% for the sheen
# alone at roughness 0.5 (the note's bound is 10%).
SHEENED = {
    "tinted sheen over red": (dict(base_color=[0.5, 0.1, 0.1], metallic=0.0, roughness=0.6, ior=1.5, sheen_weight=1.0,
                                   sheen_roughness=0.2, sheen_tint=[0.9, 0.8, 0.7]), TOLERANCE),
    "rough sheen over blue": (dict(base_color=[0.1, 0.1, 0.5], metallic=0.0, roughness=0.6, ior=1.5,
                                   sheen_weight=0.8, sheen_roughness=0.9), TOLERANCE),
    "sheen alone": (dict(base_color=[0.0] * 3, metallic=0.0, roughness=1.0, ior=1.0, sheen_weight=1.0,
                         sheen_roughness=0.5), 0.10),
}


@pytest.mark.parametrize("name", list(SHEENED))
def test_cycles_renders_a_sheen_as_its_note_states(name):
    from brdffit.export.blender import SHEEN_NOTE

    values, bound = SHEENED[name]
    model = models.get("blender(sheen=true)", **values)
    details = export_details(model, "blender", name=name)
    assert not details.exact and f"# approximation: {SHEEN_NOTE}" in details.text
    assert difference(_cycles(details.text), brdffit_render(model)) <= bound


def test_other_models_are_refused_or_fitted():
    source = models.get("lambert+ggx", rho_d=[0.5, 0.3, 0.2], ks=[0.3] * 3, alpha=0.2)
    with pytest.raises(ExportError, match="--for blender"):
        export(source, "blender")
    details = export_details(source, "blender", fit=True)
    assert details.mapped.spec in ("blender", "blender(coat=True)") and not details.exact
    assert "# measured deviation from the source model: " in details.text
    # Blender's dielectric has no specular amplitude of its own (its Fresnel term alone scales the lobe), so a
    # plastic of ks = 0.3 is matched only in part: 0.135 here, below the diffuse part alone's.
    assert details.deviation.rms < 0.2


def test_fit_for_blender_then_export_renders_in_cycles(tmp_path, monkeypatch):
    """The artist's path: the README's plastic fitted for Blender, exported, built by bpy and rendered by Cycles.
    The default candidates are cut to Lambert (as tests/test_fit_for_target.py does for pbrt): the model written is
    the target's own, fitted to all the data whatever the free choice beside it, and the default selection on this
    file is `tests/test_cli.py::test_quick_start_fit_recovers_the_shipped_plastic`'s."""
    import importlib

    monkeypatch.setattr(importlib.import_module("brdffit.select"), "DEFAULT_CANDIDATES", ("lambert",))
    out = tmp_path / "fit"
    assert main(["fit", str(SYNTHETIC / "plastic.h5"), "--for", "blender", "--quiet", "--no-report", "--out",
                 str(out)]) == EXIT_OK
    script = tmp_path / "plastic_blender.py"
    assert main(["export", str(out / "result.h5"), "--to", "blender", "--quiet", "--out", str(script)]) == EXIT_OK
    fitted = FitResult.load(out / "result.h5").model
    assert fitted.spec in ("blender", "blender(coat=True)")
    assert difference(_cycles(script.read_text()), brdffit_render(fitted)) <= TOLERANCE


def test_fit_option_writes_a_sheen_only_where_it_deviates_markedly_less(monkeypatch):
    """The fit option's rule for the forms Blender evaluates approximately (`Target.approximates`): one is written
    only where its deviation is at most `APPROXIMATE_GAIN` times the best exact form's. The fits are stood in for
    by given models (a real one takes 10-20 s each); the deviations are measured as the export measures them."""
    import brdffit.export.refit as refit
    from brdffit.export import APPROXIMATE_GAIN, TARGETS

    base = dict(base_color=[0.45, 0.08, 0.12], metallic=0.0, roughness=0.8, ior=1.5)
    sheen = dict(sheen_weight=0.9, sheen_roughness=0.35)
    # A sheened fabric beside a black Lambert: not the blender lobe alone, so the fit option fits the target's forms.
    source = models.get("blender(sheen=true)+lambert", **base, **sheen, rho_d=[0.0] * 3)
    assert TARGETS["blender"].approximates and APPROXIMATE_GAIN < 1

    def stand_in(weight):
        def fit_exportable(model, seed=0, spec=None):
            values = dict(base, **(dict(sheen, sheen_weight=weight) if "sheen" in spec else {}),
                          **(dict(coat_weight=0.0) if "coat" in spec else {}))
            return models.get(spec, **values), f"# fit: {spec} stood in for a fit"
        return fit_exportable

    monkeypatch.setattr(refit, "fit_exportable", stand_in(0.9))
    details = export_details(source, "blender", fit=True)
    assert details.mapped.spec.startswith("blender(") and "sheen=True" in details.mapped.spec
    assert details.deviation.rms < 1e-6 and not details.exact  # the source's own sheen, with the note
    monkeypatch.setattr(refit, "fit_exportable", stand_in(0.0))  # a sheen of weight 0: no gain
    details = export_details(source, "blender", fit=True)
    assert "sheen" not in details.mapped.spec and not details.exact
