"""The ``principled`` lobe against Mitsuba 3's ``principled`` plugin, which it claims to evaluate exactly, and the
round trip ``brdffit synth principled`` -> ``brdffit fit`` -> ``brdffit export --to mitsuba`` read by Mitsuba, held
to tests/mitsuba_plugins.py's tolerance.
"""

import numpy as np
import pytest

from brdffit import models
from brdffit.export import export
from mitsuba_plugins import TOLERANCE, both, deviations, relative, synth_fit_export

PARAMETER_SETS = {
    "plastic": dict(base_color=[0.8, 0.4, 0.2], roughness=0.4),
    "tinted anisotropic metal": dict(base_color=[0.3, 0.5, 0.7], roughness=0.25, metallic=0.7, specular=0.6,
                                     spec_tint=0.4, anisotropic=0.5),
    "sheen": dict(base_color=[0.9, 0.2, 0.1], roughness=0.7, sheen=0.8, sheen_tint=0.5),
    "clearcoat": dict(base_color=[0.2, 0.6, 0.3], roughness=0.3, clearcoat=0.9, clearcoat_gloss=0.6, specular=0.3),
    "mirror-like metal": dict(base_color=[0.5, 0.5, 0.5], roughness=0.05, metallic=1.0),
    "everything": dict(base_color=[0.7, 0.4, 0.15], metallic=0.3, roughness=0.45, specular=0.65, spec_tint=0.25,
                       anisotropic=0.6, sheen=0.4, sheen_tint=0.3, clearcoat=0.7, clearcoat_gloss=0.55),
}


def _plugin(params: dict) -> str:
    """The plugin written by hand from the parameters (not through brdffit's export)."""
    colour = ", ".join(str(v) for v in params["base_color"])
    floats = "".join(f'<float name="{k}" value="{v}"/>' for k, v in params.items() if k != "base_color")
    return f'<bsdf version="3.0.0" type="principled"><rgb name="base_color" value="{colour}"/>{floats}</bsdf>'


@pytest.mark.parametrize("name", PARAMETER_SETS)
def test_principled_evaluates_what_mitsuba_evaluates(mi, name):
    params = PARAMETER_SETS[name]
    f, g = both(models.get("principled", **params), _plugin(params), seed=3)
    assert np.all(g >= 0) and np.mean(g > 0) > 0.99
    rel = relative(f, g)
    assert np.percentile(rel, 95) <= TOLERANCE and np.median(rel) < 1e-6, (np.percentile(rel, 95), rel.max())


def test_synth_fit_export_round_trip(mi, tmp_path):
    """A principled material synthesised, fitted with the CLI, exported to Mitsuba: the parameters come back and
    Mitsuba's plugin, read from the export, evaluates the fitted model."""
    truth = dict(base_color=[0.6, 0.35, 0.2], roughness=0.35, metallic=0.2, specular=0.5, sheen=0.3,
                 clearcoat=0.4, clearcoat_gloss=0.7)
    result, text = synth_fit_export(tmp_path, "principled", truth, n=4000)
    assert result.converged, result.summary()
    np.testing.assert_allclose(np.asarray(result.params["base_color"]), truth["base_color"], rtol=0.02)
    for name in ("roughness", "metallic", "sheen", "clearcoat"):
        assert float(result.params[name]) == pytest.approx(truth[name], rel=0.05, abs=0.01), name
    assert 'type="principled"' in text and "exact" in text and "blendbsdf" not in text
    assert np.percentile(deviations(result.model, text, seed=8), 95) <= TOLERANCE


def test_a_principled_export_is_written_parameter_for_parameter():
    model = models.get("principled", **PARAMETER_SETS["everything"])
    text = export(model, "mitsuba")
    for name, value in PARAMETER_SETS["everything"].items():
        if name != "base_color":
            assert f'<float name="{name}" value="{value:g}"/>' in text, name
    assert '<rgb name="base_color" value="0.7, 0.4, 0.15"/>' in text
