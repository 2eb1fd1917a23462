"""The ``principled`` lobe against Mitsuba 3's ``principled`` plugin, which it claims to evaluate exactly, and the
round trip ``brdffit synth principled`` -> ``brdffit fit`` -> ``brdffit export --to mitsuba`` read by Mitsuba.

Mitsuba runs in float32 (``scalar_rgb``), brdffit in float64: the comparison is relative, at the 95th percentile of
2,000 direction pairs uniform in solid angle (the largest differences sit where a lobe is steep and float32 rounds
the angles), as the models issue states it.
"""

import numpy as np
import pytest

import brdffit
from brdffit import models
from brdffit.cli import EXIT_OK, main
from brdffit.export import export
from brdffit.export.mitsuba import evaluate_in_mitsuba
from brdffit.export.terms import random_pairs
from brdffit.models.model import evaluate_dirs

TOLERANCE = 1e-4  # relative, 95th percentile (float32 against float64)

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


@pytest.fixture(scope="module")
def mi():
    mitsuba = pytest.importorskip("mitsuba", reason="Mitsuba 3 (test extra) is not installed")
    mitsuba.set_variant("scalar_rgb")
    return mitsuba


def _plugin(params: dict) -> str:
    """The plugin written by hand from the parameters (not through brdffit's export)."""
    colour = ", ".join(str(v) for v in params["base_color"])
    floats = "".join(f'<float name="{k}" value="{v}"/>' for k, v in params.items() if k != "base_color")
    return f'<bsdf version="3.0.0" type="principled"><rgb name="base_color" value="{colour}"/>{floats}</bsdf>'


def _relative(f, g):
    return np.abs(f - g) / np.maximum(np.abs(g), 1e-30)


@pytest.mark.parametrize("name", PARAMETER_SETS)
def test_principled_evaluates_what_mitsuba_evaluates(mi, name):
    params = PARAMETER_SETS[name]
    wi, wo = random_pairs(2000, seed=3)
    f = np.asarray(evaluate_dirs(models.get("principled", **params), wi, wo))
    g = evaluate_in_mitsuba(_plugin(params), wi, wo)
    assert np.all(g >= 0) and np.mean(g > 0) > 0.99
    rel = _relative(f, g)
    assert np.percentile(rel, 95) <= TOLERANCE and np.median(rel) < 1e-6, (np.percentile(rel, 95), rel.max())


def test_synth_fit_export_round_trip(mi, tmp_path):
    """A principled material synthesised, fitted with the CLI, exported to Mitsuba: the parameters come back and
    Mitsuba's plugin, read from the export, evaluates the fitted model. The commands run in this process
    (`brdffit.cli.main`); each has a run as a process of its own in tests/test_memory_limits.py."""
    truth = dict(base_color=[0.6, 0.35, 0.2], roughness=0.35, metallic=0.2, specular=0.5, sheen=0.3,
                 clearcoat=0.4, clearcoat_gloss=0.7)
    data = tmp_path / "principled.h5"
    params = [arg for k, v in truth.items()
              for arg in ("--param", f"{k}={','.join(map(str, v)) if isinstance(v, list) else v}")]
    assert main(["synth", "principled", *params, "--pattern", "half-diff", "--n", "4000", "--noise",
                 "relative:0.005", "--seed", "4", "--out", str(data), "--quiet"]) == EXIT_OK
    assert main(["fit", str(data), "--model", "principled", "--out", str(tmp_path / "fit"), "--no-report",
                 "--quiet"]) == EXIT_OK
    result = brdffit.FitResult.load(tmp_path / "fit" / "result.h5")
    assert result.converged, result.summary()
    np.testing.assert_allclose(np.asarray(result.params["base_color"]), truth["base_color"], rtol=0.02)
    for name in ("roughness", "metallic", "sheen", "clearcoat"):
        assert float(result.params[name]) == pytest.approx(truth[name], rel=0.05, abs=0.01), name
    out = tmp_path / "material.xml"
    assert main(["export", str(tmp_path / "fit" / "result.h5"), "--to", "mitsuba", "--out", str(out)]) == EXIT_OK
    text = out.read_text()
    assert 'type="principled"' in text and "exact" in text and "blendbsdf" not in text
    wi, wo = random_pairs(2000, seed=8)
    f = np.asarray(evaluate_dirs(result.model, wi, wo))
    assert np.percentile(_relative(f, evaluate_in_mitsuba(text, wi, wo)), 95) <= TOLERANCE


def test_a_principled_export_is_written_parameter_for_parameter():
    model = models.get("principled", **PARAMETER_SETS["everything"])
    text = export(model, "mitsuba")
    for name, value in PARAMETER_SETS["everything"].items():
        if name != "base_color":
            assert f'<float name="{name}" value="{value:g}"/>' in text, name
    assert '<rgb name="base_color" value="0.7, 0.4, 0.15"/>' in text
